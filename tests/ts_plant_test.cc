// Checks of the independent T-S test plant (ts_plant.h) itself: its integrator against
// an exact response, its rules, its draws, the continuity of its blend and its noise.
#include "ts_plant.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <string>
#include <vector>

#include "model/core/simulate.h"
#include "model/core/transfer_function.h"
#include "model/identify/identify_global.h"

namespace flexid::testing {
namespace {

model::TransferFunction RuleAsTransferFunction(const TsPlantRule& rule, double delay_s) {
  return {{rule.num.begin(), rule.num.end()}, {rule.den.begin(), rule.den.end()}, delay_s};
}

// One hold at level_V from lead_s on, kept for hold_s.
TsProtocol OneStep(double level_V, double lead_s, double hold_s) {
  TsProtocol protocol;
  protocol.holds.push_back({TsSamplesIn(lead_s), level_V});
  protocol.samples = TsSamplesIn(lead_s + hold_s) + 1;
  return protocol;
}

TEST(TsPlant, OneRuleMatchesTheExactResponseAndItsDcGain) {
  const TsPlant plant = DrawTsPlant(7, {.rules = 1, .width_V = 0.0});
  ASSERT_EQ(plant.rules.size(), 1u);
  const model::TransferFunction tf = RuleAsTransferFunction(plant.rules[0], plant.delay_s);
  // The RK4 integrator against the matrix-exponential simulation, over a staircase.
  const TsProtocol stairs = TsStaircase(80.0);
  const std::vector<double> y = SimulateTsPlant(plant, stairs);
  std::vector<double> t_s(y.size());
  for (size_t k = 0; k < t_s.size(); ++k) t_s[k] = static_cast<double>(k) * kTsPlantSamplePeriod_s;
  const std::vector<double> exact = model::Simulate(tf, t_s, TsVoltageColumn(stairs));
  double worst_mm = 0.0;
  for (size_t k = 0; k < y.size(); ++k) worst_mm = std::max(worst_mm, std::abs(y[k] - exact[k]));
  EXPECT_LT(worst_mm, 1e-6) << DescribeTsPlant(plant);
  // A 5 V step held 3000 s (about 40 slowest time constants) settles at 5 K.
  const std::vector<double> step = SimulateTsPlant(plant, OneStep(5.0, 10.0, 3000.0));
  EXPECT_NEAR(step.back(), 5.0 * plant.rules[0].DcGain(), 1e-6 * 5.0 * plant.rules[0].DcGain());
}

TEST(TsPlant, HardSwitchGivesEachRuleItsOwnGainAtRest) {
  const TsPlant plant = DrawTsPlant(11, {.rules = 3, .width_V = 0.0});
  ASSERT_EQ(plant.rules.size(), 3u);
  for (double level_V = 0.5; level_V <= 8.0; level_V += 0.5) {
    size_t rule = 0;
    while (rule < plant.boundaries_V.size() && level_V >= plant.boundaries_V[rule]) ++rule;
    const std::vector<double> y = SimulateTsPlant(plant, OneStep(level_V, 10.0, 3000.0));
    const double expected_mm = level_V * plant.rules[rule].DcGain();
    EXPECT_NEAR(y.back(), expected_mm, 1e-6 * expected_mm)
        << level_V << " V, rule " << rule + 1 << "\n"
        << DescribeTsPlant(plant);
  }
}

TEST(TsPlant, DrawsStayInsideTheDocumentedBands) {
  int with_two = 0, with_three = 0;
  for (uint64_t seed = 1; seed <= 60; ++seed) {
    const TsPlant plant = DrawTsPlant(seed);
    const size_t rules = plant.rules.size();
    (rules == 2 ? with_two : with_three) += 1;
    ASSERT_TRUE(rules == 2 || rules == 3) << seed;
    ASSERT_EQ(plant.boundaries_V.size(), rules - 1);
    for (const TsPlantRule& rule : plant.rules) {
      EXPECT_TRUE(model::IsStable(RuleAsTransferFunction(rule, 0.0))) << seed;
      EXPECT_GE(rule.DcGain(), 0.8) << seed;
      EXPECT_LE(rule.DcGain(), 2.0) << seed;
    }
    EXPECT_GE(5.0 * plant.SteadyGainAt(5.0), 4.0) << seed;
    EXPECT_LE(5.0 * plant.SteadyGainAt(5.0), 9.0) << seed;
    EXPECT_GE(plant.delay_s, 1.0) << seed;
    EXPECT_LE(plant.delay_s, 6.0) << seed;
    const double off_grid_s =
        plant.delay_s - kTsPlantSamplePeriod_s * std::round(plant.delay_s / kTsPlantSamplePeriod_s);
    EXPECT_GT(std::abs(off_grid_s), 0.004) << seed;
    EXPECT_GE(plant.noise_std_mm, 0.02) << seed;
    EXPECT_LE(plant.noise_std_mm, 0.03) << seed;
    for (double z_V = 0.0; z_V <= 10.0; z_V += 0.01) {
      const std::vector<double> mu = plant.Memberships(z_V);
      double sum = 0.0;
      for (double m : mu) {
        EXPECT_GE(m, -1e-12) << seed << " at " << z_V << " V";
        sum += m;
      }
      EXPECT_NEAR(sum, 1.0, 1e-12) << seed << " at " << z_V << " V";
    }
  }
  EXPECT_GT(with_two, 10);
  EXPECT_GT(with_three, 10);
}

TEST(TsPlant, OutputIsContinuousWhereTheRuleChanges) {
  for (uint64_t seed : {101u, 202u, 303u, 404u}) {
    const TsPlant plant = DrawTsPlant(seed);
    TsPlant output_blend = plant;
    output_blend.blend = TsBlend::kOutputBlend;
    for (const TsProtocol& protocol : {TsStaircase(80.0), TsRandomLevels(seed)}) {
      const std::vector<double> y = SimulateTsPlant(plant, protocol);
      const std::vector<double> y_output_blend = SimulateTsPlant(output_blend, protocol);
      double previous_V = 0.0, worst_mm = 0.0, worst_output_blend_mm = 0.0;
      int rule_changes = 0;
      for (const TsHold& hold : protocol.holds) {
        const std::vector<double> before = plant.Memberships(std::abs(previous_V));
        const std::vector<double> after = plant.Memberships(std::abs(hold.level_V));
        previous_V = hold.level_V;
        double moved = 0.0;
        for (size_t r = 0; r < before.size(); ++r) moved += std::abs(after[r] - before[r]);
        // The sample pair around the delayed switch.
        const auto k = static_cast<size_t>(
            (static_cast<double>(hold.start_sample) * kTsPlantSamplePeriod_s + plant.delay_s) /
            kTsPlantSamplePeriod_s);
        if (moved < 0.5 || k + 1 >= y.size()) continue;
        ++rule_changes;
        worst_mm = std::max(worst_mm, std::abs(y[k + 1] - y[k]));
        worst_output_blend_mm =
            std::max(worst_output_blend_mm, std::abs(y_output_blend[k + 1] - y_output_blend[k]));
      }
      EXPECT_GT(rule_changes, 0) << seed;
      EXPECT_LE(worst_mm, 5.0 * plant.noise_std_mm) << seed << "\n" << DescribeTsPlant(plant);
      // The output blend of the rules' outputs would jump there (why it is not the default).
      EXPECT_GT(worst_output_blend_mm, 5.0 * plant.noise_std_mm) << seed;
    }
  }
}

TEST(TsPlant, NoiseHasTheDrawnSigmaAndRepeatsWithTheSeed) {
  const TsPlant plant = DrawTsPlant(5);
  const TsRecording a = RecordTsPlant(plant, TsStaircase(80.0), 17);
  const TsRecording b = RecordTsPlant(plant, TsStaircase(80.0), 17);
  EXPECT_EQ(a.recording.deflection_mm, b.recording.deflection_mm);
  double sum = 0.0, squares = 0.0;
  for (size_t k = 0; k < a.clean_mm.size(); ++k) {
    const double e = a.recording.deflection_mm[k] - a.clean_mm[k];
    sum += e;
    squares += e * e;
  }
  const auto n = static_cast<double>(a.clean_mm.size());
  EXPECT_NEAR(sum / n, 0.0, 4.0 * plant.noise_std_mm / std::sqrt(n));
  EXPECT_NEAR(std::sqrt(squares / n), plant.noise_std_mm, 0.03 * plant.noise_std_mm);
}

}  // namespace
}  // namespace flexid::testing
