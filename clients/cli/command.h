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
#include <iostream>
#include <stdexcept>

#include "model/core/errors.h"

namespace flexid::cli {

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
struct OperationError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The end of main() in every flexid program: runs `body` (the parse and the work; it
// returns the exit code) and turns what it throws into the exit code and one line on
// stderr, "<program>: <what>": --help and --version 0 (CLI11 prints them), bad usage or
// bad input 2 (CLI::ParseError, followed by `parse_hint`; UsageError; model::InputError),
// any other failure 1.
template <typename Body>
int RunMain(CLI::App& app, const char* program, Body&& body, const char* parse_hint = "") {
  try {
    return body();
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << program << ": " << e.what() << parse_hint << '\n';
    return 2;
  } catch (const UsageError& e) {
    std::cerr << program << ": " << e.what() << '\n';
    return 2;
  } catch (const model::InputError& e) {
    std::cerr << program << ": " << e.what() << '\n';
    return 2;
  } catch (const std::exception& e) {
    std::cerr << program << ": " << e.what() << '\n';
    return 1;
  }
}

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
