// Several flexidd on one bus (issue 16; docs/architecture.md, "Several daemons"):
//  - three flexidd, each with its own database, key and actuators, fed by rigs, with the
//    command line as separate programs on one udpm group (ttl=0, a random port): every
//    actuator listed, identify on the owner only, a signed request to a non-owner refused,
//    a daemon killed named as not answering, two daemons configured with one actuator each
//    raising the ownership alert once; the dashboard's view of them in-process;
//  - the command line's fan-out against fake daemons on the bus: a duplicate reply, a reply
//    from a daemon not heard of, a reply after the timeout;
//  - `flexid --db A --db B` merging files offline.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <flexid/ownership_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "child_process.h"
#include "cli_process.h"
#include "clients/dashboard/bus.h"
#include "clients/dashboard/live_store.h"
#include "scratch_dir.h"

namespace flexid::testing {
namespace {

using json = nlohmann::json;
using namespace std::chrono_literals;

const std::string kFlexid = FLEXID_BINARY;
const std::string kRig = FLEXID_RIG_BINARY;
const std::string kFlexidd = FLEXIDD_BINARY;

void WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
}

// Polls `check` every 200 ms for up to `limit`; true once it holds.
template <typename F>
bool Eventually(F&& check, std::chrono::seconds limit) {
  const auto end = std::chrono::steady_clock::now() + limit;
  while (std::chrono::steady_clock::now() < end) {
    if (check()) return true;
    std::this_thread::sleep_for(200ms);
  }
  return check();
}

// The rows of a merged --json document (MergedDocument) of one daemon (or file).
std::vector<json> RowsOf(const json& document, const std::string& key, const std::string& source) {
  std::vector<json> out;
  if (!document.is_object() || !document.contains(key)) return out;
  for (const json& row : document[key])
    if (row.value("daemon_id", row.value("database", "")) == source) out.push_back(row);
  return out;
}

json DaemonEntry(const json& document, const std::string& daemon_id) {
  for (const json& entry : document.value("daemons", json::array()))
    if (entry.value("daemon_id", "") == daemon_id) return entry;
  return nullptr;
}

// Three flexidd on one bus, each its own directory (database), key (keys/ID.key, so that
// the command line finds them with --key-dir) and configured actuators.
class Lab {
 public:
  explicit Lab(const std::filesystem::path& scratch) : scratch_(scratch), url_(RandomUrl()) {
    std::filesystem::create_directories(keys());
  }
  ~Lab() {
    for (auto& [id, process] : daemons_)
      if (process->Signal(SIGTERM)) process->Wait(10s);
  }

  std::filesystem::path keys() const { return scratch_ / "keys"; }
  std::filesystem::path Db(const std::string& id) const { return scratch_ / id / "flexid.db"; }
  const std::string& url() const { return url_; }

  void Start(const std::string& id, const std::vector<std::string>& actuators) {
    const std::filesystem::path dir = scratch_ / id;
    std::filesystem::create_directories(dir);
    std::string config = "daemon_id = \"" + id + "\"\ndatabase = \"" + Db(id).string() +
                         "\"\nlcm_url = \"" + url_ + "\"\nlog_file = \"\"\nauth_key_file = \"" +
                         (keys() / (id + ".key")).string() + "\"\n";
    for (const std::string& actuator : actuators)
      config += "[[actuators]]\nid = \"" + actuator + "\"\n";
    WriteText(dir / "flexidd.toml", config);
    daemons_[id] = std::make_unique<ChildProcess>(
        std::vector<std::string>{kFlexidd, "--config", (dir / "flexidd.toml").string()},
        (dir / "flexidd.out").string(), (dir / "flexidd.err").string());
  }

  // Until the daemon answers a request addressed to it.
  bool Ready(const std::string& id) {
    return Eventually(
        [&] { return Flexid("--daemon " + id + " rpc status --timeout 0.3").exit_code == 0; }, 20s);
  }

  void Kill(const std::string& id) {
    daemons_.at(id)->Signal(SIGKILL);
    daemons_.at(id)->Wait(10s);
  }

