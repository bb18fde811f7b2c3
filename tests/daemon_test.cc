// End to end: flexidd in-process on real LCM (udpm, ttl=0, a random port) and a real
// SQLite file, with the real flexid-rig binary publishing trials.
#include "daemon/daemon.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <flexid/alert_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/lcm_url.h"
#include "cli_process.h"
#include "lcmtypes/message_auth.h"
#include "model/core/model_file.h"
#include "model/core/presets.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;

const std::string kRig = FLEXID_RIG_BINARY;
const std::string kFlexid = FLEXID_BINARY;

std::string RandomUrl() {
  std::random_device device;
  std::uniform_int_distribution<int> port(20000, 60000);
  return "udpm://239.255.76.67:" + std::to_string(port(device)) + "?ttl=0";
}

// Listens to predictions, alerts and RPC replies of the daemon under test.
class Listener {
 public:
  explicit Listener(const std::string& url) : lcm_(url) {
    lcm_.subscribeFunction("FLEXID/.*/PREDICTION", &Listener::OnPrediction, this)
        ->setQueueCapacity(1 << 17);
    lcm_.subscribeFunction("FLEXID/ALERT", &Listener::OnAlert, this)->setQueueCapacity(1000);
    lcm_.subscribeFunction("FLEXID/RPC/REPLY/daemon_test", &Listener::OnReply, this)
        ->setQueueCapacity(100);
  }
  bool good() { return lcm_.good(); }
  void Pump(std::chrono::milliseconds duration) {
    const auto end = std::chrono::steady_clock::now() + duration;
    while (std::chrono::steady_clock::now() < end) lcm_.handleTimeout(20);
  }
  // Sends a request and waits for its reply. A busy worker (the policy's own diagnosis of
  // a trial that raised an alert, [policy] on_alert = diagnose) is asked again within the
  // timeout, as the command line does.
  std::optional<flexid::rpc_reply_t> Call(const std::string& method, const nlohmann::json& args,
                                          std::chrono::seconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (true) {
      flexid::rpc_request_t request;
      request.request_id = "r" + std::to_string(++requests_);
      request.client_id = "daemon_test";
      request.method = method;
      request.args_json = args.dump();
      if (key && auth::ChangesData(method)) {  // signed with the daemon's key
        request.utime = bus::WallClockUtime();
        auth::Sign(*key, &request);
      }
      reply_.reset();
      lcm_.publish("FLEXID/RPC/REQUEST", &request);
      while (std::chrono::steady_clock::now() < end &&
             (!reply_ || reply_->request_id != request.request_id))
        lcm_.handleTimeout(20);
      if (!reply_ || reply_->status != flexid::rpc_reply_t::kBusy ||
          std::chrono::steady_clock::now() >= end)
        return reply_;
      Pump(std::chrono::milliseconds(200));
    }
  }
  std::vector<flexid::prediction_t> predictions;
  std::vector<flexid::alert_t> alerts;
  std::optional<auth::Key> key;  // signs the requests that change data

 private:
  static void OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string&, Listener* self) {
    flexid::prediction_t p;
    if (p.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0)
      self->predictions.push_back(p);
  }
  static void OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string&, Listener* self) {
    flexid::alert_t a;
    if (a.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0) self->alerts.push_back(a);
  }
  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string&, Listener* self) {
    flexid::rpc_reply_t r;
    if (r.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0) self->reply_ = r;
  }
  lcm::LCM lcm_;
  std::optional<flexid::rpc_reply_t> reply_;
  int requests_ = 0;
};

// flexidd's configuration for a test: its own file, bus and name, no log file.
daemon::Config TestConfig(const std::string& database, const std::string& url,
                          const std::string& daemon_id) {
  daemon::Config config;
  config.database = database;
  config.lcm_url = url;
  config.log_file = "";
  config.daemon_id = daemon_id;
  return config;
}

