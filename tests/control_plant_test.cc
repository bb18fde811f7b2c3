// Closed loops of the controllers (model/control/controller.h) against plants that are
// not flexid's T-S simulator: the independent T-S plant (ts_plant.h) and the effect lab
// (effect_plant.h), each with its own integrator, stepped by control_harness.h.
//
// The controller's model is deliberately wrong, as an identified one is: on the T-S
// plant it has the plant's rules with every gain 10 % low, the frozen realisation instead
// of the plant's input blend, linear memberships instead of smoothsteps on the applied
// instead of the delayed voltage, and the dead time on the sample grid; on the effect lab
// it leaves out the back-relaxation the lab adds. What the tests hold each law to:
//   - predictive: the error 150-180 s into every level within 0.08 mm (four times the
//     noise's standard deviation; the model's own error there is 10 % of the level,
//     0.1-0.6 mm), every limit kept;
//   - open_loop: the model's error stays (the settled error is most of the 10 %);
//   - pi: settles too (integral action), more slowly: within 0.2 mm by each level's end.
// The mismatch is fed back as an output disturbance held over the horizon (mpc.h, the
// Smith predictor's structure): a mismatch that keeps moving with the plant's slow mode (a
// gain error after a step, back-relaxation) is removed as slowly as that mode settles, hence
// judged after 150 s rather than at once.
#include <gtest/gtest.h>

#include <cmath>
#include <string>
#include <vector>

