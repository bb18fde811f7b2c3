// An independent "lab" for tests of the mismatch diagnosis (model/diagnose/diagnose.h): a
// continuous-time plant driven by a continuous voltage waveform, with the catalogue's
// effects formulated as physics in continuous time, integrated by fixed-step RK4 and
// sampled the way the lab samples its voltage column and its deflection sensor.
//
// Independent of model/: only the TransferFunction and Recording structs are used. The
// waveform, the integrator, the effects and the noise are written here, and the effects
// are deliberately formulated otherwise than a diagnosis would model them (Bouc-Wen
// instead of a play operator, charge-driven exponential wear, tanh compression, softplus
// dead zone, warm-up plus linear drift), so that a diagnosis is tested on physics it was
// not written from.
//
// Notation (times in s, voltages in V, deflections in mm):
//   w(t)    applied voltage: piecewise-constant targets L_k from t_k on (t_k off the
//           sample grid), each approached with a first-order slew w' = (L_k - w) / tau_w
//           (tau_w = 20-50 ms); w = 0 before the first step.
//   T       dead time; the plant sees v(t) = w(t - T) (T need not be a whole number of
//           sample periods, nor of integration steps: the integrator breaks at t_k + T).
//   Plant   G(s) = num(s) / den(s), strictly proper, in controllable canonical form
//           x' = A x + B u_in,  y_p = C x;  K = G(0) its DC gain (mm/V).
//   Effects, each scaled by an amplitude a (a = 0 is the plant alone, exactly):
//     back_relaxation          r' = (a K v - r) / tau_r,        y = y_p - r
//     creep                    r' = (a K v - r) / tau_r,        y = y_p + r
//     cycle_degradation        Q' = |v|,  u_in = v exp(-a Q)    (a = 1/Q0, 1/(V s))
//     hysteresis               Bouc-Wen, n = 1, on the plant output (rate-independent):
//                              h' = (y_p' / x0) (1 - (beta sgn(y_p' h) + gamma) |h|),
//                              beta = 0.75, gamma = 0.25 (so |h| <= 1),
//                              y = y_p - a h                    (a in mm; a lag: below
//                              the plant while rising, a remanent deflection at rest)
//     electrolysis_saturation  |u_in| = V_s + tanh(a (|v| - V_s)) / a  for |v| > V_s,
//                              |u_in| = |v| below               (a = 1/width, 1/V)
//     dead_zone                u_in = sp(v - a) - sp(-v - a),  sp(x) = e ln(1 + e^{x/e}),
//                              e = 10 mV                        (a = threshold, V)
//     sensor_drift             y = y_p + a (s (1 - e^{-t/tau_d}) + (1 - s) t / t_lin)
//                              (a in mm; no dependence on the input)
//     polarity_asymmetry       u_in = v for v >= 0, (1 - a) v for v < 0
//   Sampling: t_k = k Ts (Ts = 0.1 s); voltage column w(t_k) + N(0, (1 mV)^2);
//   deflection y(t_k) + N(0, sigma^2). Noise: std::mt19937_64 and Box-Muller, so the same
//   seed gives the same recording with every standard library.
//
// Effect size (the acceptance criteria's "effect-to-noise ratio"): with d_k the noise-free
// output with the effect minus without it, the samples the effect touches are those with
// |d_k| > 5 % of max |d_k|, and the ratio is RMS(d over them) / sigma.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>
#include <variant>
#include <vector>

#include "model/core/recording.h"
#include "model/core/transfer_function.h"

namespace flexid::testing {

// ---------------------------------------------------------------------------------------
// Random numbers: std::mt19937_64 (sequence fixed by the standard) and Box-Muller.
class LabRandom {
 public:
  explicit LabRandom(uint64_t seed) : engine_(seed) {}
  // Uniform on the open interval (0, 1).
  double Uniform() { return (static_cast<double>(engine_() >> 11) + 0.5) * 0x1.0p-53; }
  double Uniform(double low, double high) { return low + (high - low) * Uniform(); }
  double LogUniform(double low, double high) {
    return std::exp(Uniform(std::log(low), std::log(high)));
  }
  double Normal() {
    const double radius = std::sqrt(-2.0 * std::log(Uniform()));
    return radius * std::cos(2.0 * std::numbers::pi * Uniform());
  }

