// Tests of flexid-rig: protocols, effects, the sample stream, the runner, and the real
// binary publishing on a real LCM bus (UDP multicast, ttl=0, random port).
#include "clients/rig/rig.h"

#include <gtest/gtest.h>
#include <sys/wait.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <memory>
#include <optional>
#include <random>
#include <regex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bus/clock.h"
#include "cli_process.h"
#include "clients/rig/effects.h"
#include "clients/rig/protocol.h"
#include "clients/rig/runner.h"
#include "lcm_subscribe.h"
#include "lcmtypes/message_auth.h"
#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/core/recording.h"
#include "model/core/simulate.h"
#include "scratch_dir.h"

namespace flexid {
namespace {

using rig::ParseEffect;
using rig::ParseProtocol;
using rig::Protocol;
using rig::ProtocolDuration;
using rig::VoltageAt;

// The error message of ParseProtocol / ParseEffect, or "" if it succeeds.
template <typename Parse>
std::string ErrorOf(Parse parse) {
  try {
    parse();
  } catch (const model::InputError& error) {
    return error.what();
  }
  return "";
}
std::string ProtocolError(const std::string& spec) {
  return ErrorOf([&] { ParseProtocol(spec); });
}
std::string EffectError(const std::string& spec) {
  return ErrorOf([&] { ParseEffect(spec); });
}

// ---------------------------------------------------------------------------------------
// Protocols
// ---------------------------------------------------------------------------------------

TEST(Protocol, StepWithAndWithoutDelay) {
  Protocol p = ParseProtocol("step:level=2,duration=600");
  EXPECT_EQ(p.shape, Protocol::Shape::kStep);
  EXPECT_EQ(p.text, "step:level=2,duration=600");
  EXPECT_EQ(p.level_V, 2.0);
  EXPECT_EQ(p.duration_s, 600.0);
  EXPECT_EQ(p.delay_s, 0.0);  // default
  EXPECT_EQ(ProtocolDuration(p), 600.0);

  p = ParseProtocol("step:delay=5,level=-1.5,duration=10");  // any key order
  EXPECT_EQ(p.level_V, -1.5);
  EXPECT_EQ(p.delay_s, 5.0);
  EXPECT_EQ(ProtocolDuration(p), 15.0);
  EXPECT_EQ(ParseProtocol("step:level=2,duration=1,delay=0").delay_s, 0.0);
}

TEST(Protocol, SquareDefaultsToHalfDuty) {
  Protocol p = ParseProtocol("square:level=5,period=220,cycles=5");
  EXPECT_EQ(p.shape, Protocol::Shape::kSquare);
  EXPECT_EQ(p.level_V, 5.0);
  EXPECT_EQ(p.period_s, 220.0);
  EXPECT_EQ(p.duty, 0.5);
  EXPECT_EQ(p.cycles, 5);
  EXPECT_EQ(ProtocolDuration(p), 1100.0);
  EXPECT_EQ(ParseProtocol("square:level=5,period=220,duty=0.25,cycles=5").duty, 0.25);
}

TEST(Protocol, StaircaseAndHold) {
  Protocol p = ParseProtocol("staircase:levels=2/4/6/8,dwell=150");
  EXPECT_EQ(p.shape, Protocol::Shape::kStaircase);
  EXPECT_EQ(p.levels_V, (std::vector<double>{2, 4, 6, 8}));
  EXPECT_EQ(p.dwell_s, 150.0);
  EXPECT_EQ(ProtocolDuration(p), 750.0);  // four levels and the final rest
  EXPECT_EQ(ParseProtocol("staircase:levels=3,dwell=1").levels_V, std::vector<double>{3});

  p = ParseProtocol("hold:level=8,duration=30");
  EXPECT_EQ(p.shape, Protocol::Shape::kHold);
  EXPECT_EQ(p.level_V, 8.0);
  EXPECT_EQ(ProtocolDuration(p), 30.0);
}

TEST(Protocol, EveryErrorIsOneClearLine) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"", "protocol \"\": empty specification (expected NAME[:KEY=VALUE,...])"},
      {":level=2", "protocol \":level=2\": empty specification (expected NAME[:KEY=VALUE,...])"},
      {"ramp:level=2",
       "protocol \"ramp:level=2\": unknown protocol \"ramp\" (expected step, square, staircase, "
       "hold, sweep, sine or random)"},
      {"step", "protocol \"step\": missing key \"level\""},
      {"step:level=2", "protocol \"step:level=2\": missing key \"duration\""},
      {"step:level=2,duration=5,speed=3",
       "protocol \"step:level=2,duration=5,speed=3\": unknown key \"speed\" (step takes level, "
       "duration and delay)"},
      {"step:level=2,duration=0",
       "protocol \"step:level=2,duration=0\": duration must be > 0 s (got 0)"},
      {"step:level=2,duration=-3",
       "protocol \"step:level=2,duration=-3\": duration must be > 0 s (got -3)"},
      {"step:level=2,duration=5,delay=-1",
       "protocol \"step:level=2,duration=5,delay=-1\": delay must be >= 0 s (got -1)"},
      {"step:level=abc,duration=5",
       "protocol \"step:level=abc,duration=5\": level is not a finite number: \"abc\""},
      {"step:level=inf,duration=5",
       "protocol \"step:level=inf,duration=5\": level is not a finite number: \"inf\""},
      {"step:level=2V,duration=5",
       "protocol \"step:level=2V,duration=5\": level is not a finite number: \"2V\""},
      {"step:level=2,level=3,duration=5",
       "protocol \"step:level=2,level=3,duration=5\": key \"level\" given twice"},
      {"step:level", "protocol \"step:level\": expected KEY=VALUE, got \"level\""},
      {"step:level=", "protocol \"step:level=\": expected KEY=VALUE, got \"level=\""},
      {"step:=2", "protocol \"step:=2\": expected KEY=VALUE, got \"=2\""},
      {"step:", "protocol \"step:\": expected KEY=VALUE, got \"\""},
      {"step:level=2,,duration=5",
       "protocol \"step:level=2,,duration=5\": expected KEY=VALUE, got \"\""},
      {"square:level=5,period=220",
       "protocol \"square:level=5,period=220\": missing key \"cycles\""},
      {"square:level=5,cycles=2", "protocol \"square:level=5,cycles=2\": missing key \"period\""},
      {"square:level=5,period=0,cycles=1",
       "protocol \"square:level=5,period=0,cycles=1\": period must be > 0 s (got 0)"},
      {"square:level=5,period=10,duty=1,cycles=1",
       "protocol \"square:level=5,period=10,duty=1,cycles=1\": duty must be > 0 and < 1 (got 1)"},
      {"square:level=5,period=10,duty=0,cycles=1",
       "protocol \"square:level=5,period=10,duty=0,cycles=1\": duty must be > 0 and < 1 (got 0)"},
      {"square:level=5,period=10,cycles=2.5",
       "protocol \"square:level=5,period=10,cycles=2.5\": cycles must be a positive whole number "
       "(got \"2.5\")"},
      {"square:level=5,period=10,cycles=0",
       "protocol \"square:level=5,period=10,cycles=0\": cycles must be a positive whole number "
       "(got \"0\")"},
      {"square:level=5,period=10,cycles=1,dwell=3",
       "protocol \"square:level=5,period=10,cycles=1,dwell=3\": unknown key \"dwell\" (square "
       "takes level, period, duty, cycles and polarity)"},
      {"square:level=5,period=10,cycles=1,polarity=bipolar",
       "protocol \"square:level=5,period=10,cycles=1,polarity=bipolar\": polarity must be same or "
       "alternate (got \"bipolar\")"},
      {"square:level=5,period=10,cycles=1,polarity=alternate,polarity=same",
       "protocol \"square:level=5,period=10,cycles=1,polarity=alternate,polarity=same\": key "
       "\"polarity\" given twice"},
      {"square:level=5,period=10,polarity=alternate",
       "protocol \"square:level=5,period=10,polarity=alternate\": missing key \"cycles\""},
      {"step:level=2,duration=5,polarity=alternate",
       "protocol \"step:level=2,duration=5,polarity=alternate\": unknown key \"polarity\" (step "
       "takes level, duration and delay)"},
      {"staircase:dwell=10", "protocol \"staircase:dwell=10\": missing key \"levels\""},
      {"staircase:levels=2/4", "protocol \"staircase:levels=2/4\": missing key \"dwell\""},
      {"staircase:levels=2/x/6,dwell=10",
       "protocol \"staircase:levels=2/x/6,dwell=10\": levels is not a list of finite numbers "
       "separated by '/': \"2/x/6\""},
      {"staircase:levels=2//6,dwell=10",
       "protocol \"staircase:levels=2//6,dwell=10\": levels is not a list of finite numbers "
       "separated by '/': \"2//6\""},
      {"staircase:levels=2/4,dwell=-1",
       "protocol \"staircase:levels=2/4,dwell=-1\": dwell must be > 0 s (got -1)"},
      {"hold:level=1", "protocol \"hold:level=1\": missing key \"duration\""},
      {"hold:level=1,duration=2,delay=1",
       "protocol \"hold:level=1,duration=2,delay=1\": unknown key \"delay\" (hold takes level and "
       "duration)"},
      {"hold:level=1,duration=1e308,",
       "protocol \"hold:level=1,duration=1e308,\": expected "
       "KEY=VALUE, got \"\""},
      {"square:level=1,period=1e308,cycles=10",
       "protocol \"square:level=1,period=1e308,cycles=10\": the protocol is too long"},
  };
  for (const auto& [spec, message] : cases) EXPECT_EQ(ProtocolError(spec), message) << spec;
}

TEST(VoltageAt, SquareWaveFollowsDutyAndPeriodThenRests) {
  const Protocol p = ParseProtocol("square:level=5,period=10,duty=0.3,cycles=2");
  EXPECT_EQ(ProtocolDuration(p), 20.0);
  EXPECT_EQ(VoltageAt(p, 0.0), 5.0);
  EXPECT_EQ(VoltageAt(p, 2.9), 5.0);
  EXPECT_EQ(VoltageAt(p, 3.0), 0.0);  // duty * period
  EXPECT_EQ(VoltageAt(p, 9.99), 0.0);
  EXPECT_EQ(VoltageAt(p, 10.0), 5.0);  // the second cycle
  EXPECT_EQ(VoltageAt(p, 12.99), 5.0);
  EXPECT_EQ(VoltageAt(p, 13.0), 0.0);
  EXPECT_EQ(VoltageAt(p, 19.99), 0.0);
  EXPECT_EQ(VoltageAt(p, 20.0), 0.0);  // after the last cycle: no third one
  EXPECT_EQ(VoltageAt(p, 1000.0), 0.0);
  EXPECT_EQ(VoltageAt(p, -1.0), 0.0);  // at rest before the start
  // Fraction of on-time over the protocol, at 1 kHz.
  int on = 0;
  for (int k = 0; k < 20000; ++k) on += VoltageAt(p, k / 1000.0) == 5.0 ? 1 : 0;
  EXPECT_EQ(on, 6000);
}

TEST(Protocol, SquarePolarityIsSameUnlessAlternate) {
  EXPECT_FALSE(ParseProtocol("square:level=5,period=220,cycles=5").alternate_polarity);
  EXPECT_FALSE(
      ParseProtocol("square:level=5,period=220,cycles=5,polarity=same").alternate_polarity);
  const Protocol p = ParseProtocol("square:polarity=alternate,level=5,period=220,cycles=6");
  EXPECT_TRUE(p.alternate_polarity);
  EXPECT_EQ(p.level_V, 5.0);
  EXPECT_EQ(ProtocolDuration(p), 1320.0);
}

TEST(VoltageAt, AlternatePolaritySquareFlipsEverySecondPeriod) {
  const Protocol p = ParseProtocol("square:level=5,period=10,duty=0.3,cycles=3,polarity=alternate");
  const std::vector<std::pair<double, double>> expected = {
      {0.0, 5},   {2.99, 5}, {3.0, 0},   {9.99, 0}, {10.0, -5}, {12.99, -5}, {13.0, 0},
      {19.99, 0}, {20.0, 5}, {22.99, 5}, {23.0, 0}, {30.0, 0},  {1000.0, 0}, {-1.0, 0}};
  for (const auto& [t_s, voltage_V] : expected) EXPECT_EQ(VoltageAt(p, t_s), voltage_V) << t_s;
  // A negative level starts negative.
  const Protocol negative = ParseProtocol("square:level=-2,period=10,cycles=2,polarity=alternate");
  EXPECT_EQ(VoltageAt(negative, 1.0), -2.0);
  EXPECT_EQ(VoltageAt(negative, 11.0), 2.0);
  // Without the option every period goes to +level (unchanged behaviour).
  const Protocol same = ParseProtocol("square:level=5,period=10,cycles=2");
  EXPECT_EQ(VoltageAt(same, 11.0), 5.0);
}

TEST(VoltageAt, StaircaseStepsThroughTheLevelsThenRestsOneDwell) {
  const Protocol p = ParseProtocol("staircase:levels=2/4/6/8,dwell=10");
  EXPECT_EQ(ProtocolDuration(p), 50.0);
  const std::vector<std::pair<double, double>> expected = {
      {0.0, 2},   {9.99, 2}, {10.0, 4},  {19.99, 4}, {20.0, 6}, {30.0, 8},
      {39.99, 8}, {40.0, 0}, {49.99, 0}, {50.0, 0},  {500.0, 0}};
  for (const auto& [t_s, voltage_V] : expected) EXPECT_EQ(VoltageAt(p, t_s), voltage_V) << t_s;
}

TEST(VoltageAt, StepAndHold) {
  const Protocol step = ParseProtocol("step:level=3,duration=10,delay=2");
  EXPECT_EQ(VoltageAt(step, 0.0), 0.0);
  EXPECT_EQ(VoltageAt(step, 1.999), 0.0);
  EXPECT_EQ(VoltageAt(step, 2.0), 3.0);
  EXPECT_EQ(VoltageAt(step, 11.99), 3.0);
  const Protocol hold = ParseProtocol("hold:level=-4,duration=10");
  EXPECT_EQ(VoltageAt(hold, 0.0), -4.0);
  EXPECT_EQ(VoltageAt(hold, 9.99), -4.0);
}