class DaemonEndToEnd : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = RandomUrl();
    listener_ = std::make_unique<Listener>(url_);
    if (!listener_->good()) GTEST_SKIP() << "no LCM multicast on this host (" << url_ << ")";
    const daemon::Config config = TestConfig(scratch_.File("flexid.db"), url_, "test");
    daemon::Validate(config);
    daemon_ = std::make_unique<daemon::Daemon>(config);
    key_file_ = daemon::KeyFilePath(config);
    listener_->key = auth::ReadKeyFile(key_file_);
    running_ = true;
    loop_ = std::thread([this] {
      while (running_) daemon_->RunOnce(20);
    });
  }
  void TearDown() override {
    running_ = false;
    if (loop_.joinable()) loop_.join();
  }
  // Runs the rig binary to completion (message time advances 200 x faster than real time);
  // each run starts in message time after the previous one ended.
  void Rig(const std::string& protocol, double duration_s, const std::string& extra = "") {
    const auto r = testing::RunCommand(
        kRig + " --lcm '" + url_ + "' --actuator S1 --protocol " + protocol +
            " --speed 200 --noise-mm 0.02 --trial-control --key-file '" + key_file_ +
            "' --start-utime " + std::to_string(next_utime_) + " " + extra,
        scratch_.path());
    ASSERT_EQ(r.exit_code, 0) << r.err;
    next_utime_ += static_cast<int64_t>((duration_s + 60.0) * 1e6);
  }
  int64_t next_utime_ = 1'000'000'000'000;
  std::string key_file_;
  testing::ScratchDir scratch_;
  std::string url_;
  std::unique_ptr<Listener> listener_;
  std::unique_ptr<daemon::Daemon> daemon_;
  std::atomic<bool> running_{false};
  std::thread loop_;
};

TEST_F(DaemonEndToEnd, RecordsIdentifiesPredictsAndFlagsBackRelaxation) {
  // Two trials of the seed's actuator: 2 V and 8 V square waves, 220 s period, 2 cycles.
  Rig("square:level=2,period=220,duty=0.5,cycles=2", 440);
  Rig("square:level=8,period=220,duty=0.5,cycles=2", 440);
  listener_->Pump(1000ms);
  const auto recorded = daemon_->counters();
  EXPECT_EQ(
      recorded.rejected_malformed + recorded.rejected_nonfinite + recorded.rejected_out_of_order,
      0);
  {
    storage::Database db = storage::Database::Open(scratch_.File("flexid.db"));
    const auto trials = db.Trials(std::string("S1"));
    for (const auto& t : trials)
      std::cout << "trial " << t.id << " " << t.protocol << " " << storage::TrialStateName(t.state)
                << " samples " << t.samples << " " << t.start_utime << ".." << t.end_utime << "\n";
    ASSERT_EQ(trials.size(), 2u);
    for (const auto& t : trials) {
      EXPECT_EQ(t.state, storage::TrialState::kComplete);
      EXPECT_GT(t.samples, 4000);  // 440 s at 10 Hz, minus what UDP dropped
    }
  }
  // Identify on both trials: a two-level T-S model becomes active.
  const auto reply = listener_->Call("identify", {{"actuator", "S1"}, {"latest", 2}}, 60s);
  ASSERT_TRUE(reply.has_value()) << "no reply to identify";
  ASSERT_EQ(reply->status, flexid::rpc_reply_t::kOk) << reply->error;
  const auto result = nlohmann::json::parse(reply->result_json);
  EXPECT_EQ(result["version"], 1);
  EXPECT_EQ(result["model"]["kind"], "ts_fuzzy");
  listener_->Pump(300ms);
  bool announced = false;
  for (const auto& a : listener_->alerts)
    announced = announced || (a.kind == "model_changed" && a.severity == 0);
  EXPECT_TRUE(announced) << "the new model was not announced on FLEXID/ALERT";

  // A fresh 2 V trial: the predictions track the measurement.
  listener_->predictions.clear();
  listener_->alerts.clear();
  Rig("square:level=2,period=220,duty=0.5,cycles=2", 440);
  listener_->Pump(1000ms);
  ASSERT_GT(listener_->predictions.size(), 4000u);
  double sum_sq = 0.0, peak = 0.0;
  for (const auto& p : listener_->predictions) {
    EXPECT_EQ(p.model_version, 1);
    sum_sq += p.residual_mm * p.residual_mm;
    peak = std::max(peak, std::abs(p.measured_mm));
  }
  const double rms = std::sqrt(sum_sq / static_cast<double>(listener_->predictions.size()));
  EXPECT_LT(rms, 0.02 * peak) << "residual RMS " << rms << " mm, peak " << peak << " mm";
  for (const auto& a : listener_->alerts) EXPECT_NE(a.kind, "back_relaxation") << a.text;

  // The same trial with back-relaxation switched on in the rig: an alert names it.
  listener_->alerts.clear();
  Rig("square:level=2,period=220,duty=0.5,cycles=2", 440,
      "--effect back_relaxation:fraction=0.3,tau=60");
  listener_->Pump(1000ms);
  bool flagged = false;
  for (const auto& a : listener_->alerts) flagged = flagged || a.kind == "back_relaxation";
  EXPECT_TRUE(flagged) << listener_->alerts.size() << " alerts, none of kind back_relaxation";

  // Diagnosis of that stored trial against the active model names the effect, in the reply
  // and in an alert of its kind.
  listener_->alerts.clear();
  const auto diagnosis = listener_->Call("diagnose", {{"actuator", "S1"}}, 60s);
  ASSERT_TRUE(diagnosis.has_value()) << "no reply to diagnose";
  ASSERT_EQ(diagnosis->status, flexid::rpc_reply_t::kOk) << diagnosis->error;
  const auto found = nlohmann::json::parse(diagnosis->result_json);
  EXPECT_EQ(found["verdict"], "back_relaxation") << found.dump(2);
  EXPECT_EQ(found["model_version"], 1);
  ASSERT_FALSE(found["findings"].empty());
  EXPECT_LT(found["findings"][0]["heldout_rmse_after_mm"].get<double>(),
            0.5 * found["findings"][0]["heldout_rmse_before_mm"].get<double>());
  listener_->Pump(300ms);
  bool named = false;
  // The effects the finding's rivals name are in its alert, and only they.
  const nlohmann::json rivals = found["findings"][0].value("rivals", nlohmann::json::array());
  for (const auto& a : listener_->alerts) {
    if (a.kind != "back_relaxation" || a.text.rfind("trial ", 0) != 0) continue;
    named = true;
    EXPECT_EQ(a.text.find("also claimed on its own") != std::string::npos, !rivals.empty())
        << a.text;
    for (const auto& r : rivals)
      EXPECT_NE(a.text.find(r["effect"].get<std::string>()), std::string::npos) << a.text;
  }
  EXPECT_TRUE(named) << "no alert names the diagnosed effect";
  // Bad arguments are refused with the argument named.
  const auto bad = listener_->Call("diagnose", {{"actuator", "S1"}, {"trial", "x"}}, 10s);
  ASSERT_TRUE(bad.has_value());
  EXPECT_EQ(bad->status, flexid::rpc_reply_t::kBadRequest);
  EXPECT_NE(bad->error.find("trial"), std::string::npos) << bad->error;
}

