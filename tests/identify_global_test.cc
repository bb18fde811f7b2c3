// Global T-S identification (model/identify/identify_global.h): what it guarantees whatever the
// data, and its one-line errors. Its accuracy on plants flexid did not write is measured
// by ../shared/data/independent/score (README, "Identification").
#include "model/identify/identify_global.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "gaussian.h"
#include "model/core/errors.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

// A 2-4 V staircase through a plant whose gain grows with the voltage (1 mm/V at 2 V,
// 1.5 mm/V at 4 V), 0.2 s samples, Gaussian noise of 0.01 mm; 30 s blocks at the voltages
// of `cycle` in turn (0, 2 and 4 V by default).
Recording Staircase(const std::string& name, unsigned seed,
                    const std::vector<double>& cycle = {0.0, 2.0, 4.0}) {
  const TransferFunction slow{{0.02, 0.01}, {1.0, 0.3, 0.01}, 0.6};  // DC gain 1 mm/V
  TransferFunction fast = slow;
  for (double& c : fast.num) c *= 1.5;
  TsModel plant = MakeTsModelOnLevels({{2.0, slow, {}}, {4.0, fast, {}}},
                                      SchedulingVariable::kAbsVoltageDelayed);
  plant.scheduling_delay_s = 0.6;
  Recording rec;
  rec.source = name;
  for (int k = 0; k < 1500; ++k) {
    rec.t_s.push_back(0.2 * k);
    rec.voltage_V.push_back(cycle[static_cast<size_t>(k / 150) % cycle.size()]);
  }
  rec.deflection_mm = SimulateUniform(plant, 0.2, rec.voltage_V);
  testing::Gaussian noise(seed);
  for (double& y : rec.deflection_mm) y += 0.01 * noise();
  return rec;
}

TEST(IdentifyGlobal, ReturnsAStableModelWithFiniteIntervalsAndItsReason) {
  const GlobalEstimate e = IdentifyGlobalTs({Staircase("a.csv", 1), Staircase("b.csv", 2)});
  EXPECT_EQ(e.levels_V, (std::vector<double>{2.0, 4.0}));
  ASSERT_FALSE(e.model.rules.empty());
  // Every frozen blend is stable, at, between and beyond the levels.
  for (double z = 0.0; z <= 8.0; z += 0.25)
    EXPECT_TRUE(IsStable(FrozenModelAt(e.model, z))) << "z = " << z;
  EXPECT_TRUE(std::isfinite(e.delay_s.half_width_95));
  // The dead time's interval (the profile of the fit over T) covers the plant's 0.6 s.
  EXPECT_LE(std::abs(e.delay_s.value - 0.6), e.delay_s.half_width_95)
      << e.delay_s.value << " +- " << e.delay_s.half_width_95;
  for (const RuleReport& rule : e.rules) EXPECT_TRUE(std::isfinite(rule.dc_gain.half_width_95));
  EXPECT_TRUE(std::isfinite(e.held_out_rmse_mm));
  EXPECT_NE(e.reason.find("held-out"), std::string::npos) << e.reason;
  // The fit reaches the noise (0.01 mm) within a factor of 2 on this plant.
  EXPECT_LT(e.fit.rmse_mm, 0.02);
  // The gain grows with the voltage, as in the plant.
  EXPECT_NEAR(DcGain(FrozenModelAt(e.model, 2.0)), 1.0, 0.05);
  EXPECT_NEAR(DcGain(FrozenModelAt(e.model, 4.0)), 1.5, 0.05);
}