#include "control_harness.h"
#include "model/control/controller.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::testing {
namespace {

using model::control::Controller;
using model::control::ControllerKind;
using model::control::ControllerOptions;
using model::control::Reference;

// The plant's rules as a flexid model, wrong as described in the file header.
model::TsModel ModelOf(const TsPlant& plant, double gain_scale) {
  std::vector<model::LocalModel> rules;
  for (size_t r = 0; r < plant.rules.size(); ++r) {
    model::LocalModel rule;
    rule.tf.num.assign(plant.rules[r].num.begin(), plant.rules[r].num.end());
    for (double& c : rule.tf.num) c *= gain_scale;
    rule.tf.den.assign(plant.rules[r].den.begin(), plant.rules[r].den.end());
    rule.tf.delay_s = std::round(plant.delay_s / 0.1) * 0.1;
    const double half_width = 0.5 * plant.widths_V[0];
    rule.level_V = r == 0 ? plant.boundaries_V[0] - half_width : plant.boundaries_V[0] + half_width;
    rules.push_back(rule);
  }
  return model::MakeTsModelOnLevels(rules);
}

// Levels held from the given times, the last one until end_s.
Reference Multilevel(const std::vector<double>& start_s, const std::vector<double>& level_mm,
                     double end_s) {
  std::vector<double> t_s = {0.0}, y_mm = {0.0};
  for (size_t i = 0; i < start_s.size(); ++i) {
    t_s.push_back(start_s[i] - 0.1);  // the previous level up to here
    y_mm.push_back(y_mm.back());
    t_s.push_back(start_s[i]);
    y_mm.push_back(level_mm[i]);
  }
  t_s.push_back(end_s);
  y_mm.push_back(level_mm.back());
  return Reference(t_s, y_mm, "multilevel");
}

// Mean |clean - reference| over the `span_s` before `end_s`.
double SettledError(const LoopResult& result, double end_s, double span_s = 30.0) {
  double sum = 0.0;
  int count = 0;
  for (size_t k = 0; k < result.t_s.size(); ++k)
    if (result.t_s[k] > end_s - span_s && result.t_s[k] <= end_s) {
      sum += std::abs(result.clean_mm[k] - result.reference_mm[k]);
      ++count;
    }
  return sum / count;
}

// Levels of 250 s; each is judged over 150-180 s after it starts: settled, and before a
// predictive controller, whose 60 s horizon sees the next level coming, leaves it.
struct TsCase {
  TsPlant plant;
  Reference reference;
  std::vector<double> judged_s;  // the end of each level's judged span
};

TsCase MakeTsCase() {
  TsPlantDrawOptions draw;
  draw.rules = 2;
  TsPlant plant = DrawTsPlant(5, draw);
  std::vector<double> starts = {20.0, 270.0, 520.0, 770.0}, levels;
  for (double volts : {2.0, 4.0, 1.0, 3.0}) levels.push_back(volts * plant.SteadyGainAt(volts));
  Reference reference = Multilevel(starts, levels, 1020.0);
  return {plant, reference, {200.0, 450.0, 700.0, 950.0}};
}

// The default limits with no charge limit (EveryCommandKeepsTheLimits tests that one).
ControllerOptions Unmetered() {
  ControllerOptions options;
  options.limits.max_charge_Vs = INFINITY;
  return options;
}

LoopResult RunTs(const TsCase& c, ControllerKind kind,
                 const ControllerOptions& base = Unmetered()) {
  ControllerOptions options = base;
  options.kind = kind;
  Controller controller(ModelOf(c.plant, 0.9), c.reference, options);
  TsPlantLoop plant(c.plant, 77);
  return RunLoop(controller, plant);
}

TEST(ControlOnTsPlant, PredictiveSettlesOnEveryLevelDespiteTheModelsErrors) {
  const TsCase c = MakeTsCase();
  const LoopResult result = RunTs(c, ControllerKind::kPredictive);
  for (double end_s : c.judged_s)
    EXPECT_LT(SettledError(result, end_s), 0.08) << "level judged up to " << end_s << " s\n"
                                                 << DescribeTsPlant(c.plant);

  std::cout << "predictive on the T-S plant: RMSE " << result.rmse_mm << " mm, voltage RMS "
            << result.voltage_rms_V << " V\n";
}

TEST(ControlOnTsPlant, EveryCommandKeepsTheLimits) {
  const TsCase c = MakeTsCase();
  ControllerOptions options;
  options.limits.min_V = -3.0;
  options.limits.max_V = 6.0;
  options.limits.rate_V_per_s = 2.0;
  options.limits.max_charge_Vs = 300.0;
  options.limits.charge_window_s = 100.0;
  for (ControllerKind kind :
       {ControllerKind::kPredictive, ControllerKind::kPi, ControllerKind::kOpenLoop}) {
    const LoopResult result = RunTs(c, kind, options);
    double lowest = 0.0, highest = 0.0;
    for (double u : result.voltage_V) {
      lowest = std::min(lowest, u);
      highest = std::max(highest, u);
    }
    const std::string name = model::control::ControllerKindName(kind);
    EXPECT_GE(lowest, -3.0) << name;
    EXPECT_LE(highest, 6.0) << name;
    EXPECT_LE(result.largest_step_V, 2.0 * 0.1 + 1e-9) << name;
    EXPECT_LE(result.peak_window_charge_Vs, 300.0 + 1e-6) << name;
  }
}

// Without feedback the model's 10 % gain error stays in the deflection; with it, it goes.
TEST(ControlOnTsPlant, OpenLoopInversionKeepsTheModelsErrorFeedbackRemovesIt) {
  const TsCase c = MakeTsCase();
  const LoopResult open = RunTs(c, ControllerKind::kOpenLoop);
  const LoopResult closed = RunTs(c, ControllerKind::kPredictive);
  const double level_mm = c.reference.At(400.0);  // the 4 V level
  EXPECT_GT(SettledError(open, 450.0), 0.05 * level_mm);
  EXPECT_LT(SettledError(closed, 450.0), 0.2 * SettledError(open, 450.0));
}

TEST(ControlOnTsPlant, SimcPiRemovesTheOffsetOnLongHolds) {
  const TsCase c = MakeTsCase();
  const LoopResult result = RunTs(c, ControllerKind::kPi);
  for (double end_s : c.judged_s)  // the PI does not look ahead: judged at each level's end
    EXPECT_LT(SettledError(result, end_s + 70.0), 0.2) << "level ending at " << end_s + 70.0;
}

// The effect lab's physics-like plant with back-relaxation (30 % of the deflection relaxes
// back with a 60 s time constant); the model is the plant without it.
TEST(ControlOnEffectPlant, FeedbackCorrectsBackRelaxationTheModelLeavesOut) {
  LabRun run;
  run.plant = LabPhysicsPlant();
  run.effect.kind = LabEffect::kBackRelaxation;
  run.effect.amplitude = 0.3;
  run.effect.relaxation_tau_s = 60.0;
  run.waveform = Waveform({}, 0.03);
  run.noise_seed = 5;
  run.max_step_s = 0.005;
  const double gain = PlantDcGain(run.plant);
  const Reference reference = Multilevel({10.0, 310.0}, {5.0 * gain, 2.0 * gain}, 610.0);
  // Judged over 200-230 s after each level starts.
  auto settled = [&](ControllerKind kind) {
    ControllerOptions options = Unmetered();
    options.kind = kind;
    Controller controller(model::SingleRule(LabPhysicsPlant()), reference, options);
    EffectPlantLoop plant(run);
    const LoopResult result = RunLoop(controller, plant);
    return std::vector<double>{SettledError(result, 240.0), SettledError(result, 540.0)};
  };
  const std::vector<double> closed = settled(ControllerKind::kPredictive);
  const std::vector<double> open = settled(ControllerKind::kOpenLoop);
  EXPECT_LT(closed[0], 0.2);
  EXPECT_LT(closed[1], 0.2);
  EXPECT_GT(open[0], 1.0);  // about 30 % of 7.5 mm relaxed back
  EXPECT_LT(closed[0], 0.1 * open[0]);
}

}  // namespace
}  // namespace flexid::testing
