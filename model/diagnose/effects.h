// The catalogue of effects the mismatch diagnosis (diagnose.h) knows: what each one is
// physically, its parameters, its model (how it changes the voltage the actuator responds
// to, or the deflection it shows), and its place in a model file (augmentations).
//
// Input effects (cycle_degradation, electrolysis_saturation, dead_zone,
// polarity_asymmetry) change the voltage a model is driven with; output effects
// (back_relaxation, creep, hysteresis, sensor_drift) change the deflection it predicts.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/simulate.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::model {

// The catalogue. Each entry: its physical meaning, its residual signature and its model
// are documented at the definition (effects.cc) and printed by EffectDescription.
enum class EffectKind {
  kBackRelaxation,          // slow relaxation opposing the response under sustained voltage
  kCreep,                   // slow further bending under sustained voltage (its opposite)
  kCycleDegradation,        // gain lost with transferred charge (cycles)
  kHysteresis,              // rate-independent, direction-dependent lag (play operator)
  kElectrolysisSaturation,  // response compressed above a voltage
  kDeadZone,                // no response below a threshold voltage
  kSensorDrift,             // baseline drifting independent of the input
  kPolarityAsymmetry,       // negative voltage acts with another gain
};

const char* EffectName(EffectKind kind);  // "back_relaxation", ...
bool ParseEffectName(const std::string& name, EffectKind* kind);
std::vector<EffectKind> AllEffects();
// One sentence: the physics, and how it shows in the residual.
const char* EffectDescription(EffectKind kind);

// One effect with its parameters (values in EffectParameterNames order).
struct Effect {
  EffectKind kind = EffectKind::kBackRelaxation;
  std::vector<double> params;
  // The scale of an effect that accrues over a recording, for cycle_degradation and
  // sensor_drift (EffectScaleName): the charge Q (V s) at which `loss` is reached, or the
  // time (s) over which drift_mm accrues. 0: the recording's own (its total charge, its
  // duration), which is what the diagnosis fits on. A model that predicts other recordings
  // and runs live needs a fixed one: the diagnosis writes the scale of the recordings it
  // fitted on into the augmentation.
  double scale = 0.0;
};
// Parameter names with units, e.g. {"fraction", "tau_s"}.
std::vector<std::string> EffectParameterNames(EffectKind kind);
// The name of an effect's scale in a model file's augmentation ("charge_Vs" for
// cycle_degradation, "span_s" for sensor_drift); nullptr for effects without one.
const char* EffectScaleName(EffectKind kind);

// What is wrong with an effect, in words ("back_relaxation: fraction must be [0, 1), not
// 1.3"), or "" when nothing is: its parameter count, each parameter finite and in the range
// where its model has a physical meaning (EffectDescription), a scale that is not negative.
std::string EffectProblem(const Effect& effect);

// Model-file augmentations ({"effect": NAME, "params": {NAME: value, ...}}) and effects;
// the scale, when the effect has one, is an optional parameter of its own name.
// Throws InputError naming the effect and the problem (unknown effect, a missing or
// non-finite parameter, one out of its range (EffectProblem), a scale that is not > 0).
Effect EffectFromAugmentation(const Augmentation& augmentation);
Augmentation AugmentationOf(const Effect& effect);
// Every augmentation of a model document as an effect; errors are prefixed with `source`
// (the file or record the document came from).
std::vector<Effect> EffectsOf(const ModelDocument& document, const std::string& source);

// True for effects that change the voltage the model is driven with.
bool IsInputEffect(EffectKind kind);
// True for input effects that scale the drive and leave the operating point alone: the
// model is scheduled on the voltage before them (SimulationOptions::premise_V). Wear
// (cycle_degradation) makes each applied volt bend the gel less, and a polarity asymmetry
// gives negative volts another gain; the state of the gel and its electrolyte that the
// rules stand for is still the applied voltage's.
bool IsGainEffect(EffectKind kind);
// An input effect applied to the voltage column (t_s the sample times, in s; *voltage_V in
// place). Output effects leave it alone.
void ApplyInputEffect(const Effect& effect, std::span<const double> t_s,
                      std::vector<double>* voltage_V);
// An output effect applied to the predicted deflection (in place, mm), from the first
// sample on as from rest. Input effects leave it alone.
void ApplyOutputEffect(const Effect& effect, std::span<const double> t_s,
                       std::vector<double>* deflection_mm);

// The scale an accruing effect takes on a recording when none is given (Effect::scale 0):
// for cycle_degradation the total charge sum |u_k| (t_{k+1} - t_k) of voltage_V (V s; 1 when
// 0), for sensor_drift the duration (s); 0 for effects without a scale.
double OwnScale(EffectKind kind, std::span<const double> t_s, std::span<const double> voltage_V);

// A model with its effects, sample by sample: the streaming form of SimulateAugmented
// (diagnose.h), what flexidd's predictor runs. Each Step is O(1) in the samples seen; fed
// a recording's samples in order it returns the batch prediction at each (the same
// arithmetic: input effects in order, the model, output effects in order). The first Step
// is the first sample: a relaxation or hysteresis state starts there as from rest, a
// degradation's charge and a drift's time count from there.
// Every effect must be complete (parameter count) and an accruing effect needs its scale
// (Effect::scale > 0): a live prediction has no recording whose total to take. Both are
// checked at construction (InputError naming the effect).
class AugmentedStreamingSimulator {
 public:
  AugmentedStreamingSimulator(const TsModel& model, std::vector<Effect> effects,
                              const SimulationOptions& options = {});
  // Preconditions as StreamingSimulator::Step: t_s increasing, both finite.
  double Step(double t_s, double voltage_V);
  const std::vector<double>& memberships() const { return simulator_.memberships(); }

 private:
  // One effect's state between samples.
  struct State {
    bool started = false;
    double t0_s = 0.0, last_t_s = 0.0;
    double last_in = 0.0;    // the effect's input at the previous sample (V or mm)
    double charge_Vs = 0.0;  // cycle_degradation: Q up to this sample
    double log_keep = 0.0;   // cycle_degradation: log(1 - loss), once for the effect
    double slow_mm = 0.0;    // back_relaxation, creep: the slow follower s
    double friction = 0.0;   // hysteresis: h
  };
  double StepInput(const Effect& effect, State* state, double t_s, double voltage_V) const;
  double StepOutput(const Effect& effect, State* state, double t_s, double deflection_mm) const;

  StreamingSimulator simulator_;
  std::vector<Effect> effects_;
  std::vector<State> states_;
};

}  // namespace flexid::model
