// One thread writes (storage/sample_writer.h, daemon/daemon.h): faults of the database
// that once stopped or starved flexidd's loop, against flexidd in-process (its loop and the
// test's bus driven in the test's own thread with RunOnce), on its own udpm port (ttl=0)
// and scratch directory. The database is locked by another connection holding BEGIN
// EXCLUSIVE, longer than the writer's 5 s busy timeout, so that writes fail and are retried:
//  1. predictions go on while the database is locked for 10 s, and every alert raised
//     meanwhile is stored exactly once after it is released;
//  2. a finished identification drained while the database is locked (its model and its
//     "model_changed" alert cannot be stored) neither ends the loop nor loses the reply:
//     flexidd answers other requests meanwhile and the identify request once the model is
//     stored;
//  3. an automatic trial whose start cannot be written does not cost the prediction its
//     voltage step, and the trial is stored once the lock is released.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <chrono>
#include <cmath>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <functional>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "bus/clock.h"
#include "child_process.h"
#include "daemon/config.h"
#include "daemon/daemon.h"
#include "fault_harness.h"
#include "lcmtypes/message_auth.h"
#include "model/core/model_file.h"
#include "model/core/simulate.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using testing::Bus;
using testing::Deflection;
using testing::Voltage;

constexpr int64_t kStartUtime = 1'000'000'000'000;

// Another program holding the database's write lock (BEGIN EXCLUSIVE) until Release().
class DatabaseLock {
 public:
  explicit DatabaseLock(const std::string& path) {
    EXPECT_EQ(sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE, nullptr), SQLITE_OK);
    sqlite3_busy_timeout(db_, 5000);
    EXPECT_EQ(sqlite3_exec(db_, "BEGIN EXCLUSIVE", nullptr, nullptr, nullptr), SQLITE_OK)
        << sqlite3_errmsg(db_);
  }
  ~DatabaseLock() {
    Release();
    sqlite3_close(db_);
  }
  DatabaseLock(const DatabaseLock&) = delete;
  DatabaseLock& operator=(const DatabaseLock&) = delete;

  void Release() {
    if (!held_) return;
    EXPECT_EQ(sqlite3_exec(db_, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK);
    held_ = false;
  }

 private:
  sqlite3* db_ = nullptr;
  bool held_ = true;
};

// A first-order model, 1 mm/V with a 1 s time constant: easy to predict by hand.
model::ModelDocument FirstOrderModel() {
  model::TransferFunction tf;
  tf.num = {1.0};
  tf.den = {1.0, 1.0};
  return model::FromTransferFunction(tf);
}

// flexidd in-process on a scratch database, with the test's bus on the same random port.
class WriterFaults : public testing::InProcessDaemonTest {
 protected:
  WriterFaults() { with_predictions_ = true; }

  // Drives the loop and the bus until done() or the timeout. Every pass of the loop must
  // return, without an exception; the longest one is kept in longest_pass_.
  bool Drive(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
    const auto end = Clock::now() + timeout;
    while (true) {
      const auto before = Clock::now();
      try {
        daemon_->RunOnce(2);
      } catch (const std::exception& e) {
        ADD_FAILURE() << "an exception left the loop: " << e.what();
        return false;
      }
      longest_pass_ = std::max(longest_pass_, Clock::now() - before);
      bus_->HandleReady();
      if (done()) return true;
      if (Clock::now() >= end) return false;
    }
  }
  // check() at most every 100 ms (it opens the database), its last answer in between.
  static std::function<bool()> Every100ms(std::function<bool()> check) {
    auto last = std::make_shared<Clock::time_point>();
    auto answer = std::make_shared<bool>(false);
    return [=] {
      if (Clock::now() - *last >= 100ms) {
        *last = Clock::now();
        *answer = check();
      }
      return *answer;
    };
  }
  void DriveFor(std::chrono::milliseconds duration) {
    const auto end = Clock::now() + duration;
    Drive([&] { return Clock::now() >= end; }, duration + 100ms);
  }