TEST(VoltageAt, ABoundaryMissedByRoundingCountsAsReached) {
  // 0.7 s at 10 Hz is sample 7, at 7 / 10.0 = 0.7 but 0.1 * 7 = 0.7000000000000001 and
  // 0.7 - 1e-16 would be before it: both must see the change that falls on 0.7 s.
  const Protocol p = ParseProtocol("step:level=1,duration=1,delay=0.7");
  EXPECT_EQ(VoltageAt(p, std::nextafter(0.7, 0.0)), 1.0);
  EXPECT_EQ(VoltageAt(p, 0.7 - 1e-12), 1.0);
  EXPECT_EQ(VoltageAt(p, 0.7 - 1e-6), 0.0);
  // A staircase with a dwell of 0.1 s sampled at 30 Hz: the change at 0.3 s lands on
  // sample 9 (9 / 30.0), not one sample late.
  const Protocol stairs = ParseProtocol("staircase:levels=1/2/3/4,dwell=0.1");
  EXPECT_EQ(VoltageAt(stairs, 9 / 30.0), 4.0);
  EXPECT_EQ(VoltageAt(stairs, 8 / 30.0), 3.0);
}

// ---------------------------------------------------------------------------------------
// Effects
// ---------------------------------------------------------------------------------------

TEST(Effects, BackRelaxationDefaultsAndParameters) {
  EXPECT_EQ(ParseEffect("back_relaxation")->Describe(), "back_relaxation:fraction=0.3,tau=60");
  EXPECT_EQ(ParseEffect("back_relaxation:tau=120.5,fraction=0.25")->Describe(),
            "back_relaxation:fraction=0.25,tau=120.5");
  EXPECT_EQ(ParseEffect("back_relaxation:fraction=1")->Describe(),
            "back_relaxation:fraction=1,tau=60");
  EXPECT_EQ(rig::EffectNames(),
            (std::vector<std::string>{"back_relaxation", "cycle_degradation", "hysteresis",
                                      "electrolysis_saturation", "sensor_drift",
                                      "polarity_asymmetry", "dead_zone"}));
}

TEST(Effects, EveryEffectHasDefaultsAndTakesItsParameters) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"cycle_degradation", "cycle_degradation:loss=0.2,charge=5000"},
      {"cycle_degradation:charge=2750,loss=0.05", "cycle_degradation:loss=0.05,charge=2750"},
      {"cycle_degradation:loss=0", "cycle_degradation:loss=0,charge=5000"},
      {"hysteresis", "hysteresis:width=0.5"},
      {"hysteresis:width=0", "hysteresis:width=0"},
      {"electrolysis_saturation", "electrolysis_saturation:onset=4,slope=0.3"},
      {"electrolysis_saturation:slope=1,onset=5", "electrolysis_saturation:onset=5,slope=1"},
      {"electrolysis_saturation:slope=0", "electrolysis_saturation:onset=4,slope=0"},
      {"sensor_drift", "sensor_drift:rate=0.001,warmup=0,tau=600"},
      {"sensor_drift:rate=-2e-05,warmup=-0.1,tau=30",
       "sensor_drift:rate=-2e-05,warmup=-0.1,tau=30"},
      {"polarity_asymmetry", "polarity_asymmetry:ratio=0.7"},
      {"polarity_asymmetry:ratio=2", "polarity_asymmetry:ratio=2"},
      {"dead_zone", "dead_zone:threshold=0.5"},
      {"dead_zone:threshold=0", "dead_zone:threshold=0"},
  };
  for (const auto& [spec, canonical] : cases) EXPECT_EQ(ParseEffect(spec)->Describe(), canonical);
  // Every listed name parses with its defaults, and Describe reads back to itself.
  for (const std::string& name : rig::EffectNames()) {
    const std::string canonical = ParseEffect(name)->Describe();
    EXPECT_EQ(canonical.rfind(name + ":", 0), 0u) << canonical;
    EXPECT_EQ(ParseEffect(canonical)->Describe(), canonical);
  }
}

// The hand computations below call the effect directly on a few samples; the Rig tests
// further down check the same equations through the whole sample stream.

// Eq. (3) with loss = 0.5, charge = 4 V*s, i.e. the gain halves per 4 V*s: |v| = 4, 4, 0, 4
// V held for 1 s each gives Q = 0, 4, 8, 8, 12 V*s at t = 0 .. 4 s and factors 1, 1/2, 1/4,
// 1/4, 1/8.
TEST(Effects, CycleDegradationLosesGainWithTheChargeMoved) {
  const auto effect = ParseEffect("cycle_degradation:loss=0.5,charge=4");
  const std::vector<double> applied_V = {4.0, -4.0, 0.0, 4.0, 4.0};
  const std::vector<double> expected_V = {4.0, -2.0, 0.0, 1.0, 0.5};
  for (size_t k = 0; k < applied_V.size(); ++k)
    EXPECT_NEAR(effect->DriveVoltage(static_cast<double>(k), applied_V[k]), expected_V[k], 1e-15)
        << k;
  // Uneven steps: 2 V for 0.5 s then 1.5 s moves 1 + 3 = 4 V*s.
  const auto uneven = ParseEffect("cycle_degradation:loss=0.5,charge=4");
  EXPECT_EQ(uneven->DriveVoltage(0.0, 2.0), 2.0);
  EXPECT_NEAR(uneven->DriveVoltage(0.5, 2.0), 2.0 * std::pow(0.5, 0.25), 1e-15);
  EXPECT_NEAR(uneven->DriveVoltage(2.0, 2.0), 1.0, 1e-15);
  // loss = 0: nothing changes, however much charge.
  const auto none = ParseEffect("cycle_degradation:loss=0,charge=1");
  for (int k = 0; k < 100; ++k) ASSERT_EQ(none->DriveVoltage(k, 8.0), 8.0);
}

// Eq. (4), width 0.5 mm, on a triangle 0 1 2 3 2 1 0 1 mm: the output lags 0.5 mm behind
// on the way up, holds while the input turns, lags 0.5 mm above on the way down.
TEST(Effects, HysteresisIsAPlayOperatorOnATriangle) {
  const auto effect = ParseEffect("hysteresis:width=0.5");
  const std::vector<double> input_mm = {0, 1, 2, 3, 2, 1, 0, 1};
  const std::vector<double> expected_mm = {0, 0.5, 1.5, 2.5, 2.5, 1.5, 0.5, 0.5};
  for (size_t k = 0; k < input_mm.size(); ++k)
    EXPECT_EQ(effect->Deflection(0.1 * static_cast<double>(k), 0.0, input_mm[k]), expected_mm[k])
        << k;
  // out_0 = y_0, wherever the stream starts; width 0 passes everything through.
  EXPECT_EQ(ParseEffect("hysteresis:width=0.5")->Deflection(0.0, 0.0, 7.25), 7.25);
  const auto zero = ParseEffect("hysteresis:width=0");
  for (const double y_mm : input_mm) EXPECT_EQ(zero->Deflection(0.0, 0.0, y_mm), y_mm);
}

// Eq. (5), onset 4 V, slope 0.3: |v| <= 4 passes; 6 V -> 4 + 0.3 * 2 = 4.6; 8 V -> 5.2.
TEST(Effects, ElectrolysisSaturationCompressesAboveTheOnset) {
  const auto effect = ParseEffect("electrolysis_saturation:onset=4,slope=0.3");
  const std::vector<std::pair<double, double>> cases = {
      {0.0, 0.0}, {2.0, 2.0}, {4.0, 4.0}, {6.0, 4.6}, {8.0, 5.2}, {-8.0, -5.2}, {-3.0, -3.0}};
  for (const auto& [applied_V, drive_V] : cases)
    EXPECT_NEAR(effect->DriveVoltage(0.0, applied_V), drive_V, 1e-15) << applied_V;
  EXPECT_EQ(ParseEffect("electrolysis_saturation:onset=4,slope=0")->DriveVoltage(0.0, 9.0), 4.0);
  EXPECT_EQ(ParseEffect("electrolysis_saturation:onset=4,slope=1")->DriveVoltage(0.0, 9.0), 9.0);
}

// Eq. (6), rate 0.001 mm/s, warm-up 0.5 mm with tau 10 s: at t = 10 s the offset is
// 0.01 + 0.5 (1 - 1/e) mm whatever the deflection and the voltage.
TEST(Effects, SensorDriftAddsARampAndAWarmUp) {
  const auto effect = ParseEffect("sensor_drift:rate=0.001,warmup=0.5,tau=10");
  EXPECT_EQ(effect->Deflection(0.0, 3.0, 1.25), 1.25);
  EXPECT_NEAR(effect->Deflection(10.0, 3.0, 1.25), 1.25 + 0.01 + 0.5 * (1.0 - std::exp(-1.0)),
              1e-15);
  EXPECT_NEAR(effect->Deflection(1000.0, -8.0, 0.0), 1.0 + 0.5, 1e-12);  // warm-up settled
  const auto down = ParseEffect("sensor_drift:rate=-0.002");
  EXPECT_NEAR(down->Deflection(50.0, 0.0, 0.0), -0.1, 1e-15);
}

// Eq. (7), ratio 0.7: positive voltages pass, negative ones act at 0.7 of themselves.
TEST(Effects, PolarityAsymmetryScalesNegativeVoltagesOnly) {
  const auto effect = ParseEffect("polarity_asymmetry:ratio=0.7");
  EXPECT_EQ(effect->DriveVoltage(0.0, 3.0), 3.0);
  EXPECT_EQ(effect->DriveVoltage(0.0, 0.0), 0.0);
  EXPECT_NEAR(effect->DriveVoltage(0.0, -3.0), -2.1, 1e-15);
  EXPECT_NEAR(ParseEffect("polarity_asymmetry:ratio=1.5")->DriveVoltage(0.0, -2.0), -3.0, 1e-15);
}

// Eq. (8), threshold 0.5 V.
TEST(Effects, DeadZoneRemovesTheThreshold) {
  const auto effect = ParseEffect("dead_zone:threshold=0.5");
  const std::vector<std::pair<double, double>> cases = {{0.0, 0.0}, {0.3, 0.0}, {-0.3, 0.0},
                                                        {0.5, 0.0}, {2.0, 1.5}, {-2.0, -1.5}};
  for (const auto& [applied_V, drive_V] : cases)
    EXPECT_EQ(effect->DriveVoltage(0.0, applied_V), drive_V) << applied_V;
}

TEST(Effects, EveryErrorIsOneClearLine) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"", "effect \"\": empty specification (expected NAME[:KEY=VALUE,...])"},
      {"wobble",
       "effect \"wobble\": unknown effect \"wobble\" (expected back_relaxation, "
       "cycle_degradation, hysteresis, electrolysis_saturation, sensor_drift, "
       "polarity_asymmetry or dead_zone)"},
      {"back_relaxation:fraction=1.5",
       "effect \"back_relaxation:fraction=1.5\": fraction must be >= 0 and <= 1 (got 1.5)"},
      {"back_relaxation:fraction=-0.1",
       "effect \"back_relaxation:fraction=-0.1\": fraction must be >= 0 and <= 1 (got -0.1)"},
      {"back_relaxation:tau=0", "effect \"back_relaxation:tau=0\": tau must be > 0 s (got 0)"},
      {"back_relaxation:tau=x",
       "effect \"back_relaxation:tau=x\": tau is not a finite number: \"x\""},
      {"back_relaxation:tau=60,size=2",
       "effect \"back_relaxation:tau=60,size=2\": unknown key \"size\" (back_relaxation takes "
       "fraction and tau)"},
      {"back_relaxation:tau", "effect \"back_relaxation:tau\": expected KEY=VALUE, got \"tau\""},
      {"cycle_degradation:loss=1",
       "effect \"cycle_degradation:loss=1\": loss must be >= 0 and < 1 (got 1)"},
      {"cycle_degradation:loss=-0.1",
       "effect \"cycle_degradation:loss=-0.1\": loss must be >= 0 and < 1 (got -0.1)"},
      {"cycle_degradation:charge=0",
       "effect \"cycle_degradation:charge=0\": charge must be > 0 V*s (got 0)"},
      {"cycle_degradation:charge=nan",
       "effect \"cycle_degradation:charge=nan\": charge is not a finite number: \"nan\""},
      {"cycle_degradation:cycles=3",
       "effect \"cycle_degradation:cycles=3\": unknown key \"cycles\" (cycle_degradation takes "
       "loss and charge)"},
      {"hysteresis:width=-0.1",
       "effect \"hysteresis:width=-0.1\": width must be >= 0 mm (got -0.1)"},
      {"hysteresis:width=0.1,tau=3",
       "effect \"hysteresis:width=0.1,tau=3\": unknown key \"tau\" (hysteresis takes width)"},
      {"electrolysis_saturation:onset=0",
       "effect \"electrolysis_saturation:onset=0\": onset must be > 0 V (got 0)"},
      {"electrolysis_saturation:slope=1.2",
       "effect \"electrolysis_saturation:slope=1.2\": slope must be >= 0 and <= 1 (got 1.2)"},
      {"electrolysis_saturation:slope=-0.5",
       "effect \"electrolysis_saturation:slope=-0.5\": slope must be >= 0 and <= 1 (got -0.5)"},
      {"sensor_drift:tau=0", "effect \"sensor_drift:tau=0\": tau must be > 0 s (got 0)"},
      {"sensor_drift:rate=inf",
       "effect \"sensor_drift:rate=inf\": rate is not a finite number: \"inf\""},
      {"sensor_drift:warmup=1mm",
       "effect \"sensor_drift:warmup=1mm\": warmup is not a finite number: \"1mm\""},
      {"polarity_asymmetry:ratio=0",
       "effect \"polarity_asymmetry:ratio=0\": ratio must be > 0 and <= 2 (got 0)"},
      {"polarity_asymmetry:ratio=2.5",
       "effect \"polarity_asymmetry:ratio=2.5\": ratio must be > 0 and <= 2 (got 2.5)"},
      {"polarity_asymmetry:ratio=-1",
       "effect \"polarity_asymmetry:ratio=-1\": ratio must be > 0 and <= 2 (got -1)"},
      {"dead_zone:threshold=-1",
       "effect \"dead_zone:threshold=-1\": threshold must be >= 0 V (got -1)"},
      {"dead_zone:level=1",
       "effect \"dead_zone:level=1\": unknown key \"level\" (dead_zone takes threshold)"},
  };
  for (const auto& [spec, message] : cases) EXPECT_EQ(EffectError(spec), message) << spec;
}