  ProcessResult Flexid(const std::string& args) const {
    return RunCommand(kFlexid + " --lcm '" + url_ + "' --key-dir '" + keys().string() + "' " + args,
                      scratch_);
  }

  // A rig run of `protocol` for `actuator`, its trial control signed with `owner`'s key.
  std::unique_ptr<ChildProcess> Rig(const std::string& actuator, const std::string& owner,
                                    const std::string& protocol, int64_t start_utime) const {
    return std::make_unique<ChildProcess>(
        std::vector<std::string>{kRig, "--lcm", url_, "--actuator", actuator, "--speed", "100",
                                 "--noise-mm", "0.02", "--trial-control", "--key-file",
                                 (keys() / (owner + ".key")).string(), "--start-utime",
                                 std::to_string(start_utime), "--protocol", protocol},
        (scratch_ / ("rig-" + actuator + ".out")).string(),
        (scratch_ / ("rig-" + actuator + ".err")).string());
  }

  json Json(const std::string& args) const {
    const ProcessResult r = Flexid(args);
    EXPECT_EQ(r.exit_code, 0) << args << "\n" << r.err;
    return json::parse(r.out, nullptr, false);
  }

 private:
  std::filesystem::path scratch_;
  std::string url_;
  std::map<std::string, std::unique_ptr<ChildProcess>> daemons_;
};

// The dashboard's bus adapter and store, in-process on the lab's bus.
class Dashboard {
 public:
  explicit Dashboard(const std::string& url) : lcm_(url), adapter_(lcm_, store_) {
    thread_ = std::thread([this] {
      while (!stop_) adapter_.Poll(50ms);
    });
  }
  ~Dashboard() {
    stop_ = true;
    thread_.join();
  }
  json Actuator(const std::string& id) const {
    const json state = store_.StateJson();
    for (const json& a : state["actuators"])
      if (a.value("id", "") == id) return a;
    return nullptr;
  }