// A bipolar square wave through a plant that bends less under negative voltage (60 % of
// its positive gain): no linear model explains it, and a free real pole pair would put one
// root near s = 0, an integrator that turns the asymmetry into a drift with a huge DC gain.
// Every pole stays at or above the slowest the recording can tell from drift.
TEST(IdentifyGlobal, NoRootBelowTheSlowestTheRecordingResolves) {
  const TransferFunction plant{{0.02, 0.01}, {1.0, 0.3, 0.01}, 0.6};  // DC gain 1 mm/V
  Recording rec;
  rec.source = "bipolar.csv";
  std::vector<double> share;  // voltage as the plant bends to it
  for (int k = 0; k < 3000; ++k) {
    rec.t_s.push_back(0.2 * k);
    const int phase = (k / 150) % 4;
    rec.voltage_V.push_back(phase == 1 ? 4.0 : phase == 3 ? -4.0 : 0.0);
    share.push_back(rec.voltage_V.back() < 0.0 ? 0.6 * rec.voltage_V.back() : rec.voltage_V.back());
  }
  rec.deflection_mm = SimulateUniform(SingleRule(plant), 0.2, share);
  testing::Gaussian noise(3);
  for (double& y : rec.deflection_mm) y += 0.01 * noise();
  const GlobalEstimate e = IdentifyGlobalTs({rec});
  const double w_min = 0.5 / rec.t_s.back();
  for (const auto& rule : e.model.rules)
    for (const auto& pole : Poles(rule.tf)) EXPECT_GE(-pole.real(), w_min * 0.999) << pole;
}

TEST(IdentifyGlobal, SaysWhatTheDataDoNotShow) {
  Recording one = Staircase("one-level.csv", 3);
  for (double& u : one.voltage_V) u = u > 0.0 ? 2.0 : 0.0;
  const GlobalEstimate e = IdentifyGlobalTs({one});
  ASSERT_EQ(e.model.rules.size(), 1u);
  bool said = false;
  for (const std::string& w : e.warnings)
    said = said || w.rfind("one-level.csv: one voltage level", 0) == 0;  // names the recording
  EXPECT_TRUE(said);
}

// A staircase that steps 1 V at a time: jumps across several levels, and so across the
// rules, are not in the data, and the estimate says so, naming the recording; a recording
// that jumps from 4 V to rest has no such warning.
TEST(IdentifyGlobal, SaysWhenTheDataStepOnlyBetweenNeighbouringLevels) {
  auto warned = [](const GlobalEstimate& e, const std::string& source) {
    for (const std::string& w : e.warnings)
      if (w.rfind(source + ": |u| changes by at most", 0) == 0) return true;
    return false;
  };
  const GlobalEstimate steps =
      IdentifyGlobalTs({Staircase("steps.csv", 5, {1.0, 2.0, 3.0, 4.0, 3.0, 2.0, 1.0, 0.0})});
  EXPECT_TRUE(warned(steps, "steps.csv")) << ::testing::PrintToString(steps.warnings);
  const GlobalEstimate jumps = IdentifyGlobalTs({Staircase("jumps.csv", 6)});
  EXPECT_FALSE(warned(jumps, "jumps.csv")) << ::testing::PrintToString(jumps.warnings);
}

// Two regimes with their own dynamics run in parallel, each driven by its share of the
// voltage (ts_fuzzy.h kParallel): a slow one at 2 V (time constants 4 and 26 s) and a fast
// one at 4 V (about 1 s), 0.2 s samples, 0.01 mm of noise. Jumps between 0, 2 and 4 V in
// an order that differs per recording.
Recording ParallelPlant(const std::string& name, unsigned seed, const std::vector<double>& order) {
  const TransferFunction slow{{0.02, 0.01}, {1.0, 0.3, 0.01}, 0.6};  // 1 mm/V
  const TransferFunction fast{{1.5, 1.5}, {1.0, 2.5, 1.0}, 0.6};     // 1.5 mm/V
  TsModel plant = MakeTsModelOnLevels({{2.0, slow, {}}, {4.0, fast, {}}});
  plant.realisation = TsRealisation::kParallel;
  Recording rec;
  rec.source = name;
  for (int k = 0; k < 250 * static_cast<int>(order.size()); ++k) {
    rec.t_s.push_back(0.2 * k);
    rec.voltage_V.push_back(order[static_cast<size_t>(k / 250)]);
  }
  rec.deflection_mm = SimulateUniform(plant, 0.2, rec.voltage_V);
  testing::Gaussian noise(seed);
  for (double& y : rec.deflection_mm) y += 0.01 * noise();
  return rec;
}