// Counts what arrives on the channels it subscribes to, by channel.
struct ChannelCounter {
  std::map<std::string, int64_t> by_channel;
  void On(const lcm::ReceiveBuffer*, const std::string& channel) { ++by_channel[channel]; }
  int64_t Total() const {
    int64_t n = 0;
    for (const auto& [channel, count] : by_channel) n += count;
    return n;
  }
};

// Runs a daemon's loop on a thread of its own until destroyed, however the test ends (an
// ASSERT returns early).
class LoopThread {
 public:
  explicit LoopThread(daemon::Daemon& daemon)
      : thread_([this, &daemon] {
          while (running_) daemon.RunOnce(20);
        }) {}
  ~LoopThread() {
    running_ = false;
    thread_.join();
  }
  LoopThread(const LoopThread&) = delete;
  LoopThread& operator=(const LoopThread&) = delete;

 private:
  std::atomic<bool> running_{true};
  std::thread thread_;
};

// flexidd with a channel prefix of its own, holding a '.' (which a subscription reads as a
// regular expression): the rig, `flexid trials import` and the command line's RPC reach it
// when given --channel-prefix, and nothing is published on, or answered from, FLEXID/.
TEST(DaemonChannelPrefix, RigImportAndCommandLineFollowThePrefix) {
  const testing::ScratchDir scratch;
  const std::string url = RandomUrl();
  const bus::Channels channels("lab.7");
  // flexidd's receive buffer: this thread does not read while the commands below run, and
  // the default one overflows with their samples and predictions (seen: 16 of 200 lost).
  lcm::LCM lcm(bus::WithReceiveBuffer(url, 8388608));
  if (!lcm.good()) GTEST_SKIP() << "no LCM multicast on this host (" << url << ")";
  ChannelCounter predictions, standard;
  lcm.subscribe(channels.AllPredictions(), &ChannelCounter::On, &predictions)
      ->setQueueCapacity(1 << 14);
  lcm.subscribe("FLEXID/.*", &ChannelCounter::On, &standard)->setQueueCapacity(1 << 14);

  daemon::Config config = TestConfig(scratch.File("flexid.db"), url, "prefixed");
  config.channel_prefix = "lab.7";
  daemon::Validate(config);
  daemon::Daemon daemon(config);
  const std::string key_file = daemon::KeyFilePath(config);
  const LoopThread loop(daemon);
  const auto pump = [&](std::chrono::milliseconds duration) {
    const auto end = std::chrono::steady_clock::now() + duration;
    while (std::chrono::steady_clock::now() < end) lcm.handleTimeout(20);
  };
  const std::string flexid = kFlexid + " --lcm '" + url + "' --key-file '" + key_file + "' ";

  // The rig on lab.7/S1/...: 300 samples in a trial of its own.
  const auto rig = testing::RunCommand(
      kRig + " --lcm '" + url + "' --channel-prefix lab.7 --actuator S1 --protocol " +
          "step:level=2,duration=30 --speed 100 --noise-mm 0.02 --trial-control --key-file '" +
          key_file + "' --start-utime 1000000000000",
      scratch.path());
  EXPECT_EQ(rig.exit_code, 0) << rig.err;
  pump(1000ms);
  EXPECT_GT(predictions.by_channel["lab.7/S1/PREDICTION"], 250);  // UDP may drop a few

  // `trials import` replays a recording onto lab.7/S2/... and reads its progress over RPC.
  const std::string csv = scratch.File("s2.csv");
  const auto recording = testing::RunCommand(
      kRig + " --out '" + csv + "' --protocol step:level=3,duration=20 --noise-mm 0.02",
      scratch.path());
  ASSERT_EQ(recording.exit_code, 0) << recording.err;
  const auto import = testing::RunCommand(flexid + "--channel-prefix lab.7 trials import '" + csv +
                                              "' --actuator S2 --start-utime 2000000000000 --json",
                                          scratch.path());
  ASSERT_EQ(import.exit_code, 0) << import.err;
  const auto imported = nlohmann::json::parse(import.out);
  ASSERT_EQ(imported.at("trials").size(), 1u) << import.out;
  EXPECT_EQ(imported["trials"][0].at("samples"), 200) << import.out;
  // The last predictions may still be on their way on a busy machine: up to 3 s for them.
  for (int i = 0; i < 30 && predictions.by_channel["lab.7/S2/PREDICTION"] < 190; ++i) pump(100ms);
  EXPECT_GE(predictions.by_channel["lab.7/S2/PREDICTION"], 190);

  // Read-only RPC through the same prefix: both trials are listed by flexidd.
  const auto list =
      testing::RunCommand(flexid + "trials list --json --channel-prefix lab.7", scratch.path());
  ASSERT_EQ(list.exit_code, 0) << list.err;
  const auto trials = nlohmann::json::parse(list.out)["trials"];
  ASSERT_EQ(trials.size(), 2u) << list.out;
  for (const auto& t : trials) EXPECT_EQ(t.at("state"), "complete") << list.out;

  // Nothing went to FLEXID/ (a status heartbeat would have by now), and on the default
  // prefix nobody answers: only the request itself is heard there.
  pump(1200ms);
  EXPECT_EQ(standard.Total(), 0) << standard.by_channel.begin()->first;
  const auto unprefixed = testing::RunCommand(flexid + "rpc status --timeout 1", scratch.path());
  EXPECT_EQ(unprefixed.exit_code, 1) << unprefixed.out;
  EXPECT_NE(unprefixed.err.find("no flexidd answered"), std::string::npos) << unprefixed.err;
  pump(200ms);
  EXPECT_EQ(standard.by_channel["FLEXID/RPC/REQUEST"], 1);  // the subscription does hear
  EXPECT_EQ(standard.Total(), 1) << standard.by_channel.rbegin()->first;
  const auto bad_prefix =
      testing::RunCommand(flexid + "--channel-prefix 'lab/7' rpc status", scratch.path());
  EXPECT_EQ(bad_prefix.exit_code, 2) << bad_prefix.err;
  EXPECT_NE(bad_prefix.err.find(bus::kPrefixRule), std::string::npos) << bad_prefix.err;
}

