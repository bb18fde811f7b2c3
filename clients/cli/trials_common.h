// What the `flexid trials` subcommands share (internal to clients/cli/trials_*.cc): checks of
// the ids they are given, a stored trial read back from its JSON, printing a JSON reply,
// and the functions that add the subcommands kept in files of their own.
//   trials_command.cc         `flexid trials`, list, show, start and stop
//   trials_export_command.cc  export
//   trials_import_command.cc  import (trial_import.h reads the file; trials_replay.h plays
//                             it to flexidd)
#pragma once

#include <CLI/CLI.hpp>
#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>

#include "storage/database.h"

namespace flexid::cli::trials {

// Adds `flexid trials export` (trials_export_command.cc) and `flexid trials import`
// (trials_import_command.cc) to `flexid trials`.
void AddExportCommand(CLI::App& trials);
void AddImportCommand(CLI::App& trials);

// Throws UsageError unless id is a valid actuator id (actuator ids name LCM channels:
// bus/ids.h).
void CheckActuatorId(const std::string& id);

// Throws UsageError unless id is a trial id (>= 1).
void CheckTrialId(int64_t id);

// storage::TrialJson read back.
storage::Trial TrialFromJson(const nlohmann::json& j);

// Prints the document indented, on standard output.
void PrintJson(const nlohmann::json& j);

}  // namespace flexid::cli::trials
