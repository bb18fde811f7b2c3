// The parts of model/control/ on their own: the predictor against the core's simulation,
// the command limits, the reference and the reachable range, the FOPDT fit and the SIMC
// rule, the bounded quadratic programme.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "model/control/box_qp.h"
#include "model/control/controller.h"
#include "model/control/limits.h"
#include "model/control/reference.h"
#include "model/control/simc.h"
#include "model/control/ts_predictor.h"
#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/core/simulate.h"
#include "test_util.h"

namespace flexid::model::control {
namespace {

double MaxDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double largest = 0.0;
  for (size_t k = 0; k < a.size(); ++k) largest = std::max(largest, std::abs(a[k] - b[k]));
  return largest;
}

std::vector<double> Stepped(TsPredictor predictor, const std::vector<double>& u) {
  std::vector<double> y;
  for (double voltage : u) y.push_back(predictor.Step(voltage));
  return y;
}

// The predictor is the core's uniform simulation, stepped: same outputs to rounding, for
// every realisation and premise flexid reads.
TEST(TsPredictor, MatchesTheCoreSimulationForEveryPremiseAndRealisation) {
  TsModel seed = SeedTsModel();
  TsModel delayed = seed;
  delayed.scheduling = SchedulingVariable::kAbsVoltageDelayed;
  delayed.scheduling_delay_s = 3.67;
  TsModel held = seed;
  held.scheduling = SchedulingVariable::kAbsVoltageHeld;
  held.rest_band_V = 0.5;
  TsModel parallel = seed;
  parallel.realisation = TsRealisation::kParallel;
  TsModel fractional = seed;
  for (LocalModel& rule : fractional.rules) rule.tf.delay_s = 2.345;
  const std::vector<double> u = testing::RandomStaircase(3000, 37, 3, -8.0, 8.0);
  for (const TsModel* model :
       std::vector<const TsModel*>{&seed, &delayed, &held, &parallel, &fractional}) {
    const std::vector<double> core = SimulateUniform(*model, 0.1, u);
    EXPECT_LT(MaxDifference(Stepped(TsPredictor(*model, 0.1), u), core), 1e-9);
  }
}

TEST(TsPredictor, StartsInTheSteadyStateOfItsInitialVoltage) {
  const TsModel seed = SeedTsModel();
  SimulationOptions options;
  options.initial_voltage_V = 4.0;
  const std::vector<double> u = testing::RandomStaircase(500, 50, 9, 0.0, 8.0);
  EXPECT_LT(MaxDifference(Stepped(TsPredictor(seed, 0.1, 4.0), u),
                          SimulateUniform(seed, 0.1, u, options)),
            1e-9);
}

// A copy steps on alone: the original is where it was.
TEST(TsPredictor, ACopyLooksAheadWithoutMovingTheOriginal) {
  TsPredictor original(SeedTsModel(), 0.1);
  for (int k = 0; k < 100; ++k) original.Step(5.0);
  TsPredictor ahead = original;
  for (int k = 0; k < 300; ++k) ahead.Step(8.0);
  TsPredictor again = original;
  EXPECT_EQ(original.Step(5.0), again.Step(5.0));
  EXPECT_NE(ahead.Step(8.0), original.Step(5.0));
}

TEST(ControlLimits, RefusesARangeWithoutZeroAndNamesTheLimit) {
  ControlLimits limits;
  limits.min_V = 1.0;
  std::string why;
  EXPECT_FALSE(limits.IsValid(&why));
  EXPECT_NE(why.find("voltage range"), std::string::npos) << why;
  limits = {};
  limits.rate_V_per_s = 0.0;
  EXPECT_FALSE(limits.IsValid(&why));
  EXPECT_NE(why.find("rate limit"), std::string::npos) << why;
}

TEST(CommandLimiter, ClipsTheRangeAndTheRate) {
  ControlLimits limits;
  limits.min_V = -2.0;
  limits.max_V = 6.0;
  limits.rate_V_per_s = 10.0;  // 1 V per 0.1 s sample
  CommandLimiter limiter(limits, 0.1);
  LimitsActed acted;
  EXPECT_DOUBLE_EQ(limiter.Apply(5.0, &acted), 1.0);
  EXPECT_TRUE(acted.rate);
  EXPECT_DOUBLE_EQ(limiter.Apply(5.0), 2.0);
  for (int k = 0; k < 10; ++k) limiter.Apply(9.0, &acted);
  EXPECT_DOUBLE_EQ(limiter.last_V(), 6.0);
  EXPECT_TRUE(acted.range);
  EXPECT_DOUBLE_EQ(limiter.Apply(-5.0), 5.0);
}

// The charge proxy over the window never exceeds the budget: 4 V for 1 s is 4 V s; with a
// 10 V s budget per 5 s window the voltage is cut after 2.5 s, and comes back as the early
// samples leave the window.
TEST(CommandLimiter, KeepsTheChargePerWindowWithinTheBudget) {
  ControlLimits limits;
  limits.rate_V_per_s = INFINITY;
  limits.max_charge_Vs = 10.0;
  limits.charge_window_s = 5.0;
  CommandLimiter limiter(limits, 0.1);
  std::vector<double> applied;
  bool cut = false;
  for (int k = 0; k < 200; ++k) {
    LimitsActed acted;
    applied.push_back(limiter.Apply(4.0, &acted));
    cut = cut || acted.charge;
    EXPECT_LE(limiter.charge_Vs(), 10.0 + 1e-9) << "sample " << k;
  }
  EXPECT_TRUE(cut);
  EXPECT_DOUBLE_EQ(applied[0], 4.0);
  EXPECT_NEAR(applied[24], 4.0, 1e-9);  // 25 samples of 0.4 V s: 10 V s
  EXPECT_NEAR(applied[25], 0.0, 1e-9);
  EXPECT_GT(applied[60], 0.0);  // the first samples have left the window
}

TEST(Reference, InterpolatesAndHoldsItsEnds) {
  const Reference reference({0.0, 10.0, 20.0}, {1.0, 3.0, 3.0}, "test");
  EXPECT_DOUBLE_EQ(reference.At(-1.0), 1.0);
  EXPECT_DOUBLE_EQ(reference.At(5.0), 2.0);
  EXPECT_DOUBLE_EQ(reference.At(25.0), 3.0);
  EXPECT_DOUBLE_EQ(reference.duration_s(), 20.0);
}

TEST(Reference, RefusesBadSamplesNamingTheSource) {
  try {
    Reference({0.0, 2.0, 1.0}, {1.0, 2.0, 3.0}, "ref.csv");
    FAIL() << "accepted";
  } catch (const InputError& error) {
    const std::string what = error.what();
    EXPECT_NE(what.find("ref.csv: time is not strictly increasing at sample 3"), std::string::npos)
        << what;
  }
  EXPECT_THROW(Reference({}, {}, "empty"), InputError);
  EXPECT_THROW(Reference({0.0}, {NAN}, "nan"), InputError);
}

// The seed's T-S model: 5.32 mm/V alone up to 2 V, 8.66 mm/V alone from 8 V.
TEST(SteadyStateMap, IsTheModelsDcGainTimesTheVoltage) {
  const SteadyStateMap map(SeedTsModel(), -8.0, 8.0);
  const double gain_2V = 1.14 / 0.2142, gain_8V = 1.97 / 0.2275;
  EXPECT_NEAR(map.DeflectionAt(2.0), 2.0 * gain_2V, 1e-6);
  EXPECT_NEAR(map.DeflectionAt(-8.0), -8.0 * gain_8V, 1e-6);
  EXPECT_NEAR(map.highest_mm(), 8.0 * gain_8V, 1e-6);
  EXPECT_NEAR(map.VoltageFor(map.DeflectionAt(5.3)), 5.3, 1e-6);
  EXPECT_NEAR(map.SlopeAt(1.0), gain_2V, 1e-6);
}

TEST(Reachability, NamesTheFirstSampleOutsideTheRange) {
  const SteadyStateMap map(SeedTsModel(), 0.0, 5.0);
  const Reference inside({0.0, 100.0}, {0.0, 30.0}, "inside");
  EXPECT_EQ(ReachabilityProblem(inside, map), "");
  const Reference outside({0.0, 50.0, 100.0}, {0.0, 60.0, -1.0}, "outside");
  const std::string why = ReachabilityProblem(outside, map);
  EXPECT_NE(why.find("60 mm at t = 50 s"), std::string::npos) << why;
  EXPECT_NE(why.find("0 .. 5 V"), std::string::npos) << why;
}

// A first-order model with a dead time is its own FOPDT fit, and SIMC gives Skogestad's
// numbers: K_c = tau / (k (tau_c + theta)), tau_I = min(tau, 4 (tau_c + theta)).
TEST(Simc, FitsAFirstOrderModelExactlyAndAppliesTheRule) {
  const TransferFunction tf{{2.0}, {40.0, 1.0}, 3.0};  // k 2 mm/V, tau 40 s, theta 3 s
  const FirstOrderPlusDeadTime fit = FitFirstOrderPlusDeadTime(SingleRule(tf), 1.0, 2.0);
  EXPECT_NEAR(fit.time_constant_s, 40.0, 0.05);
  EXPECT_NEAR(fit.dead_time_s, 3.0, 0.05);
  EXPECT_LT(fit.fit_rms, 1e-3);
  const PiTuning tuning = SimcTuning(fit);
  EXPECT_NEAR(tuning.closed_loop_time_constant_s, 3.0, 0.05);
  EXPECT_NEAR(tuning.gain_V_per_mm, 40.0 / (2.0 * 6.0), 0.05);
  EXPECT_NEAR(tuning.integral_time_s, 24.0, 0.2);  // 4 (tau_c + theta) < tau
}

TEST(BoxQp, SolvesAnUnconstrainedAndABoundedProblem) {
  Eigen::MatrixXd M(2, 2);
  M << 2.0, 0.5, 0.5, 1.0;
  const Eigen::VectorXd c = Eigen::Vector2d(1.0, 3.0);
  const Eigen::VectorXd wide = Eigen::Vector2d::Constant(100.0);
  BoxQpResult free = SolveBoxQp(M, c, -wide, wide, Eigen::Vector2d::Zero());
  EXPECT_TRUE(free.converged);
  EXPECT_LT((M * free.x - c).norm(), 1e-9);
  // With x2 <= 1 the optimum has x2 = 1 and x1 = (1 - 0.5) / 2.
  BoxQpResult bounded =
      SolveBoxQp(M, c, -wide, Eigen::Vector2d(100.0, 1.0), Eigen::Vector2d::Zero());
  EXPECT_TRUE(bounded.converged);
  EXPECT_NEAR(bounded.x(1), 1.0, 1e-12);
  EXPECT_NEAR(bounded.x(0), 0.25, 1e-12);
}

// An ill-conditioned programme like a replan's with light move weights (slow responses of
// neighbouring blocks nearly alike): many variables end at a bound, and the solution must
// satisfy the KKT conditions, where the cost cannot fall within the box. Releasing every
// held variable whose gradient pointed inwards at each iteration cycled here without
// reaching them in 100 iterations, and the controller's plans stayed where they started.
TEST(BoxQp, ReachesTheOptimumOfAnIllConditionedProblemWithManyBoundsActive) {
  std::mt19937 random(11);
  std::normal_distribution<double> normal(0.0, 1.0);
  const int n = 36, rows = 120;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(rows + n, n);
  for (int i = 0; i < rows; ++i)
    for (int b = 0; b < n; ++b)  // smooth, nearly collinear columns: step responses
      A(i, b) = (i >= b ? 1.0 - std::exp(-0.02 * (i - b + 1)) : 0.0) + 1e-3 * normal(random);
  for (int b = 0; b < n; ++b) A(rows + b, b) = std::sqrt(1e-5);  // a light ridge
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(rows + n);
  for (int i = 0; i < rows; ++i) rhs(i) = 10.0 * std::sin(0.3 * i) + normal(random);
  const Eigen::MatrixXd M = A.transpose() * A;
  const Eigen::VectorXd c = A.transpose() * rhs;
  const Eigen::VectorXd lo = Eigen::VectorXd::Constant(n, -8.0);
  const Eigen::VectorXd hi = Eigen::VectorXd::Constant(n, 8.0);
  const BoxQpResult result = SolveBoxQp(M, c, lo, hi, Eigen::VectorXd::Zero(n));
  ASSERT_TRUE(result.converged) << result.iterations << " iterations";
  const Eigen::VectorXd g = M * result.x - c;
  int at_bound = 0;
  for (int i = 0; i < n; ++i) {
    if (result.x(i) <= lo(i)) {
      EXPECT_GE(g(i), -1e-6) << i;  // the cost rises into the box
      ++at_bound;
    } else if (result.x(i) >= hi(i)) {
      EXPECT_LE(g(i), 1e-6) << i;
      ++at_bound;
    } else {
      EXPECT_NEAR(g(i), 0.0, 1e-6 * std::max(1.0, c.norm())) << i;
    }
  }
  EXPECT_GE(at_bound, 4);
}

TEST(Controller, RefusesAnUnreachableReferenceBeforeTheFirstCommand) {
  ControllerOptions options;
  options.limits.min_V = 0.0;
  options.limits.max_V = 5.0;
  const Reference too_far({0.0, 100.0}, {0.0, 50.0}, "far.csv");
  try {
    Controller controller(SeedTsModel(), too_far, options);
    FAIL() << "accepted";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find("far.csv: the reference is 50 mm at t = 100 s"),
              std::string::npos)
        << error.what();
  }
}

