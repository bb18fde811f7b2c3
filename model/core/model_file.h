// The model file format "flexid.model/1" (DESIGN.md, "Contracts other tools rely on"):
// one JSON object holding either one transfer function or a T-S fuzzy model.
//
// Transfer function (the smallest valid file):
//   {"format": "flexid.model/1", "kind": "tf",
//    "num": [0.0085, 0.842, 1.924, 1.97], "den": [1, 0.5898, 367.2, 29.41, 0.2275],
//    "delay_s": 3.67}
// T-S fuzzy model:
//   {"format": "flexid.model/1", "kind": "ts_fuzzy",
//    "local_models": [{"level_V": 2, "num": [...], "den": [...], "delay_s": 3.1, ...}, ...],
//    "scheduling": {"variable": "abs_voltage",
//                   "memberships": [{"shape": "trapezoidal", "params": [null, null, 2, 4]},
//                                   ...]},
//    "augmentations": [{"effect": "back_relaxation", "params": {...}}]}
//
// Rules:
//   - num and den are non-empty arrays of finite numbers, highest power first; den[0] != 0
//     (the convention is den[0] == 1, but any non-zero leading coefficient is read as
//     written); deg num <= deg den. delay_s is optional (default 0), finite and >= 0.
//   - every local model has level_V (finite); all local models have the same order.
//   - scheduling.variable is "abs_voltage" (the default when absent), "voltage",
//     "abs_voltage_held" (with optional rest_band_V) or "abs_voltage_delayed" (with
//     optional delay_s, the premise's delay; default the smallest local dead time);
//     memberships has one entry per local model, in the same order; shape is
//     "triangular", "trapezoidal", "gaussian" or "sigmoid" with the parameters of
//     ts_fuzzy.h's Membership. In trapezoidal parameters JSON null stands for -infinity
//     in the first two positions and +infinity in the last two (a shoulder).
//   - augmentations are optional; each has a non-empty "effect" and an optional "params"
//     object (default {}).
//   - members flexid does not interpret are kept: at the top level in
//     ModelDocument::extra, in a local model in ModelDocument::local_extra. Other
//     members of "scheduling", of a membership and of an augmentation are ignored.
//   - a document is at most 16 MiB and nests at most 64 levels deep.
// Errors are model::InputError with one line: "FILE:LINE:COLUMN: what" for JSON syntax,
// "FILE: /json/pointer: what" for content.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "model/core/metrics.h"
#include "model/core/transfer_function.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::model {

inline constexpr std::string_view kModelFormat = "flexid.model/1";
inline constexpr std::size_t kMaxModelFileBytes = std::size_t{16} << 20;  // 16 MiB

// A change suggested by diagnosis, e.g. {"effect": "back_relaxation", "params": {...}}.
struct Augmentation {
  std::string effect;
  nlohmann::json params = nlohmann::json::object();
};

struct ModelDocument {
  enum class Kind { kTransferFunction, kTsFuzzy };
  Kind kind = Kind::kTransferFunction;
  TransferFunction tf;  // used when kind == kTransferFunction
  TsModel ts;           // used when kind == kTsFuzzy
  std::vector<Augmentation> augmentations;
  // Top-level members flexid does not interpret (fit figures, provenance, ...), kept on a
  // round trip. Members that flexid writes itself take precedence over these.
  nlohmann::json extra = nlohmann::json::object();
  // For a T-S model: per local model (same order as ts.rules), the members other than
  // level_V/num/den/delay_s (fit figures, 95 % intervals, ...). Empty, or one object per
  // rule.
  std::vector<nlohmann::json> local_extra;
};

// Parses and validates a model document; source_name names it in error messages.
// Throws InputError; never crashes on any input.
ModelDocument ParseModelJson(std::string_view text, const std::string& source_name);

// Reads and parses a model file ("FILE: cannot open: ..." if it cannot be read).
ModelDocument ReadModelFile(const std::string& path);

// The JSON document of a model. Throws std::invalid_argument if the document is not
// valid (it could not be read back), e.g. a non-finite coefficient or local_extra of the
// wrong size.
nlohmann::json ModelToJson(const ModelDocument& document);

// Writes ModelToJson(document) pretty-printed (2 spaces, "format" and "kind" first,
// trailing newline) to PATH.tmp and renames it over PATH. Throws std::invalid_argument as
// ModelToJson, InputError if the file cannot be written.
void WriteModelFile(const std::string& path, const ModelDocument& document);

// The model as a T-S model: a transfer function becomes a single rule (SingleRule).
// Fit figures as stored in model files and replies: samples, fit_percent, rmse_mm, and
// the whiteness and input-residual correlation tests when they were run.
nlohmann::json FitFiguresToJson(const FitFigures& fit);

TsModel AsTsModel(const ModelDocument& document);

ModelDocument FromTransferFunction(const TransferFunction& tf);
ModelDocument FromTsModel(const TsModel& model);

}  // namespace flexid::model