 private:
  lcm::LCM lcm_;
  dashboard::LiveStore store_;
  dashboard::BusAdapter adapter_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

bool Finished(const std::vector<json>& trials, const std::string& actuator, size_t count) {
  size_t done = 0;
  for (const json& t : trials)
    done += t.value("actuator", "") == actuator && t.value("state", "") == "complete" &&
            t.value("samples", 0) > 0;
  return done >= count;
}

TEST(SeveralDaemons, ThreeDaemonsShareOneBus) {
  const ScratchDir scratch;
  Lab lab(scratch.path());
  // S1 is configured on lab-a and on lab-c: an ownership conflict, both record it.
  lab.Start("lab-a", {"S1"});
  lab.Start("lab-b", {"S2"});
  lab.Start("lab-c", {"S3", "S1"});
  for (const char* id : {"lab-a", "lab-b", "lab-c"}) ASSERT_TRUE(lab.Ready(id)) << id;
  Dashboard dashboard(lab.url());

  // The conflict: each of the two raises one alert naming the other, once.
  json alerts;
  auto conflicts = [&](const std::string& daemon) {
    std::vector<json> out;
    for (const json& a : RowsOf(alerts, "alerts", daemon))
      if (a.value("kind", "") == "ownership_conflict") out.push_back(a);
    return out;
  };
  ASSERT_TRUE(Eventually(
      [&] {
        alerts = lab.Json("alerts list --json");
        return conflicts("lab-a").size() == 1 && conflicts("lab-c").size() == 1;
      },
      20s))
      << alerts.dump(1);
  EXPECT_EQ(conflicts("lab-a")[0]["actuator"], "S1");
  EXPECT_NE(conflicts("lab-a")[0]["text"].get<std::string>().find("lab-c"), std::string::npos);
  EXPECT_NE(conflicts("lab-c")[0]["text"].get<std::string>().find("lab-a"), std::string::npos);
  EXPECT_TRUE(conflicts("lab-b").empty());

  // Rigs: S2 two square waves (to identify from), S1 and S3 a step each, meanwhile.
  const int64_t t0 = 1'700'000'000'000'000;
  {
    auto s1 = lab.Rig("S1", "lab-a", "step:level=2,duration=60", t0);
    auto s3 = lab.Rig("S3", "lab-c", "step:level=4,duration=60", t0);
    for (const char* protocol : {"square:level=2,period=220,duty=0.5,cycles=2",
                                 "square:level=8,period=220,duty=0.5,cycles=2"}) {
      const int64_t start =
          std::string(protocol).find("level=2") != std::string::npos ? t0 : t0 + 1'000'000'000;
      auto s2 = lab.Rig("S2", "lab-b", protocol, start);
      ASSERT_TRUE(s2->Wait(60s).has_value());
    }
    ASSERT_TRUE(s1->Wait(60s).has_value());
    ASSERT_TRUE(s3->Wait(60s).has_value());
  }

  // trials list: every daemon's trials, each row naming its daemon; S2 and S3 stored by
  // their owners only.
  json trials;
  ASSERT_TRUE(Eventually(
      [&] {
        trials = lab.Json("trials list --json");
        return Finished(RowsOf(trials, "trials", "lab-b"), "S2", 2) &&
               Finished(RowsOf(trials, "trials", "lab-c"), "S3", 1) &&
               Finished(RowsOf(trials, "trials", "lab-a"), "S1", 1) &&
               !RowsOf(trials, "trials", "lab-c").empty();
      },
      30s))
      << trials.dump(1);
  for (const std::string daemon : {"lab-a", "lab-c"})
    for (const json& t : RowsOf(trials, "trials", daemon)) EXPECT_NE(t["actuator"], "S2") << daemon;
  for (const std::string daemon : {"lab-a", "lab-b"})
    for (const json& t : RowsOf(trials, "trials", daemon)) EXPECT_NE(t["actuator"], "S3") << daemon;
  for (const std::string daemon : {"lab-a", "lab-b", "lab-c"})
    EXPECT_EQ(DaemonEntry(trials, daemon).value("answered", false), true) << daemon;
  const ProcessResult table = lab.Flexid("trials list");
  ASSERT_EQ(table.exit_code, 0) << table.err;
  for (const char* text : {"daemon", "lab-a", "lab-b", "lab-c", "S1", "S2", "S3"})
    EXPECT_NE(table.out.find(text), std::string::npos) << text << "\n" << table.out;

  // actuators: each daemon lists what it records, and nothing it only saw.
  const json actuators = lab.Json("actuators --json");
  std::map<std::string, std::vector<std::string>> listed;
  for (const json& a : actuators["actuators"])
    listed[a["daemon_id"].get<std::string>()].push_back(a["id"].get<std::string>() + ":" +
                                                        a.value("claim", ""));
  EXPECT_EQ(listed["lab-a"], std::vector<std::string>{"S1:configured"});
  EXPECT_EQ(listed["lab-b"], std::vector<std::string>{"S2:configured"});
  EXPECT_EQ(listed["lab-c"], (std::vector<std::string>{"S1:configured", "S3:configured"}));

  // identify S2: on lab-b, found through the actuator, signed with lab-b's key (--key-dir).
  const ProcessResult identified = lab.Flexid("identify --actuator S2 --json --timeout 300");
  ASSERT_EQ(identified.exit_code, 0) << identified.err;
  EXPECT_EQ(json::parse(identified.out).value("version", 0), 1);
  const json models = lab.Json("models list --actuator S2 --json");
  ASSERT_EQ(models["models"].size(), 1u) << models.dump(1);
  EXPECT_EQ(models["models"][0]["daemon_id"], "lab-b");
  // The other daemons stored nothing of S2: no actuator, no trial, no model in their files.
  for (const std::string daemon : {"lab-a", "lab-c"}) {
    const ProcessResult none =
        lab.Flexid("--db '" + lab.Db(daemon).string() + "' models list --actuator S2");
    EXPECT_EQ(none.exit_code, 2) << daemon << ": " << none.out << none.err;
    EXPECT_NE(none.err.find("unknown actuator \"S2\""), std::string::npos) << none.err;
  }

  // A signed request sent to a daemon that does not own the actuator: refused, naming the
  // owner, and nothing changes there.
  const ProcessResult refused = lab.Flexid("--daemon lab-a identify --actuator S2 --timeout 30");
  EXPECT_EQ(refused.exit_code, 2) << refused.out;
  EXPECT_NE(refused.err.find("lab-a does not own actuator \"S2\": flexidd lab-b does"),
            std::string::npos)
      << refused.err;
  // And S1, claimed by two daemons, is not sent to either unasked.
  const ProcessResult ambiguous = lab.Flexid("identify --actuator S1 --timeout 30");
  EXPECT_EQ(ambiguous.exit_code, 2);
  EXPECT_NE(ambiguous.err.find("is claimed by lab-a and lab-c"), std::string::npos)
      << ambiguous.err;

  // Keys by daemon: --key-file ID=PATH signs for that daemon only. lab-a's key given as
  // lab-b's is refused by lab-b, and nothing starts.
  const std::string plain = kFlexid + " --lcm '" + lab.url() + "' ";
  auto key_of = [&](const std::string& id) {
    return "'" + (lab.keys() / (id + ".key")).string() + "'";
  };
  ProcessResult keyed =
      RunCommand(plain + "--key-file lab-b=" + key_of("lab-a") + " trials start --actuator S2",
                 scratch.path());
  EXPECT_EQ(keyed.exit_code, 1) << keyed.out;
  EXPECT_NE(keyed.err.find("lab-b: not authorised: bad signature"), std::string::npos) << keyed.err;
  keyed = RunCommand(plain + "--key-file lab-a=" + key_of("lab-a") + " --key-file lab-b=" +
                         key_of("lab-b") + " trials start --actuator S2 --json",
                     scratch.path());
  ASSERT_EQ(keyed.exit_code, 0) << keyed.err;
  keyed = RunCommand(plain + "--key-file lab-b=" + key_of("lab-b") + " trials stop --actuator S2",
                     scratch.path());
  EXPECT_EQ(keyed.exit_code, 0) << keyed.err;

  // The dashboard: every daemon's actuators on one page, each naming its daemon; S2's model
  // versions from its owner.
  ASSERT_TRUE(Eventually(
      [&] {
        const json s2 = dashboard.Actuator("S2");
        return s2.is_object() && s2["daemon"] == "lab-b" && s2["versions"].is_array() &&
               s2["versions"].size() == 1;
      },
      20s))
      << dashboard.Actuator("S2").dump(1);
  EXPECT_EQ(dashboard.Actuator("S3").value("daemon", json()), "lab-c");
  EXPECT_TRUE(dashboard.Actuator("S1").value("daemon", json()).is_string());

  // lab-c killed: named as not answering within the timeout, the others still listed.
  lab.Kill("lab-c");
  const ProcessResult after = lab.Flexid("--reply-timeout 2 trials list --json");
  ASSERT_EQ(after.exit_code, 0) << after.err;
  const json partial = json::parse(after.out);
  EXPECT_FALSE(RowsOf(partial, "trials", "lab-a").empty());
  EXPECT_FALSE(RowsOf(partial, "trials", "lab-b").empty());
  EXPECT_TRUE(RowsOf(partial, "trials", "lab-c").empty());
  EXPECT_EQ(DaemonEntry(partial, "lab-c").value("answered", true), false) << partial.dump(1);
  EXPECT_NE(after.err.find("lab-c did not answer within 2 s"), std::string::npos) << after.err;
  const ProcessResult human = lab.Flexid("--reply-timeout 2 actuators");
  ASSERT_EQ(human.exit_code, 0) << human.err;
  EXPECT_NE(human.out.find("S2"), std::string::npos) << human.out;
  EXPECT_NE(human.err.find("lab-c did not answer"), std::string::npos) << human.err;
}

// ========================================================================================
// The command line against fake daemons: the replies a real flexidd does not send.

// Answers "trials" as three daemons would, badly: lab-a announces itself and answers twice,
// ghost answers without ever announcing itself, lab-late announces itself and answers after
// the command line's timeout.
class FakeDaemons {
 public:
  FakeDaemons(const std::string& url, std::chrono::milliseconds late_by)
      : lcm_(url), late_by_(late_by) {
    lcm_.subscribeFunction("FLEXID/RPC/REQUEST", &FakeDaemons::OnRequest, this);
    thread_ = std::thread([this] {
      while (!stop_) {
        lcm_.handleTimeout(10);
        std::lock_guard lock(mutex_);
        const auto now = std::chrono::steady_clock::now();
        for (auto it = due_.begin(); it != due_.end();) {
          if (it->first > now) {
            ++it;
            continue;
          }
          lcm_.publish(it->second.first, &it->second.second);
          it = due_.erase(it);
        }
      }
    });
  }
  ~FakeDaemons() {
    stop_ = true;
    thread_.join();
  }
  bool good() { return lcm_.good(); }

