#include "model/diagnose/effects.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "model/core/errors.h"

namespace flexid::model {
namespace {

// -----------------------------------------------------------------------------------------
// The catalogue
// -----------------------------------------------------------------------------------------

struct EffectInfo {
  EffectKind kind;
  const char* name;
  const char* description;
  std::vector<std::string> params;
  bool input_side;  // changes the voltage the model is driven with
};

const std::vector<EffectInfo>& Catalogue() {
  static const std::vector<EffectInfo> catalogue = {
      {EffectKind::kBackRelaxation,
       "back_relaxation",
       "Under a sustained voltage the gel bends, then slowly bends part of the way back as "
       "ions and solvent redistribute and relax the osmotic pressure difference; when the "
       "voltage is removed it overshoots past rest. Residual: falls during holds, turns "
       "negative after them, with one slow time constant. Model: y - fraction * s, "
       "tau_s s' = y - s (an extra slow pole-zero pair, gain scaled by 1 - fraction).",
       {"fraction", "tau_s"},
       false},
      {EffectKind::kCreep,
       "creep",
       "Under a sustained voltage the beam keeps bending slowly beyond the model's "
       "equilibrium (viscoelastic creep of the polymer network, slow swelling). Residual: "
       "grows during holds with one slow time constant, positive after them. Model: "
       "y + fraction * s, tau_s s' = y - s.",
       {"fraction", "tau_s"},
       false},
      {EffectKind::kCycleDegradation,
       "cycle_degradation",
       "Repeated actuation degrades the gel and the electrode interface (ion depletion, "
       "delamination), so each volt moves the beam less as charge is transferred. "
       "Residual: amplitude shrinks from cycle to cycle in proportion to the response. "
       "Model: drive voltage u (1 - loss)^(Q(t) / Q_end), Q = integral |u| dt.",
       {"loss"},
       true},
      {EffectKind::kHysteresis,
       "hysteresis",
       "Friction in the clamp and in the polymer network make the beam lag by a fixed "
       "amount whenever its motion reverses, whatever the rate. Residual: an offset against "
       "the direction of motion, switching over the first reach_mm of travel after each "
       "reversal, persisting in holds and at rest. Model: Dahl's friction model on the "
       "model's deflection y: dh/dy = (sign(dy) - h) / reach_mm, output y - width_mm h.",
       {"width_mm", "reach_mm"},
       false},
      {EffectKind::kElectrolysisSaturation,
       "electrolysis_saturation",
       "Above the electrolyte's decomposition voltage the extra voltage drives water "
       "electrolysis (gas, current) instead of ion migration into the gel, so deflection "
       "grows more slowly with voltage. Residual: negative at the high levels only, "
       "proportional to the voltage above the onset. Model: |u| above onset_V scaled by "
       "slope.",
       {"onset_V", "slope"},
       true},
      {EffectKind::kDeadZone,
       "dead_zone",
       "Below an onset voltage the electrochemistry does not start (or an electrostatic "
       "actuator does not zip), so small voltages move nothing. Residual: the response "
       "at every level is lower by the same voltage's worth, relatively most at low "
       "levels. Model: drive sign(u) max(|u| - threshold_V, 0).",
       {"threshold_V"},
       true},
      {EffectKind::kSensorDrift,
       "sensor_drift",
       "The displacement sensor's zero moves (thermal warm-up of the sensor or the bath, a "
       "creeping mount) independent of the actuator. Residual: a slow trend that continues "
       "at rest and does not follow the voltage; it starts at 0 (the recording is tared). "
       "Model: drift_mm x + warmup_mm (1 - exp(-t / warmup_tau_s)), x = time as a fraction "
       "of the recording.",
       {"drift_mm", "warmup_mm", "warmup_tau_s"},
       false},
      {EffectKind::kPolarityAsymmetry,
       "polarity_asymmetry",
       "Negative voltage moves the beam with another gain than positive (asymmetric "
       "electrodes, different mobile ions on either side). Residual: proportional to the "
       "response during negative voltage only. Model: u < 0 driven as ratio u.",
       {"ratio"},
       true},
  };
  return catalogue;
}

const EffectInfo& Entry(EffectKind kind) {
  for (const EffectInfo& info : Catalogue())
    if (info.kind == kind) return info;
  throw std::invalid_argument("unknown effect kind");
}

// -----------------------------------------------------------------------------------------
// Effect models
// -----------------------------------------------------------------------------------------

// tau s' = y - s with y linear between samples, solved exactly per step (first-order hold);
// s starts at y_0 (steady state).
std::vector<double> SlowFollower(std::span<const double> t_s, std::span<const double> y,
                                 double tau_s) {
  std::vector<double> s(y.size());
  if (y.empty()) return s;
  s[0] = y[0];
  for (size_t k = 0; k + 1 < y.size(); ++k) {
    const double r = (t_s[k + 1] - t_s[k]) / tau_s;
    const double a = std::exp(-r);
    const double ramp = r > 1e-8 ? 1.0 - (1.0 - a) / r : 0.5 * r;
    s[k + 1] = a * s[k] + (1.0 - a) * y[k] + ramp * (y[k + 1] - y[k]);
  }
  return s;
}

}  // namespace

void ApplyInputEffect(const Effect& e, std::span<const double> t_s,
                      std::vector<double>* voltage_V) {
  std::vector<double>& u = *voltage_V;
  switch (e.kind) {
    case EffectKind::kCycleDegradation: {
      // Q(t_k) = sum_{j<k} |u_j| (t_{j+1} - t_j): the charge proxy up to the sample.
      std::vector<double> q(u.size(), 0.0);
      for (size_t k = 1; k < u.size(); ++k)
        q[k] = q[k - 1] + std::abs(u[k - 1]) * (t_s[k] - t_s[k - 1]);
      const double total = q.back() > 0 ? q.back() : 1.0;
      const double log_keep = std::log(std::max(1e-9, 1.0 - e.params[0]));
      for (size_t k = 0; k < u.size(); ++k) u[k] *= std::exp(log_keep * q[k] / total);
      break;
    }
    case EffectKind::kElectrolysisSaturation: {
      const double onset = e.params[0], slope = e.params[1];
      for (double& v : u) {
        const double a = std::abs(v);
        if (a > onset) v = std::copysign(onset + slope * (a - onset), v);
      }
      break;
    }
    case EffectKind::kDeadZone:
      for (double& v : u) v = std::copysign(std::max(std::abs(v) - e.params[0], 0.0), v);
      break;
    case EffectKind::kPolarityAsymmetry:
      for (double& v : u)
        if (v < 0) v *= e.params[0];
      break;
    default:
      break;
  }
}

void ApplyOutputEffect(const Effect& e, std::span<const double> t_s, std::vector<double>* y_mm) {
  std::vector<double>& y = *y_mm;
  const std::vector<double> base = e.kind == EffectKind::kHysteresis ? y : std::vector<double>{};
  switch (e.kind) {
    case EffectKind::kBackRelaxation:
    case EffectKind::kCreep: {
      const std::vector<double> s = SlowFollower(t_s, y, e.params[1]);
      const double sign = e.kind == EffectKind::kBackRelaxation ? -1.0 : 1.0;
      for (size_t k = 0; k < y.size(); ++k) y[k] += sign * e.params[0] * s[k];
      break;
    }
    case EffectKind::kHysteresis: {
      // Dahl's friction model, rate-independent: the friction state h moves towards the
      // direction of motion exponentially in the distance travelled, over reach_mm;
      // the beam lags by width_mm h.
      const double width = e.params[0], reach = std::max(std::abs(e.params[1]), 1e-9);
      double h = 0.0;
      for (size_t k = 1; k < y.size(); ++k) {
        const double dy = y[k] - base[k - 1];
        if (dy != 0.0) {
          const double target = dy > 0 ? 1.0 : -1.0;
          h = target + (h - target) * std::exp(-std::abs(dy) / reach);
        }
        y[k] = base[k] - width * h;
      }
      break;
    }
    case EffectKind::kSensorDrift: {
      const double t0 = t_s.front(), span = std::max(t_s.back() - t0, 1e-12);
      for (size_t k = 0; k < y.size(); ++k) {
        const double x = (t_s[k] - t0) / span;
        y[k] += e.params[0] * x +
                e.params[1] * (1.0 - std::exp(-(t_s[k] - t0) / std::max(e.params[2], 1e-9)));
      }
      break;
    }
    default:
      break;
  }
}

// -----------------------------------------------------------------------------------------
// Public catalogue functions
// -----------------------------------------------------------------------------------------

const char* EffectName(EffectKind kind) { return Entry(kind).name; }

bool ParseEffectName(const std::string& name, EffectKind* kind) {
  for (const EffectInfo& info : Catalogue())
    if (name == info.name) {
      *kind = info.kind;
      return true;
    }
  return false;
}

std::vector<EffectKind> AllEffects() {
  std::vector<EffectKind> kinds;
  for (const EffectInfo& info : Catalogue()) kinds.push_back(info.kind);
  return kinds;
}

const char* EffectDescription(EffectKind kind) { return Entry(kind).description; }

std::vector<std::string> EffectParameterNames(EffectKind kind) { return Entry(kind).params; }

Effect EffectFromAugmentation(const Augmentation& augmentation) {
  Effect effect;
  if (!ParseEffectName(augmentation.effect, &effect.kind))
    throw InputError("augmentation \"" + augmentation.effect + "\": unknown effect");
  for (const std::string& name : Entry(effect.kind).params) {
    const auto it = augmentation.params.find(name);
    if (it == augmentation.params.end() || !it->is_number() || !std::isfinite(it->get<double>()))
      throw InputError("augmentation \"" + augmentation.effect + "\": parameter " + name +
                       " must be a finite number");
    effect.params.push_back(it->get<double>());
  }
  return effect;
}

std::vector<Effect> EffectsOf(const ModelDocument& document, const std::string& source) {
  std::vector<Effect> effects;
  for (const Augmentation& a : document.augmentations) {
    try {
      effects.push_back(EffectFromAugmentation(a));
    } catch (const InputError& e) {
      throw InputError(source + ": " + e.what());
    }
  }
  return effects;
}

Augmentation AugmentationOf(const Effect& effect) {
  Augmentation a;
  a.effect = EffectName(effect.kind);
  for (size_t i = 0; i < effect.params.size(); ++i)
    a.params[Entry(effect.kind).params[i]] = effect.params[i];
  return a;
}

bool IsInputEffect(EffectKind kind) { return Entry(kind).input_side; }

}  // namespace flexid::model