// ---------------------------------------------------------------------------------------
// The sample stream
// ---------------------------------------------------------------------------------------

std::vector<rig::RigSample> Drain(rig::Rig& r) {
  std::vector<rig::RigSample> samples;
  rig::RigSample sample;
  while (r.Next(&sample)) samples.push_back(sample);
  return samples;
}

std::vector<rig::RigSample> RunStream(const model::TsModel& model, const std::string& protocol,
                                      std::vector<std::unique_ptr<rig::Effect>> effects = {},
                                      const rig::RigOptions& options = {}) {
  rig::Rig r(model, ParseProtocol(protocol), std::move(effects), options);
  return Drain(r);
}

std::vector<std::unique_ptr<rig::Effect>> OneEffect(std::unique_ptr<rig::Effect> effect) {
  std::vector<std::unique_ptr<rig::Effect>> effects;
  effects.push_back(std::move(effect));
  return effects;
}

// A pure gain of 2 mm/V: the model's output follows the voltage without lag, so an
// effect's own dynamics can be checked against closed forms.
model::TsModel GainModel() { return model::SingleRule({.num = {2.0}, .den = {1.0}}); }

TEST(Rig, WithoutEffectsTheStreamIsExactlySimulateUniform) {
  const model::TsModel model = model::SeedTsModel();
  const Protocol protocol = ParseProtocol("staircase:levels=2/4/6/8,dwell=30");
  rig::RigOptions options;
  options.start_utime = 1'700'000'000'000'000;
  rig::Rig r(model, protocol, {}, options);
  ASSERT_EQ(r.sample_count(), 1500);
  EXPECT_EQ(r.duration_s(), 150.0);
  const std::vector<rig::RigSample> samples = Drain(r);
  ASSERT_EQ(samples.size(), 1500u);

  std::vector<double> voltage_V(1500);
  for (size_t k = 0; k < voltage_V.size(); ++k)
    voltage_V[k] = VoltageAt(protocol, static_cast<double>(k) / 10.0);
  const std::vector<double> expected_mm = model::SimulateUniform(model, 0.1, voltage_V);
  for (size_t k = 0; k < samples.size(); ++k) {
    ASSERT_EQ(samples[k].index, static_cast<int64_t>(k));
    ASSERT_EQ(samples[k].utime, options.start_utime + static_cast<int64_t>(k) * 100'000);
    ASSERT_EQ(samples[k].voltage_V, voltage_V[k]) << k;
    ASSERT_EQ(samples[k].deflection_mm, expected_mm[k]) << k;
  }
  EXPECT_GT(samples[1199].deflection_mm, 1.0);  // it moved (8 V for 30 s)
  EXPECT_EQ(r.UtimeOf(r.sample_count()), options.start_utime + 150'000'000);
}

TEST(Rig, SampleCountCoversTheProtocol) {
  const model::TsModel model = GainModel();
  auto count = [&](const std::string& protocol, double rate_Hz) {
    rig::RigOptions options;
    options.rate_Hz = rate_Hz;
    return rig::Rig(model, ParseProtocol(protocol), {}, options).sample_count();
  };
  EXPECT_EQ(count("hold:level=1,duration=10", 10), 100);
  EXPECT_EQ(count("hold:level=1,duration=1", 3), 3);
  EXPECT_EQ(count("hold:level=1,duration=0.7", 10), 7);
  EXPECT_EQ(count("hold:level=1,duration=0.75", 10), 8);
  EXPECT_EQ(count("hold:level=1,duration=0.05", 10), 1);
  EXPECT_EQ(count("square:level=5,period=220,cycles=5", 10), 11000);
}

TEST(Rig, UtimeAdvancesInMessageTimeWithRounding) {
  rig::RigOptions options;
  options.rate_Hz = 3.0;
  options.start_utime = 5;
  const auto samples = RunStream(GainModel(), "hold:level=1,duration=1", {}, options);
  ASSERT_EQ(samples.size(), 3u);
  EXPECT_EQ(samples[0].utime, 5);
  EXPECT_EQ(samples[1].utime, 5 + 333'333);
  EXPECT_EQ(samples[2].utime, 5 + 666'667);
}

TEST(Rig, VoltageIsPublishedOnChangeAndAtLeastOnceASecond) {
  rig::RigOptions options;
  options.rate_Hz = 2.0;
  // Samples at 0, 0.5, ..., 3 s; the voltage changes at 1.25 s, seen at 1.5 s.
  const auto samples = RunStream(GainModel(), "step:level=1,delay=1.25,duration=2", {}, options);
  ASSERT_EQ(samples.size(), 7u);
  std::vector<int64_t> changed, published;
  for (const auto& s : samples) {
    if (s.voltage_changed) changed.push_back(s.index);
    if (s.publish_voltage) published.push_back(s.index);
  }
  EXPECT_EQ(changed, (std::vector<int64_t>{0, 3}));
  // 0 s (first), 1 s (a second since), 1.5 s (change), 2.5 s (a second since the change).
  EXPECT_EQ(published, (std::vector<int64_t>{0, 2, 3, 5}));
}

TEST(Rig, RejectsBadOptionsTooManySamplesAndUnstableModels) {
  const Protocol hold = ParseProtocol("hold:level=1,duration=10");
  rig::RigOptions options;
  options.rate_Hz = 0.0;
  EXPECT_THROW(rig::Rig(GainModel(), hold, {}, options), model::InputError);
  options = {};
  options.noise_mm = -1.0;
  EXPECT_THROW(rig::Rig(GainModel(), hold, {}, options), model::InputError);
  options = {};
  options.start_utime = -1;
  EXPECT_THROW(rig::Rig(GainModel(), hold, {}, options), model::InputError);

  const std::string too_long = ErrorOf([] {
    rig::Rig(model::TsModel(GainModel()), ParseProtocol("hold:level=1,duration=1e7"), {}, {});
  });
  EXPECT_EQ(too_long,
            "protocol \"hold:level=1,duration=1e7\" at 10 Hz needs 1e+08 samples; at most "
            "10000000 (lower --rate-hz or shorten the protocol)");

  // A pole at +1/s: exp(t) overflows long before 1000 s.
  const model::TsModel unstable = model::SingleRule({.num = {1.0}, .den = {1.0, -1.0}});
  try {
    rig::Rig(unstable, ParseProtocol("hold:level=1,duration=1000"), {}, {});
    ADD_FAILURE() << "no error";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find("diverges"), std::string::npos) << error.what();
  }
}

// Back-relaxation on a pure gain: y = Y from t = 0, so Eq. (2) gives s_n = Y (1 - a^n)
// exactly and d_n = Y (1 - fraction (1 - a^n)), a = exp(-h / tau).
TEST(Rig, BackRelaxationFallsBackWithTimeConstantTau) {
  const double fraction = 0.3, tau_s = 60.0, h_s = 0.1, y_mm = 3.0;  // 1.5 V * 2 mm/V
  const auto samples = RunStream(GainModel(), "hold:level=1.5,duration=600",
                                 OneEffect(ParseEffect("back_relaxation:fraction=0.3,tau=60")));
  ASSERT_EQ(samples.size(), 6000u);
  const double a = std::exp(-h_s / tau_s);
  for (size_t n = 0; n < samples.size(); ++n) {
    const double expected = y_mm * (1.0 - fraction * (1.0 - std::pow(a, static_cast<double>(n))));
    ASSERT_NEAR(samples[n].deflection_mm, expected, 1e-12) << n;
  }
  EXPECT_EQ(samples[0].deflection_mm, y_mm);  // first the full deflection
  // The time constant of the fall, from the excess over the final value one tau in:
  const double final_mm = (1.0 - fraction) * y_mm;
  const double excess_0 = samples[600].deflection_mm - final_mm;
  const double excess_1 = samples[601].deflection_mm - final_mm;
  EXPECT_NEAR(-h_s / std::log(excess_1 / excess_0), tau_s, 1e-6);
  // ... and at one tau the fall has gone 1 - 1/e of the way.
  EXPECT_NEAR(samples[600].deflection_mm, y_mm - fraction * y_mm * (1.0 - std::exp(-1.0)), 1e-12);
}

TEST(Rig, BackRelaxationOvershootsAtRestAndReturnsToZero) {
  // 1.5 V for 600 s (10 tau), then 0 V for 600 s.
  const auto samples = RunStream(GainModel(), "square:level=1.5,period=1200,cycles=1",
                                 OneEffect(ParseEffect("back_relaxation:fraction=0.3,tau=60")));
  ASSERT_EQ(samples.size(), 12000u);
  double lowest_mm = 0.0;
  for (size_t n = 6000; n < samples.size(); ++n)
    lowest_mm = std::min(lowest_mm, samples[n].deflection_mm);
  // Just after the voltage drops the slow part (about 0.3 * 3 mm) is left, with the sign
  // reversed: the gel swings past rest. (The first-order hold takes the drop as a ramp over
  // one sample, so the overshoot is smaller by about fraction * Y * h / (2 tau).)
  EXPECT_NEAR(lowest_mm, -0.9, 2.0 * (0.9 * 0.1 / 120.0 + 0.9 * std::exp(-10.0)));
  EXPECT_LT(lowest_mm, -0.89);
  EXPECT_NEAR(samples.back().deflection_mm, 0.0, 1e-4);  // 0.9 mm * exp(-10)
}

TEST(Rig, BackRelaxationSettlesAtItsShareOfTheSeedModel) {
  const model::TsModel model = model::SeedTsModel();
  const std::string protocol = "step:level=2,duration=3000";
  const auto plain = RunStream(model, protocol);
  const auto relaxed =
      RunStream(model, protocol, OneEffect(ParseEffect("back_relaxation:fraction=0.3,tau=60")));
  ASSERT_EQ(plain.size(), relaxed.size());
  const double model_mm = plain.back().deflection_mm;
  ASSERT_GT(std::abs(model_mm), 1.0);
  // After 50 tau and many of the model's own time constants: 1e-9 relative.
  EXPECT_NEAR(relaxed.back().deflection_mm, 0.7 * model_mm, 1e-9 * std::abs(model_mm));
  // The voltage stream is untouched.
  for (size_t k = 0; k < plain.size(); ++k) ASSERT_EQ(plain[k].voltage_V, relaxed[k].voltage_V);
}

// DriveVoltage: the model sees the effect's voltage, the bus the applied one.
class HalfVoltage : public rig::Effect {
 public:
  std::string Describe() const override { return "half_voltage"; }
  double DriveVoltage(double, double applied_V) override { return 0.5 * applied_V; }
};

TEST(Rig, DriveVoltageEffectsChangeWhatTheModelSees) {
  const model::TsModel model = model::SeedTsModel();
  const std::string protocol = "square:level=8,period=40,cycles=2";
  const auto halved = RunStream(model, protocol, OneEffect(std::make_unique<HalfVoltage>()));
  std::vector<double> drive_V;
  for (const auto& s : halved) drive_V.push_back(0.5 * s.voltage_V);
  const auto expected_mm = model::SimulateUniform(model, 0.1, drive_V);
  ASSERT_EQ(halved.size(), 800u);
  EXPECT_EQ(halved[0].voltage_V, 8.0);
  for (size_t k = 0; k < halved.size(); ++k) ASSERT_EQ(halved[k].deflection_mm, expected_mm[k]);
}

// Each effect through the whole stream, on the pure gain of 2 mm/V so that the deflection
// is 2 * drive (drive side) or the effect of 2 * voltage (output side), at 10 Hz.

// Eq. (3) with the voltage held between samples: Q(t_k) = 0.1 s * sum_{j<k} |v_j|. A square
// wave of 2 V, 10 s on and 10 s off, 3 periods: only the on-samples move charge, 2 V * 0.1 s
// each; 60 V*s in all, so the gain ends at 0.5^(60 / 20) = 1/8.
TEST(Rig, CycleDegradationFollowsTheChargeOfTheOnPeriods) {
  const auto samples = RunStream(GainModel(), "square:level=2,period=20,cycles=3",
                                 OneEffect(ParseEffect("cycle_degradation:loss=0.5,charge=20")));
  ASSERT_EQ(samples.size(), 600u);
  for (size_t k = 0; k < samples.size(); ++k) {
    const size_t on_samples_before = (k / 200) * 100 + std::min<size_t>(k % 200, 100);
    const double charge_Vs = 2.0 * 0.1 * static_cast<double>(on_samples_before);
    const double expected_mm = 2.0 * samples[k].voltage_V * std::pow(0.5, charge_Vs / 20.0);
    ASSERT_NEAR(samples[k].deflection_mm, expected_mm, 1e-12) << k;
  }
  EXPECT_NEAR(samples[400].deflection_mm, 4.0 * 0.25, 1e-12);  // third pulse: 40 V*s moved
  EXPECT_EQ(samples[599].voltage_V, 0.0);
}

// Eq. (4) with width 0.25 mm on the steps y = 1, 3, 1, 0 mm (staircase 0.5/1.5/0.5 V):
// out = 1 (out_0 = y_0), 3 - 0.25 (rising), 1 + 0.25 (falling), 0.25 (still above rest).
TEST(Rig, HysteresisLagsTheStepsByItsWidth) {
  const auto samples = RunStream(GainModel(), "staircase:levels=0.5/1.5/0.5,dwell=1",
                                 OneEffect(ParseEffect("hysteresis:width=0.25")));
  ASSERT_EQ(samples.size(), 40u);
  const std::vector<double> expected_mm = {1.0, 2.75, 1.25, 0.25};
  for (size_t k = 0; k < samples.size(); ++k)
    ASSERT_NEAR(samples[k].deflection_mm, expected_mm[k / 10], 1e-12) << k;
}

// Eq. (5), onset 4 V, slope 0.3, on a staircase 2/4/6/8 V: drive 2, 4, 4.6, 5.2 V.
TEST(Rig, ElectrolysisSaturationCompressesTheUpperSteps) {
  const auto samples =
      RunStream(GainModel(), "staircase:levels=2/4/6/8,dwell=1",
                OneEffect(ParseEffect("electrolysis_saturation:onset=4,slope=0.3")));
  ASSERT_EQ(samples.size(), 50u);
  const std::vector<double> expected_mm = {4.0, 8.0, 9.2, 10.4, 0.0};
  for (size_t k = 0; k < samples.size(); ++k)
    ASSERT_NEAR(samples[k].deflection_mm, expected_mm[k / 10], 1e-12) << k;
  EXPECT_EQ(samples[35].voltage_V, 8.0);  // the bus still sees the applied voltage
}

// Eq. (6) on a constant 2 mm: out(t) = 2 + rate t + warmup (1 - exp(-t / tau)).
TEST(Rig, SensorDriftMovesTheBaselineWhateverTheInput) {
  const auto samples =
      RunStream(GainModel(), "hold:level=1,duration=100",
                OneEffect(ParseEffect("sensor_drift:rate=2e-3,warmup=0.3,tau=20")));
  ASSERT_EQ(samples.size(), 1000u);
  for (size_t k = 0; k < samples.size(); ++k) {
    const double t_s = static_cast<double>(k) / 10.0;
    ASSERT_NEAR(samples[k].deflection_mm, 2.0 + 2e-3 * t_s + 0.3 * (1.0 - std::exp(-t_s / 20.0)),
                1e-12)
        << k;
  }
}

// Eq. (7), ratio 0.7, on an alternating square of 5 V: +10 mm, then -7 mm.
TEST(Rig, PolarityAsymmetryWeakensTheNegativePulses) {
  const auto samples = RunStream(GainModel(), "square:level=5,period=2,cycles=2,polarity=alternate",
                                 OneEffect(ParseEffect("polarity_asymmetry:ratio=0.7")));
  ASSERT_EQ(samples.size(), 40u);
  const std::vector<double> expected_mm = {10.0, 0.0, -7.0, 0.0};  // per second
  for (size_t k = 0; k < samples.size(); ++k)
    ASSERT_NEAR(samples[k].deflection_mm, expected_mm[k / 10], 1e-12) << k;
  EXPECT_EQ(samples[25].voltage_V, -5.0);
}

// Drive-side effects act in the order given: a dead zone of 0.5 V and a ratio of 0.7 on
// -2 V give 0.7 * (-1.5) = -1.05 V one way round and -1.4 + 0.5 = -0.9 V the other.
TEST(Rig, DeadZoneAndEffectsInTheOrderGiven) {
  auto both = [](const std::string& first, const std::string& second) {
    std::vector<std::unique_ptr<rig::Effect>> effects;
    effects.push_back(ParseEffect(first));
    effects.push_back(ParseEffect(second));
    return RunStream(GainModel(), "staircase:levels=0.3/1/-2,dwell=1", std::move(effects));
  };
  const auto dead_zone_first = both("dead_zone:threshold=0.5", "polarity_asymmetry:ratio=0.7");
  const auto ratio_first = both("polarity_asymmetry:ratio=0.7", "dead_zone:threshold=0.5");
  ASSERT_EQ(dead_zone_first.size(), 40u);
  const std::vector<double> expected_mm = {0.0, 1.0, -2.1, 0.0};
  const std::vector<double> reversed_mm = {0.0, 1.0, -1.8, 0.0};
  for (size_t k = 0; k < 40; ++k) {
    ASSERT_NEAR(dead_zone_first[k].deflection_mm, expected_mm[k / 10], 1e-12) << k;
    ASSERT_NEAR(ratio_first[k].deflection_mm, reversed_mm[k / 10], 1e-12) << k;
  }
}

TEST(Rig, SeededNoiseIsReproducibleAndHasTheGivenSigma) {
  const model::TsModel model = model::SeedTsModel();
  const std::string protocol = "square:level=5,period=220,cycles=1";
  rig::RigOptions options;
  options.noise_mm = 0.05;
  options.seed = 42;
  const auto a = RunStream(model, protocol, {}, options);
  const auto b = RunStream(model, protocol, {}, options);
  options.seed = 43;
  const auto c = RunStream(model, protocol, {}, options);
  const auto clean = RunStream(model, protocol);
  ASSERT_EQ(a.size(), 2200u);
  int differing = 0;
  double sum = 0.0, sum_squares = 0.0;
  for (size_t k = 0; k < a.size(); ++k) {
    ASSERT_EQ(a[k].deflection_mm, b[k].deflection_mm) << k;
    differing += a[k].deflection_mm != c[k].deflection_mm ? 1 : 0;
    const double noise = a[k].deflection_mm - clean[k].deflection_mm;
    sum += noise;
    sum_squares += noise * noise;
  }
  EXPECT_EQ(differing, 2200);
  // 2200 samples: the mean's standard error is 0.05 / sqrt(2200) ~ 0.0011 mm and the
  // sigma estimate's about 1.5 %; bounds at about 4 standard errors.
  const double n = static_cast<double>(a.size());
  const double mean = sum / n;
  EXPECT_NEAR(mean, 0.0, 0.0045);
  EXPECT_NEAR(std::sqrt(sum_squares / n - mean * mean), 0.05, 0.05 * 0.06);
}

// ---------------------------------------------------------------------------------------
// Frequency sweep and multilevel random
// ---------------------------------------------------------------------------------------

// The times at which VoltageAt changes, sampled every millisecond over [0, end_s], with the
// new voltage; the first entry is the voltage at 0 s.
std::vector<std::pair<double, double>> Transitions(const Protocol& p, double end_s) {
  std::vector<std::pair<double, double>> changes = {{0.0, VoltageAt(p, 0.0)}};
  const auto steps = static_cast<int64_t>(std::llround(end_s * 1000.0));
  for (int64_t k = 1; k <= steps; ++k) {
    const double t_s = static_cast<double>(k) / 1000.0;
    const double voltage_V = VoltageAt(p, t_s);
    if (voltage_V != changes.back().second) changes.emplace_back(t_s, voltage_V);
  }
  return changes;
}

TEST(Protocol, SweepDefaultsToTheSeedsFrequencies) {
  const Protocol p = ParseProtocol("sweep:level=5");
  EXPECT_EQ(p.shape, Protocol::Shape::kSweep);
  EXPECT_EQ(p.level_V, 5.0);
  EXPECT_EQ(p.frequencies_Hz,
            (std::vector<double>{0.0025, 0.02, 0.031, 0.054, 0.11, 0.15, 1.1}));  // Figure 6
  EXPECT_EQ(p.cycles, 3);
  EXPECT_EQ(p.duty, 0.5);
  // 3 * (400 + 50 + 32.258... + 18.518... + 9.0909... + 6.666... + 0.90909...) s.
  EXPECT_NEAR(ProtocolDuration(p), 1552.329749103945, 1e-9);
  const Protocol q = ParseProtocol("sweep:duty=0.25,frequencies=0.5/2,level=-3,cycles=4");
  EXPECT_EQ(q.frequencies_Hz, (std::vector<double>{0.5, 2.0}));
  EXPECT_EQ(q.cycles, 4);
  EXPECT_EQ(q.duty, 0.25);
  EXPECT_EQ(q.level_V, -3.0);
  EXPECT_EQ(ProtocolDuration(q), 4 * 2.0 + 4 * 0.5);
}

// A sine: level + amplitude sin(2 pi F t); a period must hold 4 samples.
TEST(Protocol, SineAroundItsLevel) {
  const Protocol p = ParseProtocol("sine:level=3,amplitude=2,frequency=0.05,duration=60");
  EXPECT_EQ(p.shape, Protocol::Shape::kSine);
  EXPECT_EQ(ProtocolDuration(p), 60.0);
  EXPECT_NEAR(VoltageAt(p, 0.0), 3.0, 1e-12);
  EXPECT_NEAR(VoltageAt(p, 5.0), 5.0, 1e-12);   // a quarter period
  EXPECT_NEAR(VoltageAt(p, 15.0), 1.0, 1e-12);  // three quarters
  EXPECT_EQ(SamplingProblem(p, 10.0), "");
  const Protocol fast = ParseProtocol("sine:amplitude=1,frequency=4,duration=10");
  EXPECT_EQ(fast.level_V, 0.0);
  EXPECT_NE(SamplingProblem(fast, 10.0).find("under 4 sample periods"), std::string::npos);
  EXPECT_THROW(ParseProtocol("sine:amplitude=1,frequency=0,duration=10"), model::InputError);
  EXPECT_THROW(ParseProtocol("sine:amplitude=1,duration=10"), model::InputError);
}

// 0.1 Hz then 0.5 Hz, 2 cycles each, duty 0.25: on 2.5 s of every 10 s for 20 s, then on
// 0.5 s of every 2 s for 4 s, then rest.
TEST(VoltageAt, SweepPlaysEachFrequencyInTurn) {
  const Protocol p = ParseProtocol("sweep:level=5,frequencies=0.1/0.5,cycles=2,duty=0.25");
  EXPECT_EQ(ProtocolDuration(p), 24.0);
  const std::vector<std::pair<double, double>> expected = {
      {0.0, 5}, {2.5, 0}, {10.0, 5}, {12.5, 0}, {20.0, 5}, {20.5, 0}, {22.0, 5}, {22.5, 0}};
  EXPECT_EQ(Transitions(p, 60.0), expected);
  EXPECT_EQ(VoltageAt(p, -1.0), 0.0);
  // The frequencies play in the order given: 0.5 Hz first.
  const Protocol reversed = ParseProtocol("sweep:level=5,frequencies=0.5/0.1,cycles=2,duty=0.25");
  EXPECT_EQ(Transitions(reversed, 60.0),
            (std::vector<std::pair<double, double>>{
                {0.0, 5}, {0.5, 0}, {2.0, 5}, {2.5, 0}, {4.0, 5}, {6.5, 0}, {14.0, 5}, {16.5, 0}}));
}

// The seed's sweep: the first 0.0025 Hz period is 200 s on, 200 s off; the 1.1 Hz part
// starts after 3 rounds of the six slower periods and ends the protocol.
TEST(VoltageAt, TheSeedsSweepStartsEachFrequencyOnTime) {
  const Protocol p = ParseProtocol("sweep:level=5");
  EXPECT_EQ(VoltageAt(p, 199.9), 5.0);
  EXPECT_EQ(VoltageAt(p, 200.1), 0.0);
  EXPECT_EQ(VoltageAt(p, 1199.9), 0.0);  // the end of the 3rd 0.0025 Hz period
  EXPECT_EQ(VoltageAt(p, 1200.0), 5.0);  // 0.02 Hz starts: 25 s on
  EXPECT_EQ(VoltageAt(p, 1224.9), 5.0);
  EXPECT_EQ(VoltageAt(p, 1225.1), 0.0);
  double start_s = 0.0;
  for (const double f_Hz : {0.0025, 0.02, 0.031, 0.054, 0.11, 0.15}) start_s += 3.0 / f_Hz;
  EXPECT_EQ(VoltageAt(p, start_s - 1e-3), 0.0);
  EXPECT_EQ(VoltageAt(p, start_s + 1e-3), 5.0);
  EXPECT_EQ(VoltageAt(p, start_s + 0.5 / 1.1 - 1e-3), 5.0);
  EXPECT_EQ(VoltageAt(p, start_s + 0.5 / 1.1 + 1e-3), 0.0);
  EXPECT_NEAR(ProtocolDuration(p), start_s + 3.0 / 1.1, 1e-9);
  EXPECT_EQ(VoltageAt(p, ProtocolDuration(p) + 100.0), 0.0);
}

// Through the Rig at 10 Hz: 0.05 Hz (20 s) and 0.25 Hz (4 s), 2 cycles each.
TEST(Rig, SweepChangesTheVoltageAtTheRightSamples) {
  rig::RigOptions options;
  options.start_utime = 1'000'000;
  rig::Rig r(model::SeedTsModel(), ParseProtocol("sweep:level=5,frequencies=0.05/0.25,cycles=2"),
             {}, options);
  ASSERT_EQ(r.sample_count(), 480);
  std::vector<int64_t> changed;
  std::vector<double> changed_to_V;
  rig::RigSample sample;
  while (r.Next(&sample)) {
    if (!sample.voltage_changed) continue;
    changed.push_back(sample.index);
    changed_to_V.push_back(sample.voltage_V);
    EXPECT_EQ(sample.utime, 1'000'000 + sample.index * 100'000);
  }
  EXPECT_EQ(changed, (std::vector<int64_t>{0, 100, 200, 300, 400, 420, 440, 460}));
  EXPECT_EQ(changed_to_V, (std::vector<double>{5, 0, 5, 0, 5, 0, 5, 0}));
}

TEST(Rig, RejectsASweepItsRateCannotResolve) {
  const Protocol seed_sweep = ParseProtocol("sweep:level=5");
  rig::RigOptions options;  // 10 Hz: 1.1 Hz has 0.45 s halves, over 2 samples
  EXPECT_EQ(rig::Rig(GainModel(), seed_sweep, {}, options).sample_count(), 15524);
  options.rate_Hz = 4.5;
  EXPECT_NO_THROW(rig::Rig(GainModel(), seed_sweep, {}, options));
  options.rate_Hz = 4.0;
  EXPECT_EQ(ErrorOf([&] { rig::Rig(GainModel(), seed_sweep, {}, options); }),
            "protocol \"sweep:level=5\": at 1.1 Hz the shorter part of a period (0.454545 s at "
            "duty 0.5) is under 2 sample periods (0.5 s at 4 Hz); raise --rate-hz to at least 4.4 "
            "or leave 1.1 Hz out");
  // The shorter part of the period counts: duty 0.9 at 1 Hz leaves 0.1 s at 0 V.
  options.rate_Hz = 10.0;
  EXPECT_NE(ErrorOf([&] {
              rig::Rig(GainModel(), ParseProtocol("sweep:level=5,frequencies=1,duty=0.9"), {},
                       options);
            }),
            "");
  EXPECT_NO_THROW(
      rig::Rig(GainModel(), ParseProtocol("sweep:level=5,frequencies=1,duty=0.8"), {}, options));
  EXPECT_EQ(ErrorOf([&] {
              rig::Rig(GainModel(),
                       ParseProtocol("random:levels=1/2,dwell_min=0.15,dwell_max=1,duration=5"), {},
                       options);
            }),
            "protocol \"random:levels=1/2,dwell_min=0.15,dwell_max=1,duration=5\": dwell_min "
            "(0.15 s) is under 2 sample periods (0.2 s at 10 Hz); raise --rate-hz to at least "
            "13.3333 or lengthen dwell_min");
}

// The documented algorithm, written again: level first (r mod n, redrawn below 2^64 mod
// n), then the dwell from the top 53 bits.
std::vector<Protocol::Dwell> ExpectedSchedule(const std::vector<double>& levels_V,
                                              double dwell_min_s, double dwell_max_s,
                                              double duration_s, uint64_t seed) {
  std::mt19937_64 generator(seed);
  const uint64_t n = levels_V.size();
  const uint64_t threshold = (UINT64_MAX - n + 1) % n;
  std::vector<Protocol::Dwell> dwells;
  for (double t_s = 0.0; t_s < duration_s;) {
    uint64_t r = generator();
    while (r < threshold) r = generator();
    dwells.push_back({t_s, levels_V[r % n]});
    t_s += dwell_min_s +
           std::ldexp(static_cast<double>(generator() >> 11), -53) * (dwell_max_s - dwell_min_s);
  }
  return dwells;
}

bool SameSchedule(const std::vector<Protocol::Dwell>& a, const std::vector<Protocol::Dwell>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i)
    if (a[i].start_s != b[i].start_s || a[i].level_V != b[i].level_V) return false;
  return true;
}

TEST(Protocol, RandomIsDeterministicForASeed) {
  const std::string spec = "random:levels=1/2/3,dwell_min=2,dwell_max=5,duration=100,seed=7";
  const Protocol p = ParseProtocol(spec);
  EXPECT_EQ(p.shape, Protocol::Shape::kRandom);
  EXPECT_EQ(p.levels_V, (std::vector<double>{1, 2, 3}));
  EXPECT_EQ(p.dwell_min_s, 2.0);
  EXPECT_EQ(p.dwell_max_s, 5.0);
  EXPECT_EQ(p.seed, 7u);
  EXPECT_EQ(ProtocolDuration(p), 100.0);
  EXPECT_TRUE(SameSchedule(p.dwells, ParseProtocol(spec).dwells));
  EXPECT_TRUE(SameSchedule(p.dwells, ExpectedSchedule({1, 2, 3}, 2, 5, 100, 7)));
  EXPECT_FALSE(SameSchedule(
      p.dwells,
      ParseProtocol("random:levels=1/2/3,dwell_min=2,dwell_max=5,duration=100,seed=8").dwells));
  // seed defaults to 1, whatever the rig's --seed.
  EXPECT_TRUE(SameSchedule(
      ParseProtocol("random:levels=1/2/3,dwell_min=2,dwell_max=5,duration=100").dwells,
      ParseProtocol("random:levels=1/2/3,dwell_min=2,dwell_max=5,duration=100,seed=1").dwells));
  EXPECT_TRUE(SameSchedule(
      ParseProtocol("random:levels=4/-4,dwell_min=0.5,dwell_max=3,duration=50,seed=0").dwells,
      ExpectedSchedule({4, -4}, 0.5, 3, 50, 0)));
  // VoltageAt holds each dwell's level from its start to the next start.
  for (size_t i = 0; i < p.dwells.size(); ++i) {
    const double end_s = i + 1 < p.dwells.size() ? p.dwells[i + 1].start_s : 100.0;
    EXPECT_EQ(VoltageAt(p, p.dwells[i].start_s), p.dwells[i].level_V) << i;
    EXPECT_EQ(VoltageAt(p, end_s - 1e-6), p.dwells[i].level_V) << i;
  }
  EXPECT_EQ(VoltageAt(p, 1000.0), p.dwells.back().level_V);  // the last level holds
}

TEST(Protocol, RandomLevelsComeFromTheListAndDwellsStayInBounds) {
  const std::vector<double> levels_V = {-2, 0.5, 4, 8};
  const Protocol p =
      ParseProtocol("random:levels=-2/0.5/4/8,dwell_min=2,dwell_max=5,duration=10000,seed=3");
  ASSERT_GT(p.dwells.size(), 2000u);  // about 10000 / 3.5
  EXPECT_EQ(p.dwells.front().start_s, 0.0);
  std::vector<int> drawn(levels_V.size(), 0);
  double shortest_s = 1e9, longest_s = 0.0;
  for (size_t i = 0; i < p.dwells.size(); ++i) {
    const auto level = std::find(levels_V.begin(), levels_V.end(), p.dwells[i].level_V);
    ASSERT_NE(level, levels_V.end()) << p.dwells[i].level_V;
    ++drawn[static_cast<size_t>(level - levels_V.begin())];
    if (i + 1 == p.dwells.size()) {  // the last one is cut at the duration
      EXPECT_LT(p.dwells[i].start_s, 10000.0);
      EXPECT_GT(p.dwells[i].start_s, 10000.0 - 5.0);
      continue;
    }
    const double dwell_s = p.dwells[i + 1].start_s - p.dwells[i].start_s;
    ASSERT_GE(dwell_s, 2.0 - 1e-9) << i;
    ASSERT_LE(dwell_s, 5.0 + 1e-9) << i;
    shortest_s = std::min(shortest_s, dwell_s);
    longest_s = std::max(longest_s, dwell_s);
  }
  // Uniform over [2, 5] s: ~2860 dwells come within 0.05 s of both ends (a miss has
  // probability (1 - 0.05 / 3)^2860 ~ 1e-21); and each of the 4 levels gets about a quarter
  // (binomial sd ~ 23 of ~715; 15 % is ~4.6 sd).
  EXPECT_LT(shortest_s, 2.05);
  EXPECT_GT(longest_s, 4.95);
  const double quarter = static_cast<double>(p.dwells.size()) / 4.0;
  for (const int count : drawn) EXPECT_NEAR(count, quarter, 0.15 * quarter);
  // dwell_min == dwell_max: a fixed dwell, starts 0, 2, 4, ...
  const Protocol fixed = ParseProtocol("random:levels=1/2,dwell_min=2,dwell_max=2,duration=9");
  ASSERT_EQ(fixed.dwells.size(), 5u);
  for (size_t i = 0; i < fixed.dwells.size(); ++i)
    EXPECT_EQ(fixed.dwells[i].start_s, 2.0 * static_cast<double>(i));
}

// Through the Rig: duration * rate samples, and the voltage only from the list.
TEST(Rig, RandomProtocolCoversItsDurationWithListedLevels) {
  const Protocol p = ParseProtocol("random:levels=2/5/8,dwell_min=1,dwell_max=4,duration=60");
  rig::Rig r(GainModel(), p, {}, {});
  ASSERT_EQ(r.sample_count(), 600);
  size_t dwell = 0;
  rig::RigSample sample;
  while (r.Next(&sample)) {
    ASSERT_TRUE(sample.voltage_V == 2.0 || sample.voltage_V == 5.0 || sample.voltage_V == 8.0);
    while (dwell + 1 < p.dwells.size() && p.dwells[dwell + 1].start_s <= sample.t_s) ++dwell;
    ASSERT_EQ(sample.voltage_V, p.dwells[dwell].level_V) << sample.t_s;
    ASSERT_NEAR(sample.deflection_mm, 2.0 * sample.voltage_V, 1e-12);
  }
}

TEST(Protocol, SweepAndRandomErrorsAreOneClearLine) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"sweep", "protocol \"sweep\": missing key \"level\""},
      {"sweep:level=5,frequencies=0.1/0",
       "protocol \"sweep:level=5,frequencies=0.1/0\": frequencies must all be > 0 Hz (got 0)"},
      {"sweep:level=5,frequencies=-1",
       "protocol \"sweep:level=5,frequencies=-1\": frequencies must all be > 0 Hz (got -1)"},
      {"sweep:level=5,frequencies=0.1/x",
       "protocol \"sweep:level=5,frequencies=0.1/x\": frequencies is not a list of finite "
       "numbers separated by '/': \"0.1/x\""},
      {"sweep:level=5,cycles=0",
       "protocol \"sweep:level=5,cycles=0\": cycles must be a positive whole number (got \"0\")"},
      {"sweep:level=5,duty=1",
       "protocol \"sweep:level=5,duty=1\": duty must be > 0 and < 1 (got 1)"},
      {"sweep:level=5,period=3",
       "protocol \"sweep:level=5,period=3\": unknown key \"period\" (sweep takes level, "
       "frequencies, cycles and duty)"},
      {"sweep:level=5,frequencies=1e-308",
       "protocol \"sweep:level=5,frequencies=1e-308\": the protocol is too long"},
      {"random:dwell_min=1,dwell_max=2,duration=10",
       "protocol \"random:dwell_min=1,dwell_max=2,duration=10\": missing key \"levels\""},
      {"random:levels=1/2,dwell_max=2,duration=10",
       "protocol \"random:levels=1/2,dwell_max=2,duration=10\": missing key \"dwell_min\""},
      {"random:levels=1/2,dwell_min=1,duration=10",
       "protocol \"random:levels=1/2,dwell_min=1,duration=10\": missing key \"dwell_max\""},
      {"random:levels=1/2,dwell_min=1,dwell_max=2",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2\": missing key \"duration\""},
      {"random:levels=1/2,dwell_min=0,dwell_max=2,duration=10",
       "protocol \"random:levels=1/2,dwell_min=0,dwell_max=2,duration=10\": dwell_min must be > "
       "0 s (got 0)"},
      {"random:levels=1/2,dwell_min=5,dwell_max=2,duration=10",
       "protocol \"random:levels=1/2,dwell_min=5,dwell_max=2,duration=10\": dwell_max must be >= "
       "dwell_min (got 2 < 5)"},
      {"random:levels=1/2,dwell_min=1,dwell_max=2,duration=-10",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2,duration=-10\": duration must be > "
       "0 s (got -10)"},
      {"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,seed=-1",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,seed=-1\": seed must be "
       "a whole number >= 0 (got \"-1\")"},
      {"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,seed=1.5",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,seed=1.5\": seed must "
       "be a whole number >= 0 (got \"1.5\")"},
      {"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,dwell=1",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2,duration=10,dwell=1\": unknown key "
       "\"dwell\" (random takes levels, dwell_min, dwell_max, duration and seed)"},
      {"random:levels=1/2,dwell_min=1,dwell_max=2,duration=1e7",
       "protocol \"random:levels=1/2,dwell_min=1,dwell_max=2,duration=1e7\": duration / "
       "dwell_min must be < 10000000 (the schedule is computed in advance)"},
  };
  for (const auto& [spec, message] : cases) EXPECT_EQ(ProtocolError(spec), message) << spec;
  // The largest seed is a seed like any other.
  EXPECT_EQ(ParseProtocol("random:levels=1,dwell_min=1,dwell_max=1,duration=2,"
                          "seed=18446744073709551615")
                .seed,
            UINT64_MAX);
}

