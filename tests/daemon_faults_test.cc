// Fault injection against flexidd (DESIGN.md, "Rules for reliability"):
//  - kill -9 of the real flexidd binary in the middle of a trial: every sample STATUS
//    acknowledged is in the file, the file is intact, and the next start marks the trial
//    interrupted;
//  - malformed, truncated, oversized, non-finite, out-of-order and misaddressed input is
//    rejected and counted exactly, and the daemon goes on predicting;
//  - RPC requests with bad client ids, bad arguments or unknown methods;
//  - LCM string fields with a crafted length prefix (against the real binary, since the
//    generated decoder is the part under test and may take the process down).
// Every test has its own udpm port (ttl=0) and its own scratch directory. The in-process
// tests run the daemon's loop and the test's bus in the test's own thread (RunOnce), so
// counters() is never read while another thread updates it.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/status_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <functional>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "bus/clock.h"
#include "child_process.h"
#include "daemon/daemon.h"
#include "fault_harness.h"
#include "lcmtypes/message_auth.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using testing::Bus;
using testing::Bytes;
using testing::ChildProcess;
using testing::Deflection;
using testing::DescribeStatus;
using testing::Encode;
using testing::RandomUrl;
using testing::ReadFile;
using testing::RecordFault;
using testing::Voltage;

const std::string kFlexidd = FLEXIDD_BINARY;
const std::string kRig = FLEXID_RIG_BINARY;

// An encoded voltage_sample_t whose actuator_id length prefix (bytes 16..19, big-endian,
// counting the terminating NUL) is replaced by `length`.
Bytes VoltageWithStringLength(int32_t length) {
  Bytes bytes = Encode(Voltage(1'000'000, 1.0));
  const auto u = static_cast<uint32_t>(length);
  bytes[16] = static_cast<uint8_t>(u >> 24);
  bytes[17] = static_cast<uint8_t>(u >> 16);
  bytes[18] = static_cast<uint8_t>(u >> 8);
  bytes[19] = static_cast<uint8_t>(u);
  return bytes;
}

// ---------------------------------------------------------------------------------------
// 1. kill -9 in the middle of a trial
// ---------------------------------------------------------------------------------------

