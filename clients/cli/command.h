// Shared conventions of the flexid command line (DESIGN.md, "Command lines"):
// exit 0 on success, 1 when the operation fails, 2 for bad usage or bad input; errors
// are one line on stderr; --json prints exactly one JSON document on stdout.
//
// Each command lives in its own file and exposes Register<Name>Command(CLI::App&), which
// adds a subcommand whose callback does the work. Callbacks throw UsageError (bad
// arguments or bad input, exit 2) or OperationError (exit 1); main() turns them into the
// exit code and the error line. model::InputError counts as bad input (exit 2).
#pragma once

#include <CLI/CLI.hpp>
#include <stdexcept>

namespace flexid::cli {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
struct OperationError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

void RegisterTfCommand(CLI::App& app);
void RegisterSimulateCommand(CLI::App& app);
void RegisterPhysicsCommand(CLI::App& app);
void RegisterIdentifyCommand(CLI::App& app);
void RegisterDiagnoseCommand(CLI::App& app);
void RegisterPlotCommand(CLI::App& app);
void RegisterBusCommands(CLI::App& app);
void RegisterStatusCommands(CLI::App& app);
void RegisterTrialsCommand(CLI::App& app);
void RegisterAlertsCommand(CLI::App& app);
void RegisterModelsCommand(CLI::App& app);
void RegisterReportCommand(CLI::App& app);
void RegisterDbCommand(CLI::App& app);

}  // namespace flexid::cli
