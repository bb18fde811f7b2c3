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
};
// Parameter names with units, e.g. {"fraction", "tau_s"}.
std::vector<std::string> EffectParameterNames(EffectKind kind);

// Model-file augmentations ({"effect": NAME, "params": {NAME: value, ...}}) and effects.
// Throws InputError naming the effect and the problem (unknown effect, a missing or
// non-finite parameter).
Effect EffectFromAugmentation(const Augmentation& augmentation);
Augmentation AugmentationOf(const Effect& effect);
// Every augmentation of a model document as an effect; errors are prefixed with `source`
// (the file or record the document came from).
std::vector<Effect> EffectsOf(const ModelDocument& document, const std::string& source);

// True for effects that change the voltage the model is driven with.
bool IsInputEffect(EffectKind kind);
// An input effect applied to the voltage column (t_s the sample times, in s; *voltage_V in
// place). Output effects leave it alone.
void ApplyInputEffect(const Effect& effect, std::span<const double> t_s,
                      std::vector<double>* voltage_V);
// An output effect applied to the predicted deflection (in place, mm), from the first
// sample on as from rest. Input effects leave it alone.
void ApplyOutputEffect(const Effect& effect, std::span<const double> t_s,
                       std::vector<double>* deflection_mm);

}  // namespace flexid::model