TEST(DaemonKill, AcknowledgedSamplesSurviveKill9AndTrialBecomesInterrupted) {
  testing::ScratchDir scratch;
  const std::string url = RandomUrl();
  Bus bus(url, /*with_predictions=*/false);
  if (!bus.good()) GTEST_SKIP() << "no LCM multicast on this host (" << url << ")";
  const std::string db_path = scratch.File("flexid.db");
  const std::vector<std::string> daemon_args = {
      kFlexidd, "--db", db_path, "--lcm", url, "--log-file", scratch.File("flexidd.log")};
  constexpr double kSpeed = 50.0;
  constexpr int64_t kSamplePeriodUs = 10'000;  // --rate-hz 100
  // Not whole multiples of the 100 ms commit interval apart, so that the kills land at
  // different moments of the commit cycle.
  const std::chrono::milliseconds kill_delays[] = {1550ms, 2680ms, 3730ms};
  // The rig signs its trial control with the key flexidd creates next to its database.
  const std::string key_file = scratch.File("flexidd.key");

  for (int round = 0; round < 3; ++round) {
    const std::chrono::milliseconds delay = kill_delays[round];
    SCOPED_TRACE("round " + std::to_string(round) + ", kill " + std::to_string(delay.count()) +
                 " ms into the trial");
    const std::string tag = std::to_string(round);
    const int64_t start_utime = 1'000'000'000'000 + round * 100'000'000'000LL;

    // flexidd, ready once its first STATUS is out (it has joined the bus by then).
    bus.statuses.clear();
    auto daemon =
        std::make_unique<ChildProcess>(daemon_args, scratch.File("flexidd" + tag + ".out"),
                                       scratch.File("flexidd" + tag + ".err"));
    ASSERT_TRUE(daemon->started());
    ASSERT_TRUE(bus.PumpUntil([&] { return !bus.statuses.empty(); }, 10s))
        << "flexidd sent no STATUS: " << ReadFile(scratch.File("flexidd" + tag + ".err"));

    // A long hold at 5 V, 100 Hz of message time, 50 x real time: 5,000 samples/s.
    const std::string rig_out = scratch.File("rig" + tag + ".out");
    ChildProcess rig(
        {kRig, "--lcm", url, "--actuator", "S1", "--protocol", "hold:level=5,duration=10000",
         "--rate-hz", "100", "--speed", "50", "--noise-mm", "0.02", "--trial-control", "--key-file",
         key_file, "--start-utime", std::to_string(start_utime)},
        rig_out, scratch.File("rig" + tag + ".err"));
    ASSERT_TRUE(rig.started());
    const auto kill_at = Clock::now() + delay;
    bus.PumpUntil([&] { return Clock::now() >= kill_at; }, delay + 1s);
    // Make sure the daemon acknowledged something before it dies (a slow start-up).
    ASSERT_TRUE(bus.PumpUntil([&] { return bus.MaxStored() > 0; }, 5s))
        << "no STATUS with samples_stored > 0; rig: "
        << ReadFile(scratch.File("rig" + tag + ".err"));
    ASSERT_TRUE(rig.Running()) << "the rig ended early: " << ReadFile(rig_out);

    ASSERT_TRUE(daemon->Signal(SIGKILL));
    const auto killed_at = Clock::now();
    const auto killed = daemon->Wait(5s);
    ASSERT_TRUE(killed.has_value());
    EXPECT_TRUE(WIFSIGNALED(*killed) && WTERMSIG(*killed) == SIGKILL) << DescribeStatus(*killed);
    bus.Pump(50ms);  // heartbeats still in flight were sent before the kill
    const int64_t acknowledged = bus.MaxStored();

    ASSERT_TRUE(rig.Signal(SIGTERM));
    const auto rig_stopped_at = Clock::now();
    const auto rig_status = rig.Wait(10s);
    ASSERT_TRUE(rig_status.has_value()) << "the rig ignored SIGTERM";
    EXPECT_TRUE(WIFEXITED(*rig_status) && WEXITSTATUS(*rig_status) == 1)  // interrupted
        << DescribeStatus(*rig_status) << ": " << ReadFile(scratch.File("rig" + tag + ".err"));

    // The file as kill -9 left it.
    storage::Trial trial;
    std::vector<storage::Sample> samples;
    {
      storage::Database db = storage::Database::Open(db_path);
      EXPECT_EQ(db.IntegrityCheck(), "ok");
      const auto trials = db.Trials(std::string("S1"), 1);
      ASSERT_EQ(trials.size(), 1u);
      trial = trials.front();
      EXPECT_EQ(trial.start_utime, start_utime);
      EXPECT_EQ(trial.state, storage::TrialState::kRecording);
      EXPECT_GE(trial.samples, acknowledged) << "STATUS acknowledged samples that are not stored";
      samples = db.Samples(trial.id);
      ASSERT_EQ(static_cast<int64_t>(samples.size()), trial.samples);
      ASSERT_FALSE(samples.empty());
      for (const auto& s : samples) {
        ASSERT_TRUE(std::isfinite(s.voltage_V) && std::isfinite(s.deflection_mm));
        ASSERT_GE(s.utime, start_utime);
      }
    }
    // Loss window: message time the rig had reached at the kill minus the last stored
    // sample, in wall time. The rig's last sample went out when it got SIGTERM.
    std::smatch match;
    const std::string rig_summary = ReadFile(rig_out);
    if (std::regex_search(rig_summary, match, std::regex("final utime (-?[0-9]+)"))) {
      const int64_t final_utime = std::stoll(match[1].str());
      const double between_s = std::chrono::duration<double>(rig_stopped_at - killed_at).count();
      const double at_kill_utime = static_cast<double>(final_utime) - between_s * kSpeed * 1e6;
      const double window_ms =
          (at_kill_utime - static_cast<double>(samples.back().utime)) / kSpeed / 1e3;
      const int64_t expected = (samples.back().utime - samples.front().utime) / kSamplePeriodUs + 1;
      std::cout << "round " << round << ": killed after " << delay.count() << " ms; STATUS acked "
                << acknowledged << ", stored " << trial.samples << " (+"
                << trial.samples - acknowledged << " after the last STATUS), gaps "
                << expected - trial.samples << " samples (UDP), loss window ~" << window_ms
                << " ms of wall time\n";
      EXPECT_LT(window_ms, 500.0) << "unacknowledged samples span more than the documented window";
    } else {
      ADD_FAILURE() << "no summary line from the rig: " << rig_summary;
    }

    // A clean start marks the trial interrupted, ending at its last stored sample; SIGTERM
    // then stops the daemon with exit code 0.
    bus.statuses.clear();
    const auto restarted_at = Clock::now();
    ChildProcess again(daemon_args, scratch.File("flexidd" + tag + "b.out"),
                       scratch.File("flexidd" + tag + "b.err"));
    ASSERT_TRUE(again.started());
    ASSERT_TRUE(bus.PumpUntil([&] { return !bus.statuses.empty(); }, 10s))
        << "restarted flexidd sent no STATUS: "
        << ReadFile(scratch.File("flexidd" + tag + "b.err"));
    EXPECT_EQ(bus.statuses.back().trials_recording, 0);
    bus.PumpUntil([&] { return Clock::now() >= restarted_at + 1500ms; }, 2s);
    ASSERT_TRUE(again.Signal(SIGTERM));
    const auto stopped = again.Wait(10s);
    ASSERT_TRUE(stopped.has_value()) << "flexidd ignored SIGTERM";
    EXPECT_TRUE(WIFEXITED(*stopped) && WEXITSTATUS(*stopped) == 0)
        << "flexidd did not stop cleanly on SIGTERM (" << DescribeStatus(*stopped)
        << "): " << ReadFile(scratch.File("flexidd" + tag + "b.err"));
    {
      storage::Database db = storage::Database::Open(db_path);
      EXPECT_EQ(db.IntegrityCheck(), "ok");
      const auto after = db.FindTrial(trial.id);
      ASSERT_TRUE(after.has_value());
      EXPECT_EQ(after->state, storage::TrialState::kInterrupted);
      EXPECT_EQ(after->end_utime, samples.back().utime);
      EXPECT_EQ(after->samples, trial.samples);
    }
  }
}