  // A voltage and a deflection sample of S1 at utime, and the prediction that follows.
  void Pair(int64_t utime, double volts, double mm) {
    bus_->Publish("FLEXID/S1/VOLTAGE", Voltage(utime, volts));
    bus_->Publish("FLEXID/S1/DEFLECTION", Deflection(utime, mm));
    ++deflections_sent_;
  }

  // Publishes a request (signed when it changes data) and returns its id.
  std::string Request(const std::string& method, const nlohmann::json& args) {
    flexid::rpc_request_t r;
    r.utime = bus::WallClockUtime();
    r.request_id = "w" + std::to_string(++requests_);
    r.client_id = "writer_test";
    r.method = method;
    r.args_json = args.dump();
    if (auth::ChangesData(method)) auth::Sign(key_, &r);
    EXPECT_EQ(bus_->Publish("FLEXID/RPC/REQUEST", r), 0);
    return r.request_id;
  }
  std::optional<flexid::rpc_reply_t> ReplyTo(const std::string& id) const {
    const auto replies = bus_->RepliesTo(id);
    if (replies.empty()) return std::nullopt;
    return replies.front().second;
  }

  // All alerts in the file, as a query from time 0 finds them (an alert raised before any
  // sample is stamped with the latest message time or the wall clock), read with a
  // connection of the test's own.
  std::vector<storage::AlertRecord> StoredAlerts() const {
    return storage::Database::Open(config_.database).Alerts(std::nullopt, 0, -1);
  }
  static size_t Count(const std::vector<storage::AlertRecord>& stored, const flexid::alert_t& a) {
    size_t n = 0;
    for (const storage::AlertRecord& s : stored)
      n += s.kind == a.kind && s.actuator_id == a.actuator_id && s.utime == a.utime &&
           s.text == a.text;
    return n;
  }

  int requests_ = 0;
  int64_t deflections_sent_ = 0;
  Clock::duration longest_pass_{};
};

// ---------------------------------------------------------------------------------------
// 1. A database locked for 10 s
// ---------------------------------------------------------------------------------------

