// An independent Takagi-Sugeno test plant for the global identification
// (model/identify/identify_global.h): R local transfer functions of the seed's Eq. (18) form,
// drawn from a seed inside Eq. (18)'s coefficient intervals, each realised and integrated
// here, blended by smooth memberships on the delayed voltage, sampled at 10 Hz with
// Gaussian sensor noise.
//
// Independent of model/: only the Recording struct is used. The realisation (observer
// canonical form), the integrator (classical RK4), the memberships (smoothstep), the
// input protocols and the random numbers are written here.
//
// Notation (times in s, voltages in V, deflections in mm):
//   w(t)     applied voltage: piecewise constant, switching only at sample instants
//            (so the voltage column w(k Ts) is exact, and its zero-order hold is w);
//            w = 0 before t = 0.
//   T        dead time, drawn in [1, 6] s with T mod Ts at least 5 ms from 0 and Ts (so
//            the delayed switches t_j + T never fall on a sample instant).
//   v(t)     = w(t - T), the voltage as it reaches the actuator.
//   z(t)     = |v(t)|, the scheduling variable.
//   Rule r   (r = 1 .. R, R = 2 or 3 drawn), Eq. (18) with b1 = 1:
//              G_r(s) = kappa (a1 s^3 + a2 s^2 + a3 s + a4) / (s^4 + b2 s^3 + b3 s^2 + b4 s + b5)
//            every coefficient drawn uniformly in the r-th of R equal parts of its
//            interval (rule 1 lowest), so rule r's gain and dynamics differ from rule r+1's:
//              a1 [0.0063, 0.0085]  a2 [0.6381, 0.842]  a3 [1.152, 1.924]  a4 [1.14, 1.97]
//              b2 [0.3631, 0.5898]  b3 [225.5, 367.2]   b4 [14.98, 29.41]  b5 [0.2142, 0.2275]
//            K_r = kappa a4 / b5 is rule r's DC gain (mm/V).
//   kappa    one numerator scale for the whole plant (see "Corrections").
//   Memberships, smoothstep S(x) = 0 (x <= 0), 3x^2 - 2x^3 (0 < x < 1), 1 (x >= 1):
//              s_j(z) = S((z - c_j) / d_j + 1/2),   j = 1 .. R-1   (d_j = 0: z >= c_j)
//              mu_1 = 1 - s_1,  mu_r = s_{r-1} - s_r,  mu_R = s_{R-1}
//            boundaries c_j drawn in [3, 6.5] V, widths d_j in [0.3, 1.2] V, redrawn
//            until neighbouring transitions do not overlap (c_{j+1} - c_j >=
//            (d_j + d_{j+1}) / 2), so mu_r >= 0, sum mu_r = 1, at most two rules fire.
//   Output, rules integrated in parallel from rest, rule r in observer canonical form
//            (x_r in R^4, y_r = x_r1), driven by u_r:
//              kInputBlend (default):  u_r = mu_r(z) v,  y = sum_r y_r
//              kOutputBlend:           u_r = v,          y = sum_r mu_r(z) y_r
//            Both give y = sum_r mu_r(z) K_r v at rest on a constant voltage.
//   Sampling: t_k = k Ts, Ts = 0.1 s; voltage column w(t_k) exactly; deflection
//            y(t_k) + N(0, sigma^2), sigma drawn in [0.02, 0.03] mm. Noise: std::mt19937_64
//            and Box-Muller, so the same seed gives the same recording with every standard
//            library. The noise-free y(t_k) is returned too.
//   Integrator: classical RK4, equal steps of at most 5 ms between break points (sample
//            instants and delayed switches t_j + T), so every u_r is constant on each step.
//
// Corrections to the seed's intervals (computed, not assumed):
//   - Stability: every quartic from the intervals passes Routh-Hurwitz (b2 b3 >= 81.9 >
//     29.41 >= b4, and b4 (b2 b3 - b4) >= 1000 > 0.08 >= b2^2 b5). The draw still checks
//     it and would redraw; that never happens.
//   - Scale: a4 / b5 lies in [5.0, 9.2] per volt, so a 5 V step would settle at 25-46 mm,
//     not the 5.92 mm the seed measured at 5 V (Table 1): the output unit of Eq. (18) is
//     unstated. The minimal correction is one scale kappa on every numerator, the shape of
//     each rule untouched: kappa is drawn uniformly in [0.8 / min a4/b5, 2.0 / max a4/b5]
//     (every K_r in [0.8, 2.0] mm/V) and redrawn until the 5 V steady state
//     5 sum_r mu_r(5) K_r lies in [4, 9] mm.
//   - Left as the seed has it: each rule has a lightly damped pole pair near 15-19 rad/s
//     (damping ratio about 0.01) and two slow modes with time constants of about 15-25 s
//     and 50-110 s (for low b4 and high b3 they merge into a well damped complex pair).
//     Holds of 80-120 s end well before the plant settles. The fast
//     pair hardly shows: its share of a step response is about 3e-3 of the step per volt
//     before kappa (under 1 micrometre per volt after it), far below the noise.
//
// Why kInputBlend is the default: z jumps with v at every voltage switch, so blending
// the rules' outputs, y = sum mu_r(z) y_r jumps by (mu_r(z+) - mu_r(z-)) (y_r - y_{r'}), about
// (K_2 - K_1) v: a millimetre at 4 -> 6 V across a boundary, tens of noise sigmas, which no
// beam does. Weighting the rules' inputs instead keeps y continuous (every G_r is strictly
// proper) and has the same steady state. kOutputBlend stays available for comparison.
// A consequence: after a voltage change the old rule's share relaxes with the old rule's
// dynamics while the new rule's share rises with its own; a model that switches one
// frozen transfer function with the operating point (model/core/ts_fuzzy.h) can only
// approximate that when the rules' dynamics differ.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/core/recording.h"