// The rate limit is the plan's to use: after a step of the reference the voltage moves by
// up to rate x Ts per sample, and more than a replan's 0.5 V per 0.5 s (when each plan's
// first block was bounded by what the rate reaches by the block's start, the controller
// moved at a fifth of the limit).
TEST(Controller, ThePlanUsesTheWholeRateLimitAfterAStep) {
  const TsModel model = SeedTsModel();
  const SteadyStateMap steady(model, -8.0, 8.0);
  const Reference step({0.0, 30.0, 30.1, 120.0},
                       {steady.DeflectionAt(1.0), steady.DeflectionAt(1.0),
                        steady.DeflectionAt(5.0), steady.DeflectionAt(5.0)},
                       "step");
  ControllerOptions options;
  options.kind = ControllerKind::kOpenLoop;
  Controller controller(model, step, options);
  std::vector<double> u_V;
  for (long k = 0; !controller.Finished(k); ++k) u_V.push_back(controller.Next(k, NAN).voltage_V);
  const double per_sample_V = options.limits.rate_V_per_s * options.sample_period_s;
  double largest_step_V = 0.0, largest_half_second_V = 0.0;
  for (size_t k = 1; k < u_V.size(); ++k) {
    largest_step_V = std::max(largest_step_V, std::abs(u_V[k] - u_V[k - 1]));
    if (k >= 5)
      largest_half_second_V = std::max(largest_half_second_V, std::abs(u_V[k] - u_V[k - 5]));
  }
  EXPECT_LE(largest_step_V, per_sample_V + 1e-9);
  EXPECT_GT(largest_half_second_V, 2.0 * per_sample_V);
}

}  // namespace
}  // namespace flexid::model::control