// A model identified from noise-free rig data: the rig's own model with its gains off by
// 1 part in 10^5 (identification never returns the truth exactly), with the tiny fit RMSE
// such data gives. On the rig's clean samples the residual is that model error, ~1e-4 mm
// at the 2 V plateau: nothing a sensor resolves. Without a floor under sigma, S1 (RMSE
// 1e-5 mm, taken as the noise) would raise a critical alert every hold (issue 15: "beyond
// 0.000 mm ... sigma 0.0000 mm"), and S2 (RMSE 0: sigma estimated, ~1e-7 mm from this
// smooth residual) would stay in its warm-up for 1200 s and then do the same. Floored at
// alerts.sigma_floor_mm (model/diagnose/monitor.h) both get finite thresholds and raise nothing.
TEST(DaemonSigmaFloor, ModelsWithNoNoiseRaiseNoAlertsOnTheirOwnCleanData) {
  const testing::ScratchDir scratch;
  const std::string url = RandomUrl();
  Listener listener(url);
  if (!listener.good()) GTEST_SKIP() << "no LCM multicast on this host (" << url << ")";
  const daemon::Config config = TestConfig(scratch.File("flexid.db"), url, "floor");
  daemon::Validate(config);
  model::TsModel identified = model::SeedTsModel();
  for (model::LocalModel& rule : identified.rules)
    for (double& b_k : rule.tf.num) b_k *= 1.00001;
  for (const auto& [actuator, rmse_mm] : {std::pair{"S1", 1e-5}, std::pair{"S2", 0.0}}) {
    storage::ModelRecord record;
    record.actuator_id = actuator;
    record.model_json = model::ModelToJson(model::FromTsModel(identified)).dump();
    record.fit_json = nlohmann::json{{"fit_percent", 100.0}, {"rmse_mm", rmse_mm}}.dump();
    record.active = true;
    storage::Database::Open(config.database).StoreModel(record);
  }
  daemon::Daemon daemon(config);
  const std::string key_file = daemon::KeyFilePath(config);
  const LoopThread loop(daemon);

  // 660 s of 2 V square wave on both, without noise. S2's warm-up ends at the first block
  // after 120 s of usable residual (its estimate is far below the floor), and the
  // detectors run for the rest.
  const auto rig = testing::RunCommand(
      kRig + " --lcm '" + url + "' --actuator S1,S2 --protocol " +
          "square:level=2,period=220,duty=0.5,cycles=3 --speed 200 --trial-control " +
          "--key-file '" + key_file + "' --start-utime 1000000000000",
      scratch.path());
  ASSERT_EQ(rig.exit_code, 0) << rig.err;
  listener.Pump(1000ms);

  ASSERT_GT(listener.predictions.size(), 12000u);  // 13,200 sent, UDP may drop a few
  double largest_mm = 0.0;
  for (const auto& p : listener.predictions) {
    EXPECT_EQ(p.model_version, 1);
    largest_mm = std::max(largest_mm, std::abs(p.residual_mm));
  }
  EXPECT_LT(largest_mm, 2e-4) << "not the model's clean data";
  std::string warnings;
  std::vector<flexid::alert_t> estimates;
  for (const auto& a : listener.alerts) {
    if (a.severity >= 1) warnings += a.kind + ": " + a.text + "\n";
    if (a.kind == "noise_estimate") estimates.push_back(a);
  }
  EXPECT_EQ(warnings, "");
  // S1's sigma is given: no estimate. S2's is estimated, and the floor is used.
  ASSERT_EQ(estimates.size(), 1u) << "S2's monitor did not finish its warm-up";
  EXPECT_EQ(estimates[0].actuator_id, "S2");
  EXPECT_EQ(estimates[0].magnitude_mm, config.alerts.sigma_floor_mm);
  EXPECT_NE(estimates[0].text.find("sigma 0.0050 mm (the floor sigma_floor_mm"), std::string::npos)
      << estimates[0].text;
}

}  // namespace
}  // namespace flexid
