// flexid physics: what the seed's physics chain (Eqs. 1-13, model/physics/physics.h) predicts with
// the illustrative S1 parameters: the parameters, how well the N-term rational model of
// Eq. (13) approximates the exact Eq. (11), and Table 1 predicted vs measured. With
// --table1, only Table 1: how the deflection scales with L, W and h in the chain and in the
// measurements, which dimension departs beyond the table's reading precision, and what
// physics could explain it.
//
// This file holds the command line and its checks; physics_chain.h computes and prints the
// default report, physics_table1.h the --table1 analysis.
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/physics_chain.h"
#include "clients/cli/physics_table1.h"
#include "model/physics/physics.h"

namespace flexid::cli {
namespace {

struct PhysicsOptions {
  bool json = false;
  bool table1 = false;  // only the Table 1 scaling analysis
  int terms = 0;        // model to print in full; meaningful only if terms_option->count() > 0
  double voltage_V = model::kSeedTable1Voltage_V;
  const CLI::Option* terms_option = nullptr;
  const CLI::Option* voltage_option = nullptr;
};

void RunTable1(const PhysicsOptions& options) {
  // Table 1 was measured at 5 V and the analysis is of those measurements: the options that
  // change the chain's voltage or print its models do not apply.
  if (options.terms_option->count() > 0)
    throw UsageError("--table1 analyses Table 1 only; --terms does not apply");
  if (options.voltage_option->count() > 0)
    throw UsageError("--table1 compares with Table 1's 5 V measurements; --voltage does not apply");
  physics::Table1Report report;
  try {
    report = physics::ComputeTable1();
  } catch (const std::invalid_argument& e) {
    throw OperationError(std::string("physics --table1: ") + e.what());
  }
  if (options.json) {
    std::cout << physics::Table1Json(report).dump(2) << "\n";
  } else {
    physics::PrintTable1Human(report);
  }
}

void Run(const PhysicsOptions& options) {
  if (options.table1) return RunTable1(options);
  if (!std::isfinite(options.voltage_V) || !(options.voltage_V > 0.0)) {
    char value[32];
    std::snprintf(value, sizeof value, "%g", options.voltage_V);
    throw UsageError(std::string("--voltage must be finite and > 0, got ") + value);
  }
  if (options.terms_option->count() > 0 &&
      (options.terms < 1 || options.terms > model::kMaxTransferFunctionTerms))
    throw UsageError("--terms must be in 1.." + std::to_string(model::kMaxTransferFunctionTerms) +
                     ", got " + std::to_string(options.terms));
  std::optional<int> terms;  // the model to print in full
  if (options.terms_option->count() > 0) terms = options.terms;
  physics::ChainReport report;
  try {
    report = physics::ComputeChainReport(options.voltage_V, terms);
  } catch (const std::invalid_argument& e) {
    throw OperationError(std::string("physics: ") + e.what());
  }
  if (options.json) {
    std::cout << physics::ChainReportJson(report, options.terms).dump(2) << "\n";
  } else {
    physics::PrintChainReport(report, options.terms);
  }
}

}  // namespace

void RegisterPhysicsCommand(CLI::App& app) {
  auto options = std::make_shared<PhysicsOptions>();
  CLI::App* sub = app.add_subcommand(
      "physics",
      "What the seed's physics chain (Eqs. 1-13) predicts for actuator S1: parameters, exact "
      "Eq. (11) vs the N-term rational model, and Table 1 predicted vs measured");
  sub->footer(
      "Examples:\n"
      "  flexid physics\n"
      "  flexid physics --terms 3 --voltage 2\n"
      "  flexid physics --json\n"
      "  flexid physics --table1          # how Table 1 departs from the chain's scaling\n"
      "  flexid physics --table1 --json\n");
  sub->add_flag(
      "--json", options->json,
      "Print one JSON document (parameters, truncation, table1; with --table1 only the Table 1 "
      "analysis)");
  options->terms_option =
      sub->add_option("--terms", options->terms,
                      "Also print the coefficients of the N-term model (1.." +
                          std::to_string(model::kMaxTransferFunctionTerms) + ")");
  options->voltage_option = sub->add_option("--voltage", options->voltage_V,
                                            "Applied voltage in V for the steady deflections (> 0)")
                                ->capture_default_str();
  sub->add_flag("--table1", options->table1,
                "Only Table 1: predicted vs measured scaling of the deflection with L, W and h, "
                "which dimension departs beyond reading precision, and hypotheses why");
  sub->callback([options] { Run(*options); });
}

}  // namespace flexid::cli