TEST_F(WriterFaults, LockedDatabaseStopsNeitherPredictionsNorLosesAlerts) {
  StartDaemon();
  // An automatic trial (5 V), stored before the lock.
  int64_t utime = kStartUtime;
  for (int k = 0; k < 20; ++k, utime += 10'000) Pair(utime, 5.0, 0.5);
  ASSERT_TRUE(Drive(Every100ms([&] {
                      return static_cast<int64_t>(bus_->predictions.size()) == deflections_sent_ &&
                             !storage::Database::Open(config_.database).Trials().empty();
                    }),
                    5s));

  DatabaseLock lock(config_.database);
  const auto locked_at = Clock::now();
  const size_t alerts_before = bus_->alerts.size();
  const int64_t sent_before = deflections_sent_;
  longest_pass_ = {};
  // 10 s of samples, and once a second the sensor falls silent for 3 s of message time
  // while the voltage goes on: a sensor_dropout alert each time (alerts.dropout_s 2 s).
  auto next_dropout = Clock::now() + 500ms;
  while (Clock::now() - locked_at < 10s) {
    if (Clock::now() >= next_dropout) {
      // In slices of 20, the loop and the bus served in between: a burst of 300 datagrams
      // overflows a receive buffer the size of the kernel's default on a busy machine, and
      // the alert that follows it would be lost in transit to the test (seen: 2 of 9).
      for (int k = 0; k < 300; ++k, utime += 10'000) {
        bus_->Publish("FLEXID/S1/VOLTAGE", Voltage(utime, 5.0));
        if (k % 20 == 19) DriveFor(1ms);
      }
      next_dropout += 1s;
    }
    Pair(utime, 5.0, 0.5);
    utime += 10'000;
    DriveFor(5ms);
  }
  // Every deflection gets its prediction. UDP on the loopback may drop a packet or two
  // when the machine is busy (seen: 2 of 1,555), so 0.5 % may go missing in transit; a
  // loop that waited for the lock would miss seconds of them (hundreds).
  Drive([&] { return static_cast<int64_t>(bus_->predictions.size()) == deflections_sent_; }, 2s);
  const int64_t missing = deflections_sent_ - static_cast<int64_t>(bus_->predictions.size());
  EXPECT_LE(missing, (deflections_sent_ - sent_before) / 200)
      << "predictions stopped while the database was locked: " << missing << " of "
      << deflections_sent_ - sent_before << " missing";
  // A pass that waited for the lock would take the 5 s busy timeout.
  EXPECT_LT(longest_pass_, 2500ms) << "the loop waited for the locked database";
  const std::vector<flexid::alert_t> during(bus_->alerts.begin() + alerts_before,
                                            bus_->alerts.end());
  size_t dropouts = 0, failing = 0;
  for (const auto& a : during) {
    dropouts += a.kind == "sensor_dropout";
    failing += a.kind == "storage_failing";
  }
  // About one a second; a busy machine stretches the test's own loop, so fewer (seen: 4).
  // What is tested is that each one raised during the lock is stored once, below.
  EXPECT_GE(dropouts, 3u);
  EXPECT_EQ(failing, 1u) << "the failing writes are not reported";

  lock.Release();
  std::vector<storage::AlertRecord> stored;
  auto all_stored = [&] {
    stored = StoredAlerts();
    for (const auto& a : during)
      if (Count(stored, a) == 0) return false;
    return true;
  };
  EXPECT_TRUE(Drive(Every100ms(all_stored), 15s)) << "alerts raised during the lock are missing";
  for (const auto& a : during) EXPECT_EQ(Count(stored, a), 1u) << "[" << a.kind << "] " << a.text;
  EXPECT_EQ(daemon_->counters().alerts_dropped, 0);
  EXPECT_EQ(daemon_->counters().dropped_queue_full, 0);
}

// ---------------------------------------------------------------------------------------
// 2. A result drained while its writes fail
// ---------------------------------------------------------------------------------------

TEST_F(WriterFaults, IdentificationDrainedWhileLockedKeepsTheLoopAndAnswers) {
  // A finished trial of S1: a first-order response to a 0/5 V square wave, 50 Hz.
  int64_t trial = 0;
  {
    storage::Database db = storage::Database::Open(config_.database);
    trial = db.StartTrial("S1", "square:level=5,period=10", kStartUtime);
    std::vector<storage::Sample> samples;
    double y = 0.0;
    const double dt_s = 0.02, a = std::exp(-dt_s / 1.0);
    for (int k = 0; k < 1500; ++k) {
      const double v = (k / 250) % 2 == 0 ? 5.0 : 0.0;
      samples.push_back({kStartUtime + k * 20'000, v, y + 1e-3 * std::sin(0.7 * k)});
      y = a * y + (1.0 - a) * 0.2 * v;
    }
    db.AppendSamples(trial, samples);
    db.EndTrial(trial, samples.back().utime, storage::TrialState::kComplete);
  }
  config_.auto_trials = false;
  config_.identification.method = "time";
  config_.identification.zeros = 0;
  config_.identification.poles = 1;
  config_.identification.orders_given = true;
  config_.identification.max_delay_s = 0.5;
  StartDaemon();

  const std::string identify = Request("identify", {{"actuator", "S1"}, {"trials", {trial}}});
  const int64_t received = daemon_->counters().messages_received;
  ASSERT_TRUE(Drive([&] { return daemon_->counters().messages_received > received; }, 3s));
  // Let the worker finish without draining its result (no loop pass). Where the worker
  // stores the model itself it shows in the file; otherwise the writer stores it after
  // the drain, and the worker has had these seconds.
  const auto waited = Clock::now();
  while (Clock::now() - waited < 3s &&
         storage::Database::Open(config_.database).Models("S1").empty())
    std::this_thread::sleep_for(20ms);

  DatabaseLock lock(config_.database);
  const size_t alerts_before = bus_->alerts.size();
  const auto locked_at = Clock::now();
  // Over the busy timeout: the model and its alert fail to be written, and are retried.
  DriveFor(6500ms);
  EXPECT_LT(Clock::now() - locked_at, 9s);
  const std::string status = Request("status", nlohmann::json::object());
  ASSERT_TRUE(Drive([&] { return ReplyTo(status).has_value(); }, 3s))
      << "flexidd does not answer while a drained result cannot be stored";
  EXPECT_EQ(ReplyTo(status)->status, flexid::rpc_reply_t::kOk);

  lock.Release();
  ASSERT_TRUE(Drive([&] { return ReplyTo(identify).has_value(); }, 15s))
      << "the identify request was never answered";
  const flexid::rpc_reply_t reply = *ReplyTo(identify);
  ASSERT_EQ(reply.status, flexid::rpc_reply_t::kOk) << reply.error;
  EXPECT_EQ(nlohmann::json::parse(reply.result_json).value("version", 0), 1);
  EXPECT_EQ(storage::Database::Open(config_.database).Models("S1").size(), 1u);

  std::vector<flexid::alert_t> changed;
  for (size_t k = alerts_before; k < bus_->alerts.size(); ++k)
    if (bus_->alerts[k].kind == "model_changed") changed.push_back(bus_->alerts[k]);
  ASSERT_EQ(changed.size(), 1u);
  std::vector<storage::AlertRecord> stored;
  EXPECT_TRUE(Drive(Every100ms([&] {
                      stored = StoredAlerts();
                      return Count(stored, changed.front()) > 0;
                    }),
                    5s));
  EXPECT_EQ(Count(stored, changed.front()), 1u);
}

// ---------------------------------------------------------------------------------------
// 3. An automatic trial whose start cannot be written
// ---------------------------------------------------------------------------------------

TEST_F(WriterFaults, AutomaticTrialStartThatCannotBeWrittenKeepsItsVoltageStep) {
  {
    storage::ModelRecord record;
    record.actuator_id = "S1";
    record.model_json = model::ModelToJson(FirstOrderModel()).dump();
    record.fit_json = "{}";
    record.active = true;
    storage::Database::Open(config_.database).StoreModel(record);
  }
  StartDaemon();
  // At rest: a prediction at 0.5 s.
  bus_->Publish("FLEXID/S1/VOLTAGE", Voltage(kStartUtime, 0.0));
  bus_->Publish("FLEXID/S1/DEFLECTION", Deflection(kStartUtime + 500'000, 0.0));
  ASSERT_TRUE(Drive([&] { return bus_->predictions.size() == 1; }, 3s));

  DatabaseLock lock(config_.database);
  // 5 V at 1 s starts an automatic trial (its row cannot be written now); at 2 s the
  // model has had the step for 1 s.
  bus_->Publish("FLEXID/S1/VOLTAGE", Voltage(kStartUtime + 1'000'000, 5.0));
  bus_->Publish("FLEXID/S1/DEFLECTION", Deflection(kStartUtime + 2'000'000, 3.0));
  ASSERT_TRUE(Drive([&] { return bus_->predictions.size() == 2; }, 10s));
  const flexid::prediction_t p = bus_->predictions.back();

  model::StreamingSimulator expected(model::AsTsModel(FirstOrderModel()));
  expected.Step(0.0, 0.0);
  expected.Step(0.5, 0.0);
  expected.Step(1.0, 5.0);
  const double expected_mm = expected.Step(2.0, 5.0);  // 5 (1 - e^-1) = 3.16 mm
  EXPECT_NEAR(expected_mm, 5.0 * (1.0 - std::exp(-1.0)), 1e-6);
  EXPECT_NEAR(p.predicted_mm, expected_mm, 1e-9) << "the voltage step was skipped";
  EXPECT_NE(p.trial_id, 0) << "no trial recording";

  // The start is retried until it is written, with the id the prediction carried.
  lock.Release();
  std::vector<storage::Trial> trials;
  ASSERT_TRUE(Drive(Every100ms([&] {
                      trials = storage::Database::Open(config_.database).Trials();
                      return !trials.empty() && trials.front().samples == 1;
                    }),
                    15s))
      << "the trial or its sample was never stored";
  EXPECT_EQ(trials.front().id, p.trial_id);
  EXPECT_EQ(trials.front().start_utime, kStartUtime + 1'000'000);
  EXPECT_EQ(trials.front().protocol, "automatic");
}

}  // namespace
}  // namespace flexid