namespace flexid::testing {

inline constexpr double kTsPlantSamplePeriod_s = 0.1;
inline constexpr double kTsPlantMaxStep_s = 0.005;

// ---------------------------------------------------------------------------------------
// Random numbers: std::mt19937_64 and Box-Muller (both values of each pair used).
class TsPlantRandom {
 public:
  explicit TsPlantRandom(uint64_t seed) : engine_(seed) {}
  // Uniform on (0, 1): 53 random bits, offset by half a unit so 0 and 1 never occur.
  double Uniform() { return (static_cast<double>(engine_() >> 11) + 0.5) / 9007199254740992.0; }
  double Uniform(double low, double high) { return low + (high - low) * Uniform(); }
  // Uniform integer in [0, n).
  size_t Index(size_t n) {
    const auto i = static_cast<size_t>(Uniform() * static_cast<double>(n));
    return std::min(i, n - 1);
  }
  double Normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    const double radius = std::sqrt(-2.0 * std::log(Uniform()));
    const double angle = 2.0 * std::numbers::pi * Uniform();
    spare_ = radius * std::sin(angle);
    has_spare_ = true;
    return radius * std::cos(angle);
  }

 private:
  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

// ---------------------------------------------------------------------------------------
// The plant.

// One rule: kappa-scaled numerator a1..a4 and monic denominator 1, b2..b5 (Eq. 18).
struct TsPlantRule {
  std::array<double, 4> num{};  // s^3 .. s^0
  std::array<double, 5> den{};  // s^4 .. s^0, den[0] = 1
  double DcGain() const { return num[3] / den[4]; }
};

enum class TsBlend { kInputBlend, kOutputBlend };

struct TsPlant {
  std::vector<TsPlantRule> rules;    // ascending in voltage
  std::vector<double> boundaries_V;  // c_j, rules.size() - 1 of them, ascending
  std::vector<double> widths_V;      // d_j, same size
  double delay_s = 0.0;              // T
  double noise_std_mm = 0.02;        // sigma
  double numerator_scale = 1.0;      // kappa (already in every rule's num)
  TsBlend blend = TsBlend::kInputBlend;

