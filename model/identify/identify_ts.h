// Identification of a T-S fuzzy model from recordings: find the voltage levels
// (levels.h), fit one local transfer function per level on that level's segments
// (identify.h; recordings that share a level are fitted jointly), and place the
// memberships on the identified levels (MakeTsModelOnLevels). Every figure is measured:
// in-sample per level, for the blend on all data, leave-one-level-out (how well the
// blend of the other levels predicts a level it was not fitted on), and on validation
// recordings when given.
//
// Recordings start at rest (0 V held before the first sample), as in `flexid simulate`.
// A segment that begins with a lead-in starts in steady state under the lead-in voltage.
// Recordings on non-uniform grids are resampled to their median sample period (voltage
// held, deflection interpolated linearly) and the result says so.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "model/core/levels.h"
#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/ts_fuzzy.h"
#include "model/identify/identify.h"

namespace flexid::model {

struct TsIdentifyOptions {
  IdentifyOptions local;         // per local model
  LevelDetectionOptions levels;  // plateau / level detection
  // Samples with t_s in [first, second) of any span are simulated but never fitted (held
  // out, e.g. for diagnosis): a level's segment that overlaps a span is fitted as pieces,
  // each simulated from the segment's start and fitted only on its own samples. The
  // recordings' deflection inside the spans still enters the linear starting estimate's
  // regressors (stage 1-2 of identify.h), so pass placeholders there if those samples
  // must stay unseen. The fit figures of TsEstimate cover every sample.
  std::vector<std::pair<double, double>> excluded_spans_s;
  bool IsValid(std::string* error) const;
};

struct LocalModelReport {
  double level_V = 0.0;
  size_t segments = 0;
  TfEstimate estimate;
};

// How the blend of the other levels predicts one level's segments.
struct LevelOutReport {
  double level_V = 0.0;
  double in_sample_rmse_mm = 0.0;  // the full blend on this level's segments
  double left_out_rmse_mm = 0.0;   // the blend without this level's local model
  double left_out_fit_percent = 0.0;
};

struct TsEstimate {
  TsModel model;                                    // one rule per level
  std::vector<LocalModelReport> local;              // ascending level
  FitFigures fit;                                   // the blend on every segment's fitted samples
  std::vector<LevelOutReport> leave_one_level_out;  // empty with one level
  bool plateau_input = true;  // false: no plateaus found, one level (levels.h)
  double dt_s = 0.0;
  std::vector<std::string> notes;  // resampling and similar, in plain words
};

// Throws InputError for unusable recordings (named by Recording::source).
TsEstimate IdentifyTsModel(const std::vector<Recording>& recordings,
                           const TsIdentifyOptions& options = {});

// The model file of a per-level identification, as both `flexid identify --method time`
// and flexidd write it: the model (one transfer function, or the T-S blend), its fit, each
// local model's level, fit, coefficient intervals, DC gain, poles and noise (in the
// document's extra members for one level, in local_extra for several), the
// leave-one-level-out figures and the notes.
ModelDocument ToModelDocument(const TsEstimate& estimate);

// {"NAME": {"value": .., "half_width_95": ..}} (null half-width when not determined).
nlohmann::json ParameterEstimatesToJson(const std::vector<ParameterEstimate>& estimates);
// [{"re", "im", "re_half_width_95", "im_half_width_95"}].
nlohmann::json PoleEstimatesToJson(const std::vector<PoleEstimate>& poles);

// Fit figures of a T-S model on whole recordings (validation).
FitFigures EvaluateTsFit(const TsModel& model, const std::vector<Recording>& recordings,
                         int correlation_lags = 25);

}  // namespace flexid::model