// SIGTERM stops the real binary cleanly (exit 0, "stopping" logged), also when it was
// started with no signal blocked, as systemd or a shell starts it.
TEST(DaemonSignals, SigtermStopsTheBinaryWithExitCode0) {
  testing::ScratchDir scratch;
  const std::string url = RandomUrl();
  Bus bus(url, /*with_predictions=*/false);
  if (!bus.good()) GTEST_SKIP() << "no LCM multicast on this host (" << url << ")";
  const std::string err = scratch.File("flexidd.err");
  ChildProcess daemon({kFlexidd, "--db", scratch.File("flexid.db"), "--lcm", url, "--log-file",
                       scratch.File("flexidd.log")},
                      scratch.File("flexidd.out"), err);
  ASSERT_TRUE(daemon.started());
  ASSERT_TRUE(bus.PumpUntil([&] { return !bus.statuses.empty(); }, 10s))
      << "flexidd sent no STATUS: " << ReadFile(err);
  ASSERT_TRUE(daemon.Signal(SIGTERM));
  const auto stopped = daemon.Wait(10s);
  ASSERT_TRUE(stopped.has_value()) << "flexidd ignored SIGTERM";
  EXPECT_TRUE(WIFEXITED(*stopped) && WEXITSTATUS(*stopped) == 0)
      << "flexidd did not stop cleanly on SIGTERM (" << DescribeStatus(*stopped)
      << "): " << ReadFile(err);
  EXPECT_NE(ReadFile(err).find("stopping [signal: 15]"), std::string::npos) << ReadFile(err);
}

// ---------------------------------------------------------------------------------------
// In-process daemon, driven from the test's thread.
// ---------------------------------------------------------------------------------------

class InProcessDaemon : public ::testing::Test {
 protected:
  void Start(int64_t max_message_bytes) {
    url_ = RandomUrl();
    bus_ = std::make_unique<Bus>(url_, /*with_predictions=*/true);
    if (!bus_->good()) GTEST_SKIP() << "no LCM multicast on this host (" << url_ << ")";
    daemon::Config config;
    config.database = scratch_.File("flexid.db");
    config.lcm_url = url_;
    config.log_file = "";
    config.log_level = "warn";
    config.daemon_id = "faults";
    config.max_message_bytes = max_message_bytes;
    daemon::Validate(config);
    daemon_ = std::make_unique<daemon::Daemon>(config);
    key_ = auth::ReadKeyFile(daemon::KeyFilePath(config));  // created by the daemon
  }

  // Runs the daemon's loop and the test's bus until done() or the timeout.
  bool Drive(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
    return testing::DriveInProcess(*daemon_, *bus_, done, timeout);
  }

  // Publishes one raw message and runs the daemon until it has received it (one message
  // at a time: a modest rate, and any UDP loss is seen and reported).
  void SendRaw(const std::string& channel, const Bytes& bytes) {
    const int64_t before = daemon_->counters().messages_received;
    ASSERT_EQ(bus_->PublishRaw(channel, bytes), 0) << channel << ", " << bytes.size() << " bytes";
    ++sent_;
    if (!Drive([&] { return daemon_->counters().messages_received > before; }, 2s)) {
      ++lost_;
      ADD_FAILURE() << "a message on " << channel << " (" << bytes.size()
                    << " bytes) never reached the daemon (UDP loss on loopback?)";
    }
  }
  template <typename Message>
  void Send(const std::string& channel, const Message& message) {
    SendRaw(channel, Encode(message));
  }

