// The bus-free halves of flexid-control and flexid-rig --closed-loop: the control session
// (clients/control/session.h: sample numbering, commands for the next sample, stale
// measurement, stops) and the rig's command inbox and closed-loop plant
// (clients/rig/closed_loop.h: signatures, freshness, message-time order, the watchdog).
#include <gtest/gtest.h>

#include <cmath>
#include <flexid/voltage_command_t.hpp>
#include <string>
#include <vector>

#include "clients/control/reference_input.h"
#include "clients/control/session.h"
#include "clients/rig/closed_loop.h"
#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/core/simulate.h"

namespace flexid {
namespace {

constexpr int64_t kStart = 1'700'000'000'000'000;  // message time of the first sample
constexpr int64_t kWall = 1'800'000'000'000'000;   // a wall clock

control::ControlSession Session() {
  model::control::ControllerOptions options;
  options.kind = model::control::ControllerKind::kPi;
  model::control::Controller controller(
      model::SeedTsModel(), control::ReferenceFromProtocol("hold:level=10,duration=2", 0.1),
      options);
  return control::ControlSession(std::move(controller), {}, kWall);
}

TEST(ControlSession, AnswersEachSampleForTheNextAndIgnoresOldOnes) {
  control::ControlSession session = Session();
  const auto first = session.OnDeflection(kStart, 0.0, kWall);
  ASSERT_TRUE(first);
  EXPECT_EQ(first->utime, kStart + 100'000);
  EXPECT_EQ(first->sequence, 1);
  EXPECT_GT(first->voltage_V, 0.0);  // 10 mm wanted, 0 measured
  // It carries the reference at the sample it answers.
  EXPECT_EQ(first->reference_utime, kStart);
  EXPECT_DOUBLE_EQ(first->reference_mm, 10.0);
  EXPECT_FALSE(session.OnDeflection(kStart, 0.0, kWall));  // the same sample again
  const auto later = session.OnDeflection(kStart + 300'000, 0.5, kWall + 10'000);  // 2 missed
  ASSERT_TRUE(later);
  EXPECT_EQ(later->utime, kStart + 400'000);
  EXPECT_EQ(session.rows().size(), 2u);
}

TEST(ControlSession, StopsAfterTheReferenceAndOnAStaleMeasurement) {
  control::ControlSession session = Session();
  EXPECT_FALSE(session.Stop(control::StopReason::kSignal));  // nothing to stop before a sample
  control::ControlSession running = Session();
  running.OnDeflection(kStart, 0.0, kWall);
  EXPECT_FALSE(running.StaleAt(kWall + 400'000));
  EXPECT_EQ(running.StaleAt(kWall + 600'000), control::StopReason::kStaleMeasurement);
  for (int k = 1; k <= 21 && !running.finished(); ++k)
    running.OnDeflection(kStart + k * 100'000, 1.0, kWall + k * 1000);
  EXPECT_TRUE(running.finished());  // 2 s of reference at 10 Hz
  const auto stop = running.Stop(control::StopReason::kFinished);
  ASSERT_TRUE(stop);
  EXPECT_TRUE(stop->stop);
  EXPECT_EQ(stop->voltage_V, 0.0);
  EXPECT_EQ(stop->reference_utime, 0);  // a stop follows no reference
  EXPECT_EQ(stop->utime, running.last_utime() + 100'000);
  EXPECT_FALSE(running.Stop(control::StopReason::kSignal));  // once
}

TEST(ControlSession, ModelMismatchAlertsStopOnlyAControllerWithoutFeedback) {
  for (const char* kind : {"residual", "drift", "back_relaxation"}) {
    EXPECT_FALSE(control::AlertStopsControl(kind, /*feedback=*/true)) << kind;
    EXPECT_TRUE(control::AlertStopsControl(kind, /*feedback=*/false)) << kind;
  }
  for (const char* kind : {"sensor_dropout", "storage_failing", "a_kind_added_later"}) {
    EXPECT_TRUE(control::AlertStopsControl(kind, true)) << kind;
    EXPECT_TRUE(control::AlertStopsControl(kind, false)) << kind;
  }
  EXPECT_FALSE(control::AlertStopsControl("control_stop", true));
  EXPECT_FALSE(control::AlertStopsControl("control_stop", false));
}

TEST(ControlSession, NoMeasurementWithinTheStartTimeoutIsNoticed) {
  const control::ControlSession session = Session();
  EXPECT_FALSE(session.StartTimedOut(kWall + 9'000'000));
  EXPECT_TRUE(session.StartTimedOut(kWall + 11'000'000));
}

TEST(ReferenceFromProtocol, ReadsTheLevelsInMillimetres) {
  const model::control::Reference reference =
      control::ReferenceFromProtocol("staircase:levels=5/12,dwell=10", 0.1);
  EXPECT_DOUBLE_EQ(reference.At(5.0), 5.0);
  EXPECT_DOUBLE_EQ(reference.At(15.0), 12.0);
  EXPECT_DOUBLE_EQ(reference.At(25.0), 0.0);
  EXPECT_DOUBLE_EQ(reference.duration_s(), 30.0);
  EXPECT_THROW(control::ReferenceFromProtocol("sine:amplitude=1,frequency=5,duration=10", 0.1),
               model::InputError);
}

auth::Key TestKey() {
  auth::Key key;
  for (size_t i = 0; i < key.bytes.size(); ++i) key.bytes[i] = static_cast<uint8_t>(i * 7 + 1);
  return key;
}

flexid::voltage_command_t Signed(int64_t utime, double voltage_V, int64_t sequence,
                                 int64_t sent_utime, const auth::Key& key) {
  flexid::voltage_command_t command;
  command.utime = utime;
  command.actuator_id = "S1";
  command.voltage_V = voltage_V;
  command.sequence = sequence;
  command.controller_id = "c1";
  command.mode = flexid::voltage_command_t::kTrack;
  command.reference_mm = 10.0;
  command.reference_utime = utime - 100'000;
  command.sent_utime = sent_utime;
  auth::Sign(key, &command);
  return command;
}

TEST(CommandInbox, AcceptsFreshSignedCommandsInOrderAndRefusesTheRest) {
  const auth::Key key = TestKey();
  std::vector<std::string> log;
  rig::CommandInbox inbox(key, "S1", 0.5, [&](const std::string& line) { log.push_back(line); });
  flexid::voltage_command_t unsigned_command = Signed(kStart, 3.0, 1, kWall, key);
  unsigned_command.auth.clear();
  EXPECT_EQ(inbox.Receive(unsigned_command, kWall), "no signature");
  EXPECT_EQ(inbox.Receive(Signed(kStart, 3.0, 2, kWall - 2'000'000, key), kWall),
            "command time 2.0 s behind this host's clock (window 0.5 s)");
  flexid::voltage_command_t other = Signed(kStart, 3.0, 3, kWall, key);
  other.actuator_id = "S2";
  EXPECT_NE(inbox.Receive(other, kWall), "");
  // Signed, but a field no controller sends: refused before the signature is looked at.
  flexid::voltage_command_t ahead = Signed(kStart, 3.0, 3, kWall, key);
  ahead.reference_utime = kStart + 100'000;
  auth::Sign(key, &ahead);
  EXPECT_EQ(inbox.Receive(ahead, kWall),
            "invalid: reference_utime 1700000000100000 is after the command's utime "
            "1700000000000000");
  flexid::voltage_command_t nan_reference = Signed(kStart, 3.0, 3, kWall, key);
  nan_reference.reference_mm = std::nan("");
  auth::Sign(key, &nan_reference);
  EXPECT_EQ(inbox.Receive(nan_reference, kWall), "invalid: reference_mm is not finite (nan)");
  // The signature covers the reference: changed after signing, it no longer matches.
  flexid::voltage_command_t moved = Signed(kStart, 3.0, 3, kWall, key);
  moved.reference_mm = 11.0;
  EXPECT_EQ(inbox.Receive(moved, kWall), "bad signature");
  EXPECT_EQ(inbox.counts().Refused(), 6);
  EXPECT_EQ(inbox.counts().refused_unsigned, 1);
  EXPECT_EQ(inbox.counts().refused_stale, 1);
  EXPECT_EQ(inbox.counts().refused_bad_signature, 1);

  EXPECT_DOUBLE_EQ(inbox.VoltageFor(kStart, kWall), 0.0);  // nothing accepted yet
  EXPECT_EQ(inbox.Receive(Signed(kStart + 100'000, 2.5, 4, kWall, key), kWall), "");
  EXPECT_TRUE(inbox.Answered(kStart + 100'000));
  EXPECT_DOUBLE_EQ(inbox.VoltageFor(kStart + 100'000, kWall + 1000), 2.5);
  // For a sample already played, or an older sequence: stale.
  EXPECT_NE(inbox.Receive(Signed(kStart + 100'000, 4.0, 5, kWall, key), kWall).find("stale"),
            std::string::npos);
  EXPECT_NE(inbox.Receive(Signed(kStart + 200'000, 4.0, 3, kWall, key), kWall).find("stale"),
            std::string::npos);
  // The watchdog: no command for more than 0.5 s of wall time, 0 V.
  EXPECT_DOUBLE_EQ(inbox.VoltageFor(kStart + 200'000, kWall + 400'000), 2.5);
  EXPECT_DOUBLE_EQ(inbox.VoltageFor(kStart + 300'000, kWall + 600'000), 0.0);
  EXPECT_EQ(inbox.counts().timeouts, 1);
  EXPECT_FALSE(log.empty());
}

// The closed-loop plant is the rig's model stepped on the voltage given: on a voltage
// known in advance it is the batch simulation.
TEST(ClosedLoopPlant, IsTheModelOnTheVoltageGiven) {
  rig::ClosedLoopPlant plant(model::SeedTsModel(), {}, {});
  std::vector<double> voltages, deflections;
  for (int k = 0; k < 600; ++k) {
    voltages.push_back(k < 50 ? 0.0 : (k < 300 ? 5.0 : -2.0));
    deflections.push_back(plant.Next(voltages.back()).deflection_mm);
  }
  const std::vector<double> batch = model::SimulateUniform(model::SeedTsModel(), 0.1, voltages);
  for (size_t k = 0; k < batch.size(); ++k) EXPECT_NEAR(deflections[k], batch[k], 1e-9) << k;
}

}  // namespace
}  // namespace flexid
