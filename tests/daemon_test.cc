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
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

#include "bus/clock.h"
#include "cli_process.h"
#include "lcmtypes/message_auth.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;

const std::string kRig = FLEXID_RIG_BINARY;

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
  // Sends a request and waits for its reply.
  std::optional<flexid::rpc_reply_t> Call(const std::string& method, const nlohmann::json& args,
                                          std::chrono::seconds timeout) {
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
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end &&
           (!reply_ || reply_->request_id != request.request_id))
      lcm_.handleTimeout(20);
    return reply_;
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

class DaemonEndToEnd : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = RandomUrl();
    listener_ = std::make_unique<Listener>(url_);
    if (!listener_->good()) GTEST_SKIP() << "no LCM multicast on this host (" << url_ << ")";
    daemon::Config config;
    config.database = scratch_.File("flexid.db");
    config.lcm_url = url_;
    config.log_file = "";
    config.daemon_id = "test";
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
  for (const auto& a : listener_->alerts)
    named = named || (a.kind == "back_relaxation" && a.text.rfind("trial ", 0) == 0);
  EXPECT_TRUE(named) << "no alert names the diagnosed effect";
  // Bad arguments are refused with the argument named.
  const auto bad = listener_->Call("diagnose", {{"actuator", "S1"}, {"trial", "x"}}, 10s);
  ASSERT_TRUE(bad.has_value());
  EXPECT_EQ(bad->status, flexid::rpc_reply_t::kBadRequest);
  EXPECT_NE(bad->error.find("trial"), std::string::npos) << bad->error;
}

}  // namespace
}  // namespace flexid