  flexid::rpc_request_t Request(const std::string& method, const std::string& args_json,
                                const std::string& client_id = "faults_test") {
    flexid::rpc_request_t r;
    r.utime = 0;
    r.request_id = "q" + std::to_string(++requests_);
    r.client_id = client_id;
    r.method = method;
    r.args_json = args_json;
    // Signed where flexidd asks for it, so that what is tested here is the method itself
    // (tests/auth_test.cc tests the signatures).
    if (auth::ChangesData(method)) {
      r.utime = bus::WallClockUtime();
      auth::Sign(key_, &r);
    }
    return r;
  }
  // Sends a request and waits for its one reply on the client's channel.
  std::optional<flexid::rpc_reply_t> Call(const flexid::rpc_request_t& request) {
    Send("FLEXID/RPC/REQUEST", request);
    Drive([&] { return !bus_->RepliesTo(request.request_id).empty(); }, 3s);
    const auto replies = bus_->RepliesTo(request.request_id);
    if (replies.empty()) return std::nullopt;
    EXPECT_EQ(replies.size(), 1u);
    EXPECT_EQ(replies.front().first, "FLEXID/RPC/REPLY/" + request.client_id);
    EXPECT_EQ(replies.front().second.daemon_id, "faults");
    return replies.front().second;
  }
  std::optional<flexid::rpc_reply_t> Call(const std::string& method, const std::string& args_json) {
    return Call(Request(method, args_json));
  }
  // Expects a kBadRequest reply whose error contains `needle`.
  void ExpectBadRequest(const std::string& method, const std::string& args_json,
                        const std::string& needle) {
    SCOPED_TRACE(method + " " + args_json.substr(0, 80));
    const auto reply = Call(method, args_json);
    ASSERT_TRUE(reply.has_value()) << "no reply";
    EXPECT_EQ(reply->status, flexid::rpc_reply_t::kBadRequest) << reply->error;
    EXPECT_NE(reply->error.find(needle), std::string::npos)
        << "error \"" << reply->error << "\" does not name " << needle;
    EXPECT_EQ(reply->error.find('\n'), std::string::npos) << "error is not one line";
  }

  testing::ScratchDir scratch_;
  std::string url_;
  std::unique_ptr<Bus> bus_;
  std::unique_ptr<daemon::Daemon> daemon_;
  int64_t sent_ = 0;
  int64_t lost_ = 0;
  int requests_ = 0;
  auth::Key key_;
};

// ---------------------------------------------------------------------------------------
// 2. Bad input on the sample channels is rejected and counted exactly
// ---------------------------------------------------------------------------------------