 private:
  std::mt19937_64 engine_;
};

// ---------------------------------------------------------------------------------------
// Plants.

// The seed's 8 V model (Eq. 18, upper ends), written out here rather than taken from
// model/presets so that the lab does not depend on model/.
inline model::TransferFunction LabSeedPlant8V() {
  return {{0.0085, 0.842, 1.924, 1.97}, {1.0, 0.5898, 367.2, 29.41, 0.2275}, 3.67};
}

// A physics-like plant: 4 real poles (-0.0087, -0.07, -0.5, -3 rad/s) interlaced with 3
// real zeros (-0.02, -0.2, -1.2 rad/s), 0 < p1 < z1 < p2 < z2 < p3 < z3 < p4. Interlacing
// makes every residue of G(s) positive, so the impulse response is a sum of decaying
// exponentials with positive weights and the step response rises monotonically (no
// overshoot, no fall-back). DC gain 1.5 mm/V; dead time 1.2 s (MakeRun can add a random
// fraction of a sample period).
inline model::TransferFunction LabPhysicsPlant() {
  const std::array<double, 4> poles = {0.0087, 0.07, 0.5, 3.0};
  const std::array<double, 3> zeros = {0.02, 0.2, 1.2};
  auto expand = [](const auto& roots) {  // prod (s + root), highest power first
    std::vector<double> poly = {1.0};
    for (double root : roots) {
      std::vector<double> next(poly.size() + 1, 0.0);
      for (size_t i = 0; i < poly.size(); ++i) {
        next[i] += poly[i];
        next[i + 1] += root * poly[i];
      }
      poly = next;
    }
    return poly;
  };
  std::vector<double> num = expand(zeros);
  const std::vector<double> den = expand(poles);
  const double gain = 1.5 * den.back() / num.back();
  for (double& c : num) c *= gain;
  return {num, den, 1.2};
}

// ---------------------------------------------------------------------------------------
// Voltage waveform.

struct VoltageStep {
  double t_s = 0.0;      // when the target changes
  double level_V = 0.0;  // the new target
};

// w(t): 0 V before the first step; from steps[j].t_s on, a first-order approach to
// steps[j].level_V with time constant slew_tau_s (0: an ideal jump). "Piece" p = 0 is
// before the first step, p = j + 1 starts at steps[j].
class Waveform {
 public:
  Waveform() = default;
  Waveform(std::vector<VoltageStep> steps, double slew_tau_s)
      : steps_(std::move(steps)), slew_tau_s_(slew_tau_s) {
    double previous_t_s = -INFINITY, value_V = 0.0, target_V = 0.0;
    for (const VoltageStep& step : steps_) {
      if (!(step.t_s > previous_t_s))
        throw std::invalid_argument("Waveform: step times must increase");
      if (previous_t_s > -INFINITY) value_V = Approach(value_V, target_V, step.t_s - previous_t_s);
      start_V_.push_back(value_V);
      previous_t_s = step.t_s;
      target_V = step.level_V;
    }
  }

  // The piece that holds time t (right-continuous at the steps).
  size_t PieceAt(double t_s) const {
    return static_cast<size_t>(
        std::upper_bound(steps_.begin(), steps_.end(), t_s,
                         [](double t, const VoltageStep& step) { return t < step.t_s; }) -
        steps_.begin());
  }
  // w(t) evaluated with the formula of the given piece (the integrator fixes the piece
  // for a whole integration interval, so a step that falls on an interval boundary is
  // never evaluated from the wrong side through rounding).
  double InPiece(size_t piece, double t_s) const {
    if (piece == 0) return 0.0;
    const VoltageStep& step = steps_[piece - 1];
    return Approach(start_V_[piece - 1], step.level_V, t_s - step.t_s);
  }
  double operator()(double t_s) const { return InPiece(PieceAt(t_s), t_s); }

  const std::vector<VoltageStep>& steps() const { return steps_; }
  double slew_tau_s() const { return slew_tau_s_; }

 private:
  // First-order slew from start_V towards target_V, elapsed_s after the step.
  double Approach(double start_V, double target_V, double elapsed_s) const {
    elapsed_s = std::max(elapsed_s, 0.0);
    if (slew_tau_s_ <= 0.0 || elapsed_s > 40.0 * slew_tau_s_) return target_V;
    return target_V + (start_V - target_V) * std::exp(-elapsed_s / slew_tau_s_);
  }