// ---------------------------------------------------------------------------------------
// Several actuators
// ---------------------------------------------------------------------------------------

TEST(Actuators, AnEffectForOneActuatorIsWrittenIdSlashName) {
  const rig::ActuatorEffect everyone = rig::ParseActuatorEffect("back_relaxation:tau=60");
  EXPECT_EQ(everyone.actuator_id, "");
  EXPECT_EQ(everyone.effect, "back_relaxation:tau=60");
  const rig::ActuatorEffect one = rig::ParseActuatorEffect("S2/back_relaxation:fraction=0.3");
  EXPECT_EQ(one.actuator_id, "S2");
  EXPECT_EQ(one.effect, "back_relaxation:fraction=0.3");
  EXPECT_EQ(rig::ParseActuatorEffect("S2/dead_zone").effect, "dead_zone");
  EXPECT_EQ(ErrorOf([] { rig::ParseActuatorEffect("/dead_zone"); }),
            "effect \"/dead_zone\": empty actuator id before '/' (expected ID/NAME[:k=v,...])");
}

// The streams of MakeActuatorRigs against single Rigs built by hand: actuator i has seed +
// i and the effects meant for it, in the order given.
TEST(Actuators, EachActuatorHasItsOwnNoiseAndItsOwnEffects) {
  const model::TsModel model = model::SeedTsModel();
  const std::string protocol = "square:level=5,period=100,cycles=2";
  rig::RigOptions options;
  options.noise_mm = 0.05;
  options.seed = 10;
  std::vector<rig::Rig> rigs = rig::MakeActuatorRigs(
      model, ParseProtocol(protocol), {"S1", "S2", "S3"},
      {"sensor_drift:rate=0.001", "S2/back_relaxation:fraction=0.3,tau=60"}, options);
  ASSERT_EQ(rigs.size(), 3u);
  auto single = [&](uint64_t seed, const std::vector<std::string>& effect_specs) {
    std::vector<std::unique_ptr<rig::Effect>> effects;
    for (const std::string& spec : effect_specs) effects.push_back(ParseEffect(spec));
    rig::RigOptions own = options;
    own.seed = seed;
    return RunStream(model, protocol, std::move(effects), own);
  };
  const std::vector<std::vector<rig::RigSample>> expected = {
      single(10, {"sensor_drift:rate=0.001"}),
      single(11, {"sensor_drift:rate=0.001", "back_relaxation:fraction=0.3,tau=60"}),
      single(12, {"sensor_drift:rate=0.001"})};
  for (size_t i = 0; i < 3; ++i) {
    const std::vector<rig::RigSample> stream = Drain(rigs[i]);
    ASSERT_EQ(stream.size(), 2000u);
    for (size_t k = 0; k < stream.size(); ++k) {
      ASSERT_EQ(stream[k].voltage_V, expected[i][k].voltage_V) << i << " " << k;
      ASSERT_EQ(stream[k].deflection_mm, expected[i][k].deflection_mm) << i << " " << k;
    }
  }
}

