// What the `flexid models` subcommands share (internal to clients/cli/models_*.cc): reading
// the JSON of stored models (a version's summary, its local models), the cells and dates
// they print, the checks of --actuator and of a version as typed, and the functions that
// add each subcommand.
//   models_command.cc       `flexid models`, list and activate
//   models_show_command.cc  show
//   models_diff_command.cc  diff
#pragma once

#include <CLI/CLI.hpp>
#include <cmath>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/transfer_function.h"

namespace flexid::cli::models {

using json = nlohmann::json;

// Adds `flexid models show` (models_show_command.cc) and `flexid models diff`
// (models_diff_command.cc) to `flexid models`.
void AddShowCommand(CLI::App& models);
void AddDiffCommand(CLI::App& models);

// Microseconds since the epoch as ISO-8601 UTC, e.g. "2025-11-21T11:40:02Z"; "-" for 0 or
// less.
std::string IsoUtc(int64_t utime);

// The items of a JSON list, e.g. "3, 4" or "2, 8"; "-" for none.
std::string JoinNumbers(const json& list, const std::string& separator = ", ");

// The number object[key], NaN if it is absent or not a number (or object not an object).
double NumberIn(const json& object, const char* key);

// A table cell: the value to `significant` digits, "-" if it is not finite.
std::string Cell(double value, int significant = 4);

// A version as typed: "3", "v3", or "active" (0). Throws UsageError naming `what`.
int32_t ParseVersion(const std::string& text, const std::string& what);

// Throws UsageError for an empty --actuator.
void RequireActuator(const std::string& actuator);

// One stored model: Query("model") with the summary and the parsed document.
// A proposed version's lineage (the "lineage" of a models reply, proposal.h in daemon/), in
// words; "" for an identified version. Short, for a table: "v4 + back_relaxation, 4.0x".
// Long: "proposed on v4 by diagnose from trial 12: back_relaxation (fraction 0.21 +- 0.03,
// tau_s 31 +- 4); held-out RMSE 0.085 -> 0.021 mm, 4.0 times smaller".
std::string LineageShort(const json& summary);
std::string LineageLong(const json& summary);

struct StoredVersion {
  json summary;  // ModelSummaryJson, without "model"
  json document;
  model::ModelDocument doc;
  std::string name;  // "S1 model v3"
};

// The stored model `version` of the actuator (0: the active one), online or from --db.
StoredVersion FetchVersion(const std::string& actuator, int32_t version);

// The local models of a document with their levels (NaN when a single transfer function
// does not say) and their own fit figures where the document holds them.
struct Local {
  double level_V = NAN;
  model::TransferFunction tf;
  json fit;  // {fit_percent, rmse_mm, samples, ...} or null
};

std::vector<Local> LocalsOf(const model::ModelDocument& doc);

}  // namespace flexid::cli::models
