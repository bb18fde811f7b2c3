// What the fault tests share (tests/daemon_faults_test.cc, tests/daemon_fault_matrix_test.cc):
// encoding sample messages, the test's side of the bus (STATUS, RPC replies, alerts,
// predictions), a paced sample publisher on its own thread, and the fault log that
// bench/fault-table turns into the README's table.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/status_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <functional>
#include <lcm/lcm-cpp.hpp>
#include <memory>
#include <mutex>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "bus/lcm_url.h"
#include "child_process.h"
#include "daemon/daemon.h"
#include "lcmtypes/message_auth.h"
#include "scratch_dir.h"

namespace flexid::testing {

using Bytes = std::vector<uint8_t>;

inline std::string ReadFile(const std::string& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

template <typename Message>
Bytes Encode(const Message& message) {
  Bytes bytes(static_cast<size_t>(message.getEncodedSize()));
  EXPECT_EQ(message.encode(bytes.data(), 0, static_cast<int>(bytes.size())),
            static_cast<int>(bytes.size()));
  return bytes;
}

inline flexid::voltage_sample_t Voltage(int64_t utime, double volts, const std::string& id = "S1") {
  flexid::voltage_sample_t m;
  m.utime = utime;
  m.actuator_id = id;
  m.voltage_V = volts;
  return m;
}

inline flexid::deflection_sample_t Deflection(int64_t utime, double mm,
                                              const std::string& id = "S1") {
  flexid::deflection_sample_t m;
  m.utime = utime;
  m.actuator_id = id;
  m.deflection_mm = mm;
  return m;
}

// The test's side of the bus: STATUS heartbeats, alerts, predictions of S1 (if asked), RPC
// replies to anyone; raw and encoded publishing. Handled on the test's thread only.
class Bus {
 public:
  using Clock = std::chrono::steady_clock;

  // With the daemon's 8 MiB receive buffer (as far as the kernel allows), so that a burst
  // of samples does not push the test's own alerts and replies out in transit.
  explicit Bus(const std::string& url, bool with_predictions)
      : lcm_(bus::WithReceiveBuffer(url, 8388608)) {
    if (!lcm_.good()) return;
    lcm_.subscribeFunction("FLEXID/STATUS", &Bus::OnStatus, this)->setQueueCapacity(1000);
    lcm_.subscribeFunction("FLEXID/RPC/REPLY/.*", &Bus::OnReply, this)->setQueueCapacity(1000);
    lcm_.subscribeFunction("FLEXID/ALERT", &Bus::OnAlert, this)->setQueueCapacity(1000);
    if (with_predictions)
      lcm_.subscribeFunction("FLEXID/S1/PREDICTION", &Bus::OnPrediction, this)
          ->setQueueCapacity(10000);
  }
  bool good() { return lcm_.good(); }

  int PublishRaw(const std::string& channel, const Bytes& bytes) {
    return lcm_.publish(channel, bytes.data(), static_cast<unsigned int>(bytes.size()));
  }
  template <typename Message>
  int Publish(const std::string& channel, const Message& message) {
    return lcm_.publish(channel, &message);
  }

  // Handles whatever has arrived, without waiting.
  void HandleReady() {
    while (lcm_.handleTimeout(0) > 0) {
    }
  }
  // Handles messages until done() or the timeout; returns done(). With poll_status, asks
  // the daemon for its counters (RPC "status") every 50 ms meanwhile, so that MaxStored()
  // is at most ~50 ms old.
  bool PumpUntil(const std::function<bool()>& done, std::chrono::milliseconds timeout,
                 bool poll_status = false) {
    const auto end = Clock::now() + timeout;
    auto next_poll = Clock::now();
    while (!done() && Clock::now() < end) {
      if (poll_status && Clock::now() >= next_poll) {
        RequestStatus();
        next_poll = Clock::now() + std::chrono::milliseconds(50);
      }
      lcm_.handleTimeout(10);
    }
    return done();
  }
  void Pump(std::chrono::milliseconds duration, bool poll_status = false) {
    const auto end = Clock::now() + duration;
    PumpUntil([&] { return Clock::now() >= end; }, duration + std::chrono::milliseconds(100),
              poll_status);
  }
  // Publishes an RPC "status" request; its reply counts in MaxStored().
  void RequestStatus() {
    flexid::rpc_request_t request;
    request.utime = 0;
    request.request_id = "status" + std::to_string(++status_requests_);
    request.client_id = "fault_harness";
    request.method = "status";
    lcm_.publish("FLEXID/RPC/REQUEST", &request);
  }

  // The highest samples_stored of the STATUS messages and status replies received so far
  // (-1: none): what the daemon has acknowledged.
  int64_t MaxStored() const {
    int64_t best = stored_by_reply_;
    for (const auto& s : statuses) best = std::max(best, s.samples_stored);
    return best;
  }
  // Forgets everything received (a new daemon process counts from 0 again).
  void Clear() {
    statuses.clear();
    predictions.clear();
    replies.clear();
    alerts.clear();
    stored_by_reply_ = -1;
  }
  // Replies with that request id.
  std::vector<std::pair<std::string, flexid::rpc_reply_t>> RepliesTo(const std::string& id) const {
    std::vector<std::pair<std::string, flexid::rpc_reply_t>> out;
    for (const auto& r : replies)
      if (r.second.request_id == id) out.push_back(r);
    return out;
  }
  // Alerts of that kind received so far.
  std::vector<flexid::alert_t> AlertsOf(const std::string& kind) const {
    std::vector<flexid::alert_t> out;
    for (const auto& a : alerts)
      if (a.kind == kind) out.push_back(a);
    return out;
  }

  std::vector<flexid::status_t> statuses;
  std::vector<flexid::prediction_t> predictions;
  std::vector<std::pair<std::string, flexid::rpc_reply_t>> replies;  // channel, reply
  std::vector<flexid::alert_t> alerts;

 private:
  static void OnStatus(const lcm::ReceiveBuffer* rbuf, const std::string&, Bus* self) {
    flexid::status_t s;
    if (s.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0) self->statuses.push_back(s);
  }
  static void OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string&, Bus* self) {
    flexid::prediction_t p;
    if (p.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0)
      self->predictions.push_back(p);
  }
  static void OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string&, Bus* self) {
    flexid::alert_t a;
    if (a.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0) self->alerts.push_back(a);
  }
  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string& channel, Bus* self) {
    flexid::rpc_reply_t r;
    if (r.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    if (r.request_id.rfind("status", 0) == 0 && channel == "FLEXID/RPC/REPLY/fault_harness") {
      const auto result = nlohmann::json::parse(r.result_json, nullptr, false);
      if (result.is_object() && result.contains("samples_stored") &&
          result["samples_stored"].is_number_integer())
        self->stored_by_reply_ =
            std::max(self->stored_by_reply_, result["samples_stored"].get<int64_t>());
      return;  // not kept: polling would fill `replies`
    }
    self->replies.emplace_back(channel, r);
  }

  lcm::LCM lcm_;
  int64_t stored_by_reply_ = -1;
  int status_requests_ = 0;
};