TEST(Actuators, NoiseStreamsAreIndependent) {
  const model::TsModel model = model::SeedTsModel();
  const Protocol protocol = ParseProtocol("hold:level=3,duration=300");
  rig::RigOptions options;
  options.noise_mm = 0.05;
  std::vector<rig::Rig> rigs = rig::MakeActuatorRigs(model, protocol, {"A", "B"}, {}, options);
  const auto a = Drain(rigs[0]);
  const auto b = Drain(rigs[1]);
  const auto clean = RunStream(model, "hold:level=3,duration=300");
  ASSERT_EQ(a.size(), 3000u);
  ASSERT_EQ(b.size(), 3000u);
  double sum_ab = 0.0, sum_aa = 0.0, sum_bb = 0.0;
  int equal = 0;
  for (size_t k = 0; k < a.size(); ++k) {
    const double noise_a = a[k].deflection_mm - clean[k].deflection_mm;
    const double noise_b = b[k].deflection_mm - clean[k].deflection_mm;
    equal += noise_a == noise_b ? 1 : 0;
    sum_ab += noise_a * noise_b;
    sum_aa += noise_a * noise_a;
    sum_bb += noise_b * noise_b;
  }
  EXPECT_EQ(equal, 0);
  // Independent: correlation ~ N(0, 1 / 3000), sd 0.018; the bound is about 4.4 sd. The
  // same stream would give 1.
  EXPECT_LT(std::abs(sum_ab / std::sqrt(sum_aa * sum_bb)), 0.08);
  EXPECT_NEAR(std::sqrt(sum_bb / 3000.0), 0.05, 0.05 * 0.06);
}