TEST_F(InProcessDaemon, BadInputIsRejectedCountedAndHarmless) {
  Start(/*max_message_bytes=*/1024);
  if (IsSkipped()) return;
  const int64_t B = 1'000'000'000'000;
  const std::string V = "FLEXID/S1/VOLTAGE", D = "FLEXID/S1/DEFLECTION";
  daemon::Counters want;
  std::vector<storage::Sample> stored;  // what the trial must hold, in order
  const auto accepted_voltage = [&](int64_t utime, double volts) {
    Send(V, Voltage(utime, volts));
    ++want.samples_accepted;
  };
  const auto accepted_deflection = [&](int64_t utime, double volts, double mm) {
    Send(D, Deflection(utime, mm));
    ++want.samples_accepted;
    ++want.predictions_published;
    stored.push_back({utime, volts, mm});
  };

  // A valid start: 5 V starts an automatic trial; the deflection is paired with it.
  accepted_voltage(B, 5.0);
  accepted_deflection(B + 100'000, 5.0, 0.10);

  // Malformed: undecodable, truncated, trailing bytes, another type, bad string length,
  // oversized (> 1024 bytes), misaddressed, an unknown trial action, bad RPC requests.
  const Bytes voltage = Encode(Voltage(B + 200'000, 6.0));
  const Bytes deflection = Encode(Deflection(B + 200'000, 0.6));
  const std::string text = "not an LCM message";
  const auto malformed = [&](const std::string& channel, const Bytes& bytes) {
    SendRaw(channel, bytes);
    ++want.rejected_malformed;
  };
  malformed(V, Bytes(text.begin(), text.end()));
  malformed(D, Bytes{});
  malformed(V, Bytes(voltage.begin(), voltage.end() - 3));
  malformed(D, Bytes(deflection.begin(), deflection.begin() + 8));
  Bytes trailing = voltage;
  trailing.push_back(0);
  malformed(V, trailing);
  malformed(V, deflection);  // a deflection_sample_t on the voltage channel
  malformed(D, voltage);
  malformed(V, VoltageWithStringLength(1000));  // longer than the message
  Bytes huge(70'000);
  for (size_t i = 0; i < huge.size(); ++i) huge[i] = static_cast<uint8_t>(i * 131u);
  malformed(V, huge);
  Bytes padded = deflection;
  padded.resize(2000, 0);
  malformed(D, padded);
  malformed("FLEXID/S2/VOLTAGE", Encode(Voltage(B + 300'000, 7.0, "S1")));
  malformed("FLEXID/S2/DEFLECTION", Encode(Deflection(B + 300'000, 0.7, "S1")));
  malformed(V, Encode(Voltage(B + 300'000, 7.0, "S1x")));
  malformed(D, Encode(Deflection(B + 300'000, 0.7, "S")));
  flexid::trial_control2_t control;  // correctly signed, but no such action
  control.utime = B + 300'000;
  control.actuator_id = "S1";
  control.action = 7;
  control.protocol = "bogus";
  control.sent_utime = bus::WallClockUtime();
  auth::Sign(key_, &control);
  malformed("FLEXID/TRIAL", Encode(control));
  malformed("FLEXID/RPC/REQUEST", Bytes(text.begin(), text.end()));
  // A valid "status" request of 2000 bytes: over the limit, so no reply.
  flexid::rpc_request_t big = Request("status", "");
  big.request_id = "oversized";
  big.args_json = nlohmann::json({{"pad", std::string(1900, 'x')}}).dump();
  ASSERT_GT(big.getEncodedSize(), 1024);
  malformed("FLEXID/RPC/REQUEST", Encode(big));

  // Non-finite values (their utime is later than anything accepted; they must not move
  // the stream's clock).
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  for (double bad : {nan, inf, -inf}) {
    Send(V, Voltage(B + 400'000, bad));
    ++want.rejected_nonfinite;
  }
  for (double bad : {nan, inf}) {
    Send(D, Deflection(B + 400'000, bad));
    ++want.rejected_nonfinite;
  }
  accepted_voltage(B + 150'000, 4.0);
  accepted_deflection(B + 200'000, 4.0, 0.20);

  // Out of order and duplicates, on both streams.
  for (int64_t utime : {B + 150'000, B + 100'000}) {
    Send(V, Voltage(utime, 9.0));
    ++want.rejected_out_of_order;
  }
  for (int64_t utime : {B + 200'000, B + 150'000, int64_t{-5}}) {
    Send(D, Deflection(utime, 0.9));
    ++want.rejected_out_of_order;
  }

  // A request of exactly max_message_bytes is served.
  flexid::rpc_request_t exact = Request("status", "");
  exact.args_json = nlohmann::json({{"pad", ""}}).dump();
  const int base_size = exact.getEncodedSize();
  exact.args_json =
      nlohmann::json({{"pad", std::string(static_cast<size_t>(1024 - base_size), 'x')}}).dump();
  ASSERT_EQ(exact.getEncodedSize(), 1024);
  const auto exact_reply = Call(exact);
  ASSERT_TRUE(exact_reply.has_value()) << "no reply to a request of exactly max_message_bytes";
  EXPECT_EQ(exact_reply->status, flexid::rpc_reply_t::kOk) << exact_reply->error;

  // Still alive and predicting: a valid pair produces a prediction.
  accepted_voltage(B + 500'000, 3.0);
  accepted_deflection(B + 600'000, 3.0, 0.30);
  ASSERT_TRUE(Drive(
      [&] {
        return std::any_of(bus_->predictions.begin(), bus_->predictions.end(),
                           [&](const auto& p) { return p.utime == B + 600'000; });
      },
      3s))
      << "no prediction for the last deflection sample";
  const auto& last = bus_->predictions.back();
  EXPECT_EQ(last.utime, B + 600'000);
  EXPECT_EQ(last.actuator_id, "S1");
  EXPECT_EQ(last.voltage_V, 3.0);
  EXPECT_EQ(last.measured_mm, 0.30);
  EXPECT_GT(last.trial_id, 0);
  EXPECT_TRUE(bus_->RepliesTo("oversized").empty()) << "an oversized request was served";

  // Exactly what was sent, nothing lost, nothing else counted.
  const daemon::Counters got = daemon_->counters();
  EXPECT_EQ(lost_, 0) << "UDP loss on loopback";
  EXPECT_EQ(got.messages_received, sent_);
  EXPECT_EQ(got.samples_accepted, want.samples_accepted);
  EXPECT_EQ(got.rejected_malformed, want.rejected_malformed);
  EXPECT_EQ(got.rejected_nonfinite, want.rejected_nonfinite);
  EXPECT_EQ(got.rejected_out_of_order, want.rejected_out_of_order);
  EXPECT_EQ(got.rejected_unknown_actuator, 0);
  EXPECT_EQ(got.dropped_queue_full, 0);
  EXPECT_EQ(got.predictions_published, want.predictions_published);
  std::cout << "sent " << sent_ << " messages: accepted " << got.samples_accepted << ", malformed "
            << got.rejected_malformed << ", non-finite " << got.rejected_nonfinite
            << ", out of order " << got.rejected_out_of_order << ", lost " << lost_ << "\n";

  // STATUS carries the same figures (the next heartbeat, at most a second away).
  ASSERT_TRUE(Drive(
      [&] {
        return !bus_->statuses.empty() && bus_->statuses.back().messages_received == sent_ &&
               bus_->statuses.back().samples_stored == static_cast<int64_t>(stored.size());
      },
      3s))
      << "no STATUS with the final counters";
  const flexid::status_t& status = bus_->statuses.back();
  EXPECT_EQ(status.daemon_id, "faults");
  EXPECT_EQ(status.samples_accepted, want.samples_accepted);
  EXPECT_EQ(status.rejected_malformed, want.rejected_malformed);
  EXPECT_EQ(status.rejected_nonfinite, want.rejected_nonfinite);
  EXPECT_EQ(status.rejected_out_of_order, want.rejected_out_of_order);
  EXPECT_EQ(status.rejected_unknown_actuator, 0);
  EXPECT_EQ(status.trials_recording, 1);

  // Stored data: only the accepted samples, paired with the voltage in force; no actuator
  // was created from a misaddressed message.
  daemon_.reset();
  storage::Database db = storage::Database::Open(scratch_.File("flexid.db"));
  EXPECT_EQ(db.IntegrityCheck(), "ok");
  const auto actuators = db.Actuators();
  ASSERT_EQ(actuators.size(), 1u);
  EXPECT_EQ(actuators.front().id, "S1");
  const auto trials = db.Trials();
  ASSERT_EQ(trials.size(), 1u);
  EXPECT_EQ(trials.front().start_utime, B);
  const auto samples = db.Samples(trials.front().id);
  ASSERT_EQ(samples.size(), stored.size());
  for (size_t i = 0; i < samples.size(); ++i) {
    EXPECT_EQ(samples[i].utime, stored[i].utime) << i;
    EXPECT_EQ(samples[i].voltage_V, stored[i].voltage_V) << i;
    EXPECT_EQ(samples[i].deflection_mm, stored[i].deflection_mm) << i;
  }
  // For bench/fault-table: every accepted sample is stored exactly as sent.
  int64_t missing = 0;
  for (const storage::Sample& want_sample : stored)
    missing += std::none_of(samples.begin(), samples.end(), [&](const storage::Sample& s) {
      return s.utime == want_sample.utime && s.voltage_V == want_sample.voltage_V &&
             s.deflection_mm == want_sample.deflection_mm;
    });
  RecordFault({"bad input (malformed, oversized, NaN/Inf, out of order, duplicate, misaddressed)",
               got.rejected_malformed + got.rejected_nonfinite + got.rejected_out_of_order,
               static_cast<int64_t>(stored.size()), missing, db.IntegrityCheck(), "never stopped",
               "each rejected and counted by kind; the daemon went on predicting"});
}

// ---------------------------------------------------------------------------------------
// 3. RPC robustness
// ---------------------------------------------------------------------------------------

TEST_F(InProcessDaemon, RpcRejectsBadRequestsAndServesAnEmptyDatabase) {
  Start(/*max_message_bytes=*/65536);
  if (IsSkipped()) return;

  // An empty database: read-only queries succeed.
  for (const char* method : {"trials", "actuators", "alerts"}) {
    const auto reply = Call(method, "");
    ASSERT_TRUE(reply.has_value()) << method;
    EXPECT_EQ(reply->status, flexid::rpc_reply_t::kOk) << method << ": " << reply->error;
    EXPECT_EQ(nlohmann::json::parse(reply->result_json), nlohmann::json::array()) << method;
  }
  {
    const auto reply = Call("status", "{}");
    ASSERT_TRUE(reply.has_value());
    EXPECT_EQ(reply->status, flexid::rpc_reply_t::kOk) << reply->error;
    const auto result = nlohmann::json::parse(reply->result_json);
    EXPECT_EQ(result["daemon_id"], "faults");
    EXPECT_EQ(result["samples_stored"], 0);
    EXPECT_EQ(result["rejected_malformed"], 0);
  }

  // Invalid client ids: no reply anywhere, no crash.
  const std::vector<std::string> bad_clients = {"",    "has space", "a/b",
                                                "x\n", "ü",         std::string(65, 'a')};
  for (const std::string& client : bad_clients) {
    const flexid::rpc_request_t request = Request("status", "", client);
    Send("FLEXID/RPC/REQUEST", request);
    Drive([] { return false; }, 100ms);
    EXPECT_TRUE(bus_->RepliesTo(request.request_id).empty())
        << "a reply to client id \"" << client << "\"";
  }
  // Request ids must be 1-128 characters: an answer saying so.
  for (const std::string& id : {std::string(), std::string(129, 'r')}) {
    flexid::rpc_request_t request = Request("status", "");
    request.request_id = id;
    Send("FLEXID/RPC/REQUEST", request);
    ASSERT_TRUE(Drive([&] { return !bus_->RepliesTo(id).empty(); }, 3s))
        << "no reply to a request id of " << id.size() << " characters";
    const flexid::rpc_reply_t reply = bus_->RepliesTo(id).front().second;  // a copy: RepliesTo
    EXPECT_EQ(reply.status, flexid::rpc_reply_t::kBadRequest);             // returns by value
    EXPECT_NE(reply.error.find("request_id"), std::string::npos) << reply.error;
  }
  // Undecodable requests: no reply, counted.
  const int64_t malformed_before = daemon_->counters().rejected_malformed;
  SendRaw("FLEXID/RPC/REQUEST", Bytes{1, 2, 3});
  EXPECT_EQ(daemon_->counters().rejected_malformed, malformed_before + 1);

  // Arguments that are not JSON, not an object, or of the wrong type: kBadRequest naming
  // what is wrong.
  ExpectBadRequest("trials", "{", "args_json");
  ExpectBadRequest("trials", "{\"limit\": 5", "args_json");
  for (const char* not_object : {"[1, 2]", "42", "null", "\"limit\"", "true"})
    ExpectBadRequest("trials", not_object, "args_json");
  const std::string deep = std::string(30'000, '[') + std::string(30'000, ']');
  ExpectBadRequest("status", deep, "args_json");
  ExpectBadRequest("trials", R"({"limit": "ten"})", "\"limit\"");
  ExpectBadRequest("trials", R"({"limit": 1.5})", "\"limit\"");
  ExpectBadRequest("trials", R"({"limit": 0})", "\"limit\"");
  ExpectBadRequest("trials", R"({"limit": 1e30})", "\"limit\"");
  ExpectBadRequest("trials", R"({"actuator": 5})", "\"actuator\"");
  ExpectBadRequest("trials", R"({"actuator": ["S1"]})", "\"actuator\"");
  {  // An actuator the file does not know is not found (with several daemons: one that holds
     // none of it says so).
    const auto reply = Call("trials", R"({"actuator": "S9"})");
    ASSERT_TRUE(reply.has_value()) << "no reply";
    EXPECT_EQ(reply->status, flexid::rpc_reply_t::kNotFound) << reply->error;
    EXPECT_NE(reply->error.find("S9"), std::string::npos) << reply->error;
  }
  // The daemon a request is addressed to (several daemons on one bus) is named by a string.
  ExpectBadRequest("trials", R"({"daemon_id": 5})", "\"daemon_id\"");
  ExpectBadRequest("alerts", R"({"since_utime": -1})", "\"since_utime\"");
  ExpectBadRequest("alerts", R"({"limit": null})", "\"limit\"");
  ExpectBadRequest("trial_samples", R"({"trial": "1"})", "\"trial\"");
  ExpectBadRequest("trial_samples", R"({"trial": 0})", "\"trial\"");
  ExpectBadRequest("models", "{}", "\"actuator\"");
  ExpectBadRequest("model", R"({"actuator": {"id": "S1"}})", "\"actuator\"");
  ExpectBadRequest("identify", "{}", "\"actuator\"");

  // Unknown methods.
  ExpectBadRequest("frobnicate", "{}", "frobnicate");
  ExpectBadRequest("", "{}", "unknown method");
  ExpectBadRequest("STATUS", "{}", "STATUS");

  // Still serving, and nothing was stored.
  const auto reply = Call("trials", R"({"limit": 10})");
  ASSERT_TRUE(reply.has_value());
  EXPECT_EQ(reply->status, flexid::rpc_reply_t::kOk) << reply->error;
  EXPECT_EQ(nlohmann::json::parse(reply->result_json), nlohmann::json::array());
  const daemon::Counters got = daemon_->counters();
  EXPECT_EQ(lost_, 0) << "UDP loss on loopback";
  EXPECT_EQ(got.messages_received, sent_);
  EXPECT_EQ(got.rejected_malformed, malformed_before + 1);
  EXPECT_EQ(got.samples_accepted, 0);
  daemon_.reset();
  storage::Database db = storage::Database::Open(scratch_.File("flexid.db"));
  EXPECT_EQ(db.IntegrityCheck(), "ok");
  EXPECT_TRUE(db.Trials().empty());
  EXPECT_TRUE(db.Actuators().empty());
}

// ---------------------------------------------------------------------------------------
// 4. Crafted string length prefixes, against the real binary
// ---------------------------------------------------------------------------------------

// lcm-gen's C++ decoder checks a string's length prefix only against the bytes left; a
// length <= 0 makes std::string::assign throw, and INT32_MIN makes `length - 1` overflow
// to INT32_MAX, so assign reads 2 GiB past the receive buffer. The daemon must count
// such a message as malformed and go on.
class CraftedStringLength : public ::testing::Test {
 protected:
  void SetUp() override {
    url_ = RandomUrl();
    bus_ = std::make_unique<Bus>(url_, /*with_predictions=*/false);
    if (!bus_->good()) GTEST_SKIP() << "no LCM multicast on this host (" << url_ << ")";
    daemon_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{kFlexidd, "--db", scratch_.File("flexid.db"), "--lcm", url_,
                                 "--log-file", scratch_.File("flexidd.log")},
        scratch_.File("flexidd.out"), scratch_.File("flexidd.err"));
    ASSERT_TRUE(daemon_->started());
    ASSERT_TRUE(bus_->PumpUntil([&] { return !bus_->statuses.empty(); }, 10s))
        << "flexidd sent no STATUS: " << ReadFile(scratch_.File("flexidd.err"));
  }
  // The daemon's counters by RPC "status" (nothing if it does not answer).
  std::optional<nlohmann::json> Status() {
    flexid::rpc_request_t request;
    request.utime = 0;
    request.request_id = "s" + std::to_string(++requests_);
    request.client_id = "faults_test";
    request.method = "status";
    bus_->Publish("FLEXID/RPC/REQUEST", request);
    bus_->PumpUntil([&] { return !bus_->RepliesTo(request.request_id).empty(); }, 3s);
    const auto replies = bus_->RepliesTo(request.request_id);
    if (replies.empty()) return std::nullopt;
    return nlohmann::json::parse(replies.front().second.result_json);
  }
  std::string Log() { return ReadFile(scratch_.File("flexidd.err")); }

  testing::ScratchDir scratch_;
  std::string url_;
  std::unique_ptr<Bus> bus_;
  std::unique_ptr<ChildProcess> daemon_;
  int requests_ = 0;
};

TEST_F(CraftedStringLength, NonPositiveLengthIsCountedAsMalformed) {
  for (int32_t length : {0, -1, -1000}) {
    ASSERT_EQ(bus_->PublishRaw("FLEXID/S1/VOLTAGE", VoltageWithStringLength(length)), 0);
    std::this_thread::sleep_for(2ms);
  }
  const auto status = Status();
  ASSERT_TRUE(status.has_value()) << "flexidd did not answer: " << Log();
  EXPECT_EQ((*status)["messages_received"], 4);  // three samples and this request
  EXPECT_EQ((*status)["rejected_malformed"], 3) << "a malformed message went uncounted: " << Log();
  EXPECT_TRUE(daemon_->Running());
  RecordFault({"bad input: LCM string length <= 0", 3, 0, 0, "n/a", "never stopped",
               "counted as malformed"});
}

TEST_F(CraftedStringLength, MinInt32LengthDoesNotCrashTheDaemon) {
  ASSERT_EQ(bus_->PublishRaw("FLEXID/S1/VOLTAGE",
                             VoltageWithStringLength(std::numeric_limits<int32_t>::min())),
            0);
  const auto status = Status();
  const auto exited = daemon_->Wait(0ms);
  ASSERT_FALSE(exited.has_value()) << "flexidd died (" << DescribeStatus(*exited)
                                   << ") on one 28-byte message with a string length of "
                                      "INT32_MIN: "
                                   << Log();
  ASSERT_TRUE(status.has_value()) << "flexidd did not answer: " << Log();
  EXPECT_EQ((*status)["rejected_malformed"], 1);
  RecordFault({"bad input: LCM string length INT32_MIN", 1, 0, 0, "n/a", "never stopped",
               "counted as malformed (it used to crash lcm-gen's decoder)"});
}

}  // namespace
}  // namespace flexid