// Publishes S1's voltage and deflection samples (a pair per sample time, 5 V: an automatic
// trial) at a steady rate on its own thread and LCM instance, until destroyed. Message time
// advances by period_us per pair, plus an offset the test may change (a source clock
// jump). The test may pause everything or the deflection stream alone.
class SamplePublisher {
 public:
  SamplePublisher(const std::string& url, double pairs_per_s, int64_t start_utime,
                  int64_t period_us)
      : lcm_(url), rate_(pairs_per_s), next_utime_(start_utime), period_us_(period_us) {
    thread_ = std::thread([this] { Run(); });
  }
  ~SamplePublisher() { Stop(); }
  SamplePublisher(const SamplePublisher&) = delete;
  SamplePublisher& operator=(const SamplePublisher&) = delete;

  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  void Pause(bool paused) { paused_ = paused; }
  void DeflectionOff(bool off) { deflection_off_ = off; }
  void ShiftClock(int64_t by_us) { offset_us_ += by_us; }

  // Utimes of the deflection samples published so far, in order.
  std::vector<int64_t> Published() const {
    std::lock_guard lock(mutex_);
    return published_;
  }
  int64_t PublishedCount() const {
    std::lock_guard lock(mutex_);
    return static_cast<int64_t>(published_.size());
  }
  // The utime of the last deflection sample published (INT64_MIN: none).
  int64_t LastUtime() const {
    std::lock_guard lock(mutex_);
    return published_.empty() ? INT64_MIN : published_.back();
  }

