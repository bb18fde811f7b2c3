// The charts flexid draws of a model and a recording, shared by `flexid plot` and
// `flexid report` (rendered with svg_plot.h or png_plot.h):
//   fit          measured and predicted deflection over time, the applied voltage below
//   residual     measured - predicted over time
//   bode         magnitude (dB) and phase (degrees, dead time included) of local models
//                against log10 of the angular frequency
//   memberships  each rule's normalised membership against the scheduling value
// and where the two commands take their model and recording from: files, or the trials
// and models flexidd stores (source.h: online, or offline with --db).
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "clients/cli/svg_plot.h"
#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::cli {

// A model named on the command line: --model FILE, or --actuator ID [--version V] for a
// stored one (no version: the active model).
struct ModelChoice {
  std::string path;
  std::string actuator;
  std::optional<int32_t> version;
  bool Given() const { return !path.empty() || !actuator.empty(); }
};

// Throws UsageError (one line) for --model with --actuator, --version without --actuator
// or a version below 1.
void CheckModelChoice(const ModelChoice& choice);

struct LoadedModel {
  model::ModelDocument doc;
  std::string name;  // the file's path, or e.g. "S1 model v3" / "S1 active model"
};
LoadedModel LoadModel(const ModelChoice& choice);

// A recording named on the command line: a CSV file, or a stored trial (--trial N).
struct LoadedRecording {
  model::Recording recording;
  std::string name;      // the path, or "trial N"
  std::string actuator;  // of a stored trial; empty for a file
};
// Exactly one of csv_path and trial must be given (the caller checks). A trial is read
// page by page with a Progress line.
LoadedRecording LoadRecording(const std::string& csv_path, std::optional<int64_t> trial);

// The deflection the model predicts for the recording's voltage, its file's augmentations
// applied (as `flexid simulate` does). model_name names the model in errors. Throws
// OperationError naming the model and the time when the prediction diverges.
std::vector<double> PredictDeflection(const model::ModelDocument& doc,
                                      const model::Recording& recording,
                                      const std::string& model_name);

// Deflection (measured and predicted) and, below it, the applied voltage (held).
std::vector<Chart> FitCharts(const model::Recording& recording,
                             const std::vector<double>& predicted_mm, const std::string& title);

// Measured - predicted.
Chart ResidualChart(const model::Recording& recording, const std::vector<double>& predicted_mm,
                    const std::string& title);

// Magnitude and phase charts of the model's local models over 1e-4 .. 1e2 rad/s; only
// rule `rule` when given (its colour stays that of its position in the model).
std::vector<Chart> BodeCharts(const model::TsModel& model, const std::string& title,
                              std::optional<size_t> rule = std::nullopt);

// Each rule's normalised membership against the scheduling value, 0 .. 1.25 x the
// largest level.
Chart MembershipChart(const model::TsModel& model, const std::string& title);

}  // namespace flexid::cli
