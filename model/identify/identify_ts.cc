#include "model/identify/identify_ts.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

// A level's segment in the form the local fit uses. A segment at the start of its
// recording starts at rest. One with a lead-in starts where the previous level left the
// actuator: at an equilibrium that the new level's model does not share, because the
// gain changes with voltage. The lead-in is dropped and the voltage held before the
// segment is fitted (identify.h, estimate_initial_voltage): the model starts at the
// equilibrium that explains the measured deflection, and its gain is the absolute gain
// at the level.
DataSegment FitSegment(const UniformRecording& rec, const LevelSegment& seg) {
  DataSegment data;
  data.dt_s = rec.dt_s;
  const size_t first = seg.begin == 0 ? 0 : seg.fit_begin;
  data.voltage_V.assign(rec.voltage_V.begin() + static_cast<long>(first),
                        rec.voltage_V.begin() + static_cast<long>(seg.end));
  data.deflection_mm.assign(rec.deflection_mm.begin() + static_cast<long>(first),
                            rec.deflection_mm.begin() + static_cast<long>(seg.end));
  data.fit_begin = seg.begin == 0 ? seg.fit_begin : 0;
  if (seg.begin > 0) {
    data.initial_voltage_V = rec.voltage_V[seg.fit_begin - 1];  // the lead-in's voltage
    data.estimate_initial_voltage = true;
  }
  return data;
}

// The fitted samples of `data` (recording indices first + i) outside the excluded spans,
// as pieces that each simulate from the segment's start: [0, piece end) with the piece's
// samples after fit_begin. Pieces with fewer than 2 fitted samples are dropped.
std::vector<DataSegment> WithoutExcludedSpans(DataSegment data, const UniformRecording& rec,
                                              size_t first,
                                              const std::vector<std::pair<double, double>>& spans) {
  if (spans.empty()) return {std::move(data)};
  auto excluded = [&](size_t i) {
    const double t = rec.t_s[first + i];
    for (const auto& [a, b] : spans)
      if (t >= a && t < b) return true;
    return false;
  };
  std::vector<DataSegment> pieces;
  size_t i = data.fit_begin;
  const size_t n = data.voltage_V.size();
  while (i < n) {
    while (i < n && excluded(i)) ++i;
    const size_t begin = i;
    while (i < n && !excluded(i)) ++i;
    if (i - begin < 2) continue;
    DataSegment piece = data;
    piece.voltage_V.resize(i);
    piece.deflection_mm.resize(i);
    piece.fit_begin = begin;
    pieces.push_back(std::move(piece));
  }
  return pieces;
}

// A level's segment as recorded (absolute values), starting in steady state under its
// first voltage when it has a lead-in: what the blend is evaluated on.
DataSegment AbsoluteSegment(const UniformRecording& rec, const LevelSegment& seg) {
  DataSegment data;
  data.dt_s = rec.dt_s;
  data.voltage_V.assign(rec.voltage_V.begin() + static_cast<long>(seg.begin),
                        rec.voltage_V.begin() + static_cast<long>(seg.end));
  data.deflection_mm.assign(rec.deflection_mm.begin() + static_cast<long>(seg.begin),
                            rec.deflection_mm.begin() + static_cast<long>(seg.end));
  data.fit_begin = seg.fit_begin - seg.begin;
  data.initial_voltage_V = seg.begin == 0 ? 0.0 : data.voltage_V.front();
  return data;
}

// Predictions of a T-S model on a segment, from the segment's initial steady state.
std::vector<double> PredictSegment(const TsModel& model, const DataSegment& seg) {
  return SimulateUniform(model, seg.dt_s, seg.voltage_V,
                         {.initial_voltage_V = seg.initial_voltage_V});
}

FitFigures SegmentsFit(const TsModel& model, const std::vector<DataSegment>& segments, int lags) {
  return FitOnSegments(
      segments, [&model](const DataSegment& seg) { return PredictSegment(model, seg); }, lags);
}

}  // namespace

bool TsIdentifyOptions::IsValid(std::string* error) const {
  for (const auto& [a, b] : excluded_spans_s)
    if (!std::isfinite(a) || !std::isfinite(b) || !(a < b)) {
      *error = "an excluded span needs finite times with start < end";
      return false;
    }
  return local.IsValid(error) && levels.IsValid(error);
}