  std::vector<VoltageStep> steps_;
  std::vector<double> start_V_;  // w at the instant each step starts
  double slew_tau_s_ = 0.0;
};

// ---------------------------------------------------------------------------------------
// Protocols.

// cycles x (level for duty * period, then 0 V); with alternate, every second cycle is
// negative (+, -, +, ...). Starts after the lead-in; ends with the last cycle's 0 V part.
struct SquareWave {
  double level_V = 5.0;
  double period_s = 220.0;
  double duty = 0.5;
  int cycles = 5;
  bool alternate = false;
};

// Up the staircase (each level for dwell_s), then rest_s at 0 V.
struct Staircase {
  std::vector<double> levels_V = {2.0, 4.0, 6.0, 8.0};
  double dwell_s = 150.0;
  double rest_s = 150.0;
};

using Protocol = std::variant<SquareWave, Staircase>;

inline std::string ProtocolName(const Protocol& protocol) {
  if (const auto* square = std::get_if<SquareWave>(&protocol))
    return square->alternate ? "square+-" : "square";
  return "staircase";
}

// Steps of the protocol starting at start_s; *end_s receives the end of the protocol.
inline std::vector<VoltageStep> ProtocolSteps(const Protocol& protocol, double start_s,
                                              double* end_s) {
  std::vector<VoltageStep> steps;
  if (const auto* square = std::get_if<SquareWave>(&protocol)) {
    for (int c = 0; c < square->cycles; ++c) {
      const double sign = square->alternate && c % 2 == 1 ? -1.0 : 1.0;
      const double on_s = start_s + c * square->period_s;
      steps.push_back({on_s, sign * square->level_V});
      steps.push_back({on_s + square->duty * square->period_s, 0.0});
    }
    *end_s = start_s + square->cycles * square->period_s;
  } else {
    const auto& stairs = std::get<Staircase>(protocol);
    double t_s = start_s;
    for (double level_V : stairs.levels_V) {
      steps.push_back({t_s, level_V});
      t_s += stairs.dwell_s;
    }
    steps.push_back({t_s, 0.0});
    *end_s = t_s + stairs.rest_s;
  }
  return steps;
}

// ---------------------------------------------------------------------------------------
// Effects.

enum class LabEffect {
  kNone,
  kBackRelaxation,
  kCreep,
  kCycleDegradation,
  kHysteresis,
  kElectrolysisSaturation,
  kDeadZone,
  kSensorDrift,
  kPolarityAsymmetry,
};

// The diagnosis catalogue's names (model/diagnose/diagnose.h EffectName), "none" for kNone.
inline const char* LabEffectName(LabEffect effect) {
  switch (effect) {
    case LabEffect::kNone:
      return "none";
    case LabEffect::kBackRelaxation:
      return "back_relaxation";
    case LabEffect::kCreep:
      return "creep";
    case LabEffect::kCycleDegradation:
      return "cycle_degradation";
    case LabEffect::kHysteresis:
      return "hysteresis";
    case LabEffect::kElectrolysisSaturation:
      return "electrolysis_saturation";
    case LabEffect::kDeadZone:
      return "dead_zone";
    case LabEffect::kSensorDrift:
      return "sensor_drift";
    case LabEffect::kPolarityAsymmetry:
      return "polarity_asymmetry";
  }
  return "?";
}

// The catalogue, in model/diagnose/diagnose.h's order.
inline std::vector<LabEffect> LabCatalogue() {
  return {LabEffect::kBackRelaxation,
          LabEffect::kCreep,
          LabEffect::kCycleDegradation,
          LabEffect::kHysteresis,
          LabEffect::kElectrolysisSaturation,
          LabEffect::kDeadZone,
          LabEffect::kSensorDrift,
          LabEffect::kPolarityAsymmetry};
}

// One effect and its shape. `amplitude` scales it (units in the file header); the other
// fields fix its shape and are drawn per recording by MakeRun.
struct LabEffectSettings {
  LabEffect kind = LabEffect::kNone;
  double amplitude = 0.0;
  double relaxation_tau_s = 120.0;      // back_relaxation, creep: tau_r
  double hysteresis_reach_mm = 2.0;     // hysteresis: x0, output travel to saturate h
  double saturation_onset_V = 5.0;      // electrolysis_saturation: V_s
  double dead_zone_smoothing_V = 0.01;  // dead_zone: e
  double drift_warmup_tau_s = 200.0;    // sensor_drift: tau_d
  double drift_warmup_share = 0.6;      // sensor_drift: s
  double drift_linear_time_s = 1000.0;  // sensor_drift: t_lin
};

// Everything about one recording except its noise draws (those come from noise_seed).
struct LabRun {
  Waveform waveform;
  double duration_s = 0.0;
  model::TransferFunction plant;  // plant.delay_s is the dead time T
  LabEffectSettings effect;
  double sample_period_s = 0.1;
  double noise_std_mm = 0.02;
  double voltage_noise_std_V = 1e-3;
  double max_step_s = 1e-3;  // RK4 step (upper bound; steps also break at t_k + T)
  uint64_t noise_seed = 0;
};

inline size_t SampleCount(const LabRun& run) {
  return static_cast<size_t>(std::floor(run.duration_s / run.sample_period_s + 1e-9)) + 1;
}

inline double PlantDcGain(const model::TransferFunction& tf) {
  return tf.num.back() / tf.den.back();
}

namespace lab_detail {

constexpr int kMaxOrder = 8;
constexpr int kStates = kMaxOrder + 3;  // plant, relaxation r, charge Q, Bouc-Wen h
using State = std::array<double, kStates>;

inline double SoftPlus(double x, double width) {
  return std::max(x, 0.0) + width * std::log1p(std::exp(-std::abs(x) / width));
}

// The voltage the plant is driven with, from the delayed applied voltage v and charge Q.
inline double PlantInput(const LabEffectSettings& effect, double v, double charge_Vs) {
  const double a = effect.amplitude;
  switch (effect.kind) {
    case LabEffect::kCycleDegradation:
      return v * std::exp(-a * charge_Vs);
    case LabEffect::kElectrolysisSaturation: {
      const double magnitude = std::abs(v), onset = effect.saturation_onset_V;
      if (a <= 0.0 || magnitude <= onset) return v;
      return std::copysign(onset + std::tanh(a * (magnitude - onset)) / a, v);
    }
    case LabEffect::kDeadZone: {
      if (a <= 0.0) return v;
      const double e = effect.dead_zone_smoothing_V;
      return SoftPlus(v - a, e) - SoftPlus(-v - a, e);
    }
    case LabEffect::kPolarityAsymmetry:
      return v >= 0.0 ? v : (1.0 - a) * v;
    default:
      return v;
  }
}

// The plant and its effect in first-order form.
class Dynamics {
 public:
  explicit Dynamics(const LabRun& run) : run_(run) {
    const auto& tf = run.plant;
    order_ = static_cast<int>(tf.den.size()) - 1;
    if (order_ < 1 || order_ > kMaxOrder || tf.num.size() > tf.den.size() - 1)
      throw std::invalid_argument("lab plant: need a strictly proper model of order 1-8");
    const double lead = tf.den.front();
    // Monic den: s^n + alpha_{n-1} s^{n-1} + ... + alpha_0; numerator c_j on s^j.
    for (int j = 0; j < order_; ++j) alpha_[j] = tf.den[static_cast<size_t>(order_ - j)] / lead;
    for (size_t i = 0; i < tf.num.size(); ++i) c_[tf.num.size() - 1 - i] = tf.num[i] / lead;
    dc_gain_ = PlantDcGain(tf);
  }

