// An acceptance battery for the mismatch diagnosis (model/diagnose/diagnose.h) on physics its
// catalogue does not contain: the independent T-S test plant (ts_plant.h) plus at most one
// concealed effect, each formulated otherwise than the diagnosis models it (effects.cc
// Catalogue, ApplyInputEffect, ApplyOutputEffect) and otherwise than the older lab
// (effect_plant.h), driven by a protocol drawn from a lab's usual set.
//
// Independent of model/: only the Recording struct is used, and ts_plant.h for the plant
// (DrawTsPlant), its protocols (TsProtocol, TsHold) and its random numbers. The plant is
// integrated here again, together with the effects' states, by the same classical RK4.
//
// Notation (times in s, voltages in V, deflections in mm; the plant's is ts_plant.h's):
//   w(t)     applied voltage, piecewise constant, switching on sample instants.
//   v(t)     = w(t - T), the voltage as it reaches the actuator (T the plant's dead time).
//   mu_r(z)  the plant's memberships; here always z = |v|: an effect changes what drives
//            the rules, never which rules fire.
//   e        the drive: u_r = mu_r(|v|) e (kInputBlend) or u_r = e (kOutputBlend); e = v
//            without an effect.
//   y_p      the plant's output, sum_r y_r (kInputBlend) or sum_r mu_r y_r (kOutputBlend).
//   y        the deflection: y = y_p without an effect.
//   a        the effect's amplitude (units below); a = 0 gives exactly the plant, bit for bit.
// Effects (names as model::EffectName has them):
//   back_relaxation          ion diffusion with two time constants: two slow followers of
//                            the plant's response,
//                              tau_f r_f' = y_p - r_f,   tau_s r_s' = y_p - r_s,
//                              y = y_p - a (phi r_f + (1 - phi) r_s)           (a: share)
//                            tau_f log-uniform in [30, 100] s, tau_s in [120, 400] s, phi
//                            U(0.3, 0.7). Under a sustained voltage the deflection rises,
//                            then falls back by a share a; when the voltage is removed it
//                            overshoots past rest and creeps back.
//   sensor_drift             independent of the input, starts at 0, y = y_p + a D(t)
//                            (a in mm), D drawn per recording, with equal odds:
//                            - a smoothed random walk: W_k = W_{k-1} + sqrt(Ts) N(0, 1),
//                              W_0 = 0, filtered by two first-order low-passes of time
//                              constant tau_w U(30, 120) s (discretised exactly per sample,
//                              from 0), scaled to max_k |D_k| = 1;
//                            - a delayed warm-up: D = s (1 - exp(-(t - t_0) / tau_h)) for
//                              t > t_0, 0 before; t_0 U(30, 300) s, tau_h U(100, 500) s,
//                              s = +1 or -1.
//   hysteresis               a Preisach model of the plant's output x = y_p / Y (Y = max |y_p|
//                            over the recording without the effect): a grid of relays
//                            R_ij = +1 once x >= c_i + r_j, -1 once x <= c_i - r_j, kept in
//                            between; R_ij = sign(-c_i) at rest. Centres c_i, 120 cells on
//                            [-1.2, 1.2] (never 0); half-widths r_j = rho (j + 1/2) / 3,
//                            j = 0 .. 11; weights from the density
//                              w_ij ~ exp(-(c_i - c_0)^2 / (2 s_c^2)) (r_j / rho) exp(-r_j / rho),
//                            sum w_ij = 1; c_0 U(0, 0.5), s_c U(0.4, 1), rho U(0.03, 0.1).
//                              y = y_p + a Y sum_ij w_ij (R_ij - sign(x - c_i))    (a: share)
//                            i.e. the Preisach output less the same relays of zero width:
//                            the loop without its midline, rate-independent (a relay switches
//                            on the values x takes, never on how fast). Below y_p while the
//                            output rises, above it while it falls; a remanent offset at
//                            rest. Evaluated exactly: the relays of half-width r_j in state
//                            +1 are those with c_i < p_j, p_j the play operator of half-width
//                            r_j on x (p_j = 0 at rest), updated after every integration step.
//   cycle_degradation        gain lost with the square root of the transferred charge:
//                              Q' = |v|,  e = v max(0, 1 - a sqrt(Q / Q_ref)),  Q_ref = 1000 V s
//                            (a: loss at Q_ref). Loses fastest at first, unlike a loss
//                            exponential (or linear) in the charge. The catalogue's
//                            degradation has an exponent on the charge since this
//                            battery showed that: with it near 0.5 the two differ by
//                            under 1 % of the gain while the loss is under 10 %. Both
//                            leave the memberships to the applied voltage.
//   electrolysis_saturation  current-limited electrolysis: the source (series resistance
//                            R_s) feeds the gel in parallel with an electrolysis branch that
//                            conducts above the decomposition voltage V_d, a diode (Tafel
//                            slope m) in series with a resistance R_e. With i the branch
//                            current times R_e (in V) and a = R_s / R_e, for |v| > V_d
//                              (1 + a) i + m ln(1 + i / (0.1 m)) = |v| - V_d,
//                              e = sign(v) (|v| - a i),
//                            and e = v for |v| <= V_d. Above V_d the drive bends away from
//                            |v| over an exponential knee a few m wide (at V_d itself only
//                            by the slope 1 - a / (11 + a) of the diode's linear start)
//                            towards V_d + (|v| - V_d) / (1 + a) plus a logarithm: a smooth
//                            compression, not a slope change at an onset, never a cut-off.
//                            V_d U(5.5, min(7.5, top - 0.5)) with top the protocol's largest
//                            |level|; m U(0.1, 0.3) V.
//   polarity_asymmetry       a share a of the negative drive is carried by a slower species
//                            with another gain: v+ = max(v, 0), v- = min(v, 0),
//                              tau_n q' = g v- - q,   e = v+ + (1 - a) v- + a q   (a in [0, 1])
//                            g U(0.3, 0.7) or U(1.4, 2) (equal odds), tau_n U(3, 30) s.
//                            Positive voltage acts as the plant; negative with the gain
//                            1 - a + a g and a lag, and its drive fades out after it.
//   none                     the plant alone.
// Protocols (lead-in at 0 V U(10, 30) s; levels rounded to 0.1 V; every duration drawn
// uniformly; every time rounded to a sample):
//   square       level U(2, 8), period U(150, 260), duty U(0.35, 0.65), 3-5 cycles.
//   square+0-0   as square, every second cycle negative.
//   square+-     as square, each cycle +level for duty * period then -level for the rest;
//                then U(150, 250) s at 0 V.
//   stairs       2-5 levels top k / n (top U(4, 8)), U(100, 150) s each, then U(150, 300) s
//                at 0 V; stairs-ud also back down (top not repeated) before the rest.
//   levels       random levels, integers 0..8 V (levels+-: -8..8 V, both signs present),
//                never the same twice in a row, U(40, 120) s each, U(600, 1200) s in all.
//   step         one level U(2, 8) for U(400, 700) s, then U(300, 500) s at 0 V.
//   A family is drawn with equal odds (square, bipolar square, staircase, levels, step),
//   then its variant with equal odds; for an effect, protocols are drawn again until the
//   effect can show: polarity_asymmetry only on bipolar ones, electrolysis_saturation only
//   where top >= 6 V (so that top >= V_d + 0.5 V), the others on any.
// Effect size: d_k the noise-free output with minus without the effect; the touched
//   samples have |d_k| > 5 % of max |d_k|; the effect-to-noise ratio is RMS(d over them) /
//   sigma. a is scaled (bracketing search in log a) until the ratio is within 1e-3 of a
//   target drawn U(2.5, 9) (faint: U(0.7, 2)); a target out of reach (polarity's a <= 1, a
//   back-relaxation share <= 0.9, a degradation that keeps 20 % of the gain) redraws the
//   effect's shape.
// Sampling: t_k = k Ts, Ts = 0.1 s; the voltage column w(t_k) exactly; the deflection
//   y(t_k) + N(0, sigma^2) (sigma the plant's, U(0.02, 0.03) mm), rounded to 0.005 mm.
// Integrator: classical RK4 on the rules' states and the effect's (Q, q, r_f, r_s), equal
//   steps of at most 5 ms between break points (sample instants and delayed switches);
//   the same steps and arithmetic as ts_plant.h, so a = 0 reproduces SimulateTsPlant.
// Seeds: each case's seed is split (SplitMix64) into streams for the effect's choice, the
//   plant, the protocol, the target ratio, the effect's shape, the noise and the
//   identification recordings; std::mt19937_64 and Box-Muller (TsPlantRandom), so a seed
//   gives the same case with every standard library.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/core/recording.h"
#include "ts_plant.h"