TEST(Actuators, AnEffectForOneActuatorLeavesTheOthersAlone) {
  const model::TsModel model = model::SeedTsModel();
  const Protocol protocol = ParseProtocol("step:level=2,duration=3000");
  std::vector<rig::Rig> rigs = rig::MakeActuatorRigs(
      model, protocol, {"S1", "S2", "S3"}, {"S2/back_relaxation:fraction=0.3,tau=60"}, {});
  const auto s1 = Drain(rigs[0]);
  const auto s2 = Drain(rigs[1]);
  const auto s3 = Drain(rigs[2]);
  const auto plain = RunStream(model, "step:level=2,duration=3000");
  for (size_t k = 0; k < plain.size(); ++k) {
    ASSERT_EQ(s1[k].deflection_mm, plain[k].deflection_mm) << k;
    ASSERT_EQ(s3[k].deflection_mm, plain[k].deflection_mm) << k;
    ASSERT_EQ(s2[k].voltage_V, plain[k].voltage_V) << k;
  }
  // S2 relaxed to 70 % (see BackRelaxationSettlesAtItsShareOfTheSeedModel).
  const double model_mm = plain.back().deflection_mm;
  ASSERT_GT(std::abs(model_mm), 1.0);
  EXPECT_NEAR(s2.back().deflection_mm, 0.7 * model_mm, 1e-9 * std::abs(model_mm));
}

TEST(Actuators, AnEffectForAnUnknownActuatorIsRejected) {
  const Protocol protocol = ParseProtocol("hold:level=1,duration=1");
  EXPECT_EQ(ErrorOf([&] {
              rig::MakeActuatorRigs(GainModel(), protocol, {"S1", "S2"},
                                    {"dead_zone", "S3/back_relaxation:tau=60"}, {});
            }),
            "effect \"S3/back_relaxation:tau=60\": no actuator \"S3\" (actuators: S1, S2)");
  EXPECT_EQ(
      ErrorOf([&] { rig::MakeActuatorRigs(GainModel(), protocol, {""}, {"S1/dead_zone"}, {}); }),
      "effect \"S1/dead_zone\": no actuator \"S1\" (no --actuator given)");
  EXPECT_EQ(ErrorOf([&] {
              rig::MakeActuatorRigs(GainModel(), protocol, {"S1"}, {"S1/dead_zone:level=3"}, {});
            }),
            "effect \"dead_zone:level=3\": unknown key \"level\" (dead_zone takes threshold)");
  // The sample limit counts every actuator: 4 x 3e6 samples.
  EXPECT_EQ(ErrorOf([&] {
              rig::MakeActuatorRigs(GainModel(), ParseProtocol("hold:level=1,duration=3e5"),
                                    {"A", "B", "C", "D"}, {}, {});
            }),
            "4 actuators of 3000000 samples each need 1.2e+07 samples; at most 10000000 in all "
            "(fewer actuators, lower --rate-hz or a shorter protocol)");
}

// ---------------------------------------------------------------------------------------
// The runner
// ---------------------------------------------------------------------------------------

struct Recorded {
  char kind;  // 'V', 'D', 'S' (trial start), 'E' (trial stop)
  int64_t utime;
  double value;
};

class RecordingSink : public rig::BusSink {
 public:
  bool PublishVoltage(int64_t utime, double voltage_V) override {
    messages.push_back({'V', utime, voltage_V});
    return true;
  }
  bool PublishDeflection(int64_t utime, double deflection_mm) override {
    messages.push_back({'D', utime, deflection_mm});
    return !fail_deflections;
  }
  bool PublishTrialControl(int64_t utime, rig::TrialAction action,
                           const std::string& protocol) override {
    messages.push_back({action == rig::TrialAction::kStart ? 'S' : 'E', utime, 0.0});
    trial_protocol = protocol;
    return true;
  }
  std::vector<Recorded> messages;
  std::string trial_protocol;
  bool fail_deflections = false;
};

rig::RigOptions StartingAt(int64_t start_utime) {
  rig::RigOptions options;
  options.start_utime = start_utime;
  return options;
}

TEST(Runner, PublishesInOrderWithTrialControlAroundTheSamples) {
  const std::string protocol = "step:level=3,duration=2,delay=1.05";
  rig::Rig r(GainModel(), ParseProtocol(protocol), {}, StartingAt(1'000'000));
  RecordingSink sink;
  const rig::RunSummary summary = rig::RunRig(r, sink, {.speed = 0.0, .trial_control = true});
  EXPECT_EQ(summary.samples, 31);
  EXPECT_EQ(summary.deflection_messages, 31);
  // Voltage at 0 s, 1 s (a second since), 1.1 s (the change at 1.05 s) and 2.1 s.
  EXPECT_EQ(summary.voltage_messages, 4);
  EXPECT_EQ(summary.trial_messages, 2);
  EXPECT_EQ(summary.failed_messages, 0);
  EXPECT_FALSE(summary.interrupted);
  EXPECT_EQ(summary.duration_s, 3.1);
  EXPECT_EQ(summary.final_utime, 1'000'000 + 3'000'000);
  ASSERT_EQ(sink.messages.size(), 31u + 4u + 2u);
  EXPECT_EQ(sink.trial_protocol, protocol);
  EXPECT_EQ(sink.messages.front().kind, 'S');
  EXPECT_EQ(sink.messages.front().utime, 1'000'000);
  EXPECT_EQ(sink.messages.back().kind, 'E');
  EXPECT_EQ(sink.messages.back().utime, 1'000'000 + 3'100'000);  // end of the last interval
  EXPECT_EQ(sink.messages[1].kind, 'V');  // the voltage goes before the first deflection
  EXPECT_EQ(sink.messages[2].kind, 'D');
  std::vector<int64_t> voltage_utimes;
  int64_t previous_deflection_utime = -1;
  for (const Recorded& m : sink.messages) {
    if (m.kind == 'V') voltage_utimes.push_back(m.utime);
    if (m.kind != 'D') continue;
    EXPECT_GT(m.utime, previous_deflection_utime);
    previous_deflection_utime = m.utime;
  }
  EXPECT_EQ(voltage_utimes, (std::vector<int64_t>{1'000'000, 2'000'000, 2'100'000, 3'100'000}));
  EXPECT_EQ(rig::SummaryLine(summary).rfind(
                "published 31 samples (31 deflection, 4 voltage, 2 trial-control messages) "
                "covering 3.1 s of message time in ",
                0),
            0u)
      << rig::SummaryLine(summary);
}

TEST(Runner, PacesAgainstTheWallClockAtTheGivenSpeed) {
  // 20 samples over 2 s of message time at 20 x: the last goes out 1.9 / 20 = 95 ms in.
  rig::Rig r(GainModel(), ParseProtocol("hold:level=1,duration=2"), {}, StartingAt(0));
  RecordingSink sink;
  const rig::RunSummary summary = rig::RunRig(r, sink, {.speed = 20.0});
  EXPECT_EQ(summary.samples, 20);
  EXPECT_GE(summary.wall_s, 0.095);
  EXPECT_LT(summary.wall_s, 5.0);
  EXPECT_EQ(summary.duration_s, 2.0);  // message time does not depend on the speed
}

TEST(Runner, StopsWhenAskedAndStillClosesTheTrial) {
  rig::Rig r(GainModel(), ParseProtocol("hold:level=1,duration=3600"), {}, StartingAt(0));
  RecordingSink sink;
  std::atomic<bool> stop{false};
  std::thread stopper([&stop] {
    std::this_thread::sleep_for(std::chrono::milliseconds(150));
    stop = true;
  });
  const rig::RunSummary summary =
      rig::RunRig(r, sink, {.speed = 1.0, .trial_control = true}, &stop);
  stopper.join();
  EXPECT_TRUE(summary.interrupted);
  EXPECT_GE(summary.samples, 1);
  EXPECT_LE(summary.samples, 10);  // 10 Hz for about 0.15 s (or a slow machine)
  ASSERT_FALSE(sink.messages.empty());
  EXPECT_EQ(sink.messages.back().kind, 'E');
  EXPECT_EQ(sink.messages.back().utime, summary.final_utime + 100'000);
  EXPECT_NE(rig::SummaryLine(summary).find("(interrupted)"), std::string::npos);
}

TEST(Runner, CountsMessagesTheBusRefused) {
  rig::Rig r(GainModel(), ParseProtocol("hold:level=1,duration=1"), {}, StartingAt(0));
  RecordingSink sink;
  sink.fail_deflections = true;
  const rig::RunSummary summary = rig::RunRig(r, sink, {.speed = 0.0});
  EXPECT_EQ(summary.samples, 10);
  EXPECT_EQ(summary.deflection_messages, 0);
  EXPECT_EQ(summary.failed_messages, 10);
  EXPECT_NE(rig::SummaryLine(summary).find(", 10 failed to send"), std::string::npos);
}

// Two actuators into one log, tagged: the order across actuators is what RunRigs promises.
class TaggedSink : public rig::BusSink {
 public:
  TaggedSink(char tag, std::vector<std::pair<char, Recorded>>* log) : tag_(tag), log_(log) {}
  bool PublishVoltage(int64_t utime, double voltage_V) override {
    log_->push_back({tag_, {'V', utime, voltage_V}});
    return true;
  }
  bool PublishDeflection(int64_t utime, double deflection_mm) override {
    log_->push_back({tag_, {'D', utime, deflection_mm}});
    return true;
  }
  bool PublishTrialControl(int64_t utime, rig::TrialAction action, const std::string&) override {
    log_->push_back({tag_, {action == rig::TrialAction::kStart ? 'S' : 'E', utime, 0.0}});
    return true;
  }

 private:
  char tag_;
  std::vector<std::pair<char, Recorded>>* log_;
};

TEST(Runner, SeveralActuatorsAdvanceTogetherInMessageTime) {
  std::vector<rig::Rig> rigs =
      rig::MakeActuatorRigs(GainModel(), ParseProtocol("step:level=3,duration=2,delay=1.05"),
                            {"A", "B"}, {"B/dead_zone:threshold=1"}, StartingAt(1'000'000));
  std::vector<std::pair<char, Recorded>> log;
  TaggedSink a('A', &log), b('B', &log);
  const rig::RunSummary summary =
      rig::RunRigs({{.rig = &rigs[0], .sink = &a}, {.rig = &rigs[1], .sink = &b}},
                   {.speed = 0.0, .trial_control = true});
  EXPECT_EQ(summary.actuators, 2);
  EXPECT_EQ(summary.samples, 31);
  EXPECT_EQ(summary.deflection_messages, 62);
  EXPECT_EQ(summary.voltage_messages, 8);
  EXPECT_EQ(summary.trial_messages, 4);
  EXPECT_EQ(summary.final_utime, 4'000'000);
  ASSERT_EQ(log.size(), 62u + 8u + 4u);
  // Both trial starts first, both stops last.
  EXPECT_EQ(log[0].first, 'A');
  EXPECT_EQ(log[0].second.kind, 'S');
  EXPECT_EQ(log[1].first, 'B');
  EXPECT_EQ(log[1].second.kind, 'S');
  EXPECT_EQ(log[log.size() - 2].first, 'A');
  EXPECT_EQ(log[log.size() - 2].second.kind, 'E');
  EXPECT_EQ(log.back().first, 'B');
  EXPECT_EQ(log.back().second.kind, 'E');
  EXPECT_EQ(log.back().second.utime, 4'100'000);
  // Deflections alternate A, B with the same utime, never going back in time.
  std::vector<std::pair<char, Recorded>> deflections;
  for (const auto& entry : log)
    if (entry.second.kind == 'D') deflections.push_back(entry);
  ASSERT_EQ(deflections.size(), 62u);
  for (size_t k = 0; k < 31; ++k) {
    const int64_t utime = 1'000'000 + static_cast<int64_t>(k) * 100'000;
    EXPECT_EQ(deflections[2 * k].first, 'A');
    EXPECT_EQ(deflections[2 * k + 1].first, 'B');
    EXPECT_EQ(deflections[2 * k].second.utime, utime);
    EXPECT_EQ(deflections[2 * k + 1].second.utime, utime);
    // B's dead zone of 1 V: 2 mm/V * (3 - 1) V once the step is on, A the full 6 mm.
    const double a_mm = k >= 11 ? 6.0 : 0.0;
    EXPECT_NEAR(deflections[2 * k].second.value, a_mm, 1e-12) << k;
    EXPECT_NEAR(deflections[2 * k + 1].second.value, a_mm * 2.0 / 3.0, 1e-12) << k;
  }
  EXPECT_EQ(rig::SummaryLine(summary).rfind(
                "published 31 samples for each of 2 actuators (62 deflection, 8 voltage, 4 "
                "trial-control messages) covering 3.1 s of message time in ",
                0),
            0u)
      << rig::SummaryLine(summary);
}

TEST(Runner, SeveralActuatorsArePacedAsOne) {
  // 20 samples over 2 s at 20 x, for 3 actuators: still 1.9 / 20 = 95 ms, not 3 times it.
  std::vector<rig::Rig> rigs = rig::MakeActuatorRigs(
      GainModel(), ParseProtocol("hold:level=1,duration=2"), {"A", "B", "C"}, {}, StartingAt(0));
  RecordingSink a, b, c;
  const rig::RunSummary summary = rig::RunRigs(
      {{.rig = &rigs[0], .sink = &a}, {.rig = &rigs[1], .sink = &b}, {.rig = &rigs[2], .sink = &c}},
      {.speed = 20.0});
  EXPECT_EQ(summary.samples, 20);
  EXPECT_EQ(summary.deflection_messages, 60);
  EXPECT_GE(summary.wall_s, 0.095);
  EXPECT_LT(summary.wall_s, 0.095 * 2 + 1.0);
  EXPECT_EQ(a.messages.size(), b.messages.size());
  EXPECT_EQ(c.messages.size(), 20u + 2u);  // 20 deflections, voltage at 0 s and 1 s
}

// Without --start-utime: the wall clock, unless flexidd has seen a later sample; then
// kRestartGap_s after it (one period when that is longer), saturating rather than wrapping.
TEST(Runner, ContinuedStartUtimeGoesAfterTheLatestSampleOnlyIfItIsLater) {
  constexpr int64_t kWall = 1'700'000'000'000'000;
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, std::nullopt, 10.0), kWall);
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, kWall - 5'000'000, 10.0), kWall);
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, kWall - 1'000'000, 10.0), kWall);
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, kWall + 436'000'000, 10.0), kWall + 437'000'000);
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, kWall, 0.25), kWall + 4'000'000);  // one period
  EXPECT_EQ(rig::ContinuedStartUtime(kWall, INT64_MAX - 10, 10.0), INT64_MAX);
}

