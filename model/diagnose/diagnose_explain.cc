#include "model/diagnose/diagnose_explain.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <functional>

namespace flexid::model::diagnosis {

// -----------------------------------------------------------------------------------------
// Locating: residual by operating condition, and where an effect acts
// -----------------------------------------------------------------------------------------

std::string Format(const char* fmt, double a) {
  const int size = std::snprintf(nullptr, 0, fmt, a);
  std::string out(static_cast<size_t>(std::max(size, 0)) + 1, '\0');
  std::snprintf(out.data(), out.size(), fmt, a);
  out.pop_back();
  return out;
}

std::vector<ResidualGroup> GroupResiduals(const Data& data, std::span<const double> r,
                                          std::span<const double> baseline_mm,
                                          double transition_s) {
  const Recording& rec = *data.rec;
  const size_t n = r.size();
  std::vector<ResidualGroup> groups;
  auto add = [&](const std::string& dimension, const std::string& group,
                 const std::function<bool(size_t)>& member) {
    ResidualGroup g{dimension, group, 0, 0.0, 0.0};
    for (size_t k = 0; k < n; ++k)
      if (member(k)) {
        ++g.samples;
        g.mean_mm += r[k];
        g.rms_mm += r[k] * r[k];
      }
    if (g.samples == 0) return;
    g.mean_mm /= static_cast<double>(g.samples);
    g.rms_mm = std::sqrt(g.rms_mm / static_cast<double>(g.samples));
    groups.push_back(std::move(g));
  };
  // Condition: rest, transition (within transition_s of a voltage change), held.
  std::vector<double> since_change(n, kInf);
  double last_change = -kInf;
  for (size_t k = 0; k < n; ++k) {
    if (k > 0 && std::abs(rec.voltage_V[k] - rec.voltage_V[k - 1]) > 2.0 * data.rest_band_V)
      last_change = rec.t_s[k];
    since_change[k] = rec.t_s[k] - last_change;
  }
  auto rest = [&](size_t k) { return std::abs(rec.voltage_V[k]) <= data.rest_band_V; };
  add("condition", "transition", [&](size_t k) { return since_change[k] < transition_s; });
  add("condition", "held voltage",
      [&](size_t k) { return since_change[k] >= transition_s && !rest(k); });
  add("condition", "rest (no input)",
      [&](size_t k) { return since_change[k] >= transition_s && rest(k); });
  // Level and polarity.
  for (double level : data.abs_levels_V)
    add("level", Format("%.3g V", level), [&](size_t k) {
      return !rest(k) && std::abs(std::abs(rec.voltage_V[k]) - level) <=
                             std::max(data.levels.tolerance_V, 0.05 * level);
    });
  add("polarity", "positive", [&](size_t k) { return rec.voltage_V[k] > data.rest_band_V; });
  add("polarity", "negative", [&](size_t k) { return rec.voltage_V[k] < -data.rest_band_V; });
  // Cycle number (excursions from rest) and cumulative charge.
  std::vector<int> cycle(n, 0);
  std::vector<double> charge(n, 0.0);
  int cycles = 0;
  for (size_t k = 0; k < n; ++k) {
    if (k > 0) {
      if (!rest(k) && rest(k - 1)) ++cycles;
      charge[k] = charge[k - 1] + std::abs(rec.voltage_V[k - 1]) * (rec.t_s[k] - rec.t_s[k - 1]);
    } else if (!rest(k)) {
      cycles = 1;
    }
    cycle[k] = cycles;
  }
  if (cycles >= 2) {
    const int per = std::max(1, (cycles + 7) / 8);  // at most 8 groups
    for (int c = 1; c <= cycles; c += per)
      add("cycle",
          per == 1
              ? "cycle " + std::to_string(c)
              : "cycles " + std::to_string(c) + "-" + std::to_string(std::min(cycles, c + per - 1)),
          [&, c, per](size_t k) { return cycle[k] >= c && cycle[k] < c + per; });
  }
  const double total = charge.back();
  if (total > 0)
    for (int third = 0; third < 3; ++third)
      add("charge",
          Format("%.0f", 100.0 * third / 3) + "-" +
              Format("%.0f %% of charge", 100.0 * (third + 1) / 3),
          [&, third](size_t k) {
            const double f = charge[k] / total;
            return f >= third / 3.0 && (f < (third + 1) / 3.0 || (third == 2 && f <= 1.0));
          });
  // Direction of motion of the model's deflection.
  double range = 0.0;
  for (double y : baseline_mm) range = std::max(range, std::abs(y));
  const double still = 1e-3 * range / 10.0;  // mm/s: 0.1 % of the range in 10 s
  auto rate = [&](size_t k) {
    if (k == 0) return 0.0;
    return (baseline_mm[k] - baseline_mm[k - 1]) / (rec.t_s[k] - rec.t_s[k - 1]);
  };
  add("motion", "rising", [&](size_t k) { return rate(k) > still; });
  add("motion", "falling", [&](size_t k) { return rate(k) < -still; });
  add("motion", "still", [&](size_t k) { return std::abs(rate(k)) <= still; });
  return groups;
}

std::vector<TimeSpan> Spans(const Recording& rec, std::span<const double> delta, double threshold,
                            double join_s) {
  struct Run {
    TimeSpan span;
    double weight = 0.0;
  };
  std::vector<Run> runs;
  for (size_t k = 0; k < delta.size(); ++k) {
    if (std::abs(delta[k]) < threshold) continue;
    if (!runs.empty() && rec.t_s[k] - runs.back().span.t_end_s <= join_s) {
      runs.back().span.t_end_s = rec.t_s[k];
    } else {
      runs.push_back({{rec.t_s[k], rec.t_s[k]}, 0.0});
    }
    runs.back().weight += std::abs(delta[k]);
  }
  std::erase_if(runs, [](const Run& r) { return r.span.t_end_s <= r.span.t_start_s; });
  if (runs.size() > 12) {
    std::stable_sort(runs.begin(), runs.end(),
                     [](const Run& a, const Run& b) { return a.weight > b.weight; });
    runs.resize(12);
    std::stable_sort(runs.begin(), runs.end(), [](const Run& a, const Run& b) {
      return a.span.t_start_s < b.span.t_start_s;
    });
  }
  std::vector<TimeSpan> out;
  for (const Run& r : runs) out.push_back(r.span);
  return out;
}

bool SizeDetermined(const Effect& effect, const Eigen::MatrixXd& covariance,
                    const Eigen::MatrixXd& null_space, double duration_s, double top_V,
                    std::string* text) {
  const size_t k = effect.params.size();
  std::vector<std::pair<std::string, std::function<double(const std::vector<double>&)>>> sizes;
  switch (effect.kind) {
    case EffectKind::kElectrolysisSaturation:
      // What the data see: the drive lost at the highest level (onset and slope alone
      // trade off when one level lies above the onset).
      sizes.push_back({Format("drive lost at %.3g V", top_V), [=](const std::vector<double>& p) {
                         return std::max(top_V - p[0], 0.0) * (1.0 - p[1]);
                       }});
      break;
    case EffectKind::kPolarityAsymmetry:
      sizes.push_back({"1 - ratio", [](const std::vector<double>& p) { return 1.0 - p[0]; }});
      break;
    case EffectKind::kSensorDrift:
      for (double at : {0.5, 1.0})
        sizes.push_back(
            {Format("drift at %.0f s", at * duration_s), [=](const std::vector<double>& p) {
               return p[0] * at + p[1] * (1.0 - std::exp(-at * duration_s / std::max(p[2], 1e-9)));
             }});
      break;
    default:
      sizes.push_back({EffectParameterNames(effect.kind)[0],
                       [](const std::vector<double>& p) { return p[0]; }});
      break;
  }
  const long q = covariance.rows();
  bool determined = false;
  for (const auto& [name, size] : sizes) {
    const double value = size(effect.params);
    double half_width = kInf;
    if (q >= static_cast<long>(k)) {
      // Delta method on the effect's block of the covariance.
      Eigen::VectorXd g(static_cast<long>(k));
      for (size_t i = 0; i < k; ++i) {
        std::vector<double> p = effect.params;
        const double h = 1e-6 * std::max(std::abs(p[i]), 1e-3);
        p[i] += h;
        g(static_cast<long>(i)) = (size(p) - value) / h;
      }
      const Eigen::MatrixXd block =
          covariance.bottomRightCorner(static_cast<long>(k), static_cast<long>(k));
      // Parameters the size does not depend on are left out (a held one has an infinite
      // variance). A size that moves along a direction the data do not determine is not
      // determined.
      double variance = 0.0;
      if (null_space.cols() > 0) {
        const Eigen::MatrixXd n = null_space.bottomRows(static_cast<long>(k));
        if ((n.transpose() * g).norm() > 1e-6 * g.norm() * std::max(n.norm(), 1e-300))
          variance = kInf;
      }
      for (long a = 0; a < static_cast<long>(k); ++a)
        for (long b = 0; b < static_cast<long>(k); ++b)
          if (g(a) != 0.0 && g(b) != 0.0) variance += g(a) * block(a, b) * g(b);
      half_width = std::isfinite(variance) ? 1.96 * std::sqrt(std::max(0.0, variance)) : kInf;
    }
    if (!text->empty()) *text += ", ";
    *text += name + " " + Format("%.3g", value) +
             (std::isfinite(half_width) ? " +- " + Format("%.2g", half_width)
                                        : std::string(" not determined"));
    determined |= std::isfinite(half_width) && std::abs(value) > half_width;
  }
  return determined;
}

std::vector<TimeSpan> WhereItActs(const Data& data, std::span<const double> delta,
                                  EffectKind kind) {
  double peak = 0.0;
  for (double d : delta) peak = std::max(peak, std::abs(d));
  const double threshold = std::max(0.5 * data.noise_mm, 0.3 * peak);
  if (kind != EffectKind::kBackRelaxation && kind != EffectKind::kCreep)
    return Spans(*data.rec, delta, threshold, 2.0);
  std::vector<TimeSpan> where;
  for (const Plateau& p : data.levels.plateaus) {
    if (p.level < 0 || p.end > delta.size()) continue;
    double largest = 0.0;
    for (size_t k = p.begin; k < p.end; ++k) largest = std::max(largest, std::abs(delta[k]));
    if (largest >= threshold) where.push_back({p.t_start_s, p.t_end_s});
  }
  return where;
}

// -----------------------------------------------------------------------------------------
// Explanations
// -----------------------------------------------------------------------------------------

std::string Mm(double v) { return Format("%.3g mm", v); }

namespace {

struct HoldSummary {
  int holds = 0;
  double mean_duration_s = 0.0;
  double level_V = 0.0;  // the most held |level|
};

HoldSummary Holds(const Data& data) {
  HoldSummary h;
  std::vector<double> duration_at(data.abs_levels_V.size(), 0.0);
  double total = 0.0;
  for (const Plateau& p : data.levels.plateaus) {
    if (p.level < 0) continue;
    ++h.holds;
    const double d = p.t_end_s - p.t_start_s;
    total += d;
    const double v = std::abs(p.voltage_V);
    for (size_t i = 0; i < data.abs_levels_V.size(); ++i)
      if (std::abs(v - data.abs_levels_V[i]) <= std::max(data.levels.tolerance_V, 0.05 * v))
        duration_at[i] += d;
  }
  if (h.holds > 0) h.mean_duration_s = total / h.holds;
  if (!duration_at.empty())
    h.level_V = data.abs_levels_V[static_cast<size_t>(
        std::max_element(duration_at.begin(), duration_at.end()) - duration_at.begin())];
  return h;
}

}  // namespace

std::string Explain(const Effect& e, const Data& data, std::span<const double> delta,
                    double before_mm, double after_mm, const std::string& model_words) {
  const HoldSummary holds = Holds(data);
  const std::string recordings = data.Recordings() > 1 ? "the recordings" : "the recording";
  double peak = 0.0;
  for (double d : delta) peak = std::max(peak, std::abs(d));
  std::string text;
  const std::string where_holds = holds.holds > 0
                                      ? "during the " + std::to_string(holds.holds) + " holds" +
                                            Format(" (%.0f s on average", holds.mean_duration_s) +
                                            Format(", mostly at %.3g V)", holds.level_V)
                                      : "under sustained voltage";
  switch (e.kind) {
    case EffectKind::kBackRelaxation:
      text = where_holds + " the measured deflection falls back up to " + Mm(peak) +
             Format(" with a %.0f s time constant", e.params[1]) + " while " + model_words +
             " holds steady: back-relaxation";
      break;
    case EffectKind::kCreep:
      text = where_holds + " the measured deflection keeps growing, up to " + Mm(peak) +
             Format(" beyond the model with a %.0f s time constant", e.params[1]) + ": creep";
      break;
    case EffectKind::kCycleDegradation:
      text = "the response shrinks as charge is transferred: by the end of " + recordings +
             Format(" the gain is %.1f %% lower than at the start", 100.0 * e.params[0]) +
             (e.params[1] < 0.9 ? Format(", lost fastest at first (as charge^%.2f)", e.params[1])
                                : std::string(", lost at a steady rate per charge")) +
             " (up to " + Mm(peak) + " at the last cycles): cycle degradation";
      break;
    case EffectKind::kHysteresis:
      text = "whenever the motion reverses, the measured deflection lags " + model_words +
             " by up to " + Mm(std::abs(e.params[0])) + ", switching over the first " +
             Mm(e.params[1]) +
             " of travel, at any rate, and keeps that offset while the voltage holds and at rest: "
             "hysteresis";
      break;
    case EffectKind::kElectrolysisSaturation:
      text = Format("above %.2f V", e.params[0]) +
             Format(" the deflection grows only %.3g times as fast with voltage as ", e.params[1]) +
             model_words + " predicts (up to " + Mm(peak) + " less): electrolysis saturation";
      break;
    case EffectKind::kDeadZone:
      text = Format("the first %.2f V of every level move nothing", e.params[0]) + " (up to " +
             Mm(peak) + " less than " + model_words + "): a dead zone";
      break;
    case EffectKind::kSensorDrift:
      // The drift as it acts, not its two terms: when the warm-up is slower than the
      // recording the terms nearly cancel (2.89 mm of trend against -10.4 mm of warm-up
      // for 0.1 mm of drift on one battery recording), and neither is the sensor's drift.
      text = "the measured baseline drifts by up to " + Mm(peak) + " (" +
             Mm(delta.empty() ? 0.0 : delta.back()) + " at the end of " + recordings +
             "), with no relation to the voltage, also at rest: sensor drift";
      break;
    case EffectKind::kPolarityAsymmetry:
      text = Format("negative voltage moves the beam %.3g times as much as ", e.params[0]) +
             model_words + " predicts (up to " + Mm(peak) + "): polarity asymmetry";
      break;
  }
  text += ", which " + model_words + " leaves out; adding it cut held-out RMSE from " +
          Format("%.3g", before_mm) + " to " + Format("%.3g mm", after_mm);
  return text;
}

std::vector<Absorbed> ReadAgainstPhysics(const TsModel& model, double noise_mm) {
  std::vector<Absorbed> found;
  // Read each local model against the physics chain.
  for (const LocalModel& rule : model.rules) {
    const FallBack fall = StepFallBack(rule.tf);
    const double amplitude_mm = fall.share * std::abs(DcGain(rule.tf) * rule.level_V);
    if (fall.share < 0.01 || amplitude_mm < 2.0 * noise_mm) continue;
    Absorbed absorbed;
    absorbed.effect = "back_relaxation";
    absorbed.level_V = rule.level_V;
    absorbed.tau_s = fall.tau_s;
    absorbed.fall_back = fall.share;
    absorbed.amplitude_mm = amplitude_mm;
    absorbed.explanation =
        Format("the model identified at %.3g V rises ", rule.level_V) + Mm(amplitude_mm) +
        Format(" (%.1f %%) above its final value", 100.0 * fall.share) +
        Format(" and falls back with a %.0f s time constant", fall.tau_s) +
        ", while the physics chain (Eqs. 11-13) predicts a rise without falling back: the "
        "free fit absorbed back-relaxation as a slow pole-zero pair";
    found.push_back(absorbed);
  }
  return found;
}

}  // namespace flexid::model::diagnosis