 private:
  void Run() {
    using Clock = std::chrono::steady_clock;
    const auto start = Clock::now();
    int64_t sent = 0;
    while (!stop_) {
      const double elapsed_s = std::chrono::duration<double>(Clock::now() - start).count();
      const auto due = static_cast<int64_t>(elapsed_s * rate_);
      if (paused_) sent = due;  // a pause skips its samples; message time goes on
      for (; sent < due && !stop_; ++sent) {
        const int64_t utime = next_utime_ + offset_us_.load();
        next_utime_ += period_us_;
        if (paused_) continue;
        const flexid::voltage_sample_t voltage = Voltage(utime, 5.0);
        lcm_.publish("FLEXID/S1/VOLTAGE", &voltage);
        if (deflection_off_) continue;
        const flexid::deflection_sample_t deflection =
            Deflection(utime, 0.5 + 1e-4 * static_cast<double>(sent % 97));
        lcm_.publish("FLEXID/S1/DEFLECTION", &deflection);
        std::lock_guard lock(mutex_);
        published_.push_back(utime);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }

  lcm::LCM lcm_;
  const double rate_;
  int64_t next_utime_;
  const int64_t period_us_;
  std::atomic<bool> stop_{false}, paused_{false}, deflection_off_{false};
  std::atomic<int64_t> offset_us_{0};
  mutable std::mutex mutex_;
  std::vector<int64_t> published_;
  std::thread thread_;  // last: starts after everything above is initialised
};

// One line of the fault log (JSON lines at $FLEXID_FAULT_LOG, if set), read by
// bench/fault-table: what a test tried, how often, and what it cost.
struct FaultRecord {
  std::string fault;         // e.g. "kill -9 under load"
  int64_t attempts = 0;      // times the fault was injected (or bad messages sent)
  int64_t acknowledged = 0;  // samples acknowledged (STATUS / status reply) that must survive
  int64_t lost = 0;          // of those, not in the database afterwards
  std::string integrity;     // the database check afterwards: "ok" or the problems
  std::string recovered;     // "yes", "no" or a short explanation
  std::string notes;
};

inline void RecordFault(const FaultRecord& r) {
  const char* path = std::getenv("FLEXID_FAULT_LOG");
  if (!path || !*path) return;
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const nlohmann::json line = {
      {"fault", r.fault},
      {"attempts", r.attempts},
      {"acknowledged", r.acknowledged},
      {"lost", r.lost},
      {"integrity", r.integrity},
      {"recovered", r.recovered},
      {"notes", r.notes},
      {"test", info ? std::string(info->test_suite_name()) + "." + info->name() : ""},
      {"passed", !::testing::Test::HasFailure()}};
  // One write per line, appended: tests running in parallel do not interleave lines.
  const std::string text = line.dump() + "\n";
  if (std::FILE* f = std::fopen(path, "a")) {
    std::fwrite(text.data(), 1, text.size(), f);
    std::fclose(f);
  }
}

// The configuration of an in-process flexidd on the test's bus: its database
// (flexid.db) and log (flexidd.log) in the scratch directory, actuator S1 configured.
inline daemon::Config InProcessConfig(const ScratchDir& scratch, const std::string& url,
                                      const std::string& daemon_id) {
  daemon::Config config;
  config.database = scratch.File("flexid.db");
  config.lcm_url = url;
  config.log_file = scratch.File("flexidd.log");
  config.daemon_id = daemon_id;
  storage::Actuator s1;
  s1.id = "S1";
  config.actuators = {s1};
  return config;
}

// A test with flexidd in-process: the test's bus on a random udpm port (ttl=0, skipped
// without multicast), the configuration of InProcessConfig; StartDaemon() starts it and
// reads the key its signed requests take.
class InProcessDaemonTest : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = RandomUrl();
    bus_ = std::make_unique<Bus>(url_, with_predictions_);
    if (!bus_->good()) GTEST_SKIP() << "no LCM multicast on this host (" << url_ << ")";
    config_ = InProcessConfig(scratch_, url_, "in_process");
  }
  void TearDown() override { daemon_.reset(); }

  void StartDaemon() {
    daemon::Validate(config_);
    daemon::SetUpLogging(config_);
    daemon_ = std::make_unique<daemon::Daemon>(config_);
    key_ = auth::ReadKeyFile(daemon::KeyFilePath(config_));
  }

  bool with_predictions_ = false;  // set in the constructor of a test that wants S1's
  ScratchDir scratch_;
  std::string url_;
  daemon::Config config_;
  std::unique_ptr<Bus> bus_;
  std::unique_ptr<daemon::Daemon> daemon_;
  auth::Key key_;
};

// Runs an in-process flexidd's loop and the test's bus, both in this thread (so the
// daemon's counters are never read while another thread updates them), until done() or
// the timeout; returns done().
inline bool DriveInProcess(daemon::Daemon& daemon, Bus& bus, const std::function<bool()>& done,
                           std::chrono::milliseconds timeout) {
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (true) {
    daemon.RunOnce(2);
    bus.HandleReady();
    if (done()) return true;
    if (std::chrono::steady_clock::now() >= end) return false;
  }
}

}  // namespace flexid::testing