TEST(IdentifyGlobal, ChoosesParallelRulesWhereEachRegimeKeepsItsOwnDynamics) {
  const GlobalEstimate e =
      IdentifyGlobalTs({ParallelPlant("a.csv", 11, {0, 2, 4, 0, 4, 2, 0, 2, 0}),
                        ParallelPlant("b.csv", 12, {0, 4, 2, 4, 0, 2, 4, 0, 4})});
  EXPECT_EQ(e.structure.realisation, TsRealisation::kParallel) << e.reason;
  EXPECT_EQ(e.model.realisation, TsRealisation::kParallel);
  EXPECT_NE(e.reason.find("realisation (held-out RMSE mm): frozen"), std::string::npos) << e.reason;
  // A fresh order of jumps, predicted within a few noise deviations.
  const Recording fresh = ParallelPlant("c.csv", 13, {0, 4, 0, 2, 4, 2, 0});
  const std::vector<double> predicted = Simulate(e.model, fresh.t_s, fresh.voltage_V);
  double squares = 0.0;
  for (size_t k = 0; k < predicted.size(); ++k)
    squares += (predicted[k] - fresh.deflection_mm[k]) * (predicted[k] - fresh.deflection_mm[k]);
  EXPECT_LT(std::sqrt(squares / static_cast<double>(predicted.size())), 0.02) << e.reason;

  GlobalIdentifyOptions both;
  both.premise = SchedulingVariable::kAbsVoltageDelayed;
  both.realisation = TsRealisation::kParallel;
  EXPECT_THROW(IdentifyGlobalTs({fresh}, both), std::invalid_argument);
}

// Dense data (0.02 s samples, 20,000 of them): the structure is chosen on every 5th
// sample, whose grid is blind above 31 rad/s. 0-2-4-2 V blocks of 10 s through a slow
// plant, noise 0.01 mm, and one of:
// - a lightly damped 60 rad/s mode beside it (0.05 mm/V): a misfit above the coarse band,
//   so the structure is chosen again on every sample, and that fit reaches the noise;
// - a sensor offset of +-0.05 mm switching every 34 s: a misfit of five times the noise,
//   but below the coarse band, where the coarse selection saw it: no second choice.
Recording Dense(const std::string& name, bool ringing) {
  const TransferFunction slow{{0.02, 0.01}, {1.0, 0.3, 0.01}, 0.6};  // 1 mm/V
  const double w_rad_s = 60.0;
  const TransferFunction mode{
      {0.05 * w_rad_s * w_rad_s}, {1.0, 0.01 * w_rad_s, w_rad_s * w_rad_s}, 0.6};
  Recording rec;
  rec.source = name;
  const std::vector<double> cycle = {0.0, 2.0, 4.0, 2.0};
  for (int k = 0; k < 20'000; ++k) {
    rec.t_s.push_back(0.02 * k);
    rec.voltage_V.push_back(cycle[static_cast<size_t>(k / 500) % cycle.size()]);
  }
  rec.deflection_mm = SimulateUniform(slow, 0.02, rec.voltage_V);
  const std::vector<double> rings = SimulateUniform(mode, 0.02, rec.voltage_V);
  testing::Gaussian noise(21);
  for (size_t k = 0; k < rec.deflection_mm.size(); ++k)
    rec.deflection_mm[k] += (ringing ? rings[k] : ((k / 1700) % 2 ? 0.05 : -0.05)) + 0.01 * noise();
  return rec;
}

TEST(IdentifyGlobal, ChoosesAgainOnEverySampleOnlyWhereTheCoarseGridIsBlind) {
  auto chosen_again = [](const GlobalEstimate& e) {
    for (const std::string& note : e.notes)
      if (note.rfind("structure chosen on every sample", 0) == 0) return true;
    return false;
  };
  const GlobalEstimate ringing = IdentifyGlobalTs({Dense("ringing.csv", true)});
  EXPECT_TRUE(chosen_again(ringing)) << ::testing::PrintToString(ringing.notes);
  EXPECT_LT(ringing.fit.rmse_mm, 0.015) << ringing.reason;

  const GlobalEstimate offset = IdentifyGlobalTs({Dense("offset.csv", false)});
  EXPECT_FALSE(chosen_again(offset)) << ::testing::PrintToString(offset.notes);
  EXPECT_GT(offset.fit.rmse_mm, 0.03);  // the offset is not in the model
}

