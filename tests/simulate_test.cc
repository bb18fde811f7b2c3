#include "model/core/simulate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <span>
#include <vector>

#include "model/core/presets.h"
#include "test_util.h"

namespace flexid::model {
namespace {

using testing::ExpectVectorsNear;
using testing::IntegrateRk4;
using testing::MaxAbsDifference;

std::vector<double> RandomStaircase(size_t count, size_t hold, unsigned seed) {
  return testing::RandomStaircase(count, hold, seed, -8.0, 8.0);
}

// Zero-order-hold input function over a grid, for the RK4 reference.
auto HeldInput(const std::vector<double>& t_s, const std::vector<double>& u) {
  return [&t_s, &u](double t) {
    auto it = std::upper_bound(t_s.begin(), t_s.end(), t);
    return it == t_s.begin() ? 0.0 : u[static_cast<size_t>(it - t_s.begin()) - 1];
  };
}

TEST(Simulate, ExactZohMatchesFineStepIntegrationOnAUniformGrid) {
  // The 8 V seed model has a lightly damped 19 rad/s mode, the hardest case for a
  // discretisation. RK4 at 1 ms has a local error ~ (19e-3)^5 per step: far below 1e-7.
  TransferFunction tf = SeedModel8V();
  tf.delay_s = 0.0;
  const double dt_s = 0.1;
  const std::vector<double> u = RandomStaircase(600, 7, 1);
  std::vector<double> t_s(u.size());
  for (size_t k = 0; k < t_s.size(); ++k) t_s[k] = dt_s * static_cast<double>(k);
  const auto exact = Simulate(tf, t_s, u);
  const auto reference = IntegrateRk4(tf, t_s, HeldInput(t_s, u), 1e-3);
  EXPECT_LT(MaxAbsDifference(exact, reference), 1e-7);
}

TEST(Simulate, NonUniformGridMatchesFineStepIntegration) {
  TransferFunction tf = SeedModel2V();
  tf.delay_s = 0.0;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> step(0.01, 0.5);
  std::vector<double> t_s = {0.0};
  while (t_s.size() < 800) t_s.push_back(t_s.back() + step(rng));
  const std::vector<double> u = RandomStaircase(t_s.size(), 5, 2);
  double dt = 0.0;
  ASSERT_FALSE(IsUniformGrid(t_s, &dt));
  const auto exact = Simulate(tf, t_s, u);
  const auto reference = IntegrateRk4(tf, t_s, HeldInput(t_s, u), 1e-3);
  EXPECT_LT(MaxAbsDifference(exact, reference), 1e-7);
}

TEST(Simulate, FractionalDeadTimeOnFirstOrderIsAnalytic) {
  // K / (tau s + 1) e^{-T s}, unit step at t = 0: y = K (1 - exp(-(t - T)/tau)) for t >= T.
  const double gain = 3.0, tau_s = 2.0, delay_s = 0.237, dt_s = 0.1;
  const TransferFunction tf{{gain}, {tau_s, 1.0}, delay_s};
  const auto y = SimulateUniform(tf, dt_s, std::vector<double>(100, 1.0));
  for (size_t k = 0; k < y.size(); ++k) {
    const double t = dt_s * static_cast<double>(k);
    const double expected = t < delay_s ? 0.0 : gain * (1.0 - std::exp(-(t - delay_s) / tau_s));
    EXPECT_NEAR(y[k], expected, 1e-12) << "t = " << t;
  }
}

TEST(Simulate, FractionalDeadTimeShiftsTheResponseByExactlyThatTime) {
  // A delay of 23.7 samples: the delayed response on the grid equals the undelayed step
  // response at t - T, evaluated independently on the shifted grid by the any-grid engine.
  TransferFunction delayed = SeedModel8V();
  const double dt_s = 0.1;
  delayed.delay_s = 2.37;
  TransferFunction undelayed = delayed;
  undelayed.delay_s = 0.0;
  const size_t count = 2000;
  const auto y = SimulateUniform(delayed, dt_s, std::vector<double>(count, 1.0));
  std::vector<double> shifted_t_s;
  for (size_t k = 0; k < count; ++k) {
    const double t = dt_s * static_cast<double>(k) - delayed.delay_s;
    if (t >= 0.0) shifted_t_s.push_back(t);
  }
  const auto reference = StepResponse(undelayed, shifted_t_s);
  const size_t first = count - shifted_t_s.size();
  for (size_t k = 0; k < first; ++k) EXPECT_EQ(y[k], 0.0) << "before the dead time, k = " << k;
  for (size_t k = first; k < count; ++k)
    ASSERT_NEAR(y[k], reference[k - first], 1e-9 * DcGain(undelayed)) << "k = " << k;
}

TEST(Simulate, IntegralDeadTimeIsAPureShiftOfSamples) {
  TransferFunction tf = SeedModel2V();
  tf.delay_s = 0.0;
  const std::vector<double> u = RandomStaircase(500, 9, 3);
  const auto y0 = SimulateUniform(tf, 0.1, u);
  tf.delay_s = 0.3;  // exactly three samples
  const auto y3 = SimulateUniform(tf, 0.1, u);
  for (size_t k = 3; k < u.size(); ++k) ASSERT_NEAR(y3[k], y0[k - 3], 1e-12);
}

TEST(Simulate, StreamingEngineAgreesWithTheUniformFastPath) {
  const TransferFunction tf = SeedModel8V();  // 3.67 s = 36.7 samples of dead time
  const std::vector<double> u = RandomStaircase(3000, 11, 4);
  const auto fast = SimulateUniform(tf, 0.1, u);
  StreamingSimulator streaming(SingleRule(tf));
  std::vector<double> slow;
  for (size_t k = 0; k < u.size(); ++k)
    slow.push_back(streaming.Step(0.1 * static_cast<double>(k), u[k]));
  EXPECT_LT(MaxAbsDifference(fast, slow), 1e-9);
}

// Two rules that are pure gains with a 1 s dead time: 1 mm/V up to 1 V, 2 mm/V from 5 V.
TsModel TwoGains(SchedulingVariable scheduling) {
  TsModel model = MakeTsModelOnLevels(
      {{1.0, {{1.0}, {1.0}, 1.0}, {}}, {5.0, {{2.0}, {1.0}, 1.0}, {}}}, scheduling);
  model.scheduling_delay_s = 1.0;
  return model;
}

TEST(Simulate, DelayedPremiseSwitchesTheRuleWhenTheVoltageArrives) {
  // 5 V from t = 1 s, 1 V from t = 3 s (dt = 0.5 s). The 1 V step reaches the actuator
  // at t = 4 s: until then the output is the 5 V rule's 10 mm with the delayed premise,
  // and already 5 V x 1 mm/V = 5 mm with the applied one.
  const std::vector<double> u = {0, 0, 5, 5, 5, 5, 1, 1, 1, 1, 1};
  const auto delayed = SimulateUniform(TwoGains(SchedulingVariable::kAbsVoltageDelayed), 0.5, u);
  ExpectVectorsNear(delayed, {0, 0, 0, 0, 10, 10, 10, 10, 1, 1, 1}, 1e-12);
  const auto applied = SimulateUniform(TwoGains(SchedulingVariable::kAbsVoltage), 0.5, u);
  ExpectVectorsNear(applied, {0, 0, 0, 0, 10, 10, 5, 5, 1, 1, 1}, 1e-12);
}

TEST(Simulate, DelayedPremiseStreamingAgreesWithTheUniformFastPath) {
  TsModel model = SeedTsModel();
  model.scheduling = SchedulingVariable::kAbsVoltageDelayed;
  model.scheduling_delay_s = 2.35;  // 23.5 samples: the premise switches on a sample
  const std::vector<double> u = RandomStaircase(3000, 11, 8);
  const auto fast = SimulateUniform(model, 0.1, u);
  StreamingSimulator streaming(model);
  std::vector<double> slow;
  for (size_t k = 0; k < u.size(); ++k)
    slow.push_back(streaming.Step(0.1 * static_cast<double>(k), u[k]));
  double range_mm = 0.0;
  for (double y : fast) range_mm = std::max(range_mm, std::abs(y));
  // Two exact integrations (per-sample propagators vs events): rounding only, about
  // 5e-10 of the output range over 300 s of switching.
  EXPECT_LT(MaxAbsDifference(fast, slow), 1e-9 * range_mm);
  // And the delay matters: the applied-voltage premise predicts differently.
  model.scheduling = SchedulingVariable::kAbsVoltage;
  EXPECT_GT(MaxAbsDifference(fast, SimulateUniform(model, 0.1, u)), 1e-3);
}

TEST(Simulate, APremiseSeriesSchedulesTheRulesAndTheVoltageDrivesThem) {
  // Drive 0.5 x the applied voltage, scheduled on the applied one: at 5 V applied the 5 V
  // rule's 2 mm/V acts on 2.5 V (5 mm); scheduled on the drive it would be the 1 V rule's
  // and half of the 5 V rule's blend at 2.5 V.
  const std::vector<double> applied = {0, 0, 5, 5, 5, 5, 1, 1, 1, 1, 1};
  std::vector<double> drive(applied.size());
  for (size_t k = 0; k < applied.size(); ++k) drive[k] = 0.5 * applied[k];
  const TsModel model = TwoGains(SchedulingVariable::kAbsVoltage);
  SimulationOptions options;
  options.premise_V = applied;
  std::vector<double> mu;
  const auto y = SimulateUniform(model, 0.5, drive, options, &mu);
  ExpectVectorsNear(y, {0, 0, 0, 0, 5, 5, 2.5, 2.5, 0.5, 0.5, 0.5}, 1e-12);
  EXPECT_EQ(mu[2 * 2 + 1], 1.0);  // the 5 V rule alone while 5 V is applied
  EXPECT_GT(MaxAbsDifference(y, SimulateUniform(model, 0.5, drive)), 1.0);

  // The premise equal to the voltage changes nothing, bit for bit; the streaming engine
  // (the any-grid path) agrees; and the premise is checked like the voltage.
  TsModel seed = SeedTsModel();
  const std::vector<double> u = RandomStaircase(3000, 11, 9);
  SimulationOptions same;
  same.premise_V = u;
  EXPECT_EQ(SimulateUniform(seed, 0.1, u, same), SimulateUniform(seed, 0.1, u));
  std::vector<double> worn(u.size()), t_s(u.size());
  for (size_t k = 0; k < u.size(); ++k) {
    worn[k] = u[k] * (1.0 - 0.3 * static_cast<double>(k) / static_cast<double>(u.size()));
    t_s[k] = 0.1 * static_cast<double>(k);
  }
  options.premise_V = u;
  const auto fast = SimulateUniform(seed, 0.1, worn, options);
  StreamingSimulator streaming(seed);
  std::vector<double> slow;
  for (size_t k = 0; k < u.size(); ++k) slow.push_back(streaming.Step(t_s[k], worn[k], u[k]));
  double range_mm = 0.0;
  for (double v : fast) range_mm = std::max(range_mm, std::abs(v));
  EXPECT_LT(MaxAbsDifference(fast, slow), 1e-9 * range_mm);  // rounding only, as above
  seed.realisation = TsRealisation::kParallel;
  StreamingSimulator parallel(seed);
  slow.clear();
  for (size_t k = 0; k < u.size(); ++k) slow.push_back(parallel.Step(t_s[k], worn[k], u[k]));
  EXPECT_LT(MaxAbsDifference(SimulateUniform(seed, 0.1, worn, options), slow), 1e-9 * range_mm);
  const std::vector<double> short_premise(u.size() - 1, 1.0);
  options.premise_V = short_premise;
  EXPECT_THROW(SimulateUniform(seed, 0.1, worn, options), std::invalid_argument);
  EXPECT_THROW(Simulate(seed, t_s, worn, options), std::invalid_argument);
}

// Parallel rules (ts_fuzzy.h): each rule driven by its share of the voltage.
TsModel ParallelRules(const TransferFunction& low, const TransferFunction& high) {
  TsModel model = MakeTsModelOnLevels({{2.0, low, {}}, {6.0, high, {}}});
  model.realisation = TsRealisation::kParallel;
  return model;
}

// The 6 V rule's share of u: linear from 2 to 6 V in |u| at the scheduling resolution.
double Share(double u_V) {
  const double z = std::round(std::abs(u_V) / kSchedulingResolution_V) * kSchedulingResolution_V;
  return std::clamp((z - 2.0) / 4.0, 0.0, 1.0);
}

TEST(Simulate, ParallelRulesAreEachDrivenByTheirShare) {
  const TransferFunction low{{0.5}, {4.0, 1.0}, 0.35}, high{{1.5}, {20.0, 1.0}, 0.35};
  const TsModel model = ParallelRules(low, high);
  const std::vector<double> u = RandomStaircase(2000, 37, 5);
  // By hand: the shares of a linear membership between 2 and 6 V, then each rule alone.
  std::vector<double> low_share(u.size()), high_share(u.size());
  for (size_t k = 0; k < u.size(); ++k) {
    const double w = Share(u[k]);
    low_share[k] = (1 - w) * u[k];
    high_share[k] = w * u[k];
  }
  std::vector<double> expected = SimulateUniform(low, 0.1, low_share);
  const std::vector<double> part = SimulateUniform(high, 0.1, high_share);
  for (size_t k = 0; k < u.size(); ++k) expected[k] += part[k];
  ExpectVectorsNear(SimulateUniform(model, 0.1, u), expected, 1e-12);

  // The streaming engine (and so the any-grid path) agrees.
  StreamingSimulator streaming(model);
  std::vector<double> slow;
  for (size_t k = 0; k < u.size(); ++k)
    slow.push_back(streaming.Step(0.1 * static_cast<double>(k), u[k]));
  EXPECT_LT(MaxAbsDifference(expected, slow), 1e-9);

  // And it is not the frozen blend: after a jump the old rule's share relaxes slowly.
  TsModel frozen = model;
  frozen.realisation = TsRealisation::kFrozen;
  EXPECT_GT(MaxAbsDifference(expected, SimulateUniform(frozen, 0.1, u)), 0.1);
}

TEST(Simulate, ParallelRulesWithEqualDynamicsAreAHammersteinModel) {
  // Same dynamics, gains 1 and 3 mm/V: the static map u -> K(|u|) u, then one system.
  const TransferFunction unit{{1.0}, {8.0, 6.0, 1.0}, 0.2};
  TransferFunction triple = unit;
  triple.num = {3.0};
  const TsModel model = ParallelRules(unit, triple);
  const std::vector<double> u = RandomStaircase(1500, 23, 6);
  std::vector<double> mapped(u.size());
  for (size_t k = 0; k < u.size(); ++k) {
    const double w = Share(u[k]);
    mapped[k] = ((1 - w) * 1.0 + w * 3.0) * u[k];
  }
  ExpectVectorsNear(SimulateUniform(model, 0.1, u), SimulateUniform(unit, 0.1, mapped), 1e-12);
  // Its frozen model at 4 V is the sum of the halves: DC gain 2 mm/V.
  EXPECT_NEAR(DcGain(FrozenModelAt(model, 4.0)), 2.0, 1e-12);
}

// A continuous input moves the operating point on most samples. On a long one each point
// is found in a flat table over the scheduling values, on a short one by hashing
// (simulate.cc, OperatingPointCache): the same points, so the same output bit for bit.
TEST(Simulate, OperatingPointsAreTheSameWhetherIndexedOrHashed) {
  std::vector<double> u(20000);
  for (size_t k = 0; k < u.size(); ++k) {
    const double t_s = 0.1 * static_cast<double>(k);
    u[k] = 4.0 + 3.9 * std::sin(0.002 * t_s * t_s) + ((k % 7 == 0) ? -8.0 : 0.0);
  }
  const std::span<const double> head(u.data(), 1000);  // 15,803 slots > 1,000 + 1,024: hashed
  for (TsRealisation realisation : {TsRealisation::kFrozen, TsRealisation::kParallel}) {
    TsModel model = SeedTsModel();
    model.realisation = realisation;
    const std::vector<double> indexed = SimulateUniform(model, 0.1, u);
    const std::vector<double> hashed = SimulateUniform(model, 0.1, head);
    for (size_t k = 0; k < hashed.size(); ++k)
      ASSERT_EQ(indexed[k], hashed[k]) << "sample " << k << ", " << TsRealisationName(realisation);
  }
}

TEST(Simulate, StartsInSteadyStateWhenAsked) {
  const TransferFunction tf = SeedModel2V();
  const auto y =
      SimulateUniform(tf, 0.1, std::vector<double>(200, 4.0), {.start_in_steady_state = true});
  for (double value : y) ASSERT_NEAR(value, 4.0 * DcGain(tf), 1e-9);
}

TEST(Simulate, ProperModelFeedthroughUsesTheDelayedInput) {
  // G = 2 e^{-0.15 s} (pure gain with delay): y(t) = 2 u(t - 0.15).
  const TransferFunction gain{{2.0}, {1.0}, 0.15};
  const std::vector<double> u = {1, 2, 3, 4, 5};
  const auto y = SimulateUniform(gain, 0.1, u);
  ExpectVectorsNear(y, {0, 0, 2, 4, 6}, 1e-12);
}

TEST(Simulate, SchedulingResolutionIsCoarseOnlyForContinuousInputs) {
  EXPECT_EQ(SchedulingResolutionFor(8.0, true), kSchedulingResolution_V);
  EXPECT_EQ(SchedulingResolutionFor(5000.0, true), kSchedulingResolution_V);
  EXPECT_DOUBLE_EQ(SchedulingResolutionFor(5120.0, false), 20.0);
  EXPECT_DOUBLE_EQ(SchedulingResolutionFor(-5120.0, false), 20.0);
  // Never finer than the default: a continuous input of 0.1 V keeps 1 mV.
  EXPECT_EQ(SchedulingResolutionFor(0.1, false), kSchedulingResolution_V);
}

TEST(Simulate, RejectsBadSeries) {
  const TransferFunction tf = SeedModel2V();
  const std::vector<double> t_s = {0.0, 0.1, 0.1};
  const std::vector<double> u = {0.0, 1.0, 1.0};
  EXPECT_THROW(Simulate(tf, t_s, u), std::invalid_argument);
  const std::vector<double> t_ok = {0.0, 0.1, 0.2};
  const std::vector<double> u_nan = {0.0, NAN, 1.0};
  EXPECT_THROW(Simulate(tf, t_ok, u_nan), std::invalid_argument);
  const std::vector<double> u_short = {0.0};
  EXPECT_THROW(Simulate(tf, t_ok, u_short), std::invalid_argument);
  EXPECT_THROW(SimulateUniform(tf, 0.0, u), std::invalid_argument);
}

}  // namespace
}  // namespace flexid::model
