// flexid models list|show|diff|activate: the model versions flexidd stored for an actuator
// (online through the `models`, `model` and `model_activate` requests; offline with the
// global --db PATH on the database file).
//
//   list      one row per version: created (UTC), active, trials, levels, fit figures
//   show      one version's summary and the model as `flexid tf show` presents it
//             (tf_show.h); --out writes it as a model file for simulate/diagnose --model
//   diff      two versions (or model files) side by side: per local model (matched by
//             level_V) DC gain, steady deflection, dead time, slowest time constant,
//             poles and fit figures; and both models' step responses from rest at every
//             level, with their largest difference in mm
//   activate  makes a version the one flexidd predicts with
//
// This file holds `flexid models` and its list and activate subcommands; show and diff are
// in models_show_command.cc and models_diff_command.cc, what they share in models_common.h.
#include <algorithm>
#include <cmath>
#include <iostream>
#include <memory>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/models_common.h"
#include "clients/cli/source.h"
#include "storage/database.h"

namespace flexid::cli {
namespace models {
namespace {

struct ListArgs {
  std::string actuator;
  bool json = false;
};

void RunList(const ListArgs& args) {
  RequireActuator(args.actuator);
  // From every daemon (or file) that holds the actuator: its owner's, and any another
  // daemon's file holds from when it recorded it.
  const Gathered gathered = Gather("models", {{"actuator", args.actuator}});
  PrintNotes(gathered);
  const json list = MergedRows(gathered);
  if (args.json) {
    std::cout << MergedDocument(gathered, "models", list).dump(2) << "\n";
    return;
  }
  if (list.empty()) {
    std::cout << args.actuator << ": no models stored (flexid identify --actuator " << args.actuator
              << " makes one)\n";
    return;
  }
  int64_t active = 0;
  for (const json& m : list)
    if (m.value("active", false)) active = m.value("version", int64_t{0});
  std::cout << args.actuator << ": " << list.size() << (list.size() == 1 ? " model" : " models")
            << (active ? " (v" + std::to_string(active) + " active)" : " (none active)") << "\n";
  Table table({SourceHeader(), "version", "created (UTC)", "active", "trials", "levels V", "fit %",
               "RMSE mm", "samples", "flexid", "proposed from"});
  for (const json& m : list) {
    const json fit = m.value("fit", json());
    const double samples = NumberIn(fit, "samples");
    table.AddRow({SourceCell(gathered, m), std::to_string(m.value("version", int64_t{0})),
                  IsoUtc(m.value("created_utime", int64_t{0})), m.value("active", false) ? "*" : "",
                  JoinNumbers(m.value("trials", json()), ","),
                  JoinNumbers(fit.is_object() ? fit.value("levels_V", json()) : json(), ","),
                  Cell(NumberIn(fit, "fit_percent")), Cell(NumberIn(fit, "rmse_mm"), 3),
                  std::isfinite(samples) ? std::to_string(static_cast<int64_t>(samples)) : "-",
                  m.value("flexid_version", std::string("-")),
                  LineageShort(m).empty() ? "-" : LineageShort(m)});
  }
  table.Print(std::cout);
}

struct ActivateArgs {
  std::string actuator;
  std::string version;
  bool json = false;
};

int32_t ActiveVersion(const json& list) {
  for (const json& m : list)
    if (m.value("active", false)) return m.value("version", 0);
  return 0;
}

void RunActivate(const ActivateArgs& args) {
  RequireActuator(args.actuator);
  const int32_t version = ParseVersion(args.version, "VERSION");
  if (version == 0) throw UsageError("VERSION: name the version to activate, e.g. 2");
  // The versions of the daemon that would activate it (the actuator's owner), or the file's.
  const std::string target = Offline() ? DbPath() : TargetDaemon("model_activate", args.actuator);
  const json list = Query("models", {{"actuator", args.actuator}}, target);
  const int32_t previous = ActiveVersion(list);
  const bool exists = std::any_of(list.begin(), list.end(), [version](const json& m) {
    return m.value("version", 0) == version;
  });
  if (!exists)
    throw UsageError("no model version " + std::to_string(version) + " of " + args.actuator +
                     " (flexid models list --actuator " + args.actuator + ")");
  if (Offline()) {
    try {
      storage::Database db = OpenDbFile();
      db.ActivateModel(args.actuator, version);
    } catch (const storage::StorageError& e) {
      throw OperationError(e.what());
    }
  } else {
    CallOnline("model_activate", {{"actuator", args.actuator}, {"version", version}},
               kQueryTimeout_s, target);
  }
  if (args.json) {
    std::cout << json{{"actuator", args.actuator},
                      {"version", version},
                      {"previous_version", previous},
                      {"database", Offline() ? json(DbPath()) : json()}}
                     .dump(2)
              << "\n";
    return;
  }
  std::cout << args.actuator << ": model v" << version
            << (previous == version ? " was already active"
                : previous == 0     ? " active (none was)"
                                    : " active (was v" + std::to_string(previous) + ")")
            << "\n";
  if (Offline())
    std::cout << "note: written to " << DbPath()
              << "; a flexidd running on this file keeps predicting with its loaded model "
                 "until it is restarted (without --db, flexidd switches at once)\n";
}

void AddListCommand(CLI::App& models) {
  auto list = std::make_shared<ListArgs>();
  CLI::App* list_cmd = models.add_subcommand(
      "list", "Model versions: created, active, trials, levels and fit figures");
  list_cmd->add_option("--actuator", list->actuator, "Actuator id, e.g. S1")->required();
  list_cmd->add_flag("--json", list->json, "Print the list as one JSON document");
  list_cmd->footer(
      "Examples:\n  flexid models list --actuator S1\n"
      "  flexid --db var/flexid.db models list --actuator S1 --json");
  list_cmd->callback([list] { RunList(*list); });
}

void AddActivateCommand(CLI::App& models) {
  auto activate = std::make_shared<ActivateArgs>();
  CLI::App* activate_cmd =
      models.add_subcommand("activate", "Make a model version the one flexidd predicts with");
  activate_cmd->add_option("--actuator", activate->actuator, "Actuator id, e.g. S1")->required();
  activate_cmd->add_option("VERSION", activate->version, "Model version to activate")->required();
  activate_cmd->add_flag("--json", activate->json,
                         "Print {actuator, version, previous_version} as JSON");
  activate_cmd->footer(
      "Online, flexidd switches its prediction at once. With --db the file is changed directly;\n"
      "a flexidd running on it picks the change up only when restarted, so prefer the online "
      "form.\n"
      "Examples:\n  flexid models activate --actuator S1 2\n"
      "  flexid --db var/flexid.db models activate --actuator S1 2");
  activate_cmd->callback([activate] { RunActivate(*activate); });
}

}  // namespace
}  // namespace models

void RegisterModelsCommand(CLI::App& app) {
  CLI::App* command = app.add_subcommand(
      "models", "Stored model versions of an actuator: list, show, diff, activate");
  command->require_subcommand(1);
  command->footer(
      "Examples:\n  flexid models list --actuator S1\n"
      "  flexid models diff --actuator S1 2 3\n"
      "  flexid --db var/flexid.db models show --actuator S1 --version 2 --out s1-v2.json");
  models::AddListCommand(*command);
  models::AddShowCommand(*command);
  models::AddDiffCommand(*command);
  models::AddActivateCommand(*command);
}

}  // namespace flexid::cli
