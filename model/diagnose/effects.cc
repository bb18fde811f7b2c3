#include "model/diagnose/effects.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "model/core/errors.h"

namespace flexid::model {
namespace {

// -----------------------------------------------------------------------------------------
// The catalogue
// -----------------------------------------------------------------------------------------

// Where a parameter has a physical meaning: [lower, upper], either end open.
struct Range {
  double lower = -std::numeric_limits<double>::infinity();
  double upper = std::numeric_limits<double>::infinity();
  bool lower_open = false, upper_open = false;
  bool Holds(double v) const {
    return (lower_open ? v > lower : v >= lower) && (upper_open ? v < upper : v <= upper);
  }
  std::string Text() const;
};
constexpr double kNoLimit = std::numeric_limits<double>::infinity();
const Range kAny{};
const Range kPositive{0.0, kNoLimit, true, true};
const Range kNonNegative{0.0, kNoLimit, false, true};
const Range kFraction{0.0, 1.0, false, true};  // [0, 1)

std::string Range::Text() const {
  auto number = [](double v) {
    char text[32];
    std::snprintf(text, sizeof text, "%g", v);
    return std::string(text);
  };
  if (upper == kNoLimit) return std::string(lower_open ? "> " : ">= ") + number(lower);
  return (lower_open ? "(" : "[") + number(lower) + ", " + number(upper) + (upper_open ? ")" : "]");
}

// What an effect changes: the deflection the model predicts, the voltage the model is driven
// with and scheduled on, or the drive alone (a gain: the operating point stays the applied
// voltage's, SimulationOptions::premise_V).
enum class Acts { kOnDeflection, kOnVoltage, kOnDrive };

struct EffectInfo {
  EffectKind kind;
  const char* name;
  const char* description;
  std::vector<std::string> params;
  Acts acts;
  std::vector<Range> ranges;         // of each parameter, where its model means something
  const char* scale_name = nullptr;  // Effect::scale in a model file, if it has one
  // A trailing parameter a model file may leave out, and its value then: one added to an
  // effect after files were written with it, whose value here gives the earlier model.
  const char* optional_param = nullptr;
  double optional_default = 0.0;
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
       Acts::kOnDeflection,
       {kFraction, kPositive}},
      {EffectKind::kCreep,
       "creep",
       "Under a sustained voltage the beam keeps bending slowly beyond the model's "
       "equilibrium (viscoelastic creep of the polymer network, slow swelling). Residual: "
       "grows during holds with one slow time constant, positive after them. Model: "
       "y + fraction * s, tau_s s' = y - s.",
       {"fraction", "tau_s"},
       Acts::kOnDeflection,
       {kNonNegative, kPositive}},
      {EffectKind::kCycleDegradation,
       "cycle_degradation",
       "Repeated actuation degrades the gel and the electrode interface (ion depletion, "
       "delamination), so each volt moves the beam less as charge is transferred. "
       "Residual: amplitude shrinks from cycle to cycle in proportion to the response. "
       "Model: drive voltage u (1 - loss)^((Q(t) / Q_end)^exponent), Q = integral |u| dt, "
       "the operating point still the applied voltage's; exponent 1 loses at a steady "
       "rate per charge, below 1 fastest at first (wear limited by diffusion).",
       {"loss", "exponent"},
       Acts::kOnDrive,
       {kFraction, kPositive},
       "charge_Vs",
       "exponent",
       1.0},
      {EffectKind::kHysteresis,
       "hysteresis",
       "Friction in the clamp and in the polymer network make the beam lag by a fixed "
       "amount whenever its motion reverses, whatever the rate. Residual: an offset against "
       "the direction of motion, switching over the first reach_mm of travel after each "
       "reversal, persisting in holds and at rest. Model: Dahl's friction model on the "
       "model's deflection y: dh/dy = (sign(dy) - h) / reach_mm, output y - width_mm h.",
       {"width_mm", "reach_mm"},
       Acts::kOnDeflection,
       {kNonNegative, kPositive}},
      {EffectKind::kElectrolysisSaturation,
       "electrolysis_saturation",
       "Above the electrolyte's decomposition voltage the extra voltage drives water "
       "electrolysis (gas, current) instead of ion migration into the gel, so deflection "
       "grows more slowly with voltage. Residual: negative at the high levels only, "
       "proportional to the voltage above the onset. Model: |u| above onset_V scaled by "
       "slope.",
       {"onset_V", "slope"},
       Acts::kOnVoltage,
       {kNonNegative, Range{0.0, 1.0}}},
      {EffectKind::kDeadZone,
       "dead_zone",
       "Below an onset voltage the electrochemistry does not start (or an electrostatic "
       "actuator does not zip), so small voltages move nothing. Residual: the response "
       "at every level is lower by the same voltage's worth, relatively most at low "
       "levels. Model: drive sign(u) max(|u| - threshold_V, 0).",
       {"threshold_V"},
       Acts::kOnVoltage,
       {kNonNegative}},
      {EffectKind::kSensorDrift,
       "sensor_drift",
       "The displacement sensor's zero moves (thermal warm-up of the sensor or the bath, a "
       "creeping mount) independent of the actuator. Residual: a slow trend that continues "
       "at rest and does not follow the voltage; it starts at 0 (the recording is tared). "
       "Model: drift_mm x + warmup_mm (1 - exp(-t / warmup_tau_s)), x = time as a fraction "
       "of the recording.",
       {"drift_mm", "warmup_mm", "warmup_tau_s"},
       Acts::kOnDeflection,
       {kAny, kAny, kPositive},
       "span_s"},
      {EffectKind::kPolarityAsymmetry,
       "polarity_asymmetry",
       "Negative voltage moves the beam with another gain than positive (asymmetric "
       "electrodes, different mobile ions on either side). Residual: proportional to the "
       "response during negative voltage only. Model: u < 0 driven as ratio u, the operating "
       "point still the applied voltage's.",
       {"ratio"},
       Acts::kOnDrive,
       {kPositive}},
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

// One step of tau s' = y - s with y linear between the samples y_prev and y, dt_s apart,
// solved exactly (first-order hold).
double FollowerStep(double s, double y_prev, double y, double dt_s, double tau_s) {
  const double r = dt_s / tau_s;
  const double a = std::exp(-r);
  const double ramp = r > 1e-8 ? 1.0 - (1.0 - a) / r : 0.5 * r;
  return a * s + (1.0 - a) * y_prev + ramp * (y - y_prev);
}

// The slow follower s over a series; s starts at y_0 (steady state).
std::vector<double> SlowFollower(std::span<const double> t_s, std::span<const double> y,
                                 double tau_s) {
  std::vector<double> s(y.size());
  if (y.empty()) return s;
  s[0] = y[0];
  for (size_t k = 0; k + 1 < y.size(); ++k)
    s[k + 1] = FollowerStep(s[k], y[k], y[k + 1], t_s[k + 1] - t_s[k], tau_s);
  return s;
}

// Dahl's friction state after the model's deflection moved by dy_mm: it moves towards the
// direction of motion exponentially in the distance travelled, over reach_mm.
double FrictionStep(double h, double dy_mm, double reach_mm) {
  if (dy_mm == 0.0) return h;
  const double target = dy_mm > 0 ? 1.0 : -1.0;
  return target + (h - target) * std::exp(-std::abs(dy_mm) / std::max(std::abs(reach_mm), 1e-9));
}

// The sensor's drift elapsed_s after the first sample, over a span of span_s.
double DriftAt(const Effect& e, double elapsed_s, double span_s) {
  return e.params[0] * (elapsed_s / span_s) +
         e.params[1] * (1.0 - std::exp(-elapsed_s / std::max(e.params[2], 1e-9)));
}

// The voltage an effect without memory drives the model with (dead zone, saturation,
// polarity); the others pass it through.
double MemorylessInput(const Effect& e, double v) {
  switch (e.kind) {
    case EffectKind::kElectrolysisSaturation: {
      const double onset = e.params[0], slope = e.params[1], a = std::abs(v);
      return a > onset ? std::copysign(onset + slope * (a - onset), v) : v;
    }
    case EffectKind::kDeadZone:
      return std::copysign(std::max(std::abs(v) - e.params[0], 0.0), v);
    case EffectKind::kPolarityAsymmetry:
      return v < 0 ? v * e.params[0] : v;
    default:
      return v;
  }
}

// cycle_degradation's gain at charge q_Vs, (1 - loss)^((q / scale)^exponent), with
// log(1 - loss) taken once for a series; no pow at exponent 1 (the steady law).
struct Degradation {
  explicit Degradation(const Effect& e)
      : log_keep(std::log(std::max(1e-9, 1.0 - e.params[0]))), exponent(e.params[1]) {}
  Degradation(double log_keep_in, double exponent_in)
      : log_keep(log_keep_in), exponent(exponent_in) {}
  double Gain(double q_Vs, double scale_Vs) const {
    const double x = q_Vs / scale_Vs;
    return std::exp(log_keep * (exponent == 1.0 ? x : std::pow(x, exponent)));
  }
  double log_keep, exponent;
};

}  // namespace

void ApplyInputEffect(const Effect& e, std::span<const double> t_s,
                      std::vector<double>* voltage_V) {
  std::vector<double>& u = *voltage_V;
  if (e.kind != EffectKind::kCycleDegradation) {
    for (double& v : u) v = MemorylessInput(e, v);
    return;
  }
  if (u.empty()) return;
  // Q(t_k) = sum_{j<k} |u_j| (t_{j+1} - t_j): the charge proxy up to the sample.
  std::vector<double> q(u.size(), 0.0);
  for (size_t k = 1; k < u.size(); ++k)
    q[k] = q[k - 1] + std::abs(u[k - 1]) * (t_s[k] - t_s[k - 1]);
  const double scale = e.scale > 0 ? e.scale : q.back() > 0 ? q.back() : 1.0;  // = OwnScale
  const Degradation degradation(e);
  for (size_t k = 0; k < u.size(); ++k) u[k] *= degradation.Gain(q[k], scale);
}

double OwnScale(EffectKind kind, std::span<const double> t_s, std::span<const double> voltage_V) {
  if (t_s.empty()) return 0.0;
  if (kind == EffectKind::kSensorDrift) return std::max(t_s.back() - t_s.front(), 1e-12);
  if (kind != EffectKind::kCycleDegradation) return 0.0;
  double q = 0.0;
  for (size_t k = 1; k < t_s.size(); ++k) q += std::abs(voltage_V[k - 1]) * (t_s[k] - t_s[k - 1]);
  return q > 0 ? q : 1.0;
}

void ApplyOutputEffect(const Effect& e, std::span<const double> t_s, std::vector<double>* y_mm) {
  std::vector<double>& y = *y_mm;
  switch (e.kind) {
    case EffectKind::kBackRelaxation:
    case EffectKind::kCreep: {
      const std::vector<double> s = SlowFollower(t_s, y, e.params[1]);
      const double sign = e.kind == EffectKind::kBackRelaxation ? -1.0 : 1.0;
      for (size_t k = 0; k < y.size(); ++k) y[k] += sign * e.params[0] * s[k];
      break;
    }
    case EffectKind::kHysteresis: {
      // Dahl's friction model, rate-independent: the beam lags by width_mm h.
      const std::vector<double> base = y;
      double h = 0.0;
      for (size_t k = 1; k < y.size(); ++k) {
        h = FrictionStep(h, base[k] - base[k - 1], e.params[1]);
        y[k] = base[k] - e.params[0] * h;
      }
      break;
    }
    case EffectKind::kSensorDrift: {
      if (y.empty()) break;
      const double t0 = t_s.front();
      const double span = e.scale > 0 ? e.scale : std::max(t_s.back() - t0, 1e-12);
      for (size_t k = 0; k < y.size(); ++k) y[k] += DriftAt(e, t_s[k] - t0, span);
      break;
    }
    default:
      break;
  }
}

// -----------------------------------------------------------------------------------------
// Streaming
// -----------------------------------------------------------------------------------------

AugmentedStreamingSimulator::AugmentedStreamingSimulator(const TsModel& model,
                                                         std::vector<Effect> effects,
                                                         const SimulationOptions& options)
    : simulator_(model, options), effects_(std::move(effects)), states_(effects_.size()) {
  for (const Effect& e : effects_) {
    const std::string name = EffectName(e.kind);
    if (const std::string problem = EffectProblem(e); !problem.empty())
      throw InputError("effect " + problem);
    if (EffectScaleName(e.kind) && !(e.scale > 0))
      throw InputError("effect " + name + ": a live prediction needs its " +
                       EffectScaleName(e.kind) + " (> 0; flexid diagnose writes it)");
  }
  for (size_t i = 0; i < effects_.size(); ++i)
    if (effects_[i].kind == EffectKind::kCycleDegradation)
      states_[i].log_keep = Degradation(effects_[i]).log_keep;
}

double AugmentedStreamingSimulator::StepInput(const Effect& e, State* state, double t_s,
                                              double voltage_V) const {
  if (e.kind != EffectKind::kCycleDegradation) return MemorylessInput(e, voltage_V);
  if (state->started) state->charge_Vs += std::abs(state->last_in) * (t_s - state->last_t_s);
  state->started = true;
  state->last_in = voltage_V;
  state->last_t_s = t_s;
  return voltage_V * Degradation(state->log_keep, e.params[1]).Gain(state->charge_Vs, e.scale);
}

double AugmentedStreamingSimulator::StepOutput(const Effect& e, State* state, double t_s,
                                               double y) const {
  const bool first = !state->started;
  if (first) {
    state->started = true;
    state->t0_s = t_s;
    state->slow_mm = y;
  }
  double out = y;
  switch (e.kind) {
    case EffectKind::kBackRelaxation:
    case EffectKind::kCreep:
      if (!first)
        state->slow_mm =
            FollowerStep(state->slow_mm, state->last_in, y, t_s - state->last_t_s, e.params[1]);
      out = y + (e.kind == EffectKind::kBackRelaxation ? -1.0 : 1.0) * e.params[0] * state->slow_mm;
      break;
    case EffectKind::kHysteresis:
      if (!first) state->friction = FrictionStep(state->friction, y - state->last_in, e.params[1]);
      out = y - e.params[0] * state->friction;
      break;
    case EffectKind::kSensorDrift:
      out = y + DriftAt(e, t_s - state->t0_s, e.scale);
      break;
    default:
      break;
  }
  state->last_in = y;
  state->last_t_s = t_s;
  return out;
}

double AugmentedStreamingSimulator::Step(double t_s, double voltage_V) {
  // As Predict (diagnose_fit.cc): a gain effect scales the drive u, not the premise p.
  double u = voltage_V, p = voltage_V;
  for (size_t i = 0; i < effects_.size(); ++i) {
    const Effect& e = effects_[i];
    if (!IsInputEffect(e.kind)) continue;
    if (!IsGainEffect(e.kind)) p = MemorylessInput(e, p);
    u = StepInput(e, &states_[i], t_s, u);
  }
  double y = simulator_.Step(t_s, u, p);
  for (size_t i = 0; i < effects_.size(); ++i)
    if (!IsInputEffect(effects_[i].kind)) y = StepOutput(effects_[i], &states_[i], t_s, y);
  return y;
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

const char* EffectScaleName(EffectKind kind) { return Entry(kind).scale_name; }

std::string EffectProblem(const Effect& effect) {
  const EffectInfo& info = Entry(effect.kind);
  if (effect.params.size() != info.params.size())
    return std::string(info.name) + " needs " + std::to_string(info.params.size()) +
           " parameters, not " + std::to_string(effect.params.size());
  for (size_t i = 0; i < info.params.size(); ++i) {
    char value[32];
    std::snprintf(value, sizeof value, "%g", effect.params[i]);
    if (!std::isfinite(effect.params[i]) || !info.ranges[i].Holds(effect.params[i]))
      return std::string(info.name) + ": " + info.params[i] + " must be " + info.ranges[i].Text() +
             ", not " + value;
  }
  if (info.scale_name && (effect.scale < 0 || !std::isfinite(effect.scale)))
    return std::string(info.name) + ": " + info.scale_name + " must be > 0";
  return "";
}

Effect EffectFromAugmentation(const Augmentation& augmentation) {
  Effect effect;
  if (!ParseEffectName(augmentation.effect, &effect.kind))
    throw InputError("augmentation \"" + augmentation.effect + "\": unknown effect");
  const EffectInfo& info = Entry(effect.kind);
  for (const std::string& name : info.params) {
    const auto it = augmentation.params.find(name);
    if (it == augmentation.params.end() && info.optional_param && name == info.optional_param) {
      effect.params.push_back(info.optional_default);
      continue;
    }
    if (it == augmentation.params.end() || !it->is_number() || !std::isfinite(it->get<double>()))
      throw InputError("augmentation \"" + augmentation.effect + "\": parameter " + name +
                       " must be a finite number");
    effect.params.push_back(it->get<double>());
  }
  if (const char* scale = EffectScaleName(effect.kind)) {
    const auto it = augmentation.params.find(scale);
    if (it != augmentation.params.end()) {
      if (!it->is_number() || !(it->get<double>() > 0) || !std::isfinite(it->get<double>()))
        throw InputError("augmentation \"" + augmentation.effect + "\": " + scale +
                         " must be a finite number > 0");
      effect.scale = it->get<double>();
    }
  }
  if (const std::string problem = EffectProblem(effect); !problem.empty())
    throw InputError("augmentation " + problem);
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
  if (const char* scale = EffectScaleName(effect.kind); scale && effect.scale > 0)
    a.params[scale] = effect.scale;
  return a;
}

bool IsInputEffect(EffectKind kind) { return Entry(kind).acts != Acts::kOnDeflection; }

bool IsGainEffect(EffectKind kind) { return Entry(kind).acts == Acts::kOnDrive; }

}  // namespace flexid::model
