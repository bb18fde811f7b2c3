#include "model/core/levels.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "model/core/errors.h"

namespace flexid::model {
namespace {

constexpr size_t kMinSamples = 10;
constexpr double kNoiseBandSigmas = 6.0;  // tau = 6 sigma_v before clamping
constexpr double kToleranceFloorOfRange = 1e-3;
constexpr double kToleranceCapOfRange = 0.05;
constexpr double kRestBandOfReference = 0.02;  // automatic rest band >= 2 % of V_ref
constexpr double kNoiseQuantile = 0.8;
constexpr double kNormalQuantile80 = 1.2815515655446004;  // Phi^-1(0.8)
constexpr double kMinPlateauFraction = 0.5;
constexpr double kNoiseDominatedRatio = 0.5;
constexpr size_t kStatisticsSamples = 1 << 17;

std::string FormatNumber(double value) {
  std::ostringstream out;
  out.precision(6);
  out << value;
  return out.str();
}

// The q-quantile (0 <= q <= 1) of `values` by selection (reorders them): the element at
// index floor(q (n - 1)) of the sorted order. Precondition: values not empty.
double SelectQuantile(std::vector<double>& values, double q) {
  const auto index = static_cast<size_t>(q * static_cast<double>(values.size() - 1));
  auto nth = values.begin() + static_cast<std::ptrdiff_t>(index);
  std::nth_element(values.begin(), nth, values.end());
  return *nth;
}

void CheckInput(std::span<const double> t_s, std::span<const double> voltage_V) {
  const size_t n = t_s.size();
  if (n < kMinSamples)
    throw InputError("too few samples (" + std::to_string(n) +
                     "): level detection needs at least " + std::to_string(kMinSamples));
  for (size_t k = 0; k < n; ++k) {
    if (!std::isfinite(t_s[k]))
      throw InputError("time is not finite at sample " + std::to_string(k));
    if (k > 0 && !(t_s[k] > t_s[k - 1]))
      throw InputError("time is not increasing at sample " + std::to_string(k) + " (" +
                       FormatNumber(t_s[k]) + " s after " + FormatNumber(t_s[k - 1]) + " s)");
    if (!std::isfinite(voltage_V[k]))
      throw InputError("voltage is not finite at sample " + std::to_string(k) +
                       " (t = " + FormatNumber(t_s[k]) + " s)");
  }
}

// sigma_v = Q_0.8(|dv - median(dv)|) / (Phi^-1(0.8) sqrt 2) from first differences dv
// (reorders and overwrites them). Precondition: not empty.
double NoiseFromDifferences(std::vector<double>& differences_V) {
  const double median_V = SelectQuantile(differences_V, 0.5);
  for (double& d : differences_V) d = std::abs(d - median_V);
  return SelectQuantile(differences_V, kNoiseQuantile) / (kNormalQuantile80 * std::numbers::sqrt2);
}

// Statistics of more than kStatisticsSamples values are taken on a deterministic stride
// through them, which keeps their cost at a few milliseconds.
size_t StatisticsStride(size_t count) { return std::max<size_t>(1, count / kStatisticsSamples); }

// Header, step 1, first pass.
double InitialTolerance(std::span<const double> voltage_V, double range_V) {
  const size_t n = voltage_V.size();
  const size_t stride = StatisticsStride(n);
  std::vector<double> values_V;
  values_V.reserve(n / stride + 1);
  for (size_t k = 0; k + 1 < n; k += stride) values_V.push_back(voltage_V[k + 1] - voltage_V[k]);
  const double sigma_V = NoiseFromDifferences(values_V);
  values_V.clear();
  for (size_t k = 0; k < n; k += stride) values_V.push_back(voltage_V[k]);
  const double median_V = SelectQuantile(values_V, 0.5);
  for (double& v : values_V) v = std::abs(v - median_V);
  const double spread_V = SelectQuantile(values_V, kNoiseQuantile) / kNormalQuantile80;
  const double noise_band_V = kNoiseBandSigmas * sigma_V;
  const bool noise_dominated = sigma_V >= kNoiseDominatedRatio * spread_V;
  return std::max(
      kToleranceFloorOfRange * range_V,
      noise_dominated ? noise_band_V : std::min(noise_band_V, kToleranceCapOfRange * range_V));
}

size_t SamplesOnPlateaus(const std::vector<Plateau>& plateaus) {
  size_t count = 0;
  for (const Plateau& p : plateaus) count += p.end - p.begin;
  return count;
}

// Whether plateaus hold at least kMinPlateauFraction of the n samples.
bool MostlyPlateaus(const std::vector<Plateau>& plateaus, size_t n) {
  return static_cast<double>(SamplesOnPlateaus(plateaus)) >=
         kMinPlateauFraction * static_cast<double>(n);
}

// Header, step 1, second pass: sigma_v from the first differences inside the plateaus.
// Precondition: plateaus not empty.
double PlateauNoise(std::span<const double> voltage_V, const std::vector<Plateau>& plateaus) {
  const size_t stride = StatisticsStride(SamplesOnPlateaus(plateaus));
  std::vector<double> differences_V;
  size_t counter = 0;
  for (const Plateau& p : plateaus)
    for (size_t k = p.begin; k + 1 < p.end; ++k)
      if (counter++ % stride == 0) differences_V.push_back(voltage_V[k + 1] - voltage_V[k]);
  return NoiseFromDifferences(differences_V);
}

// Header, step 2.
std::vector<Plateau> FindPlateaus(std::span<const double> t_s, std::span<const double> voltage_V,
                                  double tolerance_V, double min_hold_s, size_t max_glitch,
                                  size_t recording) {
  const size_t n = t_s.size();
  std::vector<Plateau> plateaus;
  size_t start = 0;
  while (start < n) {
    double sum_V = voltage_V[start];
    double count = 1.0;
    size_t last_in_band = start;
    size_t k = start + 1;
    while (k < n) {
      const double mean_V = sum_V / count;
      if (std::abs(voltage_V[k] - mean_V) <= tolerance_V) {
        sum_V += voltage_V[k];
        count += 1.0;
        last_in_band = k++;
        continue;
      }
      // An excursion: a glitch if the voltage returns within max_glitch samples.
      size_t back = k + 1;
      const size_t limit = std::min(n, k + 1 + max_glitch);
      while (back < limit && std::abs(voltage_V[back] - mean_V) > tolerance_V) ++back;
      if (back >= limit) break;
      k = back;
    }
    const size_t end = last_in_band + 1;
    if (t_s[last_in_band] - t_s[start] >= min_hold_s) {
      Plateau plateau;
      plateau.begin = start;
      plateau.end = end;
      plateau.t_start_s = t_s[start];
      plateau.t_end_s = t_s[last_in_band];
      plateau.voltage_V = sum_V / count;
      plateau.recording = recording;
      plateaus.push_back(plateau);
    }
    start = end;
  }
  return plateaus;
}

struct ClusterItem {
  double value = 0;
  double weight = 0;
  size_t id = 0;
};

// Clusters values ascending: a new cluster starts where a value exceeds the running
// weighted mean of the current cluster by more than tolerance. Returns the clusters'
// weighted means (ascending) and sets (*cluster_of)[id].
std::vector<double> Cluster(std::vector<ClusterItem> items, double tolerance,
                            std::vector<int>* cluster_of) {
  std::sort(items.begin(), items.end(), [](const ClusterItem& a, const ClusterItem& b) {
    return a.value < b.value || (a.value == b.value && a.id < b.id);
  });
  std::vector<double> means;
  double sum = 0, weight = 0;
  for (const ClusterItem& item : items) {
    if (means.empty() || item.value - sum / weight > tolerance) {
      if (!means.empty()) means.back() = sum / weight;
      means.push_back(item.value);
      sum = 0;
      weight = 0;
    }
    sum += item.weight * item.value;
    weight += item.weight;
    (*cluster_of)[item.id] = static_cast<int>(means.size() - 1);
  }
  if (!means.empty()) means.back() = sum / weight;
  return means;
}

// Header, step 7: whether samples [window_begin, end) show a voltage transition.
bool HasTransition(const std::vector<Plateau>& plateaus, size_t window_begin, size_t end,
                   double tolerance_V, size_t max_glitch) {
  auto first = std::partition_point(plateaus.begin(), plateaus.end(),
                                    [&](const Plateau& p) { return p.end <= window_begin; });
  size_t cursor = window_begin;
  double low_V = INFINITY, high_V = -INFINITY;
  for (auto p = first; p != plateaus.end() && p->begin < end; ++p) {
    if (p->begin > cursor && p->begin - cursor > max_glitch) return true;
    low_V = std::min(low_V, p->voltage_V);
    high_V = std::max(high_V, p->voltage_V);
    if (high_V - low_V > tolerance_V) return true;
    cursor = std::max(cursor, p->end);
  }
  return end > cursor && end - cursor > max_glitch;
}

}  // namespace

bool LevelDetectionOptions::IsValid(std::string* error) const {
  auto fail = [&](const std::string& message) {
    if (error != nullptr) *error = message;
    return false;
  };
  if (!(std::isfinite(min_hold_s) && min_hold_s > 0))
    return fail("min_hold_s must be positive and finite (is " + FormatNumber(min_hold_s) + ")");
  if (!(std::isfinite(tolerance_V) && tolerance_V >= 0))
    return fail("tolerance_V must be >= 0 and finite (is " + FormatNumber(tolerance_V) + ")");
  if (!(std::isfinite(rest_band_V) && rest_band_V >= 0))
    return fail("rest_band_V must be >= 0 and finite (is " + FormatNumber(rest_band_V) + ")");
  if (!(std::isfinite(lead_in_s) && lead_in_s >= 0))
    return fail("lead_in_s must be >= 0 and finite (is " + FormatNumber(lead_in_s) + ")");
  if (max_glitch_samples < 0)
    return fail("max_glitch_samples must be >= 0 (is " + std::to_string(max_glitch_samples) + ")");
  return true;
}

namespace {

// Header, steps 1-2: the tolerance (given, or a first pass and then the noise re-estimated
// inside its plateaus) and the plateaus it finds.
void FindTheTolerance(std::span<const double> t_s, std::span<const double> voltage_V,
                      const LevelDetectionOptions& options, size_t recording, double range_V,
                      LevelAnalysis* analysis) {
  const auto max_glitch = static_cast<size_t>(options.max_glitch_samples);
  auto find_plateaus = [&](double tolerance_V) {
    return FindPlateaus(t_s, voltage_V, tolerance_V, options.min_hold_s, max_glitch, recording);
  };
  if (options.tolerance_V > 0) {
    analysis->tolerance_V = options.tolerance_V;
    analysis->plateaus = find_plateaus(analysis->tolerance_V);
    return;
  }
  analysis->tolerance_V = InitialTolerance(voltage_V, range_V);
  analysis->plateaus = find_plateaus(analysis->tolerance_V);
  if (MostlyPlateaus(analysis->plateaus, voltage_V.size())) {
    const double refined_V =
        std::max(kToleranceFloorOfRange * range_V,
                 kNoiseBandSigmas * PlateauNoise(voltage_V, analysis->plateaus));
    if (refined_V != analysis->tolerance_V) {
      analysis->tolerance_V = refined_V;
      analysis->plateaus = find_plateaus(analysis->tolerance_V);
    }
  }
}

// Header, step 3: the rest band (given, or from the largest plateau or the 99 % quantile
// of |v|).
double RestBand(std::span<const double> voltage_V, const LevelDetectionOptions& options,
                const LevelAnalysis& analysis) {
  if (options.rest_band_V > 0) return options.rest_band_V;
  double reference_V = 0;
  if (!analysis.plateaus.empty()) {
    for (const Plateau& p : analysis.plateaus)
      reference_V = std::max(reference_V, std::abs(p.voltage_V));
  } else {
    const size_t n = voltage_V.size();
    std::vector<double> magnitude_V;
    for (size_t k = 0; k < n; k += StatisticsStride(n))
      magnitude_V.push_back(std::abs(voltage_V[k]));
    reference_V = SelectQuantile(magnitude_V, 0.99);
  }
  return std::max(analysis.tolerance_V, kRestBandOfReference * reference_V);
}

// Header, step 6: a continuous input is one level, its mean |v| outside the rest band
// with the sign of the mean v, over the whole recording.
void OneLevelOfAContinuousInput(std::span<const double> voltage_V, size_t recording,
                                LevelAnalysis* analysis) {
  const double rest_band_V = analysis->rest_band_V;
  auto is_rest = [rest_band_V](double v) { return std::abs(v) <= rest_band_V; };
  double sum_abs_V = 0, sum_V = 0;
  size_t count = 0;
  for (double v : voltage_V) {
    if (is_rest(v)) continue;
    sum_abs_V += std::abs(v);
    sum_V += v;
    ++count;
  }
  if (count == 0)
    throw InputError("voltage stays within the rest band (|v| <= " + FormatNumber(rest_band_V) +
                     " V): no excitation to identify from");
  VoltageLevel level;
  level.level_V = (sum_V < 0 ? -1.0 : 1.0) * sum_abs_V / static_cast<double>(count);
  level.segments.push_back({recording, 0, 0, voltage_V.size()});
  for (Plateau& p : analysis->plateaus) p.level = is_rest(p.voltage_V) ? -1 : 0;
  analysis->levels.push_back(std::move(level));
}

// Header, steps 4-5: the plateaus' voltages clustered into levels, and every stretch of
// the recording assigned to the level of its plateaus (rest plateaus to the level before,
// or after at the start), with its lead-in.
void LevelsOfThePlateaus(std::span<const double> t_s, const std::vector<ClusterItem>& items,
                         const LevelDetectionOptions& options, size_t recording,
                         LevelAnalysis* analysis) {
  std::vector<Plateau>& plateaus = analysis->plateaus;
  std::vector<int> cluster_of(plateaus.size(), -1);
  const std::vector<double> level_V = Cluster(items, analysis->tolerance_V, &cluster_of);
  analysis->levels.resize(level_V.size());
  for (size_t i = 0; i < level_V.size(); ++i) analysis->levels[i].level_V = level_V[i];
  for (size_t p = 0; p < plateaus.size(); ++p) plateaus[p].level = cluster_of[p];

  std::vector<int> assigned(plateaus.size(), -1);
  int previous = -1;
  for (size_t p = 0; p < plateaus.size(); ++p) {
    if (plateaus[p].level >= 0) previous = plateaus[p].level;
    assigned[p] = previous;
  }
  int following = -1;
  for (size_t p = plateaus.size(); p-- > 0;) {
    if (plateaus[p].level >= 0) following = plateaus[p].level;
    if (assigned[p] < 0) assigned[p] = following;
  }
  for (size_t first = 0; first < plateaus.size();) {
    size_t last = first;
    while (last + 1 < plateaus.size() && assigned[last + 1] == assigned[first]) ++last;
    LevelSegment segment;
    segment.recording = recording;
    segment.fit_begin = first == 0 ? 0 : plateaus[first - 1].end;
    segment.end = last + 1 == plateaus.size() ? t_s.size() : plateaus[last].end;
    segment.begin = segment.fit_begin;
    if (first > 0) {
      const double lead_in_start_s = t_s[segment.fit_begin] - options.lead_in_s;
      const auto begin_it = std::lower_bound(
          t_s.begin() + static_cast<std::ptrdiff_t>(plateaus[first - 1].begin),
          t_s.begin() + static_cast<std::ptrdiff_t>(segment.fit_begin), lead_in_start_s);
      segment.begin = static_cast<size_t>(begin_it - t_s.begin());
    }
    analysis->levels[static_cast<size_t>(assigned[first])].segments.push_back(segment);
    first = last + 1;
  }
}

// Header, step 7: every level is reached by a voltage transition somewhere.
void CheckEveryLevelIsExcited(const LevelAnalysis& analysis, size_t max_glitch) {
  for (const VoltageLevel& level : analysis.levels) {
    const bool excited =
        std::any_of(level.segments.begin(), level.segments.end(), [&](const LevelSegment& s) {
          const size_t window_begin =
              s.begin < s.fit_begin ? s.begin : (s.fit_begin > 0 ? s.fit_begin - 1 : 0);
          return HasTransition(analysis.plateaus, window_begin, s.end, analysis.tolerance_V,
                               max_glitch);
        });
    if (!excited)
      throw InputError("voltage level " + FormatNumber(level.level_V) +
                       " V has no excitation: the recording holds it without a voltage "
                       "transition");
  }
}

}  // namespace

LevelAnalysis DetectLevels(std::span<const double> t_s, std::span<const double> voltage_V,
                           const LevelDetectionOptions& options, size_t recording) {
  if (t_s.size() != voltage_V.size())
    throw std::invalid_argument("DetectLevels: t_s and voltage_V differ in length (" +
                                std::to_string(t_s.size()) + " and " +
                                std::to_string(voltage_V.size()) + ")");
  std::string options_error;
  if (!options.IsValid(&options_error))
    throw std::invalid_argument("DetectLevels: " + options_error);
  CheckInput(t_s, voltage_V);
  const auto [min_it, max_it] = std::minmax_element(voltage_V.begin(), voltage_V.end());
  const double range_V = *max_it - *min_it;
  if (range_V == 0.0)
    throw InputError("voltage is constant at " + FormatNumber(*min_it) +
                     " V: no excitation to identify from");

  LevelAnalysis analysis;
  FindTheTolerance(t_s, voltage_V, options, recording, range_V, &analysis);
  analysis.rest_band_V = RestBand(voltage_V, options, analysis);
  std::vector<ClusterItem> items;
  for (size_t p = 0; p < analysis.plateaus.size(); ++p) {
    const Plateau& plateau = analysis.plateaus[p];
    if (std::abs(plateau.voltage_V) > analysis.rest_band_V)
      items.push_back({plateau.voltage_V, static_cast<double>(plateau.end - plateau.begin), p});
  }
  analysis.plateau_input = !items.empty() && MostlyPlateaus(analysis.plateaus, voltage_V.size());
  if (analysis.plateau_input)
    LevelsOfThePlateaus(t_s, items, options, recording, &analysis);
  else
    OneLevelOfAContinuousInput(voltage_V, recording, &analysis);
  CheckEveryLevelIsExcited(analysis, static_cast<size_t>(options.max_glitch_samples));
  return analysis;
}

LevelAnalysis MergeLevels(const std::vector<LevelAnalysis>& per_recording, double tolerance_V) {
  if (!(std::isfinite(tolerance_V) && tolerance_V >= 0))
    throw std::invalid_argument("MergeLevels: tolerance_V must be >= 0 and finite (is " +
                                FormatNumber(tolerance_V) + ")");
  LevelAnalysis merged;
  if (per_recording.empty()) return merged;
  double merge_tolerance_V = tolerance_V;
  std::vector<ClusterItem> items;
  std::vector<size_t> first_id(per_recording.size());
  for (size_t r = 0; r < per_recording.size(); ++r) {
    const LevelAnalysis& analysis = per_recording[r];
    if (tolerance_V == 0) merge_tolerance_V = std::max(merge_tolerance_V, analysis.tolerance_V);
    merged.rest_band_V = std::max(merged.rest_band_V, analysis.rest_band_V);
    merged.plateau_input = merged.plateau_input && analysis.plateau_input;
    first_id[r] = items.size();
    for (const VoltageLevel& level : analysis.levels) {
      double fit_samples = 0;
      for (const LevelSegment& s : level.segments)
        fit_samples += static_cast<double>(s.end - s.fit_begin);
      items.push_back({level.level_V, std::max(fit_samples, 1.0), items.size()});
    }
  }
  merged.tolerance_V = merge_tolerance_V;
  std::vector<int> cluster_of(items.size(), -1);
  const std::vector<double> level_V = Cluster(items, merge_tolerance_V, &cluster_of);
  merged.levels.resize(level_V.size());
  for (size_t i = 0; i < level_V.size(); ++i) merged.levels[i].level_V = level_V[i];
  for (size_t r = 0; r < per_recording.size(); ++r) {
    const LevelAnalysis& analysis = per_recording[r];
    for (size_t i = 0; i < analysis.levels.size(); ++i) {
      std::vector<LevelSegment>& segments =
          merged.levels[static_cast<size_t>(cluster_of[first_id[r] + i])].segments;
      segments.insert(segments.end(), analysis.levels[i].segments.begin(),
                      analysis.levels[i].segments.end());
    }
    for (Plateau plateau : analysis.plateaus) {
      if (plateau.level >= 0 && static_cast<size_t>(plateau.level) < analysis.levels.size())
        plateau.level = cluster_of[first_id[r] + static_cast<size_t>(plateau.level)];
      merged.plateaus.push_back(plateau);
    }
  }
  for (VoltageLevel& level : merged.levels)
    std::stable_sort(level.segments.begin(), level.segments.end(),
                     [](const LevelSegment& a, const LevelSegment& b) {
                       return a.recording < b.recording ||
                              (a.recording == b.recording && a.begin < b.begin);
                     });
  return merged;
}

}  // namespace flexid::model