  // mu_r(z) for every rule (formulas in the file header).
  std::vector<double> Memberships(double z_V) const {
    auto smoothstep = [](double x) {
      if (x <= 0.0) return 0.0;
      if (x >= 1.0) return 1.0;
      return x * x * (3.0 - 2.0 * x);
    };
    std::vector<double> mu(rules.size(), 0.0);
    double previous = 1.0;  // s_0 = 1
    for (size_t j = 0; j < boundaries_V.size(); ++j) {
      const double s = widths_V[j] > 0.0 ? smoothstep((z_V - boundaries_V[j]) / widths_V[j] + 0.5)
                                         : (z_V >= boundaries_V[j] ? 1.0 : 0.0);
      mu[j] = previous - s;
      previous = s;
    }
    mu[rules.size() - 1] = previous;  // s_R = 0
    return mu;
  }

  // Steady-state deflection per volt at a constant voltage of magnitude z.
  double SteadyGainAt(double z_V) const {
    const std::vector<double> mu = Memberships(z_V);
    double gain = 0.0;
    for (size_t r = 0; r < rules.size(); ++r) gain += mu[r] * rules[r].DcGain();
    return gain;
  }
};

// Routh-Hurwitz for the monic quartic s^4 + d1 s^3 + d2 s^2 + d3 s + d4.
inline bool TsPlantQuarticIsStable(const std::array<double, 5>& den) {
  const double d1 = den[1], d2 = den[2], d3 = den[3], d4 = den[4];
  return d1 > 0.0 && d2 > 0.0 && d3 > 0.0 && d4 > 0.0 && d1 * d2 > d3 &&
         d1 * d2 * d3 > d3 * d3 + d1 * d1 * d4;
}

struct TsPlantDrawOptions {
  int rules = 0;          // 0: drawn, 2 or 3
  double width_V = -1.0;  // < 0: drawn per boundary in [0.3, 1.2] V; >= 0: every width
};

// Draws a plant from `seed` (every draw in the file header).
inline TsPlant DrawTsPlant(uint64_t seed, const TsPlantDrawOptions& options = {}) {
  struct Interval {
    double low, high;
  };
  constexpr std::array<Interval, 4> kA = {
      {{0.0063, 0.0085}, {0.6381, 0.842}, {1.152, 1.924}, {1.14, 1.97}}};
  constexpr std::array<Interval, 4> kB = {
      {{0.3631, 0.5898}, {225.5, 367.2}, {14.98, 29.41}, {0.2142, 0.2275}}};

  TsPlantRandom draw(seed);
  TsPlant plant;
  const int count = options.rules > 0 ? options.rules : (draw.Uniform() < 0.5 ? 2 : 3);
  const auto parts = static_cast<double>(count);
  for (int r = 0; r < count; ++r) {
    const auto part = static_cast<double>(r);
    auto in_part = [&](const Interval& interval) {
      const double size = (interval.high - interval.low) / parts;
      return draw.Uniform(interval.low + part * size, interval.low + (part + 1.0) * size);
    };
    TsPlantRule rule;
    for (int attempt = 0;; ++attempt) {
      if (attempt == 100) throw std::runtime_error("DrawTsPlant: no stable rule drawn");
      for (size_t i = 0; i < 4; ++i) rule.num[i] = in_part(kA[i]);
      rule.den[0] = 1.0;
      for (size_t i = 0; i < 4; ++i) rule.den[i + 1] = in_part(kB[i]);
      if (TsPlantQuarticIsStable(rule.den)) break;
    }
    plant.rules.push_back(rule);
  }

  // Boundaries and widths, redrawn until neighbouring transitions do not overlap.
  const size_t transitions = plant.rules.size() - 1;
  for (int attempt = 0; transitions > 0; ++attempt) {
    if (attempt == 1000) throw std::runtime_error("DrawTsPlant: no boundaries drawn");
    plant.boundaries_V.clear();
    plant.widths_V.clear();
    for (size_t j = 0; j < transitions; ++j) {
      plant.boundaries_V.push_back(draw.Uniform(3.0, 6.5));
      plant.widths_V.push_back(options.width_V >= 0.0 ? options.width_V : draw.Uniform(0.3, 1.2));
    }
    std::sort(plant.boundaries_V.begin(), plant.boundaries_V.end());
    bool apart = true;
    for (size_t j = 0; j + 1 < transitions; ++j)
      apart = apart && plant.boundaries_V[j + 1] - plant.boundaries_V[j] >=
                           0.5 * (plant.widths_V[j] + plant.widths_V[j + 1]);
    if (apart) break;
  }

  // kappa: every K_r in [0.8, 2] mm/V and the 5 V steady state in [4, 9] mm.
  double smallest = INFINITY, largest = 0.0;
  for (const TsPlantRule& rule : plant.rules) {
    smallest = std::min(smallest, rule.DcGain());
    largest = std::max(largest, rule.DcGain());
  }
  const double unscaled_at_5V = plant.SteadyGainAt(5.0);
  for (int attempt = 0;; ++attempt) {
    if (attempt == 1000) throw std::runtime_error("DrawTsPlant: no numerator scale drawn");
    plant.numerator_scale = draw.Uniform(0.8 / smallest, 2.0 / largest);
    const double deflection_mm = 5.0 * plant.numerator_scale * unscaled_at_5V;
    if (deflection_mm >= 4.0 && deflection_mm <= 9.0) break;
  }
  for (TsPlantRule& rule : plant.rules)
    for (double& c : rule.num) c *= plant.numerator_scale;

  // Dead time off the sample grid by at least 5 ms.
  for (;;) {
    plant.delay_s = draw.Uniform(1.0, 6.0);
    const double fraction =
        plant.delay_s / kTsPlantSamplePeriod_s - std::floor(plant.delay_s / kTsPlantSamplePeriod_s);
    if (fraction > 0.05 && fraction < 0.95) break;
  }
  plant.noise_std_mm = draw.Uniform(0.02, 0.03);
  return plant;
}

// ---------------------------------------------------------------------------------------
// Voltage protocols: w(t) = level of the last hold started at or before t (0 V before
// the first), holds starting on sample instants.

struct TsHold {
  size_t start_sample = 0;  // starts at start_sample * Ts
  double level_V = 0.0;
};

struct TsProtocol {
  std::vector<TsHold> holds;  // start samples strictly increasing
  size_t samples = 0;         // recording length
};

inline size_t TsSamplesIn(double duration_s) {
  return static_cast<size_t>(std::llround(duration_s / kTsPlantSamplePeriod_s));
}

// lead_s at 0 V, then 1, 2, .., 8, 7, .., 1 V for hold_s each, then hold_s at 0 V.
inline TsProtocol TsStaircase(double hold_s = 120.0, double lead_s = 10.0) {
  TsProtocol protocol;
  const size_t hold = TsSamplesIn(hold_s);
  size_t at = TsSamplesIn(lead_s);
  for (int level = 1; level <= 8; ++level, at += hold)
    protocol.holds.push_back({at, static_cast<double>(level)});
  for (int level = 7; level >= 1; --level, at += hold)
    protocol.holds.push_back({at, static_cast<double>(level)});
  protocol.holds.push_back({at, 0.0});
  protocol.samples = at + hold + 1;
  return protocol;
}

// lead_s at 0 V, then the levels 0, 1, .., 8 V in random order (reshuffled when all are
// used, never the same level twice in a row), each held U(40, 120) s, cut at duration_s.
inline TsProtocol TsRandomLevels(uint64_t seed, double duration_s = 600.0, double lead_s = 10.0) {
  TsPlantRandom draw(seed);
  TsProtocol protocol;
  protocol.samples = TsSamplesIn(duration_s) + 1;
  size_t at = TsSamplesIn(lead_s);
  double previous_V = 0.0;
  std::vector<double> order;
  while (at < protocol.samples) {
    if (order.empty()) {
      for (int level = 0; level <= 8; ++level) order.push_back(static_cast<double>(level));
      for (size_t i = order.size() - 1; i > 0; --i) std::swap(order[i], order[draw.Index(i + 1)]);
      if (order.back() == previous_V) std::swap(order.back(), order.front());
    }
    const double level_V = order.back();  // taken from the back
    order.pop_back();
    protocol.holds.push_back({at, level_V});
    previous_V = level_V;
    at += TsSamplesIn(draw.Uniform(40.0, 120.0));
  }
  return protocol;
}

// ---------------------------------------------------------------------------------------
// Simulation.

namespace ts_plant_detail {

using RuleState = std::array<double, 4>;

// Observer canonical form of num / den (den monic):
//   x1' = -b2 x1 + x2 + a1 u,  x2' = -b3 x1 + x3 + a2 u,
//   x3' = -b4 x1 + x4 + a3 u,  x4' = -b5 x1 + a4 u,       y = x1.
inline RuleState Rates(const TsPlantRule& rule, const RuleState& x, double u) {
  RuleState dx{};
  for (size_t i = 0; i < 4; ++i)
    dx[i] = -rule.den[i + 1] * x[0] + (i + 1 < 4 ? x[i + 1] : 0.0) + rule.num[i] * u;
  return dx;
}

// Classical RK4 over [0, span_s] in equal steps of at most kTsPlantMaxStep_s, u constant.
inline void Advance(const TsPlantRule& rule, double u, double span_s, RuleState* x) {
  if (span_s <= 0.0) return;
  const int steps = static_cast<int>(std::ceil(span_s / kTsPlantMaxStep_s - 1e-9));
  const double h = span_s / steps;
  RuleState stage{};
  for (int n = 0; n < steps; ++n) {
    const RuleState k1 = Rates(rule, *x, u);
    for (size_t i = 0; i < 4; ++i) stage[i] = (*x)[i] + 0.5 * h * k1[i];
    const RuleState k2 = Rates(rule, stage, u);
    for (size_t i = 0; i < 4; ++i) stage[i] = (*x)[i] + 0.5 * h * k2[i];
    const RuleState k3 = Rates(rule, stage, u);
    for (size_t i = 0; i < 4; ++i) stage[i] = (*x)[i] + h * k3[i];
    const RuleState k4 = Rates(rule, stage, u);
    for (size_t i = 0; i < 4; ++i) (*x)[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
  }
}

}  // namespace ts_plant_detail

// Samples a plant on the protocol's grid: `advance(h_s)` integrates it over h_s, its
// voltage is switched by `set_voltage(V)` a dead time `delay_s` after each hold starts
// (between samples, where the switch falls), and `output(k)` reads sample k.
template <typename Advance, typename SetVoltage, typename Output>
std::vector<double> SampleWithDelayedHolds(const TsProtocol& protocol, double delay_s,
                                           Advance&& advance, SetVoltage&& set_voltage,
                                           Output&& output) {
  std::vector<double> y;
  y.reserve(protocol.samples);
  double t_s = 0.0;
  size_t next_hold = 0;  // the first hold whose delayed start is still ahead
  for (size_t k = 0; k < protocol.samples; ++k) {
    const double sample_s = static_cast<double>(k) * kTsPlantSamplePeriod_s;
    while (next_hold < protocol.holds.size()) {
      const double switch_s =
          static_cast<double>(protocol.holds[next_hold].start_sample) * kTsPlantSamplePeriod_s +
          delay_s;
      if (switch_s > sample_s) break;
      advance(switch_s - t_s);
      t_s = switch_s;
      set_voltage(protocol.holds[next_hold].level_V);
      ++next_hold;
    }
    advance(sample_s - t_s);
    t_s = sample_s;
    y.push_back(output(k));
  }
  return y;
}

// Noise-free deflection at t_k = k Ts, k = 0 .. protocol.samples - 1, from rest.
inline std::vector<double> SimulateTsPlant(const TsPlant& plant, const TsProtocol& protocol) {
  using ts_plant_detail::RuleState;
  const size_t rule_count = plant.rules.size();
  std::vector<RuleState> states(rule_count, RuleState{});
  std::vector<double> mu(rule_count, 1.0 / static_cast<double>(rule_count));
  std::vector<double> inputs(rule_count, 0.0);
  double v_V = 0.0;  // delayed voltage in force
  auto set_voltage = [&](double level_V) {
    v_V = level_V;
    mu = plant.Memberships(std::abs(v_V));
    for (size_t r = 0; r < rule_count; ++r)
      inputs[r] = plant.blend == TsBlend::kInputBlend ? mu[r] * v_V : v_V;
  };
  set_voltage(0.0);
  auto advance = [&](double span_s) {
    for (size_t r = 0; r < rule_count; ++r)
      ts_plant_detail::Advance(plant.rules[r], inputs[r], span_s, &states[r]);
  };
  auto output = [&] {
    double sum_mm = 0.0;
    for (size_t r = 0; r < rule_count; ++r)
      sum_mm += (plant.blend == TsBlend::kInputBlend ? 1.0 : mu[r]) * states[r][0];
    return sum_mm;
  };

  return SampleWithDelayedHolds(protocol, plant.delay_s, advance, set_voltage,
                                [&](size_t) { return output(); });
}

// The applied voltage column w(k Ts).
inline std::vector<double> TsVoltageColumn(const TsProtocol& protocol) {
  std::vector<double> voltage_V(protocol.samples, 0.0);
  for (size_t j = 0; j < protocol.holds.size(); ++j) {
    const size_t end =
        j + 1 < protocol.holds.size() ? protocol.holds[j + 1].start_sample : protocol.samples;
    for (size_t k = protocol.holds[j].start_sample; k < std::min(end, protocol.samples); ++k)
      voltage_V[k] = protocol.holds[j].level_V;
  }
  return voltage_V;
}

struct TsRecording {
  model::Recording recording;    // deflection with noise
  std::vector<double> clean_mm;  // noise-free deflection at the same instants
};

// What the lab records: t_s = k Ts, the exact voltage, the deflection plus N(0, sigma^2)
// drawn from noise_seed.
inline TsRecording RecordTsPlant(const TsPlant& plant, const TsProtocol& protocol,
                                 uint64_t noise_seed, const std::string& source = "ts_plant") {
  TsRecording out;
  out.clean_mm = SimulateTsPlant(plant, protocol);
  out.recording.source = source;
  out.recording.voltage_V = TsVoltageColumn(protocol);
  TsPlantRandom noise(noise_seed);
  for (size_t k = 0; k < protocol.samples; ++k) {
    out.recording.t_s.push_back(static_cast<double>(k) * kTsPlantSamplePeriod_s);
    out.recording.deflection_mm.push_back(out.clean_mm[k] + plant.noise_std_mm * noise.Normal());
  }
  return out;
}

// One line per rule and the premise, for failure messages.
inline std::string DescribeTsPlant(const TsPlant& plant) {
  std::string text = "T = " + std::to_string(plant.delay_s) +
                     " s, sigma = " + std::to_string(plant.noise_std_mm) +
                     " mm, kappa = " + std::to_string(plant.numerator_scale);
  for (size_t r = 0; r < plant.rules.size(); ++r) {
    text += "\n  rule " + std::to_string(r + 1) +
            ": K = " + std::to_string(plant.rules[r].DcGain()) + " mm/V, den =";
    for (double c : plant.rules[r].den) text += " " + std::to_string(c);
    if (r < plant.boundaries_V.size())
      text += "\n  boundary " + std::to_string(plant.boundaries_V[r]) + " V, width " +
              std::to_string(plant.widths_V[r]) + " V";
  }
  return text;
}

}  // namespace flexid::testing
