// Checks of the effect battery (effect_battery.h) itself: a = 0 is the plant bit for bit,
// each effect acts in its documented direction and only where documented, the Preisach
// model is rate-independent, the scaling reaches the target ratio, the protocols fit their
// effects, and a seed gives one case.
#include "effect_battery.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "ts_plant.h"

namespace flexid::testing {
namespace {

// Holds at the given times (s) and levels (V); `end_s` the recording's length.
TsProtocol Holds(const std::vector<std::pair<double, double>>& holds, double end_s) {
  TsProtocol protocol;
  for (const auto& [t_s, level_V] : holds) protocol.holds.push_back({TsSamplesIn(t_s), level_V});
  protocol.samples = TsSamplesIn(end_s) + 1;
  return protocol;
}

// The first sample at or after the delayed start of hold j.
size_t DelayedSample(const TsPlant& plant, const TsProtocol& protocol, size_t j) {
  const double t_s =
      static_cast<double>(protocol.holds[j].start_sample) * kTsPlantSamplePeriod_s + plant.delay_s;
  return static_cast<size_t>(std::ceil(t_s / kTsPlantSamplePeriod_s));
}

std::vector<double> Difference(const std::vector<double>& with,
                               const std::vector<double>& without) {
  std::vector<double> d(with.size());
  for (size_t k = 0; k < d.size(); ++k) d[k] = with[k] - without[k];
  return d;
}

BatteryEffectSettings Settings(BatteryEffect kind, uint64_t seed, const BatteryProtocol& protocol,
                               const std::vector<double>& plant_mm, double amplitude) {
  TsPlantRandom draw(seed);
  BatteryEffectSettings effect = DrawBatteryEffectSettings(kind, protocol, plant_mm, draw);
  effect.amplitude = amplitude;
  return effect;
}

TEST(EffectBattery, ZeroAmplitudeGivesExactlyThePlant) {
  for (uint64_t seed : {3u, 17u, 29u}) {
    TsPlant plant = DrawTsPlant(seed);
    // Both signs, up to 8 V (above every decomposition voltage), several switches.
    const TsProtocol protocol =
        Holds({{10.0, 3.0}, {150.0, 8.0}, {300.0, 0.0}, {400.0, -7.5}, {550.0, 2.0}, {650.0, 0.0}},
              800.0);
    BatteryProtocol battery{"test", "", protocol, true, 8.0};
    for (TsBlend blend : {TsBlend::kInputBlend, TsBlend::kOutputBlend}) {
      plant.blend = blend;
      const std::vector<double> expected = SimulateTsPlant(plant, protocol);
      EXPECT_EQ(SimulateBattery(plant, protocol, {}), expected);
      for (BatteryEffect kind : BatteryEffectClasses()) {
        const BatteryEffectSettings effect = Settings(kind, seed, battery, expected, 0.0);
        EXPECT_EQ(SimulateBattery(plant, protocol, effect), expected)
            << BatteryEffectName(kind) << ", seed " << seed;
      }
    }
  }
}

TEST(EffectBattery, BackRelaxationFallsBackDuringAHoldAndOvershootsRestAfterIt) {
  const TsPlant plant = DrawTsPlant(41);
  const TsProtocol protocol = Holds({{10.0, 5.0}, {2010.0, 0.0}}, 4000.0);
  BatteryProtocol battery{"test", "", protocol, false, 5.0};
  const std::vector<double> without = SimulateBattery(plant, protocol, {});
  const double a = 0.2;
  const BatteryEffectSettings effect =
      Settings(BatteryEffect::kBackRelaxation, 41, battery, without, a);
  const std::vector<double> with = SimulateBattery(plant, protocol, effect);
  const size_t release = DelayedSample(plant, protocol, 1);
  const double plant_mm = without[release - 1];
  // During the hold: rises, then falls back, in the end by the share a (the slow follower
  // has had 2000 s, at least five of its time constants). The peak is lower than the
  // plant's: the plant's own slow modes (15-110 s) rise while the followers catch up.
  const double peak_mm = *std::max_element(with.begin(), with.begin() + release);
  EXPECT_LT(with[release - 1], peak_mm - 0.1 * a * plant_mm);
  EXPECT_NEAR(with[release - 1], (1.0 - a) * plant_mm, 0.02 * a * plant_mm);
  // The plant alone does not fall back that way.
  const double plant_peak_mm = *std::max_element(without.begin(), without.begin() + release);
  EXPECT_GT(without[release - 1], plant_peak_mm - 0.01 * plant_mm);
  // After the release: past rest, then back towards it.
  const double low_mm = *std::min_element(with.begin() + release, with.end());
  EXPECT_LT(low_mm, -0.1 * a * plant_mm);
  EXPECT_GT(with.back(), 0.5 * low_mm);
  const double plant_low_mm = *std::min_element(without.begin() + release, without.end());
  EXPECT_GT(plant_low_mm, -0.01 * plant_mm);
}

TEST(EffectBattery, SensorDriftDoesNotDependOnTheInputAndStartsAtZero) {
  const TsPlant plant = DrawTsPlant(43);
  // Two different protocols of the same length.
  const TsProtocol square =
      Holds({{10.0, 6.0}, {110.0, 0.0}, {210.0, 6.0}, {310.0, 0.0}, {410.0, 6.0}}, 900.0);
  const TsProtocol step = Holds({{25.0, -3.0}, {500.0, 0.0}}, 900.0);
  BatteryProtocol battery{"test", "", square, true, 6.0};
  const std::vector<double> square_plant = SimulateBattery(plant, square, {});
  const std::vector<double> step_plant = SimulateBattery(plant, step, {});
  for (uint64_t seed = 1; seed <= 6; ++seed) {
    const BatteryEffectSettings effect =
        Settings(BatteryEffect::kSensorDrift, seed, battery, square_plant, 0.3);
    const std::vector<double> d_square =
        Difference(SimulateBattery(plant, square, effect), square_plant);
    const std::vector<double> d_step = Difference(SimulateBattery(plant, step, effect), step_plant);
    ASSERT_EQ(d_square.size(), d_step.size());
    EXPECT_EQ(d_square[0], 0.0);
    double peak = 0.0;
    for (size_t k = 0; k < d_square.size(); ++k) {
      ASSERT_NEAR(d_square[k], d_step[k], 1e-12) << "sample " << k << ", seed " << seed;
      peak = std::max(peak, std::abs(d_square[k]));
    }
    EXPECT_GT(peak, 0.1) << DescribeBatteryEffect(effect);
    if (effect.drift_walk) {
      EXPECT_NEAR(peak, 0.3, 1e-9);
    }
  }
}

// Output of a Preisach model along a path of inputs, read at every input.
std::vector<double> Along(PreisachHysteresis preisach, const std::vector<double>& path) {
  std::vector<double> out;
  for (double x : path) {
    preisach.Update(x);
    out.push_back(preisach.Output());
  }
  return out;
}

// Triangles 0 -> 1 -> 0.2 -> 0.8 -> -0.6 -> 0.4, `per_leg` inputs per leg, every input
// shifted by 0.0037 off the round numbers of the centre grid (an input exactly on a
// threshold is decided by rounding alone).
std::vector<double> Triangle(int per_leg) {
  const std::vector<double> corners = {0.0, 1.0, 0.2, 0.8, -0.6, 0.4};
  std::vector<double> path;
  for (size_t c = 0; c + 1 < corners.size(); ++c)
    for (int i = 1; i <= per_leg; ++i)
      path.push_back(0.0037 + corners[c] + (corners[c + 1] - corners[c]) * i / per_leg);
  return path;
}

TEST(EffectBattery, PreisachLoopIsTheSameForASlowAndAFastTriangle) {
  // A width off the round numbers of the centre grid and the path, so that no threshold is
  // met exactly (where rounding alone would decide).
  const PreisachHysteresis preisach(0.25, 0.7, 0.0613);
  const int fast = 40, slow = 40 * 25;  // the slow path passes every input of the fast one
  const std::vector<double> fast_out = Along(preisach, Triangle(fast));
  const std::vector<double> slow_out = Along(preisach, Triangle(slow));
  for (size_t k = 0; k < fast_out.size(); ++k)
    ASSERT_NEAR(fast_out[k], slow_out[(k + 1) * 25 - 1], 1e-12) << "input " << k;
  // A loop: at x = 0.5 below the midline on the way up, above it on the way down.
  const std::vector<double> path = Triangle(fast);
  const size_t up = 19, down = 40 + 19;  // 0.5 rising, 0.6 falling (+ 0.0037)
  EXPECT_NEAR(path[up], 0.5037, 1e-12);
  EXPECT_LT(fast_out[up], -0.01);
  EXPECT_NEAR(path[down], 0.6037, 1e-12);
  EXPECT_GT(fast_out[down], 0.01);
  // The Preisach output proper rises with the input on the way up.
  PreisachHysteresis climb = preisach;
  double previous = -1.0;
  for (int i = 0; i <= 100; ++i) {
    climb.Update(0.01 * i);
    EXPECT_GE(climb.PreisachOutput(), previous - 1e-15);
    previous = climb.PreisachOutput();
  }
}

TEST(EffectBattery, HysteresisLagsWhileRisingAndLeavesARemanentOffsetAtRest) {
  const TsPlant plant = DrawTsPlant(47);
  const TsProtocol protocol = Holds({{10.0, 6.0}, {400.0, 0.0}}, 900.0);
  BatteryProtocol battery{"test", "", protocol, false, 6.0};
  const std::vector<double> without = SimulateBattery(plant, protocol, {});
  const BatteryEffectSettings effect =
      Settings(BatteryEffect::kHysteresis, 47, battery, without, 0.3);
  const std::vector<double> d = Difference(SimulateBattery(plant, protocol, effect), without);
  const size_t on = DelayedSample(plant, protocol, 0), off = DelayedSample(plant, protocol, 1);
  for (size_t k = 0; k < on; ++k) EXPECT_EQ(d[k], 0.0);
  EXPECT_LT(d[(on + off) / 2], -0.001);  // rising: below the plant
  EXPECT_GT(d.back(), 0.001);            // fallen back to rest: above it
}

TEST(EffectBattery, SaturationActsOnlyAboveTheDecompositionVoltage) {
  const double vd = 6.3, m = 0.2;
  for (double a : {0.05, 0.5, 3.0}) {
    double previous = 0.0;
    for (double v = 0.0; v <= 9.0; v += 0.01) {
      const double e = ElectrolysisDrive(v, a, vd, m);
      EXPECT_EQ(ElectrolysisDrive(-v, a, vd, m), -e);
      if (v <= vd) {
        EXPECT_EQ(e, v);
      } else {
        EXPECT_LT(e, v);
        EXPECT_GT(e, vd + (v - vd) / (1.0 + a) - 1e-12);  // compressed, never below the asymptote
      }
      EXPECT_GT(e, previous - 1e-12);  // still rising with the voltage
      previous = e;
    }
  }
  // Smooth: the slope falls gradually over the knee, not at one point.
  const double h = 1e-4, a = 1.0;
  auto slope = [&](double v) {
    return (ElectrolysisDrive(v + h, a, vd, m) - ElectrolysisDrive(v - h, a, vd, m)) / (2 * h);
  };
  EXPECT_GT(slope(vd + 0.05), 0.85);
  EXPECT_LT(slope(vd + 0.5), 0.8);
  EXPECT_GT(slope(vd + 0.5), 0.6);
  EXPECT_LT(slope(vd + 2.5), 0.6);
  EXPECT_NEAR(slope(vd + 20.0), 1.0 / (1.0 + a), 0.01);
  // In the simulation: nothing until the delayed switch above V_d.
  const TsPlant plant = DrawTsPlant(53);
  const TsProtocol protocol = Holds({{10.0, 3.0}, {150.0, 6.0}, {300.0, 7.5}, {450.0, 0.0}}, 700.0);
  BatteryProtocol battery{"test", "", protocol, false, 7.5};
  const std::vector<double> without = SimulateBattery(plant, protocol, {});
  BatteryEffectSettings effect =
      Settings(BatteryEffect::kElectrolysisSaturation, 53, battery, without, 1.0);
  effect.decomposition_V = 6.5;
  const std::vector<double> d = Difference(SimulateBattery(plant, protocol, effect), without);
  const size_t above = DelayedSample(plant, protocol, 2);
  for (size_t k = 0; k < above; ++k) ASSERT_EQ(d[k], 0.0) << "sample " << k;
  EXPECT_LT(d[DelayedSample(plant, protocol, 3) - 1], -0.05);
}

TEST(EffectBattery, PolarityActsOnlyOnNegativeVoltageWithAnotherGainAndALag) {
  const TsPlant plant = DrawTsPlant(59);
  const TsProtocol unipolar = Holds({{10.0, 4.0}, {300.0, 7.0}, {600.0, 0.0}}, 900.0);
  const TsProtocol bipolar =
      Holds({{10.0, 4.0}, {300.0, 0.0}, {400.0, -4.0}, {2400.0, 0.0}}, 2600.0);
  BatteryProtocol battery{"test", "", bipolar, true, 4.0};
  const std::vector<double> without = SimulateBattery(plant, bipolar, {});
  const double a = 0.4;
  const BatteryEffectSettings effect =
      Settings(BatteryEffect::kPolarityAsymmetry, 59, battery, without, a);
  EXPECT_EQ(SimulateBattery(plant, unipolar, effect), SimulateBattery(plant, unipolar, {}));
  const std::vector<double> with = SimulateBattery(plant, bipolar, effect);
  const size_t negative = DelayedSample(plant, bipolar, 2), back = DelayedSample(plant, bipolar, 3);
  for (size_t k = 0; k < negative; ++k) ASSERT_EQ(with[k], without[k]) << "sample " << k;
  // Another gain: after 2000 s at -4 V, the response is (1 - a + a g) times the plant's.
  EXPECT_NEAR(with[back - 1] / without[back - 1], 1.0 - a + a * effect.negative_gain, 1e-3);
  // Other dynamics: the lagged share still acts just after the hold ends.
  const double d_after = with[back + 10] - without[back + 10];
  EXPECT_GT(std::abs(d_after), 1e-3);
}

TEST(EffectBattery, DegradationLosesMoreGainWithEveryCycle) {
  const TsPlant plant = DrawTsPlant(61);
  std::vector<std::pair<double, double>> holds;
  for (int c = 0; c < 5; ++c) {
    holds.push_back({10.0 + 200.0 * c, 6.0});
    holds.push_back({110.0 + 200.0 * c, 0.0});
  }
  const TsProtocol protocol = Holds(holds, 1010.0);
  BatteryProtocol battery{"test", "", protocol, false, 6.0};
  const std::vector<double> without = SimulateBattery(plant, protocol, {});
  const BatteryEffectSettings effect =
      Settings(BatteryEffect::kCycleDegradation, 61, battery, without, 0.2);
  const std::vector<double> d = Difference(SimulateBattery(plant, protocol, effect), without);
  double previous = 0.0;
  for (int c = 0; c < 5; ++c) {  // the largest loss within each cycle
    const size_t from = DelayedSample(plant, protocol, static_cast<size_t>(2 * c));
    const size_t to =
        c < 4 ? DelayedSample(plant, protocol, static_cast<size_t>(2 * c + 2)) : d.size();
    const double loss = -*std::min_element(d.begin() + from, d.begin() + to);
    EXPECT_GT(loss, previous * 1.05) << "cycle " << c;
    previous = loss;
  }
}

TEST(EffectBattery, ScalingHitsTheTargetRatio) {
  for (BatteryEffect kind : BatteryEffectClasses())
    for (bool faint : {false, true}) {
      const BatteryCase c = DrawBatteryCase(71, {kind, faint});
      SCOPED_TRACE(c.description);
      EXPECT_EQ(c.effect_name, BatteryEffectName(kind));
      EXPECT_GE(c.target_ratio, faint ? 0.7 : 2.5);
      EXPECT_LE(c.target_ratio, faint ? 2.0 : 9.0);
      EXPECT_NEAR(c.ratio / c.target_ratio, 1.0, 1e-3);
      const double measured =
          MeasureBatteryEffect(c.plant_mm, c.clean_mm, c.plant.noise_std_mm).ratio;
      EXPECT_DOUBLE_EQ(measured, c.ratio);
      EXPECT_TRUE(BatteryEffectCanShow(kind, c.protocol));
    }
}

TEST(EffectBattery, ProtocolsAreDrawnFromThoseOnWhichTheEffectCanShow) {
  int bipolar = 0, draws = 0;
  for (uint64_t seed = 1; seed <= 200; ++seed) {
    TsPlantRandom draw(seed);
    const BatteryProtocol protocol = DrawBatteryProtocol(draw);
    ++draws;
    bipolar += protocol.bipolar;
    EXPECT_GE(protocol.protocol.samples, TsSamplesIn(350.0));
    EXPECT_LE(protocol.top_V, 8.0);
    EXPECT_GE(protocol.top_V, 1.0);
    const std::vector<double> shown = {0.0};
    const BatteryEffectSettings effect =
        DrawBatteryEffectSettings(BatteryEffect::kElectrolysisSaturation, protocol, shown, draw);
    if (BatteryEffectCanShow(BatteryEffect::kElectrolysisSaturation, protocol)) {
      EXPECT_GE(effect.decomposition_V, 5.5);
      EXPECT_LE(effect.decomposition_V, 7.5);
      EXPECT_LE(effect.decomposition_V, protocol.top_V - 0.5 + 1e-12) << protocol.description;
    }
  }
  EXPECT_GT(bipolar, draws / 6);
  EXPECT_LT(bipolar, draws / 2);
}

TEST(EffectBattery, ASeedGivesOneCaseQuantisedToTheSensorResolution) {
  const BatteryCase a = DrawBatteryCase(83), b = DrawBatteryCase(83);
  EXPECT_EQ(a.recording.deflection_mm, b.recording.deflection_mm);
  EXPECT_EQ(a.recording.voltage_V, b.recording.voltage_V);
  EXPECT_EQ(a.description, b.description);
  for (double y : a.recording.deflection_mm)
    ASSERT_NEAR(y / kBatteryQuantum_mm, std::round(y / kBatteryQuantum_mm), 1e-6);
  const std::vector<model::Recording> identification = RecordBatteryIdentification(a);
  ASSERT_EQ(identification.size(), 2u);
  EXPECT_EQ(identification[0].t_s.size(), TsStaircase(120.0).samples);
  EXPECT_EQ(identification[1].t_s.size(), TsSamplesIn(600.0) + 1);
  const auto [low, high] =
      std::minmax_element(identification[1].voltage_V.begin(), identification[1].voltage_V.end());
  EXPECT_LT(*low, 0.0);
  EXPECT_GT(*high, 0.0);
}

}  // namespace
}  // namespace flexid::testing