 private:
  void Announce(const std::string& daemon_id) {
    flexid::ownership_t a{};
    a.utime = bus::WallClockUtime();
    a.daemon_id = daemon_id;
    a.instance_id = "fake-" + daemon_id;
    a.num_claims = 0;
    a.num_peers = 0;
    lcm_.publish("FLEXID/OWNERSHIP", &a);
  }
  static flexid::rpc_reply_t Reply(const flexid::rpc_request_t& request, const std::string& daemon,
                                   const std::string& actuator) {
    flexid::rpc_reply_t reply;
    reply.utime = bus::WallClockUtime();
    reply.request_id = request.request_id;
    reply.daemon_id = daemon;
    reply.status = flexid::rpc_reply_t::kOk;
    reply.result_json = json::array({{{"id", 1},
                                      {"actuator", actuator},
                                      {"protocol", "step"},
                                      {"start_utime", 1'700'000'000'000'000},
                                      {"end_utime", 1'700'000'060'000'000},
                                      {"state", "complete"},
                                      {"samples", 600}}})
                            .dump();
    return reply;
  }
  static void OnRequest(const lcm::ReceiveBuffer* rbuf, const std::string&, FakeDaemons* self) {
    flexid::rpc_request_t request;
    if (request.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    self->Announce("lab-a");
    self->Announce("lab-late");
    const std::string channel = "FLEXID/RPC/REPLY/" + request.client_id;
    const flexid::rpc_reply_t first = Reply(request, "lab-a", "S1");
    self->lcm_.publish(channel, &first);
    self->lcm_.publish(channel, &first);  // the duplicate
    const flexid::rpc_reply_t ghost = Reply(request, "ghost", "G1");
    self->lcm_.publish(channel, &ghost);
    std::lock_guard lock(self->mutex_);
    self->due_.emplace(std::chrono::steady_clock::now() + self->late_by_,
                       std::make_pair(channel, Reply(request, "lab-late", "L1")));
  }

  lcm::LCM lcm_;
  std::chrono::milliseconds late_by_;
  std::mutex mutex_;
  std::multimap<std::chrono::steady_clock::time_point, std::pair<std::string, flexid::rpc_reply_t>>
      due_;
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

TEST(SeveralDaemonsCli, DuplicateUnknownAndLateRepliesAreHandled) {
  const ScratchDir scratch;
  const std::string url = RandomUrl();
  FakeDaemons fakes(url, 2500ms);
  if (!fakes.good()) GTEST_SKIP() << "no LCM multicast on this host (" << url << ")";
  const ProcessResult r = RunCommand(
      kFlexid + " --lcm '" + url + "' --reply-timeout 1 trials list --json", scratch.path());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json doc = json::parse(r.out);
  // The duplicate counted once; the unknown daemon's row kept and marked; the late one not
  // taken, its daemon named as not answering.
  EXPECT_EQ(RowsOf(doc, "trials", "lab-a").size(), 1u) << doc.dump(1);
  EXPECT_EQ(RowsOf(doc, "trials", "ghost").size(), 1u);
  EXPECT_TRUE(RowsOf(doc, "trials", "lab-late").empty());
  EXPECT_EQ(DaemonEntry(doc, "lab-a").value("answered", false), true);
  EXPECT_EQ(DaemonEntry(doc, "ghost").value("announced", true), false);
  EXPECT_EQ(DaemonEntry(doc, "lab-late").value("answered", true), false);
  const std::string notes = doc["notes"].dump();
  EXPECT_NE(notes.find("1 duplicate reply from lab-a ignored"), std::string::npos) << notes;
  EXPECT_NE(notes.find("ghost answered but was not heard of on the bus"), std::string::npos)
      << notes;
  EXPECT_NE(notes.find("lab-late did not answer within 1 s"), std::string::npos) << notes;
  // The same on stderr for a person, and the mark in the table.
  const ProcessResult human =
      RunCommand(kFlexid + " --lcm '" + url + "' --reply-timeout 1 trials list", scratch.path());
  ASSERT_EQ(human.exit_code, 0) << human.err;
  EXPECT_NE(human.out.find("ghost (not announced)"), std::string::npos) << human.out;
  EXPECT_EQ(human.out.find("L1"), std::string::npos) << human.out;
  EXPECT_NE(human.err.find("flexid: note: lab-late did not answer within 1 s"), std::string::npos)
      << human.err;
}

// ========================================================================================
// Offline: several --db files merged.

TEST(SeveralDaemonsCli, OfflineMergesDatabaseFiles) {
  const ScratchDir scratch;
  std::string csv = "t_s,voltage_V,deflection_mm\n";
  for (int k = 0; k < 300; ++k)
    csv += std::to_string(0.1 * k) + "," + (k >= 20 ? "2" : "0") + "," +
           std::to_string(k >= 20 ? 0.01 * (k - 20) : 0.0) + "\n";
  WriteText(scratch.File("rec.csv"), csv);
  const std::string a = scratch.File("A.db"), b = scratch.File("B.db");
  auto offline = [&](const std::string& args) {
    return RunCommand(kFlexid + " " + args, scratch.path());
  };
  for (const auto& [db, actuator] : {std::pair{a, "S1"}, std::pair{b, "S2"}}) {
    const ProcessResult imported = offline("--db '" + db + "' trials import '" +
                                           scratch.File("rec.csv") + "' --actuator " + actuator);
    ASSERT_EQ(imported.exit_code, 0) << imported.err;
  }
  const ProcessResult list = offline("--db '" + a + "' --db '" + b + "' trials list --json");
  ASSERT_EQ(list.exit_code, 0) << list.err;
  const json doc = json::parse(list.out);
  ASSERT_EQ(RowsOf(doc, "trials", a).size(), 1u) << doc.dump(1);
  ASSERT_EQ(RowsOf(doc, "trials", b).size(), 1u);
  EXPECT_EQ(RowsOf(doc, "trials", a)[0]["actuator"], "S1");
  EXPECT_EQ(RowsOf(doc, "trials", b)[0]["actuator"], "S2");
  EXPECT_EQ(doc["databases"].size(), 2u);
  const ProcessResult table = offline("--db '" + a + "' --db '" + b + "' actuators");
  ASSERT_EQ(table.exit_code, 0) << table.err;
  EXPECT_NE(table.out.find("database"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("A.db"), std::string::npos) << table.out;
  EXPECT_NE(table.out.find("B.db"), std::string::npos) << table.out;
  // Trial 1 is in both files: which one is meant must be said.
  const ProcessResult show = offline("--db '" + a + "' --db '" + b + "' trials show 1");
  EXPECT_EQ(show.exit_code, 2);
  EXPECT_NE(show.err.find("trial 1 is in"), std::string::npos) << show.err;
}

}  // namespace
}  // namespace flexid::testing