// The rig learns its start from flexidd after its input is checked: moving the start moves
// every utime and nothing else; a start that leaves no room is refused, as in the
// constructor, and the run keeps its start.
TEST(Rig, SetStartUtimeMovesMessageTimeOnly) {
  rig::Rig moved(GainModel(), ParseProtocol("step:level=1,duration=2"), {}, StartingAt(0));
  moved.SetStartUtime(5'000'000);
  rig::Rig direct(GainModel(), ParseProtocol("step:level=1,duration=2"), {}, StartingAt(5'000'000));
  rig::RigSample a, b;
  while (direct.Next(&b)) {
    ASSERT_TRUE(moved.Next(&a));
    EXPECT_EQ(a.utime, b.utime);
    EXPECT_EQ(a.deflection_mm, b.deflection_mm);
    EXPECT_EQ(a.publish_voltage, b.publish_voltage);
  }
  EXPECT_FALSE(moved.Next(&a));
  EXPECT_EQ(moved.UtimeOf(0), 5'000'000);

  rig::Rig refused(GainModel(), ParseProtocol("step:level=1,duration=2"), {}, StartingAt(7));
  EXPECT_EQ(ErrorOf([&] { refused.SetStartUtime(INT64_MAX - 10); }),
            "the start utime is too large for the protocol");
  EXPECT_EQ(ErrorOf([&] { refused.SetStartUtime(-1); }), "the start utime must be >= 0");
  EXPECT_EQ(refused.UtimeOf(0), 7);
  refused.Next(&a);
  EXPECT_THROW(refused.SetStartUtime(0), std::logic_error);
}

TEST(Runner, RigsThatDoNotAgreeCannotRunTogether) {
  rig::Rig one(GainModel(), ParseProtocol("hold:level=1,duration=1"), {}, StartingAt(0));
  rig::Rig two(GainModel(), ParseProtocol("hold:level=1,duration=2"), {}, StartingAt(0));
  RecordingSink a, b;
  EXPECT_THROW(rig::RunRigs({{.rig = &one, .sink = &a}, {.rig = &two, .sink = &b}}, {}),
               std::invalid_argument);
  EXPECT_THROW(rig::RunRigs({}, {}), std::invalid_argument);
  EXPECT_TRUE(a.messages.empty());
}

// ---------------------------------------------------------------------------------------
// The real binary on a real bus
// ---------------------------------------------------------------------------------------

const std::string kRig = FLEXID_RIG_BINARY;

struct BusCounter {
  void OnVoltage(const lcm::ReceiveBuffer*, const std::string&,
                 const flexid::voltage_sample_t* message) {
    voltage_utimes.push_back(message->utime);
    ids_ok = ids_ok && message->actuator_id == "E2E";
    Touch();
  }
  void OnDeflection(const lcm::ReceiveBuffer*, const std::string&,
                    const flexid::deflection_sample_t* message) {
    deflection_utimes.push_back(message->utime);
    ids_ok = ids_ok && message->actuator_id == "E2E";
    Touch();
  }
  void OnTrial(const lcm::ReceiveBuffer*, const std::string&,
               const flexid::trial_control2_t* message) {
    trial_actions.push_back(message->action);
    ids_ok = ids_ok && message->actuator_id == "E2E";
    // Signed with the key given, on the wall clock (not the message time of --start-utime).
    signed_ok = signed_ok && key != nullptr &&
                auth::SignatureMatches(*key, auth::CanonicalForm(*message), message->auth) &&
                std::abs(message->sent_utime - bus::WallClockUtime()) < 60'000'000;
    Touch();
  }
  void Touch() { last_message = std::chrono::steady_clock::now(); }

  std::vector<int64_t> voltage_utimes, deflection_utimes;
  std::vector<int8_t> trial_actions;
  bool ids_ok = true;
  const auth::Key* key = nullptr;
  bool signed_ok = true;
  std::chrono::steady_clock::time_point last_message = std::chrono::steady_clock::now();
};

std::string RandomUdpmUrl() {
  std::random_device device;
  std::uniform_int_distribution<int> port(20000, 60000);
  return "udpm://239.255.76.67:" + std::to_string(port(device)) + "?ttl=0";
}

class RigBinary : public ::testing::Test {
 protected:
  testing::ProcessResult Run(const std::string& args) {
    return testing::RunCommand(kRig + " " + args, scratch_.path());
  }
  // A key file for --trial-control (as flexidd would create it): " --key-file 'PATH' ".
  std::string KeyFlag() {
    key_ = auth::LoadOrCreateKeyFile(scratch_.File("flexidd.key"));
    return " --key-file '" + scratch_.File("flexidd.key") + "' ";
  }
  testing::ScratchDir scratch_;
  auth::Key key_;
};

TEST_F(RigBinary, PublishesWhatItsSummarySaysOverLcm) {
  const std::string url = RandomUdpmUrl();
  lcm::LCM lcm(url);
  if (!lcm.good()) GTEST_SKIP() << "cannot open LCM on " << url << " (no multicast route?)";
  BusCounter counter;
  const std::string key_flag = KeyFlag();
  counter.key = &key_;
  // LCM queues at most 30 messages per subscription by default and drops the rest; the
  // rig at --speed 0 publishes faster than that is drained.
  for (lcm::Subscription* subscription :
       {testing::SubscribeMember<&BusCounter::OnVoltage>(lcm, "FLEXID/E2E/VOLTAGE", &counter),
        testing::SubscribeMember<&BusCounter::OnDeflection>(lcm, "FLEXID/E2E/DEFLECTION", &counter),
        testing::SubscribeMember<&BusCounter::OnTrial>(lcm, "FLEXID/TRIAL", &counter)})
    subscription->setQueueCapacity(100000);
  lcm.getFileno();  // the receive socket exists before the rig publishes

  testing::ProcessResult result;
  std::atomic<bool> done{false};
  std::thread rig([&] {
    result = Run("--lcm '" + url +
                 "' --actuator E2E --protocol step:level=3,duration=5,delay=1 --speed 0 "
                 "--start-utime 1000000 --trial-control --effect back_relaxation --noise-mm 0.01" +
                 key_flag);
    done = true;
  });
  while (!done ||
         std::chrono::steady_clock::now() - counter.last_message < std::chrono::milliseconds(500))
    lcm.handleTimeout(50);
  rig.join();

  ASSERT_EQ(result.exit_code, 0) << result.err;
  EXPECT_EQ(result.err, "");
  std::smatch match;
  const std::regex summary(
      "^published (\\d+) samples \\((\\d+) deflection, (\\d+) voltage, (\\d+) trial-control "
      "messages\\) covering 6 s of message time in [0-9.e+-]+ s, final utime 6900000\n$");
  ASSERT_TRUE(std::regex_match(result.out, match, summary)) << result.out;
  EXPECT_EQ(match[1].str(), "60");
  EXPECT_EQ(std::to_string(counter.deflection_utimes.size()), match[2].str());
  EXPECT_EQ(std::to_string(counter.voltage_utimes.size()), match[3].str());
  EXPECT_EQ(std::to_string(counter.trial_actions.size()), match[4].str());
  EXPECT_EQ(counter.voltage_utimes.size(), 6u);  // 0 .. 5 s, the change at 1 s among them
  EXPECT_TRUE(counter.ids_ok);
  ASSERT_EQ(counter.deflection_utimes.size(), 60u);
  for (size_t k = 0; k < 60; ++k)
    EXPECT_EQ(counter.deflection_utimes[k], 1'000'000 + static_cast<int64_t>(k) * 100'000);
  EXPECT_EQ(counter.trial_actions, (std::vector<int8_t>{flexid::trial_control2_t::kStart,
                                                        flexid::trial_control2_t::kStop}));
  EXPECT_TRUE(counter.signed_ok) << "trial control not signed with the key given";
}

// No flexidd on the bus to ask where message time stands: the wall clock, and a line on
// stderr says why. (With a flexidd: tests/rig_live_test.cc.)
TEST_F(RigBinary, WithoutFlexiddMessageTimeStartsAtTheWallClock) {
  const std::string url = RandomUdpmUrl();
  const int64_t before_utime = bus::WallClockUtime();
  const auto result =
      Run("--lcm '" + url + "' --actuator E2E --protocol hold:level=1,duration=1 --speed 0");
  const int64_t after_utime = bus::WallClockUtime();
  ASSERT_EQ(result.exit_code, 0) << result.err;
  EXPECT_EQ(result.err,
            "flexid-rig: no flexidd answered status within 0.5 s: message time starts at the "
            "wall clock [url: " +
                url + "]\n");
  std::smatch match;
  ASSERT_TRUE(std::regex_search(result.out, match, std::regex("final utime (\\d+)"))) << result.out;
  const int64_t first_utime = std::stoll(match[1].str()) - 900'000;  // 10 samples at 10 Hz
  EXPECT_GE(first_utime, before_utime);
  EXPECT_LE(first_utime, after_utime);
}

TEST_F(RigBinary, TrialControlWithoutAKeyFailsBeforeSendingAnything) {
  const std::string missing = scratch_.File("no-such.key");
  const auto result =
      Run("--lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator K1 --protocol "
          "hold:level=1,duration=1 --speed 0 --trial-control --key-file '" +
          missing + "'");
  EXPECT_EQ(result.exit_code, 1);
  EXPECT_EQ(result.out, "");
  EXPECT_NE(result.err.find("cannot read key file " + missing), std::string::npos) << result.err;
  EXPECT_EQ(std::count(result.err.begin(), result.err.end(), '\n'), 1) << result.err;
}

TEST_F(RigBinary, BadUsageIsOneLineAndExitTwo) {
  const std::string bus = " --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator S1";
  const std::vector<std::pair<std::string, std::string>> cases = {
      {bus + " --protocol step:level=2",
       "flexid-rig: protocol \"step:level=2\": missing key \"duration\"\n"},
      {bus + " --protocol hold:level=1,duration=1 --effect wobble",
       "flexid-rig: effect \"wobble\": unknown effect \"wobble\" (expected back_relaxation, "
       "cycle_degradation, hysteresis, electrolysis_saturation, sensor_drift, polarity_asymmetry "
       "or dead_zone)\n"},
      {bus + " --protocol hold:level=1,duration=1 --speed -1",
       "flexid-rig: --speed must be 0 (as fast as possible) or a finite number >= 0.001\n"},
      {bus + " --protocol hold:level=1,duration=1 --rate-hz 0",
       "flexid-rig: the sample rate must be > 0 and <= 1e6 Hz\n"},
      {bus + " --protocol hold:level=1,duration=1 --noise-mm -1",
       "flexid-rig: the noise standard deviation must be finite and >= 0 mm\n"},
      {bus + " --protocol hold:level=1,duration=1 --start-utime -5",
       "flexid-rig: the start utime must be >= 0\n"},
      {" --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator 'S 1' --protocol hold:level=1,"
       "duration=1",
       "flexid-rig: --actuator must be 1 to 64 of A-Z a-z 0-9 _ - (got \"S 1\")\n"},
      {bus + " --protocol hold:level=1,duration=1 --model " + scratch_.File("missing.json"),
       ""},  // the model file's own one-line message
      {" --actuator S1 --protocol hold:level=1,duration=1",
       "flexid-rig: --lcm URL (on the bus) or --out FILE.csv is required\n"},
      {" --lcm 'udpm://239.255.76.67:7667?ttl=0' --protocol hold:level=1,duration=1",
       "flexid-rig: --actuator is required with --lcm\n"},
      {" --lcm 'udpm://239.255.76.67:7667?ttl=0' --out " + scratch_.File("x.csv") +
           " --protocol hold:level=1,duration=1",
       "flexid-rig: --out and --lcm cannot be combined (--out writes the recording to a file, "
       "without the bus)\n"},
      {" --out " + scratch_.File("x.csv") + " --protocol hold:level=1,duration=1 --speed 0",
       "flexid-rig: --out and --speed cannot be combined (--out writes the recording to a file, "
       "without the bus)\n"},
      {" --out " + scratch_.File("x.csv") + " --protocol hold:level=1,duration=1 --trial-control",
       "flexid-rig: --out and --trial-control cannot be combined (--out writes the recording to a "
       "file, without the bus)\n"},
      {" --out " + scratch_.File("x.csv") +
           " --protocol hold:level=1,duration=1 --effect "
           "hysteresis:width=-1",
       "flexid-rig: effect \"hysteresis:width=-1\": width must be >= 0 mm (got -1)\n"},
      {bus + ",S2 --actuator S1 --protocol hold:level=1,duration=1",
       "flexid-rig: --actuator \"S1\" given twice\n"},
      {bus + ",S2 --protocol hold:level=1,duration=1 --effect S3/dead_zone",
       "flexid-rig: effect \"S3/dead_zone\": no actuator \"S3\" (actuators: S1, S2)\n"},
      {" --out " + scratch_.File("x.csv") +
           " --protocol hold:level=1,duration=1 --effect "
           "S1/dead_zone",
       "flexid-rig: effect \"S1/dead_zone\": no actuator \"S1\" (no --actuator given)\n"},
      {bus + " --protocol sweep:level=5 --rate-hz 4",
       "flexid-rig: protocol \"sweep:level=5\": at 1.1 Hz the shorter part of a period "
       "(0.454545 s at duty 0.5) is under 2 sample periods (0.5 s at 4 Hz); raise --rate-hz to "
       "at least 4.4 or leave 1.1 Hz out\n"},
      {bus + " --protocol random:levels=1/2,dwell_min=3,dwell_max=2,duration=9",
       "flexid-rig: protocol \"random:levels=1/2,dwell_min=3,dwell_max=2,duration=9\": "
       "dwell_max must be >= dwell_min (got 2 < 3)\n"},
  };
  for (const auto& [args, message] : cases) {
    const auto r = Run(args);
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.err;
    EXPECT_EQ(r.out, "") << args;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    if (!message.empty()) {
      EXPECT_EQ(r.err, message) << args;
    }
  }
}

// The stream flexid-rig --out writes, as the library makes it in-process.
std::vector<rig::RigSample> ExpectedStream(const std::string& protocol,
                                           const std::vector<std::string>& effect_specs,
                                           double noise_mm, uint64_t seed) {
  std::vector<std::unique_ptr<rig::Effect>> effects;
  for (const std::string& spec : effect_specs) effects.push_back(ParseEffect(spec));
  rig::RigOptions options;
  options.noise_mm = noise_mm;
  options.seed = seed;
  return RunStream(model::SeedTsModel(), protocol, std::move(effects), options);
}

TEST_F(RigBinary, OfflineWritesTheWholeRunAsARecordingCsv) {
  const std::string path = scratch_.File("rec.csv");
  const std::string protocol = "square:level=5,period=20,cycles=2,polarity=alternate";
  const auto r = Run("--out " + path + " --protocol " + protocol +
                     " --noise-mm 0.02 --seed 7 --effect polarity_asymmetry:ratio=0.8 "
                     "--effect hysteresis:width=0.05");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(r.out, "wrote 400 samples (0 .. 39.9 s) to " + path + "\n");

  const model::Recording recording = model::ReadRecordingCsv(path);
  const auto expected =
      ExpectedStream(protocol, {"polarity_asymmetry:ratio=0.8", "hysteresis:width=0.05"}, 0.02, 7);
  ASSERT_EQ(recording.t_s.size(), expected.size());
  ASSERT_EQ(recording.deflection_mm.size(), expected.size());
  for (size_t k = 0; k < expected.size(); ++k) {
    // The CSV holds the shortest form that reads back to the same double: exact.
    ASSERT_EQ(recording.t_s[k], expected[k].t_s) << k;
    ASSERT_EQ(recording.voltage_V[k], expected[k].voltage_V) << k;
    ASSERT_EQ(recording.deflection_mm[k], expected[k].deflection_mm) << k;
  }
  EXPECT_EQ(recording.voltage_V[0], 5.0);
  EXPECT_EQ(recording.voltage_V[250], -5.0);  // the second period at -level
}

TEST_F(RigBinary, OfflineNoiseIsSeededWithSeedOneByDefault) {
  const std::string protocol = " --protocol step:level=8,duration=30 --noise-mm 0.05";
  ASSERT_EQ(Run("--out " + scratch_.File("default.csv") + protocol).exit_code, 0);
  ASSERT_EQ(Run("--out " + scratch_.File("one.csv") + protocol + " --seed 1").exit_code, 0);
  ASSERT_EQ(Run("--out " + scratch_.File("two.csv") + protocol + " --seed 2").exit_code, 0);
  const model::Recording by_default = model::ReadRecordingCsv(scratch_.File("default.csv"));
  const model::Recording one = model::ReadRecordingCsv(scratch_.File("one.csv"));
  const model::Recording two = model::ReadRecordingCsv(scratch_.File("two.csv"));
  ASSERT_EQ(by_default.deflection_mm.size(), 300u);
  EXPECT_EQ(by_default.deflection_mm, one.deflection_mm);
  EXPECT_NE(one.deflection_mm, two.deflection_mm);
  // Without noise and effects the recording is the model's response, exactly.
  ASSERT_EQ(
      Run("--out " + scratch_.File("clean.csv") + " --protocol step:level=8,duration=30").exit_code,
      0);
  const model::Recording clean = model::ReadRecordingCsv(scratch_.File("clean.csv"));
  const auto expected = ExpectedStream("step:level=8,duration=30", {}, 0.0, 1);
  ASSERT_EQ(clean.deflection_mm.size(), expected.size());
  for (size_t k = 0; k < expected.size(); ++k)
    ASSERT_EQ(clean.deflection_mm[k], expected[k].deflection_mm) << k;
}

// Reads the CSV of several actuators: header and rows as text fields.
std::vector<std::vector<std::string>> ReadCsvRows(const std::string& path) {
  std::ifstream in(path);
  std::vector<std::vector<std::string>> rows;
  std::string line;
  while (std::getline(in, line)) {
    std::vector<std::string> fields;
    std::stringstream fields_in(line);
    std::string field;
    while (std::getline(fields_in, field, ',')) fields.push_back(field);
    rows.push_back(fields);
  }
  return rows;
}

// Offline, three actuators: one row per actuator and sample in time order; each
// actuator's rows are the stream of a single rig with seed + i and its own effects.
TEST_F(RigBinary, OfflineSeveralActuatorsGetAnActuatorColumn) {
  const std::string path = scratch_.File("three.csv");
  const std::string protocol = "sweep:level=5,frequencies=0.1/0.5,cycles=2";
  const auto r = Run("--out " + path + " --actuator S1,S2 --actuator S3 --protocol " + protocol +
                     " --noise-mm 0.02 --seed 7 --effect hysteresis:width=0.05 "
                     "--effect S2/back_relaxation:fraction=0.3,tau=60");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.err, "");
  EXPECT_EQ(r.out,
            "wrote 720 rows (240 samples for each of 3 actuators, 0 .. 23.9 s) to " + path + "\n");
  const auto rows = ReadCsvRows(path);
  ASSERT_EQ(rows.size(), 721u);
  EXPECT_EQ(rows[0], (std::vector<std::string>{"actuator", "t_s", "voltage_V", "deflection_mm"}));
  const std::vector<std::string> ids = {"S1", "S2", "S3"};
  const std::vector<std::vector<rig::RigSample>> expected = {
      ExpectedStream(protocol, {"hysteresis:width=0.05"}, 0.02, 7),
      ExpectedStream(protocol, {"hysteresis:width=0.05", "back_relaxation:fraction=0.3,tau=60"},
                     0.02, 8),
      ExpectedStream(protocol, {"hysteresis:width=0.05"}, 0.02, 9)};
  for (size_t k = 0; k < 240; ++k)
    for (size_t i = 0; i < 3; ++i) {
      const std::vector<std::string>& row = rows[1 + 3 * k + i];
      ASSERT_EQ(row.size(), 4u);
      ASSERT_EQ(row[0], ids[i]) << k;
      ASSERT_EQ(std::stod(row[1]), expected[i][k].t_s) << k;
      ASSERT_EQ(std::stod(row[2]), expected[i][k].voltage_V) << k;
      ASSERT_EQ(std::stod(row[3]), expected[i][k].deflection_mm) << i << " " << k;
    }
  EXPECT_NE(expected[0][100].deflection_mm, expected[2][100].deflection_mm);  // own noise
  // Not a recording CSV: time repeats, and the reader says so.
  EXPECT_THROW(model::ReadRecordingCsv(path), model::InputError);
}

