// The catalogue's effects sample by sample (model::AugmentedStreamingSimulator, what
// flexidd's predictor runs) against the batch prediction `flexid simulate` prints
// (model::SimulateAugmented), and the scale an accruing effect carries in a model file.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/core/recording.h"
#include "model/diagnose/diagnose.h"
#include "model/diagnose/effects.h"

namespace flexid {
namespace {

using model::Effect;
using model::EffectKind;

// Holds of both signs and several lengths on a jittered grid (10 Hz +- 20 %): every effect
// acts (holds for the slow ones, reversals for the friction, negative voltage for the
// polarity, large |u| for the saturation).
model::Recording Staircase() {
  model::Recording rec;
  rec.source = "staircase";
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> jitter(0.08, 0.12);
  const std::vector<double> levels_V = {0, 3, 8, 0, -5, 6, 2, 0, 7, -2, 0};
  const std::vector<double> holds_s = {5, 40, 25, 30, 35, 10, 60, 20, 15, 30, 40};
  double t = 0.0;
  for (size_t i = 0; i < levels_V.size(); ++i)
    for (const double end = t + holds_s[i]; t < end; t += jitter(rng)) {
      rec.t_s.push_back(t);
      rec.voltage_V.push_back(levels_V[i]);
      rec.deflection_mm.push_back(0.0);
    }
  return rec;
}

// One effect of every kind, with sizes that move the prediction by tenths of a mm and more.
std::vector<Effect> EveryEffect(double charge_Vs, double span_s) {
  return {
      {EffectKind::kDeadZone, {0.4}},
      {EffectKind::kPolarityAsymmetry, {0.7}},
      {EffectKind::kElectrolysisSaturation, {5.0, 0.5}},
      {EffectKind::kCycleDegradation, {0.3, 0.5}, charge_Vs},
      {EffectKind::kBackRelaxation, {0.2, 30.0}},
      {EffectKind::kCreep, {0.1, 80.0}},
      {EffectKind::kHysteresis, {0.15, 0.4}},
      {EffectKind::kSensorDrift, {0.3, 0.1, 20.0}, span_s},
  };
}

std::vector<double> Streamed(const model::TsModel& model, const std::vector<Effect>& effects,
                             const model::Recording& rec) {
  model::AugmentedStreamingSimulator simulator(model, effects);
  std::vector<double> y;
  for (size_t k = 0; k < rec.t_s.size(); ++k)
    y.push_back(simulator.Step(rec.t_s[k], rec.voltage_V[k]));
  return y;
}

double MaxAbsDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double worst = 0.0;
  for (size_t k = 0; k < a.size(); ++k) worst = std::max(worst, std::abs(a[k] - b[k]));
  return worst;
}

TEST(EffectsStreaming, EachEffectAloneMatchesTheBatchPrediction) {
  const model::Recording rec = Staircase();
  const model::TsModel model = model::SeedTsModel();
  const std::vector<double> plain = model::SimulateAugmented(model, rec, {});
  for (const Effect& e : EveryEffect(700.0, 300.0)) {
    const std::vector<double> batch = model::SimulateAugmented(model, rec, {e});
    EXPECT_GT(MaxAbsDifference(batch, plain), 0.05) << model::EffectName(e.kind) << " did nothing";
    EXPECT_LT(MaxAbsDifference(Streamed(model, {e}, rec), batch), 1e-9)
        << model::EffectName(e.kind);
  }
}

TEST(EffectsStreaming, AllEffectsTogetherMatchTheBatchPrediction) {
  const model::Recording rec = Staircase();
  const std::vector<Effect> effects = EveryEffect(700.0, 300.0);
  const model::TsModel model = model::SeedTsModel();
  EXPECT_LT(MaxAbsDifference(Streamed(model, effects, rec),
                             model::SimulateAugmented(model, rec, effects)),
            1e-9);
}

TEST(EffectsStreaming, AFixedScaleEqualToTheRecordingsOwnChangesNothing) {
  const model::Recording rec = Staircase();
  const model::TsModel model = model::SeedTsModel();
  for (EffectKind kind : {EffectKind::kCycleDegradation, EffectKind::kSensorDrift}) {
    Effect own = kind == EffectKind::kCycleDegradation ? Effect{kind, {0.3, 1.0}}
                                                       : Effect{kind, {0.3, 0.1, 20.0}};
    Effect fixed = own;
    fixed.scale = model::OwnScale(kind, rec.t_s, rec.voltage_V);
    EXPECT_GT(fixed.scale, 0.0);
    EXPECT_LT(MaxAbsDifference(model::SimulateAugmented(model, rec, {own}),
                               model::SimulateAugmented(model, rec, {fixed})),
              1e-12)
        << model::EffectName(kind);
    // A doubled charge scale halves the loss's exponent: the batch form honours it.
    fixed.scale *= 2.0;
    EXPECT_GT(MaxAbsDifference(model::SimulateAugmented(model, rec, {own}),
                               model::SimulateAugmented(model, rec, {fixed})),
              1e-3)
        << model::EffectName(kind);
  }
}

TEST(EffectsStreaming, AnAccruingEffectWithoutItsScaleCannotRunLive) {
  for (const auto& [effect, scale_name] :
       {std::pair{Effect{EffectKind::kCycleDegradation, {0.3, 1.0}}, "charge_Vs"},
        std::pair{Effect{EffectKind::kSensorDrift, {0.3, 0.1, 20.0}}, "span_s"}}) {
    try {
      model::AugmentedStreamingSimulator simulator(model::SeedTsModel(), {effect});
      FAIL() << "accepted " << model::EffectName(effect.kind) << " without its scale";
    } catch (const model::InputError& e) {
      EXPECT_NE(std::string(e.what()).find(scale_name), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(model::EffectName(effect.kind)), std::string::npos);
    }
  }
  EXPECT_THROW(model::AugmentedStreamingSimulator(model::SeedTsModel(),
                                                  {Effect{EffectKind::kBackRelaxation, {0.2}}}),
               model::InputError);
}

TEST(EffectsStreaming, TheScaleTravelsInTheAugmentationAndIsChecked) {
  const Effect e{EffectKind::kCycleDegradation, {0.3, 1.0}, 512.5};
  const model::Augmentation a = model::AugmentationOf(e);
  EXPECT_EQ(a.params.at("charge_Vs").get<double>(), 512.5);
  EXPECT_EQ(model::EffectFromAugmentation(a).scale, 512.5);
  EXPECT_FALSE(
      model::AugmentationOf(Effect{EffectKind::kSensorDrift, {1, 2, 3}}).params.contains("span_s"));
  for (const nlohmann::json& bad :
       {nlohmann::json(0.0), nlohmann::json(-3.0), nlohmann::json("x")}) {
    model::Augmentation wrong = a;
    wrong.params["charge_Vs"] = bad;
    try {
      model::EffectFromAugmentation(wrong);
      FAIL() << "accepted charge_Vs " << bad;
    } catch (const model::InputError& error) {
      EXPECT_NE(std::string(error.what()).find("charge_Vs"), std::string::npos) << error.what();
    }
  }
}

TEST(EffectsStreaming, AParameterOutOfItsRangeIsNamed) {
  model::Augmentation a{"back_relaxation", {{"fraction", 1.3}, {"tau_s", 30.0}}};
  try {
    model::EffectFromAugmentation(a);
    FAIL() << "accepted a fraction of 1.3";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("fraction must be [0, 1), not 1.3"), std::string::npos)
        << e.what();
  }
  EXPECT_EQ(model::EffectProblem({EffectKind::kHysteresis, {0.1, 0.0}}),
            "hysteresis: reach_mm must be > 0, not 0");
  EXPECT_EQ(model::EffectProblem({EffectKind::kElectrolysisSaturation, {4.0, 0.5}}), "");
  EXPECT_THROW(model::AugmentedStreamingSimulator(model::SeedTsModel(),
                                                  {Effect{EffectKind::kPolarityAsymmetry, {-1.0}}}),
               model::InputError);
}

}  // namespace
}  // namespace flexid