TEST(IdentifyGlobal, BadRecordingsGetOneLineNamingThem) {
  Recording flat = Staircase("flat.csv", 4);
  std::fill(flat.deflection_mm.begin(), flat.deflection_mm.end(), 1.0);
  try {
    IdentifyGlobalTs({flat});
    FAIL() << "a constant deflection was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("flat.csv: the deflection is constant", 0), 0u)
        << e.what();
  }
  Recording nan = Staircase("nan.csv", 5);
  nan.deflection_mm[700] = std::numeric_limits<double>::quiet_NaN();
  try {
    IdentifyGlobalTs({nan});
    FAIL() << "NaN was accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(std::string(e.what()), "nan.csv: non-finite value at sample 700");
  }
  Recording rest = Staircase("rest.csv", 6);
  std::fill(rest.voltage_V.begin(), rest.voltage_V.end(), 0.0);
  EXPECT_THROW(IdentifyGlobalTs({rest}), InputError);
  GlobalIdentifyOptions bad;
  bad.num_zeros = 3;
  bad.num_poles = 2;
  EXPECT_THROW(IdentifyGlobalTs({Staircase("a.csv", 7)}, bad), std::invalid_argument);
  GlobalIdentifyOptions too_many;
  too_many.rules_at_most = too_many.max_rules + 1;
  EXPECT_THROW(IdentifyGlobalTs({Staircase("a.csv", 7)}, too_many), std::invalid_argument);
}

// rules_at_most (the diagnosis's baseline): a recording visiting four levels would get a
// knot at each; limited to two, the result has one rule or two with smooth hand-overs.
TEST(IdentifyGlobal, RulesAtMostLimitsTheRules) {
  const Recording four = Staircase("four.csv", 8, {1.0, 2.0, 3.0, 4.0, 0.0, 3.0, 1.0, 4.0, 2.0});
  GlobalIdentifyOptions options;
  options.rules_at_most = 2;
  const GlobalEstimate limited = IdentifyGlobalTs({four}, options);
  EXPECT_LE(limited.model.rules.size(), 2u) << limited.structure.Describe();
  EXPECT_LE(limited.structure.knots_V.size(), 2u) << limited.reason;
}

// Raising an estimate's orders keeps every other choice, fits about as well in sample
// (the raised structure holds the estimate, though its start is not exact) and costs a
// few fits, not a selection.
TEST(IdentifyGlobal, RaisedOrderKeepsTheStructureAndFitsNoWorse) {
  const Recording rec = Staircase("raise.csv", 12);
  const GlobalEstimate base = IdentifyGlobalTs({rec});
  ASSERT_FALSE(base.theta.empty());
  GlobalIdentifyOptions options;
  options.raise_order_of = &base;
  const GlobalEstimate raised = IdentifyGlobalTs({rec}, options);
  EXPECT_EQ(raised.structure.num_poles, base.structure.num_poles + 1);
  EXPECT_EQ(raised.structure.num_zeros, base.structure.num_zeros + 1);
  EXPECT_EQ(raised.structure.knots_V, base.structure.knots_V);
  EXPECT_EQ(raised.structure.dynamics_knots_V, base.structure.dynamics_knots_V);
  EXPECT_EQ(raised.structure.premise, base.structure.premise);
  EXPECT_EQ(raised.structure.realisation, base.structure.realisation);
  EXPECT_DOUBLE_EQ(raised.delay_s.value, base.delay_s.value);
  EXPECT_LE(raised.fit.rmse_mm, base.fit.rmse_mm * 1.02);
  EXPECT_LE(raised.fits, 4);
  EXPECT_LT(raised.fits, base.fits);
  EXPECT_NE(raised.reason.find("raised by one pole and one zero"), std::string::npos)
      << raised.reason;

  // An estimate without parameters, or already at six poles, cannot be raised.
  GlobalEstimate empty;
  options.raise_order_of = &empty;
  std::string why;
  EXPECT_FALSE(options.IsValid(&why));
  EXPECT_NE(why.find("raise_order_of"), std::string::npos) << why;
  EXPECT_THROW(IdentifyGlobalTs({rec}, options), std::invalid_argument);
}