TsEstimate IdentifyTsModel(const std::vector<Recording>& recordings,
                           const TsIdentifyOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("identification options: " + why);
  if (recordings.empty()) throw InputError("no recordings to identify from");
  TsEstimate result;
  const std::vector<UniformRecording> uniform = OnCommonUniformGrid(recordings, &result.notes);
  std::vector<LevelAnalysis> analyses;
  for (size_t r = 0; r < recordings.size(); ++r) {
    const UniformRecording& u = uniform[r];
    try {
      analyses.push_back(DetectLevels(u.t_s, u.voltage_V, options.levels, r));
    } catch (const InputError& e) {
      throw InputError(recordings[r].source + ": " + e.what());
    }
  }
  result.dt_s = uniform.front().dt_s;
  const LevelAnalysis levels = MergeLevels(analyses, 0.0);
  result.plateau_input = levels.plateau_input;

  // One local model per level.
  std::vector<std::vector<DataSegment>> level_segments;
  std::vector<LocalModel> rules;
  for (const VoltageLevel& level : levels.levels) {
    std::vector<DataSegment> segments, absolute;
    for (const LevelSegment& seg : level.segments) {
      const UniformRecording& rec = uniform[seg.recording];
      for (DataSegment& piece :
           WithoutExcludedSpans(FitSegment(rec, seg), rec, seg.begin == 0 ? 0 : seg.fit_begin,
                                options.excluded_spans_s))
        segments.push_back(std::move(piece));
      absolute.push_back(AbsoluteSegment(uniform[seg.recording], seg));
    }
    LocalModelReport report;
    report.level_V = level.level_V;
    report.segments = segments.size();
    // Levels are fitted in ascending order, each also started from the previous level's
    // model, so that neighbouring local models share a structure (a fast mode stays a
    // fast mode) and their blend between the levels is meaningful.
    IdentifyOptions local_options = options.local;
    if (!rules.empty()) local_options.start = rules.back().tf;
    try {
      report.estimate = IdentifyTransferFunction(segments, local_options);
    } catch (const InputError& e) {
      char level_text[32];
      std::snprintf(level_text, sizeof level_text, "%.4g V", level.level_V);
      throw InputError(std::string("level ") + level_text + ": " + e.what());
    }
    rules.push_back({level.level_V, report.estimate.tf, {}});
    result.local.push_back(std::move(report));
    level_segments.push_back(std::move(absolute));
  }
  // Rest keeps the last level's operating point: each local model was fitted on its
  // level's relaxation too (ts_fuzzy.h, kAbsVoltageHeld).
  result.model =
      MakeTsModelOnLevels(rules, SchedulingVariable::kAbsVoltageHeld, levels.rest_band_V);

  std::vector<DataSegment> all;
  for (const auto& segments : level_segments)
    all.insert(all.end(), segments.begin(), segments.end());
  result.fit = SegmentsFit(result.model, all, options.local.correlation_lags);

  // Leave one level out: the blend of the other levels on this level's segments.
  if (rules.size() >= 2) {
    for (size_t left_out = 0; left_out < rules.size(); ++left_out) {
      std::vector<LocalModel> others;
      for (size_t i = 0; i < rules.size(); ++i)
        if (i != left_out) others.push_back(rules[i]);
      const TsModel reduced =
          MakeTsModelOnLevels(others, SchedulingVariable::kAbsVoltageHeld, levels.rest_band_V);
      const FitFigures in_sample = SegmentsFit(result.model, level_segments[left_out], 1);
      const FitFigures out = SegmentsFit(reduced, level_segments[left_out], 1);
      result.leave_one_level_out.push_back(
          {rules[left_out].level_V, in_sample.rmse_mm, out.rmse_mm, out.fit_percent});
    }
  }
  return result;
}

FitFigures EvaluateTsFit(const TsModel& model, const std::vector<Recording>& recordings,
                         int correlation_lags) {
  std::vector<double> measured, predicted, input;
  for (const Recording& rec : recordings) {
    if (rec.deflection_mm.size() != rec.t_s.size())
      throw InputError(rec.source + ": validation needs a deflection_mm column");
    const std::vector<double> y = Simulate(model, rec.t_s, rec.voltage_V);
    measured.insert(measured.end(), rec.deflection_mm.begin(), rec.deflection_mm.end());
    predicted.insert(predicted.end(), y.begin(), y.end());
    input.insert(input.end(), rec.voltage_V.begin(), rec.voltage_V.end());
  }
  if (measured.empty()) throw InputError("no validation samples");
  return FitFiguresOf(measured, predicted, input, correlation_lags);
}

namespace {

nlohmann::json NumberOrNull(double value) {
  return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(nullptr);
}

}  // namespace

nlohmann::json ParameterEstimatesToJson(const std::vector<ParameterEstimate>& estimates) {
  nlohmann::json out = nlohmann::json::object();
  for (const auto& e : estimates)
    out[e.name] = {{"value", e.value}, {"half_width_95", NumberOrNull(e.half_width_95)}};
  return out;
}

nlohmann::json PoleEstimatesToJson(const std::vector<PoleEstimate>& poles) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& p : poles)
    out.push_back({{"re", p.re},
                   {"im", p.im},
                   {"re_half_width_95", NumberOrNull(p.re_half_width_95)},
                   {"im_half_width_95", NumberOrNull(p.im_half_width_95)}});
  return out;
}

ModelDocument ToModelDocument(const TsEstimate& estimate) {
  ModelDocument doc;
  if (estimate.local.size() == 1) {
    doc = FromTransferFunction(estimate.local[0].estimate.tf);
    doc.extra["level_V"] = estimate.local[0].level_V;
  } else {
    doc = FromTsModel(estimate.model);
  }
  for (size_t i = 0; i < estimate.local.size(); ++i) {
    const TfEstimate& e = estimate.local[i].estimate;
    nlohmann::json local = {
        {"fit", FitFiguresToJson(e.fit)},
        {"intervals", ParameterEstimatesToJson(e.coefficients)},
        {"dc_gain",
         {{"value", e.dc_gain.value}, {"half_width_95", NumberOrNull(e.dc_gain.half_width_95)}}},
        {"poles", PoleEstimatesToJson(e.poles)},
        {"noise_std_mm", e.noise_std_mm}};
    if (estimate.local.size() == 1) {
      for (auto& [key, value] : local.items()) doc.extra[key] = value;
    } else if (i < doc.local_extra.size()) {
      doc.local_extra[i] = local;
    }
  }
  doc.extra["fit"] = FitFiguresToJson(estimate.fit);
  if (!estimate.leave_one_level_out.empty()) {
    nlohmann::json lolo = nlohmann::json::array();
    for (const auto& r : estimate.leave_one_level_out)
      lolo.push_back({{"level_V", r.level_V},
                      {"in_sample_rmse_mm", r.in_sample_rmse_mm},
                      {"left_out_rmse_mm", r.left_out_rmse_mm},
                      {"left_out_fit_percent", NumberOrNull(r.left_out_fit_percent)}});
    doc.extra["leave_one_level_out"] = lolo;
  }
  if (!estimate.notes.empty()) doc.extra["notes"] = estimate.notes;
  return doc;
}

}  // namespace flexid::model