namespace flexid::testing {

inline constexpr double kBatteryQuantum_mm = 0.005;
inline constexpr double kBatteryChargeRef_Vs = 1000.0;

// ---------------------------------------------------------------------------------------
// Effects.

enum class BatteryEffect {
  kNone,
  kBackRelaxation,
  kSensorDrift,
  kHysteresis,
  kCycleDegradation,
  kElectrolysisSaturation,
  kPolarityAsymmetry,
};

inline const char* BatteryEffectName(BatteryEffect effect) {
  switch (effect) {
    case BatteryEffect::kNone:
      return "none";
    case BatteryEffect::kBackRelaxation:
      return "back_relaxation";
    case BatteryEffect::kSensorDrift:
      return "sensor_drift";
    case BatteryEffect::kHysteresis:
      return "hysteresis";
    case BatteryEffect::kCycleDegradation:
      return "cycle_degradation";
    case BatteryEffect::kElectrolysisSaturation:
      return "electrolysis_saturation";
    case BatteryEffect::kPolarityAsymmetry:
      return "polarity_asymmetry";
  }
  return "?";
}

// The six effect classes, in the order the battery cycles through them.
inline std::vector<BatteryEffect> BatteryEffectClasses() {
  return {BatteryEffect::kBackRelaxation,
          BatteryEffect::kSensorDrift,
          BatteryEffect::kHysteresis,
          BatteryEffect::kCycleDegradation,
          BatteryEffect::kElectrolysisSaturation,
          BatteryEffect::kPolarityAsymmetry};
}

// Independent sub-seeds of one seed (SplitMix64's finaliser).
inline uint64_t BatterySubSeed(uint64_t seed, uint64_t stream) {
  uint64_t z = seed + 0x9E3779B97F4A7C15ull * (stream + 1);
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

inline std::string BatteryFormat(const char* format, auto... values) {
  const int size = std::snprintf(nullptr, 0, format, values...);
  std::string text(static_cast<size_t>(std::max(size, 0)) + 1, '\0');
  std::snprintf(text.data(), text.size(), format, values...);
  text.pop_back();
  return text;
}

// ---------------------------------------------------------------------------------------
// Protocols.

struct BatteryProtocol {
  std::string name;         // "square", "square+0-0", "square+-", "stairs", ...
  std::string description;  // levels and timing, one line
  TsProtocol protocol;
  bool bipolar = false;  // drives both polarities
  double top_V = 0.0;    // largest |level|
};

namespace battery_detail {

inline double RoundLevel(double level_V) { return std::round(level_V * 10.0) / 10.0; }

// Appends a hold from t_s on (rounded to a sample; later than the previous hold).
inline void AddHold(TsProtocol* protocol, double t_s, double level_V) {
  const size_t start = TsSamplesIn(t_s);
  if (!protocol->holds.empty() && start <= protocol->holds.back().start_sample)
    throw std::logic_error("effect_battery: holds must start later and later");
  protocol->holds.push_back({start, level_V});
}

inline void Finish(BatteryProtocol* out, double end_s) {
  out->protocol.samples = TsSamplesIn(end_s) + 1;
  bool positive = false, negative = false;
  for (const TsHold& hold : out->protocol.holds) {
    out->top_V = std::max(out->top_V, std::abs(hold.level_V));
    positive = positive || hold.level_V > 0.0;
    negative = negative || hold.level_V < 0.0;
  }
  out->bipolar = positive && negative;
}

inline BatteryProtocol DrawSquare(TsPlantRandom& draw, double lead_s, int variant) {
  BatteryProtocol out;
  const double level_V = RoundLevel(draw.Uniform(2.0, 8.0));
  const double period_s = draw.Uniform(150.0, 260.0);
  const double duty = draw.Uniform(0.35, 0.65);
  const int cycles = 3 + static_cast<int>(draw.Index(3));
  const double rest_s = draw.Uniform(150.0, 250.0);
  out.name = variant == 0 ? "square" : variant == 1 ? "square+0-0" : "square+-";
  out.description = BatteryFormat("%s %.1f V, period %.0f s, duty %.2f, %d cycles",
                                  out.name.c_str(), level_V, period_s, duty, cycles);
  double t_s = lead_s;
  for (int c = 0; c < cycles; ++c, t_s += period_s) {
    const double sign = variant == 1 && c % 2 == 1 ? -1.0 : 1.0;
    AddHold(&out.protocol, t_s, sign * level_V);
    AddHold(&out.protocol, t_s + duty * period_s, variant == 2 ? -level_V : 0.0);
  }
  if (variant == 2) {
    AddHold(&out.protocol, t_s, 0.0);
    t_s += rest_s;
  }
  Finish(&out, t_s);
  return out;
}

inline BatteryProtocol DrawStaircase(TsPlantRandom& draw, double lead_s) {
  BatteryProtocol out;
  const int steps = 2 + static_cast<int>(draw.Index(4));
  const double top_V = draw.Uniform(4.0, 8.0);
  const double hold_s = draw.Uniform(100.0, 150.0);
  const bool down = draw.Index(2) == 1;
  const double rest_s = draw.Uniform(150.0, 300.0);
  std::vector<double> levels_V;
  for (int i = 1; i <= steps; ++i) levels_V.push_back(RoundLevel(top_V * i / steps));
  if (down)
    for (int i = steps - 2; i >= 0; --i) levels_V.push_back(levels_V[static_cast<size_t>(i)]);
  out.name = down ? "stairs-ud" : "stairs";
  out.description =
      BatteryFormat("%s %d levels to %.1f V, %.0f s each, rest %.0f s", out.name.c_str(), steps,
                    levels_V[static_cast<size_t>(steps - 1)], hold_s, rest_s);
  double t_s = lead_s;
  for (double level_V : levels_V) {
    AddHold(&out.protocol, t_s, level_V);
    t_s += hold_s;
  }
  AddHold(&out.protocol, t_s, 0.0);
  Finish(&out, t_s + rest_s);
  return out;
}

inline BatteryProtocol DrawLevels(TsPlantRandom& draw, double lead_s, bool bipolar,
                                  double duration_s) {
  const int lowest = bipolar ? -8 : 0;
  const auto choices = static_cast<size_t>(8 - lowest + 1);
  for (;;) {  // bipolar: drawn again until both signs occur
    BatteryProtocol out;
    out.name = bipolar ? "levels+-" : "levels";
    double t_s = lead_s, previous_V = 0.0;
    while (t_s < duration_s) {
      double level_V = previous_V;
      while (level_V == previous_V)
        level_V = static_cast<double>(lowest + static_cast<int>(draw.Index(choices)));
      AddHold(&out.protocol, t_s, level_V);
      previous_V = level_V;
      t_s += draw.Uniform(40.0, 120.0);
    }
    Finish(&out, duration_s);
    out.description =
        BatteryFormat("%s %zu holds of 40-120 s over %.0f s, top %.0f V", out.name.c_str(),
                      out.protocol.holds.size(), duration_s, out.top_V);
    if (!bipolar || out.bipolar) return out;
  }
}

inline BatteryProtocol DrawStep(TsPlantRandom& draw, double lead_s) {
  BatteryProtocol out;
  const double level_V = RoundLevel(draw.Uniform(2.0, 8.0));
  const double on_s = draw.Uniform(400.0, 700.0);
  const double rest_s = draw.Uniform(300.0, 500.0);
  out.name = "step";
  out.description = BatteryFormat("step %.1f V for %.0f s, rest %.0f s", level_V, on_s, rest_s);
  AddHold(&out.protocol, lead_s, level_V);
  AddHold(&out.protocol, lead_s + on_s, 0.0);
  Finish(&out, lead_s + on_s + rest_s);
  return out;
}

}  // namespace battery_detail

// One protocol of the lab's usual set (file header), from `draw`.
inline BatteryProtocol DrawBatteryProtocol(TsPlantRandom& draw) {
  const size_t family = draw.Index(5);
  const double lead_s = draw.Uniform(10.0, 30.0);
  switch (family) {
    case 0:
      return battery_detail::DrawSquare(draw, lead_s, 0);
    case 1:
      return battery_detail::DrawSquare(draw, lead_s, 1 + static_cast<int>(draw.Index(2)));
    case 2:
      return battery_detail::DrawStaircase(draw, lead_s);
    case 3: {
      const bool bipolar = draw.Index(2) == 1;
      return battery_detail::DrawLevels(draw, lead_s, bipolar, draw.Uniform(600.0, 1200.0));
    }
    default:
      return battery_detail::DrawStep(draw, lead_s);
  }
}

// Whether the effect can show on the protocol at all (file header).
inline bool BatteryEffectCanShow(BatteryEffect effect, const BatteryProtocol& protocol) {
  switch (effect) {
    case BatteryEffect::kPolarityAsymmetry:
      return protocol.bipolar;
    case BatteryEffect::kElectrolysisSaturation:
      return protocol.top_V >= 6.0;
    default:
      return true;
  }
}

// ---------------------------------------------------------------------------------------
// The effect's settings and its models.

struct BatteryEffectSettings {
  BatteryEffect kind = BatteryEffect::kNone;
  double amplitude = 0.0;  // a (file header)
  // back_relaxation
  double relax_fast_tau_s = 60.0;  // tau_f
  double relax_slow_tau_s = 250.0;
  double relax_fast_share = 0.5;  // phi
  // sensor_drift
  bool drift_walk = false;  // true: smoothed random walk; false: delayed warm-up
  uint64_t drift_walk_seed = 0;
  double drift_filter_tau_s = 60.0;  // tau_w
  double drift_delay_s = 100.0;      // t_0
  double drift_tau_s = 300.0;        // tau_h
  double drift_sign = 1.0;           // s
  // hysteresis
  double preisach_scale_mm = 1.0;  // Y
  double preisach_centre = 0.2;    // c_0
  double preisach_spread = 0.6;    // s_c
  double preisach_width = 0.06;    // rho
  // electrolysis_saturation
  double decomposition_V = 6.5;  // V_d
  double tafel_V = 0.2;          // m
  // polarity_asymmetry
  double negative_gain = 0.5;    // g
  double negative_tau_s = 10.0;  // tau_n
};

// The Preisach model of the file header, on a normalised input x.
class PreisachHysteresis {
 public:
  static constexpr size_t kWidths = 12;
  static constexpr size_t kCentres = 120;
  static constexpr double kCentreLow = -1.2;
  static constexpr double kCentreStep = 2.4 / static_cast<double>(kCentres);

  PreisachHysteresis(double centre, double spread, double width) {
    std::array<std::array<double, kCentres>, kWidths> weights{};
    double total = 0.0;
    for (size_t j = 0; j < kWidths; ++j) {
      half_width_[j] = width * (static_cast<double>(j) + 0.5) / 3.0;
      const double r = half_width_[j] / width;
      for (size_t i = 0; i < kCentres; ++i) {
        const double c = (Centre(i) - centre) / spread;
        weights[j][i] = std::exp(-0.5 * c * c) * r * std::exp(-r);
        total += weights[j][i];
      }
    }
    for (size_t j = 0; j < kWidths; ++j) {
      below_[j][0] = 0.0;
      for (size_t i = 0; i < kCentres; ++i) below_[j][i + 1] = below_[j][i] + weights[j][i] / total;
    }
  }

  static double Centre(size_t i) {
    return kCentreLow + (static_cast<double>(i) + 0.5) * kCentreStep;
  }

  // Moves the relays with the input (every play p_j).
  void Update(double x) {
    x_ = x;
    for (size_t j = 0; j < kWidths; ++j)
      play_[j] = std::clamp(play_[j], x - half_width_[j], x + half_width_[j]);
  }

  // sum_ij w_ij (R_ij - sign(x - c_i)) at the last input.
  double Output() const {
    double sum = 0.0;
    for (size_t j = 0; j < kWidths; ++j) sum += 2.0 * (Below(j, play_[j]) - Below(j, x_));
    return sum;
  }

  // sum_ij w_ij R_ij, the Preisach output itself.
  double PreisachOutput() const {
    double sum = 0.0;
    for (size_t j = 0; j < kWidths; ++j) sum += 2.0 * Below(j, play_[j]) - below_[j][kCentres];
    return sum;
  }

 private:
  // Weight of the relays of width j whose centre lies below p.
  double Below(size_t j, double p) const {
    const double cells = std::ceil((p - kCentreLow) / kCentreStep - 0.5);
    const auto count = static_cast<size_t>(std::clamp(cells, 0.0, static_cast<double>(kCentres)));
    return below_[j][count];
  }

  std::array<double, kWidths> half_width_{};
  std::array<double, kWidths> play_{};
  std::array<std::array<double, kCentres + 1>, kWidths> below_{};
  double x_ = 0.0;
};

// electrolysis_saturation's drive for the delayed voltage v (file header).
inline double ElectrolysisDrive(double v_V, double amplitude, double decomposition_V,
                                double tafel_V) {
  const double magnitude = std::abs(v_V);
  if (amplitude <= 0.0 || magnitude <= decomposition_V) return v_V;
  const double excess = magnitude - decomposition_V;
  const double exchange = 0.1 * tafel_V;
  double low = 0.0, high = excess / (1.0 + amplitude);  // h(low) < 0 < h(high)
  for (int iteration = 0; iteration < 200 && high - low > 1e-15 * high; ++iteration) {
    const double mid = 0.5 * (low + high);
    const double h = (1.0 + amplitude) * mid + tafel_V * std::log1p(mid / exchange) - excess;
    (h > 0.0 ? high : low) = mid;
  }
  return std::copysign(magnitude - amplitude * 0.5 * (low + high), v_V);
}

// sensor_drift's D(t_k), k = 0 .. samples - 1 (file header).
inline std::vector<double> DriftShape(const BatteryEffectSettings& effect, size_t samples) {
  std::vector<double> shape(samples, 0.0);
  if (effect.drift_walk) {
    TsPlantRandom walk(effect.drift_walk_seed);
    const double keep = std::exp(-kTsPlantSamplePeriod_s / effect.drift_filter_tau_s);
    double w = 0.0, first = 0.0, second = 0.0, peak = 0.0;
    for (size_t k = 0; k < samples; ++k) {
      shape[k] = second;
      peak = std::max(peak, std::abs(second));
      w += std::sqrt(kTsPlantSamplePeriod_s) * walk.Normal();
      first = keep * first + (1.0 - keep) * w;
      second = keep * second + (1.0 - keep) * first;
    }
    if (peak > 0.0)
      for (double& d : shape) d *= effect.drift_sign / peak;
  } else {
    for (size_t k = 0; k < samples; ++k) {
      const double t_s = static_cast<double>(k) * kTsPlantSamplePeriod_s;
      if (t_s > effect.drift_delay_s)
        shape[k] = effect.drift_sign *
                   (1.0 - std::exp(-(t_s - effect.drift_delay_s) / effect.drift_tau_s));
    }
  }
  return shape;
}

// ---------------------------------------------------------------------------------------
// Simulation.

namespace battery_detail {

constexpr size_t kMaxRules = 6;
constexpr size_t kMaxStates = 4 * kMaxRules + 4;  // rules, then Q, q, r_f, r_s
using State = std::array<double, kMaxStates>;

// The plant with the effect in first-order form, for one delayed voltage v at a time.
class Dynamics {
 public:
  Dynamics(const TsPlant& plant, const BatteryEffectSettings& effect)
      : plant_(plant), effect_(effect), rules_(plant.rules.size()) {
    if (rules_ == 0 || rules_ > kMaxRules)
      throw std::invalid_argument("effect_battery: the plant needs 1-6 rules");
    mu_.assign(rules_, 0.0);
    SetVoltage(0.0);
  }

  size_t states() const { return 4 * rules_ + 4; }

  void SetVoltage(double v_V) {
    v_ = v_V;
    mu_ = plant_.Memberships(std::abs(v_));
    drive_ =
        effect_.kind == BatteryEffect::kElectrolysisSaturation
            ? ElectrolysisDrive(v_, effect_.amplitude, effect_.decomposition_V, effect_.tafel_V)
            : v_;
  }

  double PlantOutput(const State& s) const {
    double sum_mm = 0.0;
    for (size_t r = 0; r < rules_; ++r)
      sum_mm += (plant_.blend == TsBlend::kInputBlend ? 1.0 : mu_[r]) * s[4 * r];
    return sum_mm;
  }

  void Rates(const State& s, State* ds) const {
    const size_t n = 4 * rules_;
    const double a = effect_.amplitude;
    double e = drive_;
    if (effect_.kind == BatteryEffect::kCycleDegradation)
      e = v_ * std::max(0.0, 1.0 - a * std::sqrt(std::max(s[n], 0.0) / kBatteryChargeRef_Vs));
    else if (effect_.kind == BatteryEffect::kPolarityAsymmetry)
      e = std::max(v_, 0.0) + (1.0 - a) * std::min(v_, 0.0) + a * s[n + 1];
    for (size_t r = 0; r < rules_; ++r) {
      const TsPlantRule& rule = plant_.rules[r];
      const double u = plant_.blend == TsBlend::kInputBlend ? mu_[r] * e : e;
      const size_t o = 4 * r;
      for (size_t i = 0; i < 4; ++i)
        (*ds)[o + i] = -rule.den[i + 1] * s[o] + (i + 1 < 4 ? s[o + i + 1] : 0.0) + rule.num[i] * u;
    }
    (*ds)[n] = std::abs(v_);
    (*ds)[n + 1] = (effect_.negative_gain * std::min(v_, 0.0) - s[n + 1]) / effect_.negative_tau_s;
    const double y_p = PlantOutput(s);
    (*ds)[n + 2] = (y_p - s[n + 2]) / effect_.relax_fast_tau_s;
    (*ds)[n + 3] = (y_p - s[n + 3]) / effect_.relax_slow_tau_s;
  }

 private:
  const TsPlant& plant_;
  const BatteryEffectSettings& effect_;
  size_t rules_;
  std::vector<double> mu_;
  double v_ = 0.0;
  double drive_ = 0.0;
};

}  // namespace battery_detail

// Noise-free deflection at t_k = k Ts, k = 0 .. protocol.samples - 1, from rest.
inline std::vector<double> SimulateBattery(const TsPlant& plant, const TsProtocol& protocol,
                                           const BatteryEffectSettings& effect) {
  using battery_detail::State;
  battery_detail::Dynamics dynamics(plant, effect);
  const size_t count = dynamics.states();
  const size_t n = count - 4;
  const double a = effect.amplitude;
  const bool hysteresis = effect.kind == BatteryEffect::kHysteresis;
  PreisachHysteresis preisach(effect.preisach_centre, effect.preisach_spread,
                              effect.preisach_width);
  const std::vector<double> drift = effect.kind == BatteryEffect::kSensorDrift
                                        ? DriftShape(effect, protocol.samples)
                                        : std::vector<double>{};
  State s{}, k1{}, k2{}, k3{}, k4{}, stage{};
  auto advance = [&](double span_s) {
    if (span_s <= 0.0) return;
    const int steps = static_cast<int>(std::ceil(span_s / kTsPlantMaxStep_s - 1e-9));
    const double h = span_s / steps;
    for (int step = 0; step < steps; ++step) {
      dynamics.Rates(s, &k1);
      for (size_t i = 0; i < count; ++i) stage[i] = s[i] + 0.5 * h * k1[i];
      dynamics.Rates(stage, &k2);
      for (size_t i = 0; i < count; ++i) stage[i] = s[i] + 0.5 * h * k2[i];
      dynamics.Rates(stage, &k3);
      for (size_t i = 0; i < count; ++i) stage[i] = s[i] + h * k3[i];
      dynamics.Rates(stage, &k4);
      for (size_t i = 0; i < count; ++i)
        s[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
      if (hysteresis) preisach.Update(dynamics.PlantOutput(s) / effect.preisach_scale_mm);
    }
  };

  return SampleWithDelayedHolds(
      protocol, plant.delay_s, advance, [&](double level_V) { dynamics.SetVoltage(level_V); },
      [&](size_t k) {
        const double y_p = dynamics.PlantOutput(s);
        switch (effect.kind) {
          case BatteryEffect::kBackRelaxation:
            return y_p - a * (effect.relax_fast_share * s[n + 2] +
                              (1.0 - effect.relax_fast_share) * s[n + 3]);
          case BatteryEffect::kHysteresis:
            return y_p + a * effect.preisach_scale_mm * preisach.Output();
          case BatteryEffect::kSensorDrift:
            return y_p + a * drift[k];
          default:
            return y_p;
        }
      });
}

// ---------------------------------------------------------------------------------------
// Effect size and scaling.

struct BatteryEffectSize {
  double ratio = 0.0;   // RMS over the touched samples / sigma
  double rms_mm = 0.0;  // RMS of d over the touched samples
  size_t touched = 0;   // samples with |d| > 5 % of max |d|
};

inline BatteryEffectSize MeasureBatteryEffect(const std::vector<double>& without_mm,
                                              const std::vector<double>& with_mm,
                                              double noise_std_mm) {
  double peak = 0.0;
  for (size_t k = 0; k < with_mm.size(); ++k)
    peak = std::max(peak, std::abs(with_mm[k] - without_mm[k]));
  BatteryEffectSize size;
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

// The ratio cannot reach the target within the amplitude's physical range.
struct BatteryOutOfReach : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The largest amplitude the battery uses for the effect on the protocol (file header).
inline double BatteryAmplitudeLimit(const BatteryEffectSettings& effect,
                                    const TsProtocol& protocol) {
  switch (effect.kind) {
    case BatteryEffect::kBackRelaxation:
      return 0.9;
    case BatteryEffect::kPolarityAsymmetry:
      return 1.0;
    case BatteryEffect::kCycleDegradation: {
      double charge_Vs = 0.0;
      for (double v : TsVoltageColumn(protocol)) charge_Vs += std::abs(v) * kTsPlantSamplePeriod_s;
      return charge_Vs > 0.0 ? 0.8 / std::sqrt(charge_Vs / kBatteryChargeRef_Vs) : 0.0;
    }
    default:
      return 1e4;
  }
}

// Sets effect->amplitude so that the effect-to-noise ratio against `without_mm` (the plant
// alone) is within 1e-3 of target_ratio, and returns the ratio reached. A bracketing
// search: each new amplitude interpolated in log(ratio) against log(amplitude), replaced
// by the bracket's geometric mean when it does not fall well inside. Throws
// BatteryOutOfReach when the amplitude limit does not reach the target.
inline double ScaleBatteryEffect(const TsPlant& plant, const TsProtocol& protocol,
                                 const std::vector<double>& without_mm, double target_ratio,
                                 BatteryEffectSettings* effect) {
  if (effect->kind == BatteryEffect::kNone)
    throw std::invalid_argument("ScaleBatteryEffect: no effect to scale");
  const double limit = BatteryAmplitudeLimit(*effect, protocol);
  auto ratio_at = [&](double amplitude) {
    effect->amplitude = amplitude;
    return MeasureBatteryEffect(without_mm, SimulateBattery(plant, protocol, *effect),
                                plant.noise_std_mm)
        .ratio;
  };
  double amplitude = std::min(0.05, 0.5 * limit);
  double ratio = ratio_at(amplitude);
  double low_a = 0.0, low_r = 0.0, high_a = 0.0, high_r = 0.0;  // bracket (high_a = 0: none)
  for (int iteration = 0; iteration < 80; ++iteration) {
    if (std::abs(ratio / target_ratio - 1.0) < 1e-3) return ratio;
    if (ratio < target_ratio) {
      low_a = amplitude;
      low_r = ratio;
      if (amplitude >= limit)
        throw BatteryOutOfReach(BatteryFormat("%s: ratio %.3g at the amplitude limit %.3g < %.3g",
                                              BatteryEffectName(effect->kind), ratio, limit,
                                              target_ratio));
    } else {
      high_a = amplitude;
      high_r = ratio;
    }
    double next = 0.0;
    if (low_a > 0.0 && low_r > 0.0 && high_a > 0.0) {
      const double slope = std::log(high_r / low_r) / std::log(high_a / low_a);
      next = low_a * std::exp(std::log(target_ratio / low_r) / slope);
      const double position = std::log(next / low_a) / std::log(high_a / low_a);
      if (!(position > 0.02 && position < 0.98)) next = std::sqrt(low_a * high_a);
    } else if (high_a > 0.0) {  // only an upper end: assume ratio ~ amplitude
      next = high_a * std::max(target_ratio / high_r, 1.0 / 16.0);
    } else {  // only a lower end
      next = ratio > 0.0 ? low_a * std::min(target_ratio / ratio, 16.0) : low_a * 16.0;
      next = std::min(next, limit);
    }
    amplitude = next;
    ratio = ratio_at(amplitude);
  }
  throw std::runtime_error("ScaleBatteryEffect: did not converge");
}

// ---------------------------------------------------------------------------------------
// One case.

// Draws every shape parameter of every effect (the same draws whatever the kind, so one
// seed gives one shape per effect), for the protocol and the plant's output without it.
inline BatteryEffectSettings DrawBatteryEffectSettings(BatteryEffect kind,
                                                       const BatteryProtocol& protocol,
                                                       const std::vector<double>& plant_mm,
                                                       TsPlantRandom& draw) {
  BatteryEffectSettings effect;
  effect.kind = kind;
  effect.relax_fast_tau_s = std::exp(draw.Uniform(std::log(30.0), std::log(100.0)));
  effect.relax_slow_tau_s = std::exp(draw.Uniform(std::log(120.0), std::log(400.0)));
  effect.relax_fast_share = draw.Uniform(0.3, 0.7);
  effect.drift_walk = draw.Index(2) == 1;
  effect.drift_walk_seed = static_cast<uint64_t>(draw.Uniform() * 0x1.0p53);
  effect.drift_filter_tau_s = draw.Uniform(30.0, 120.0);
  effect.drift_delay_s = draw.Uniform(30.0, 300.0);
  effect.drift_tau_s = draw.Uniform(100.0, 500.0);
  effect.drift_sign = draw.Index(2) == 1 ? 1.0 : -1.0;
  double peak_mm = 0.0;
  for (double y : plant_mm) peak_mm = std::max(peak_mm, std::abs(y));
  effect.preisach_scale_mm = peak_mm > 0.0 ? peak_mm : 1.0;
  effect.preisach_centre = draw.Uniform(0.0, 0.5);
  effect.preisach_spread = draw.Uniform(0.4, 1.0);
  effect.preisach_width = draw.Uniform(0.03, 0.1);
  effect.decomposition_V = draw.Uniform(5.5, std::max(5.5, std::min(7.5, protocol.top_V - 0.5)));
  effect.tafel_V = draw.Uniform(0.1, 0.3);
  effect.negative_gain = draw.Index(2) == 1 ? draw.Uniform(1.4, 2.0) : draw.Uniform(0.3, 0.7);
  effect.negative_tau_s = draw.Uniform(3.0, 30.0);
  return effect;
}

inline std::string DescribeBatteryEffect(const BatteryEffectSettings& effect) {
  const double a = effect.amplitude;
  switch (effect.kind) {
    case BatteryEffect::kNone:
      return "none";
    case BatteryEffect::kBackRelaxation:
      return BatteryFormat("back_relaxation share %.3f, tau %.0f s (%.2f) and %.0f s", a,
                           effect.relax_fast_tau_s, effect.relax_fast_share,
                           effect.relax_slow_tau_s);
    case BatteryEffect::kSensorDrift:
      return effect.drift_walk
                 ? BatteryFormat("sensor_drift walk %.3f mm, filter %.0f s", a,
                                 effect.drift_filter_tau_s)
                 : BatteryFormat("sensor_drift warm-up %+.3f mm after %.0f s, tau %.0f s",
                                 a * effect.drift_sign, effect.drift_delay_s, effect.drift_tau_s);
    case BatteryEffect::kHysteresis:
      return BatteryFormat("hysteresis Preisach share %.3f of %.2f mm, c0 %.2f sc %.2f rho %.3f", a,
                           effect.preisach_scale_mm, effect.preisach_centre, effect.preisach_spread,
                           effect.preisach_width);
    case BatteryEffect::kCycleDegradation:
      return BatteryFormat("cycle_degradation %.3f per sqrt(1000 V s)", a);
    case BatteryEffect::kElectrolysisSaturation:
      return BatteryFormat("electrolysis_saturation V_d %.2f V, m %.2f V, R_s/R_e %.3g",
                           effect.decomposition_V, effect.tafel_V, a);
    case BatteryEffect::kPolarityAsymmetry:
      return BatteryFormat("polarity_asymmetry share %.3f, gain %.2f, tau %.1f s", a,
                           effect.negative_gain, effect.negative_tau_s);
  }
  return "?";
}

struct BatteryCaseOptions {
  std::optional<BatteryEffect> effect;  // absent: drawn from the seed (none included)
  bool faint = false;                   // target ratio U(0.7, 2) instead of U(2.5, 9)
};

struct BatteryCase {
  uint64_t seed = 0;
  TsPlant plant;
  BatteryProtocol protocol;
  BatteryEffectSettings effect;
  std::string effect_name;    // compared with model::Diagnosis::verdict
  double target_ratio = 0.0;  // 0 without an effect
  double ratio = 0.0;         // reached
  model::Recording recording;
  std::vector<double> clean_mm;  // noise-free, with the effect
  std::vector<double> plant_mm;  // noise-free, the plant alone
  std::string description;       // one line
};

// Rounds to the sensor's resolution.
inline double QuantiseDeflection(double y_mm) {
  return std::round(y_mm / kBatteryQuantum_mm) * kBatteryQuantum_mm;
}

// What the lab records: t_k, w(t_k), quantise(y_k + N(0, sigma^2)).
inline model::Recording RecordBatteryOutput(const TsPlant& plant, const TsProtocol& protocol,
                                            const std::vector<double>& clean_mm,
                                            uint64_t noise_seed, const std::string& source) {
  model::Recording recording;
  recording.source = source;
  recording.voltage_V = TsVoltageColumn(protocol);
  TsPlantRandom noise(noise_seed);
  for (size_t k = 0; k < clean_mm.size(); ++k) {
    recording.t_s.push_back(static_cast<double>(k) * kTsPlantSamplePeriod_s);
    recording.deflection_mm.push_back(
        QuantiseDeflection(clean_mm[k] + plant.noise_std_mm * noise.Normal()));
  }
  return recording;
}

// Draws one case from `seed` (file header) and records it.
inline BatteryCase DrawBatteryCase(uint64_t seed, const BatteryCaseOptions& options = {}) {
  BatteryCase out;
  out.seed = seed;
  BatteryEffect kind = BatteryEffect::kNone;
  if (options.effect) {
    kind = *options.effect;
  } else {
    TsPlantRandom choose(BatterySubSeed(seed, 0));
    const size_t index = choose.Index(7);
    if (index > 0) kind = BatteryEffectClasses()[index - 1];
  }
  out.effect_name = BatteryEffectName(kind);
  out.plant = DrawTsPlant(BatterySubSeed(seed, 1));
  TsPlantRandom protocol_draw(BatterySubSeed(seed, 2));
  do {
    out.protocol = DrawBatteryProtocol(protocol_draw);
  } while (!BatteryEffectCanShow(kind, out.protocol));
  TsPlantRandom ratio_draw(BatterySubSeed(seed, 3));
  const double target = options.faint ? ratio_draw.Uniform(0.7, 2.0) : ratio_draw.Uniform(2.5, 9.0);
  out.plant_mm = SimulateBattery(out.plant, out.protocol.protocol, {});
  TsPlantRandom effect_draw(BatterySubSeed(seed, 4));
  for (int attempt = 0;; ++attempt) {
    out.effect = DrawBatteryEffectSettings(kind, out.protocol, out.plant_mm, effect_draw);
    if (kind == BatteryEffect::kNone) break;
    try {
      out.ratio =
          ScaleBatteryEffect(out.plant, out.protocol.protocol, out.plant_mm, target, &out.effect);
      out.target_ratio = target;
      break;
    } catch (const BatteryOutOfReach&) {
      if (attempt == 20) throw;
    }
  }
  out.clean_mm = kind == BatteryEffect::kNone
                     ? out.plant_mm
                     : SimulateBattery(out.plant, out.protocol.protocol, out.effect);
  out.recording =
      RecordBatteryOutput(out.plant, out.protocol.protocol, out.clean_mm, BatterySubSeed(seed, 5),
                          "effect-battery-" + std::to_string(seed) + ".csv");
  out.description = BatteryFormat("%s; ratio %.2f; %s; plant %zu rules, T %.2f s, sigma %.3f mm",
                                  DescribeBatteryEffect(out.effect).c_str(), out.ratio,
                                  out.protocol.description.c_str(), out.plant.rules.size(),
                                  out.plant.delay_s, out.plant.noise_std_mm);
  return out;
}

// The clean identification recordings of a case's plant, as a lab makes them before the
// later recording it diagnoses: the 1-8-1 V staircase, 120 s per level (TsStaircase), and
// 600 s of random levels -8..8 V (both signs), 40-120 s each; noise and resolution as
// above, noise and levels from the case's seed.
inline std::vector<model::Recording> RecordBatteryIdentification(const BatteryCase& battery_case) {
  const uint64_t seed = battery_case.seed;
  const TsPlant& plant = battery_case.plant;
  const TsProtocol stairs = TsStaircase(120.0);
  TsPlantRandom levels_draw(BatterySubSeed(seed, 6));
  const TsProtocol bipolar = battery_detail::DrawLevels(levels_draw, 10.0, true, 600.0).protocol;
  const std::string name = "effect-battery-" + std::to_string(seed);
  return {RecordBatteryOutput(plant, stairs, SimulateBattery(plant, stairs, {}),
                              BatterySubSeed(seed, 7), name + "-staircase.csv"),
          RecordBatteryOutput(plant, bipolar, SimulateBattery(plant, bipolar, {}),
                              BatterySubSeed(seed, 8), name + "-levels.csv")};
}

}  // namespace flexid::testing