// One --actuator offline: the plain recording CSV, the same as without --actuator, and an
// effect for that actuator acts.
TEST_F(RigBinary, OfflineOneActuatorIsAPlainRecording) {
  const std::string protocol =
      " --protocol random:levels=2/4/8,dwell_min=1,dwell_max=3,duration=30";
  ASSERT_EQ(Run("--out " + scratch_.File("plain.csv") + protocol + " --effect dead_zone").exit_code,
            0);
  const auto r = Run("--out " + scratch_.File("one.csv") + " --actuator S7" + protocol +
                     " --effect S7/dead_zone");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "wrote 300 samples (0 .. 29.9 s) to " + scratch_.File("one.csv") + "\n");
  const model::Recording plain = model::ReadRecordingCsv(scratch_.File("plain.csv"));
  const model::Recording one = model::ReadRecordingCsv(scratch_.File("one.csv"));
  EXPECT_EQ(one.voltage_V, plain.voltage_V);
  EXPECT_EQ(one.deflection_mm, plain.deflection_mm);
  const auto expected = ExpectedStream("random:levels=2/4/8,dwell_min=1,dwell_max=3,duration=30",
                                       {"dead_zone"}, 0.0, 1);
  ASSERT_EQ(one.deflection_mm.size(), expected.size());
  for (size_t k = 0; k < expected.size(); ++k)
    ASSERT_EQ(one.deflection_mm[k], expected[k].deflection_mm) << k;
}

struct ChannelCounter {
  void OnVoltage(const lcm::ReceiveBuffer*, const std::string& channel,
                 const flexid::voltage_sample_t* message) {
    ++voltages[channel];
    ids_ok = ids_ok && channel == "FLEXID/" + message->actuator_id + "/VOLTAGE";
    Touch();
  }
  void OnDeflection(const lcm::ReceiveBuffer*, const std::string& channel,
                    const flexid::deflection_sample_t* message) {
    deflections[channel].push_back(message->utime);
    ids_ok = ids_ok && channel == "FLEXID/" + message->actuator_id + "/DEFLECTION";
    Touch();
  }
  void OnTrial(const lcm::ReceiveBuffer*, const std::string&,
               const flexid::trial_control2_t* message) {
    trials.push_back(message->actuator_id +
                     (message->action == flexid::trial_control2_t::kStart ? ":start" : ":stop"));
    Touch();
  }
  void Touch() { last_message = std::chrono::steady_clock::now(); }

  std::map<std::string, int> voltages;
  std::map<std::string, std::vector<int64_t>> deflections;
  std::vector<std::string> trials;
  bool ids_ok = true;
  std::chrono::steady_clock::time_point last_message = std::chrono::steady_clock::now();
};

TEST_F(RigBinary, SeveralActuatorsPublishOnTheirOwnChannels) {
  const std::string url = RandomUdpmUrl();
  lcm::LCM lcm(url);
  if (!lcm.good()) GTEST_SKIP() << "cannot open LCM on " << url << " (no multicast route?)";
  ChannelCounter counter;
  const std::string key_flag = KeyFlag();
  for (lcm::Subscription* subscription :
       {testing::SubscribeMember<&ChannelCounter::OnVoltage>(lcm, "FLEXID/.*/VOLTAGE", &counter),
        testing::SubscribeMember<&ChannelCounter::OnDeflection>(lcm, "FLEXID/.*/DEFLECTION",
                                                                &counter),
        testing::SubscribeMember<&ChannelCounter::OnTrial>(lcm, "FLEXID/TRIAL", &counter)})
    subscription->setQueueCapacity(100000);
  lcm.getFileno();

  testing::ProcessResult result;
  std::atomic<bool> done{false};
  std::thread rig([&] {
    result = Run("--lcm '" + url +
                 "' --actuator M1,M2 --protocol sweep:level=3,frequencies=0.5,cycles=2 "
                 "--speed 0 --start-utime 2000000 --trial-control --noise-mm 0.01 "
                 "--effect M2/dead_zone" +
                 key_flag);
    done = true;
  });
  while (!done ||
         std::chrono::steady_clock::now() - counter.last_message < std::chrono::milliseconds(500))
    lcm.handleTimeout(50);
  rig.join();

  ASSERT_EQ(result.exit_code, 0) << result.err;
  EXPECT_EQ(result.out.rfind("published 40 samples for each of 2 actuators (80 deflection, ", 0),
            0u)
      << result.out;
  EXPECT_TRUE(counter.ids_ok);
  ASSERT_EQ(counter.deflections.size(), 2u);
  for (const std::string id : {"M1", "M2"}) {
    const std::vector<int64_t>& utimes = counter.deflections["FLEXID/" + id + "/DEFLECTION"];
    ASSERT_EQ(utimes.size(), 40u) << id;
    for (size_t k = 0; k < 40; ++k)
      EXPECT_EQ(utimes[k], 2'000'000 + static_cast<int64_t>(k) * 100'000);
    // Changes at 0, 1, 2, 3 s; nothing else needs repeating within a second.
    EXPECT_EQ(counter.voltages["FLEXID/" + id + "/VOLTAGE"], 4) << id;
  }
  EXPECT_EQ(counter.trials,
            (std::vector<std::string>{"M1:start", "M2:start", "M1:stop", "M2:stop"}));
}

TEST_F(RigBinary, OfflineWithAModelFile) {
  const std::string model_path = scratch_.File("gain.json");
  testing::WriteFile(model_path,
                     R"({"format": "flexid.model/1", "kind": "tf", "num": [2], "den": [1]})");
  const std::string path = scratch_.File("rec.csv");
  const auto r = Run("--out " + path + " --model " + model_path +
                     " --protocol staircase:levels=2/4/6/8,dwell=1 --effect "
                     "electrolysis_saturation:onset=4,slope=0.3");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const model::Recording recording = model::ReadRecordingCsv(path);
  ASSERT_EQ(recording.deflection_mm.size(), 50u);
  const std::vector<double> expected_mm = {4.0, 8.0, 9.2, 10.4, 0.0};
  for (size_t k = 0; k < 50; ++k)
    EXPECT_NEAR(recording.deflection_mm[k], expected_mm[k / 10], 1e-12) << k;
}

TEST_F(RigBinary, OfflineCannotWriteIsAnOperationFailure) {
  const auto r =
      Run("--out " + scratch_.File("no/such/dir/rec.csv") + " --protocol hold:level=1,duration=1");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_EQ(r.err.rfind("flexid-rig: ", 0), 0u) << r.err;
}

TEST_F(RigBinary, ABadBusUrlIsAnOperationFailure) {
  const auto r = Run("--lcm 'nosuchprovider://x' --actuator S1 --protocol hold:level=1,duration=1");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_EQ(r.out, "");
  // LCM prints its own diagnostic first ("Error: LCM provider ... not found").
  const std::string ours = "flexid-rig: cannot open the LCM bus [url: nosuchprovider://x]\n";
  ASSERT_GE(r.err.size(), ours.size()) << r.err;
  EXPECT_EQ(r.err.substr(r.err.size() - ours.size()), ours) << r.err;
}

}  // namespace
}  // namespace flexid