  int order() const { return order_; }

  // ds/dt at time t, with the delayed voltage taken from the given waveform piece.
  void Rates(double t_s, size_t piece, const State& s, State* ds) const {
    const LabEffectSettings& effect = run_.effect;
    const double v = run_.waveform.InPiece(piece, t_s - run_.plant.delay_s);
    const int n = order_;
    const double u_in = PlantInput(effect, v, s[n + 1]);
    double top = u_in;
    for (int j = 0; j < n; ++j) {
      top -= alpha_[j] * s[j];
      if (j + 1 < n) (*ds)[j] = s[j + 1];
    }
    (*ds)[n - 1] = top;
    (*ds)[n] = 0.0;
    (*ds)[n + 1] = 0.0;
    (*ds)[n + 2] = 0.0;
    switch (effect.kind) {
      case LabEffect::kBackRelaxation:
      case LabEffect::kCreep:
        (*ds)[n] = (effect.amplitude * dc_gain_ * v - s[n]) / effect.relaxation_tau_s;
        break;
      case LabEffect::kCycleDegradation:
        (*ds)[n + 1] = std::abs(v);
        break;
      case LabEffect::kHysteresis: {
        double rate = 0.0;  // y_p' = C x' (strictly proper: no feed-through)
        for (int j = 0; j < n; ++j) rate += c_[j] * (*ds)[j];
        const double h = s[n + 2];
        constexpr double kBeta = 0.75, kGamma = 0.25;
        const double sign = rate * h >= 0.0 ? 1.0 : -1.0;
        (*ds)[n + 2] =
            rate / effect.hysteresis_reach_mm * (1.0 - (kBeta * sign + kGamma) * std::abs(h));
        break;
      }
      default:
        break;
    }
  }