// The physics chain's prior: with max_fall_back, no chosen rule falls back further, where
// a free fit of a relaxing plant (a slow zero under its slow pole) does.
TEST(IdentifyGlobal, MaxFallBackKeepsTheStepResponseFromFallingBack) {
  // Poles at 0.2 and 0.02 rad/s, a zero at 0.012 rad/s: the step overshoots by about 60 %
  // of its final value and falls back over a minute or so.
  const TransferFunction plant{{1.0 / 0.012 * 0.004, 0.004}, {1.0, 0.22, 0.004}, 1.0};
  ASSERT_GT(StepFallBack(plant).share, 0.2);
  Recording rec;
  rec.source = "relaxing.csv";
  for (int k = 0; k < 2400; ++k) {
    rec.t_s.push_back(0.5 * k);
    rec.voltage_V.push_back((k / 600) % 2 == 1 ? 3.0 : 0.0);
  }
  rec.deflection_mm = Simulate(plant, rec.t_s, rec.voltage_V);
  testing::Gaussian noise(21);
  for (double& y : rec.deflection_mm) y += 0.01 * noise();
  const GlobalEstimate free = IdentifyGlobalTs({rec});
  EXPECT_GT(StepFallBack(free.model.rules.front().tf).share, 0.2) << free.structure.Describe();
  GlobalIdentifyOptions options;
  options.max_fall_back = 0.01;
  const GlobalEstimate held = IdentifyGlobalTs({rec}, options);
  for (const LocalModel& rule : held.model.rules)
    EXPECT_LE(StepFallBack(rule.tf).share, 0.01) << held.structure.Describe();
  EXPECT_GT(held.fit.rmse_mm, 2.0 * free.fit.rmse_mm);  // what it cannot express stays out
  options.max_fall_back = -1.0;
  EXPECT_FALSE(options.IsValid(nullptr));
}

// Smooth rules say where they hand over unseen: the plant's gain changes between 2 and
// 4 V, and levels 1, 2, 4 and 5 V leave that gap unvisited.
TEST(IdentifyGlobal, SmoothRulesSayWhenTheirHandOverIsNotInTheData) {
  GlobalIdentifyOptions options;
  options.rules_at_most = 2;
  const GlobalEstimate e = IdentifyGlobalTs(
      {Staircase("gap.csv", 9, {1.0, 2.0, 4.0, 5.0, 0.0, 4.0, 1.0, 5.0, 2.0})}, options);
  ASSERT_EQ(e.structure.membership, MembershipShape::kGaussian) << e.structure.Describe();
  bool said = false;
  for (const std::string& w : e.warnings)
    said |= w.rfind("between 2 and 4 V the DC gain changes", 0) == 0 &&
            w.find("where the rules hand over is not in the data") != std::string::npos;
  EXPECT_TRUE(said) << ::testing::PrintToString(e.warnings);
}

// The same plant through a dense staircase: its gain grows from 2 to 4 V over four visited
// gaps, which trace the hand-over, so no gap is said to hide it.
TEST(IdentifyGlobal, SmoothRulesThroughDenseLevelsDoNotWarnOfUnseenHandOvers) {
  GlobalIdentifyOptions options;
  options.rules_at_most = 2;
  const GlobalEstimate e = IdentifyGlobalTs(
      {Staircase("dense.csv", 10, {0.0, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0, 4.5, 5.0}),
       Staircase("dense-down.csv", 11, {0.0, 5.0, 4.5, 4.0, 3.5, 3.0, 2.5, 2.0, 1.5, 1.0})},
      options);
  ASSERT_EQ(e.structure.membership, MembershipShape::kGaussian) << e.structure.Describe();
  for (const std::string& w : e.warnings)
    EXPECT_EQ(w.find("where the rules hand over is not in the data"), std::string::npos) << w;
}

}  // namespace
}  // namespace flexid::model
