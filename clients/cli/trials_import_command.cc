// flexid trials import FILE.csv|FILE.lcmlog --actuator ID [--protocol TEXT]
// [--start-utime U] [--json]: stores the file straight into the --db file (trial_import.h),
// or, online, replays it to flexidd over the bus (trials_replay.h). An lcm-logger log
// (detected by its magic number, not its name) is read as trial_import.h describes; trials
// are split at its trial_control_t messages for that actuator.
#include <cstdint>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "bus/clock.h"
#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "clients/cli/trial_import.h"
#include "clients/cli/trials_common.h"
#include "clients/cli/trials_replay.h"
#include "storage/database.h"

namespace flexid::cli::trials {
namespace {

struct ImportArgs {
  std::string file;
  std::string actuator;
  std::optional<std::string> protocol;
  std::optional<int64_t> start_utime;
  bool as_json = false;
};

nlohmann::json LogCountsJson(const LogCounts& c) {
  return {{"events", c.events},
          {"voltage", c.voltage},
          {"deflection", c.deflection},
          {"trial_control", c.trial_control},
          {"malformed", c.malformed},
          {"misaddressed", c.misaddressed},
          {"nonfinite", c.nonfinite},
          {"out_of_order", c.out_of_order},
          {"outside_trial", c.outside_trial},
          {"other_channels", c.other_channels},
          {"empty_trials", c.empty_trials},
          {"truncated", c.truncated}};
}

void RunImport(const ImportArgs& args) {
  CheckActuatorId(args.actuator);
  if (args.protocol && args.protocol->size() > 1000)
    throw UsageError("--protocol: at most 1000 characters");
  PlanOptions options;
  options.actuator = args.actuator;
  options.protocol = args.protocol;
  options.start_utime = args.start_utime;
  options.now_utime = bus::WallClockUtime();
  options.channels = BusChannels();  // a log recorded under that prefix
  // The whole file is read and checked before anything is written or sent.
  const ImportPlan plan =
      IsLcmLog(args.file) ? PlanFromLcmLog(args.file, options) : PlanFromCsv(args.file, options);
  Progress progress("import " + args.file);
  std::vector<StoredImport> stored;
  if (Offline()) {
    std::optional<storage::Database> db;
    try {
      db.emplace(storage::Database::Open(DbPath()));  // may create the file
    } catch (const storage::StorageError& e) {
      throw OperationError(e.what());
    }
    stored =
        StorePlan(*db, plan, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  } else {
    stored = ReplayOnBus(plan, &progress);
  }
  progress.Finish();

  int64_t total = 0;
  nlohmann::json trials = nlohmann::json::array();
  for (size_t i = 0; i < stored.size(); ++i) {
    total += stored[i].samples;
    trials.push_back({{"trial", stored[i].trial_id},
                      {"samples", stored[i].samples},
                      {"protocol", plan.trials[i].protocol},
                      {"start_utime", plan.trials[i].start_utime}});
    if (stored[i].samples != plan.trials[i].deflections)
      throw OperationError("trial " + std::to_string(stored[i].trial_id) + " holds " +
                           std::to_string(stored[i].samples) + " of the " +
                           std::to_string(plan.trials[i].deflections) + " samples imported");
  }
  if (args.as_json) {
    nlohmann::json out = {{"trial", stored.front().trial_id},
                          {"samples", total},
                          {"actuator", plan.actuator},
                          {"source", plan.source},
                          {"format", plan.format},
                          {"trials", trials}};
    if (plan.format == "lcmlog") out["log"] = LogCountsJson(plan.log);
    return PrintJson(out);
  }
  for (size_t i = 0; i < stored.size(); ++i)
    std::cout << "imported trial " << stored[i].trial_id << ": " << stored[i].samples
              << " samples of " << plan.actuator << " (protocol \"" << plan.trials[i].protocol
              << "\", start " << FormatUtcTime(plan.trials[i].start_utime) << ") from "
              << plan.source << "\n";
  if (plan.format == "lcmlog") {
    const LogCounts& c = plan.log;
    std::cout << "log: " << c.events << " events; used " << c.voltage << " voltage, "
              << c.deflection << " deflection, " << c.trial_control
              << " trial-control messages; skipped " << c.malformed << " malformed, "
              << c.misaddressed << " misaddressed, " << c.nonfinite << " non-finite, "
              << c.out_of_order << " out of order, " << c.outside_trial
              << " deflections outside a trial, " << c.other_channels << " on other channels; "
              << c.empty_trials << " empty trials left out"
              << (c.truncated ? "; the file ends inside an event" : "") << "\n";
  }
}

}  // namespace

void AddImportCommand(CLI::App& trials) {
  auto imp = std::make_shared<ImportArgs>();
  CLI::App* import_cmd = trials.add_subcommand(
      "import",
      "Store a recording CSV or an lcm-logger log as a trial (--db), or replay it to "
      "flexidd");
  import_cmd->add_option("FILE", imp->file, "Recording CSV, or an lcm-logger log (by content)")
      ->required();
  import_cmd->add_option("--actuator", imp->actuator, "The actuator the samples belong to")
      ->required();
  import_cmd->add_option("--protocol", imp->protocol,
                         "Protocol text of the trial (default: the file's, or \"import FILE\")");
  import_cmd->add_option("--start-utime", imp->start_utime,
                         "The trial starts at this utime, us (default: the file's; a CSV "
                         "without one starts now); a log's times shift with it");
  import_cmd->add_flag("--json", imp->as_json,
                       "Print {\"trial\", \"samples\", \"actuator\", \"trials\", ...} as JSON");
  import_cmd->footer(
      "With --db the file is stored directly (the database file is created if needed);\n"
      "otherwise it is replayed over the bus to flexidd, paced so that no sample is lost.\n"
      "A log's trials are split at its trial_control_t messages for the actuator.\n"
      "Examples:\n  flexid --db var/flexid.db trials import run-5V.csv --actuator S1\n"
      "  flexid trials import lcmlog-2024-01-05.00 --actuator S1 --json");
  import_cmd->callback([imp] { RunImport(*imp); });
}

}  // namespace flexid::cli::trials