  // Deflection (mm) from the state at time t.
  double Output(double t_s, const State& s) const {
    const LabEffectSettings& effect = run_.effect;
    const int n = order_;
    double y = 0.0;
    for (int j = 0; j < n; ++j) y += c_[j] * s[j];
    switch (effect.kind) {
      case LabEffect::kBackRelaxation:
        return y - s[n];
      case LabEffect::kCreep:
        return y + s[n];
      case LabEffect::kHysteresis:
        return y - effect.amplitude * s[n + 2];
      case LabEffect::kSensorDrift: {
        const double share = effect.drift_warmup_share;
        return y + effect.amplitude * (share * (1.0 - std::exp(-t_s / effect.drift_warmup_tau_s)) +
                                       (1.0 - share) * t_s / effect.drift_linear_time_s);
      }
      default:
        return y;
    }
  }

 private:
  const LabRun& run_;
  int order_ = 0;
  std::array<double, kMaxOrder> alpha_{};
  std::array<double, kMaxOrder> c_{};
  double dc_gain_ = 0.0;
};

// RK4 over [t_s, end_s], a span within which the delayed voltage's waveform piece does not
// change, in equal steps of at most run.max_step_s.
inline void IntegrateSpan(const Dynamics& dynamics, const LabRun& run, double t_s, double end_s,
                          State* s) {
  const double span = end_s - t_s;
  const int steps = static_cast<int>(std::ceil(span / run.max_step_s - 1e-9));
  const double h = span / steps;
  const size_t piece = run.waveform.PieceAt(t_s + 0.5 * span - run.plant.delay_s);
  const int states = dynamics.order() + 3;
  State k1{}, k2{}, k3{}, k4{}, stage{};
  for (int i = 0; i < steps; ++i) {
    const double t0 = t_s + i * h;
    dynamics.Rates(t0, piece, *s, &k1);
    for (int j = 0; j < states; ++j) stage[j] = (*s)[j] + 0.5 * h * k1[j];
    dynamics.Rates(t0 + 0.5 * h, piece, stage, &k2);
    for (int j = 0; j < states; ++j) stage[j] = (*s)[j] + 0.5 * h * k2[j];
    dynamics.Rates(t0 + 0.5 * h, piece, stage, &k3);
    for (int j = 0; j < states; ++j) stage[j] = (*s)[j] + h * k3[j];
    dynamics.Rates(t0 + h, piece, stage, &k4);
    for (int j = 0; j < states; ++j)
      (*s)[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
  }
}

}  // namespace lab_detail

// Noise-free deflection (mm) at the sample instants k Ts, k = 0 .. SampleCount - 1, from
// rest at t = 0. RK4 with equal steps of at most max_step_s between consecutive break
// points (the sample instants and the delayed step times t_k + T), so that the kinks and
// jumps of the delayed input fall on step boundaries.
inline std::vector<double> SimulateClean(const LabRun& run) {
  const lab_detail::Dynamics dynamics(run);
  const size_t count = SampleCount(run);
  const double delay_s = run.plant.delay_s;
  std::vector<double> breaks;
  breaks.reserve(count + run.waveform.steps().size());
  for (size_t k = 0; k < count; ++k) breaks.push_back(static_cast<double>(k) * run.sample_period_s);
  const double end_s = breaks.back();
  for (const VoltageStep& step : run.waveform.steps())
    if (step.t_s + delay_s > 0.0 && step.t_s + delay_s < end_s)
      breaks.push_back(step.t_s + delay_s);
  std::sort(breaks.begin(), breaks.end());

  std::vector<double> y;
  y.reserve(count);
  lab_detail::State s{};
  double t = 0.0;
  size_t next_sample = 0;
  for (double target : breaks) {
    if (target - t > 1e-12) {
      lab_detail::IntegrateSpan(dynamics, run, t, target, &s);
      t = target;
    }
    // Record each sample instant once (a delayed step may coincide with one).
    while (next_sample < count &&
           static_cast<double>(next_sample) * run.sample_period_s <= t + 1e-12) {
      y.push_back(dynamics.Output(t, s));
      ++next_sample;
    }
  }
  return y;
}

// What the lab records: the applied voltage sampled at k Ts plus 1 mV noise, and the
// deflection plus sensor noise; t_s from 0.
inline model::Recording Record(const LabRun& run) {
  const std::vector<double> clean = SimulateClean(run);
  LabRandom noise(run.noise_seed);
  model::Recording recording;
  recording.source = "effect_plant";
  for (size_t k = 0; k < clean.size(); ++k) {
    const double t_s = static_cast<double>(k) * run.sample_period_s;
    recording.t_s.push_back(t_s);
    recording.voltage_V.push_back(run.waveform(t_s) + run.voltage_noise_std_V * noise.Normal());
    recording.deflection_mm.push_back(clean[k] + run.noise_std_mm * noise.Normal());
  }
  return recording;
}

// ---------------------------------------------------------------------------------------
// Effect size.

struct EffectSize {
  double ratio = 0.0;   // RMS over the touched samples / noise std
  double rms_mm = 0.0;  // RMS of the difference over the touched samples
  size_t touched = 0;   // samples with |difference| > 5 % of its maximum
};

inline EffectSize MeasureEffect(const std::vector<double>& without_mm,
                                const std::vector<double>& with_mm, double noise_std_mm) {
  double peak = 0.0;
  for (size_t k = 0; k < with_mm.size(); ++k)
    peak = std::max(peak, std::abs(with_mm[k] - without_mm[k]));
  EffectSize size;
  if (peak == 0.0) return size;
  double sum = 0.0;
  for (size_t k = 0; k < with_mm.size(); ++k) {
    const double d = with_mm[k] - without_mm[k];
    if (std::abs(d) > 0.05 * peak) {
      sum += d * d;
      ++size.touched;
    }
  }
  size.rms_mm = std::sqrt(sum / static_cast<double>(size.touched));
  size.ratio = size.rms_mm / noise_std_mm;
  return size;
}

// Clean outputs with and without the run's effect.
struct CleanPair {
  std::vector<double> without_mm;
  std::vector<double> with_mm;
  EffectSize size;
};

inline CleanPair CleanWithAndWithout(const LabRun& run) {
  LabRun plain = run;
  plain.effect.amplitude = 0.0;
  CleanPair pair{SimulateClean(plain), SimulateClean(run), {}};
  pair.size = MeasureEffect(pair.without_mm, pair.with_mm, run.noise_std_mm);
  return pair;
}

// Sets run->effect.amplitude so that the effect-to-noise ratio is target_ratio (relative
// tolerance 1e-3) and returns the ratio reached. The ratio increases monotonically with
// the amplitude for every effect here, roughly as a power of it: a bracketing search,
// each new amplitude interpolated in log(ratio) against log(amplitude) and replaced by the
// bracket's geometric mean (bisection in log amplitude) when the interpolation does not
// fall well inside the bracket.
inline double ScaleEffectToNoise(LabRun* run, double target_ratio) {
  if (run->effect.kind == LabEffect::kNone) throw std::invalid_argument("no effect to scale");
  LabRun plain = *run;
  plain.effect.amplitude = 0.0;
  const std::vector<double> without = SimulateClean(plain);
  auto ratio_at = [&](double amplitude) {
    run->effect.amplitude = amplitude;
    return MeasureEffect(without, SimulateClean(*run), run->noise_std_mm).ratio;
  };
  double amplitude = 1e-3;  // small for every effect's units
  double ratio = ratio_at(amplitude);
  double low_a = 0.0, low_r = 0.0, high_a = 0.0, high_r = 0.0;  // bracket (high_a = 0: none)
  for (int iteration = 0; iteration < 80; ++iteration) {
    if (std::abs(ratio / target_ratio - 1.0) < 1e-3) return ratio;
    if (ratio < target_ratio) {
      low_a = amplitude;
      low_r = ratio;
    } else {
      high_a = amplitude;
      high_r = ratio;
    }
    double next = 0.0;
    if (low_a > 0.0 && low_r > 0.0 && high_a > 0.0) {
      const double slope = std::log(high_r / low_r) / std::log(high_a / low_a);
      next = low_a * std::exp(std::log(target_ratio / low_r) / slope);
      const double width = std::log(high_a / low_a);
      const double position = std::log(next / low_a) / width;
      if (!(position > 0.02 && position < 0.98)) next = std::sqrt(low_a * high_a);
    } else if (high_a > 0.0) {  // only an upper end: assume ratio ~ amplitude
      next = high_a * std::max(target_ratio / high_r, 1.0 / 16.0);
    } else {  // only a lower end
      next = ratio > 0.0 ? low_a * std::min(target_ratio / ratio, 16.0) : low_a * 16.0;
    }
    amplitude = next;
    ratio = ratio_at(amplitude);
  }
  throw std::runtime_error("ScaleEffectToNoise: did not converge");
}

// ---------------------------------------------------------------------------------------
// One recording's set-up, drawn from a seed.

struct RunOptions {
  double lead_s = 5.0;            // 0 V before the protocol starts (plus a fraction of Ts)
  bool fractional_delay = false;  // add U(0, Ts) to the plant's dead time
  double noise_std_mm = 0.02;
  double sample_period_s = 0.1;
};

// Draws, from `seed`: the protocol's start (lead_s plus U(0.05, 0.95) Ts, so that no step
// is on the sample grid), the slew time constant U(20, 50) ms, the dead time's extra
// fraction (fractional_delay), the effect's shape (tau_r log-uniform in [60, 200] s; x0 =
// U(0.1, 0.4) |K| x 1 V; V_s = U(0.55, 0.8) x the largest |level|; tau_d U(100, 400) s,
// s U(0.4, 0.8), t_lin = the duration) and the noise seed. The amplitude is left at 0
// (ScaleEffectToNoise sets it).
inline LabRun MakeRun(const Protocol& protocol, const model::TransferFunction& plant,
                      LabEffect effect, uint64_t seed, const RunOptions& options = {}) {
  LabRandom draw(seed);
  LabRun run;
  run.sample_period_s = options.sample_period_s;
  run.noise_std_mm = options.noise_std_mm;
  const double start_s = options.lead_s + draw.Uniform(0.05, 0.95) * options.sample_period_s;
  const double slew_tau_s = draw.Uniform(0.02, 0.05);
  double end_s = 0.0;
  std::vector<VoltageStep> steps = ProtocolSteps(protocol, start_s, &end_s);
  double largest_V = 0.0;
  for (const VoltageStep& step : steps) largest_V = std::max(largest_V, std::abs(step.level_V));
  run.waveform = Waveform(std::move(steps), slew_tau_s);
  run.duration_s = std::floor(end_s / options.sample_period_s) * options.sample_period_s;
  run.plant = plant;
  const double extra_delay = draw.Uniform() * options.sample_period_s;
  if (options.fractional_delay) run.plant.delay_s += extra_delay;
  run.effect.kind = effect;
  run.effect.relaxation_tau_s = draw.LogUniform(60.0, 200.0);
  run.effect.hysteresis_reach_mm = draw.Uniform(0.1, 0.4) * std::abs(PlantDcGain(plant));
  run.effect.saturation_onset_V = draw.Uniform(0.55, 0.8) * largest_V;
  run.effect.drift_warmup_tau_s = draw.Uniform(100.0, 400.0);
  run.effect.drift_warmup_share = draw.Uniform(0.4, 0.8);
  run.effect.drift_linear_time_s = run.duration_s;
  run.noise_seed = static_cast<uint64_t>(draw.Uniform() * 0x1.0p53);
  return run;
}

}  // namespace flexid::testing
