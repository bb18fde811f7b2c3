// flexid trials list|show|export|import|start|stop: the stored trials of flexidd (online,
// --lcm URL) or of a database file (offline, --db PATH).
//
//   flexid trials list [--actuator ID] [--limit N] [--json]   (every daemon, or every --db)
//   flexid trials show ID [--json]
//   flexid trials export ID [--out FILE.csv]
//   flexid trials import FILE.csv|FILE.lcmlog --actuator ID [--protocol TEXT]
//                        [--start-utime U] [--json]
//   flexid trials start --actuator ID [--protocol TEXT] [--json]      (online only)
//   flexid trials stop --actuator ID [--json]                         (online only)
//
// This file holds `flexid trials` with list, show, start and stop; export and import are in
// trials_export_command.cc and trials_import_command.cc (the bus replay in trials_replay.h),
// what they share in trials_common.h.
#include <algorithm>
#include <cstdint>
#include <exception>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "clients/cli/trials_common.h"
#include "model/core/levels.h"
#include "storage/database.h"

namespace flexid::cli {
namespace trials {
namespace {

// Seconds from start to end; none while recording (end 0).
std::optional<double> DurationOf(const storage::Trial& t) {
  if (t.end_utime == 0) return std::nullopt;
  return 1e-6 * static_cast<double>(t.end_utime - t.start_utime);
}

// --- list --------------------------------------------------------------------------------

struct ListArgs {
  std::string actuator;
  std::optional<int> limit;  // none: the default (100)
  bool as_json = false;
};

void RunList(const ListArgs& args) {
  nlohmann::json query = nlohmann::json::object();
  if (!args.actuator.empty()) query["actuator"] = args.actuator;
  if (args.limit) {
    if (*args.limit < 1 || *args.limit > 10000) throw UsageError("--limit must be 1 .. 10000");
    query["limit"] = *args.limit;
  }
  // Every source's trials, newest first, at most --limit of them in all.
  const Gathered gathered = Gather("trials", query);
  PrintNotes(gathered);
  const nlohmann::json list =
      NewestFirst(MergedRows(gathered), "start_utime", args.limit.value_or(100));
  if (args.as_json) return PrintJson(MergedDocument(gathered, "trials", list));
  if (list.empty()) {
    std::cout << "no trials" << (args.actuator.empty() ? "" : " of " + args.actuator) << "\n";
    return;
  }
  Table table({SourceHeader(), "id", "actuator", "protocol", "start (UTC)", "start_utime",
               "duration_s", "state", "samples"});
  for (const nlohmann::json& item : list) {
    const storage::Trial t = TrialFromJson(item);
    const auto duration = DurationOf(t);
    table.AddRow({SourceCell(gathered, item), std::to_string(t.id), t.actuator_id, t.protocol,
                  FormatUtcTime(t.start_utime), std::to_string(t.start_utime),
                  duration ? FormatNumber(*duration, 6) : "-", storage::TrialStateName(t.state),
                  std::to_string(t.samples)});
  }
  table.Print(std::cout, "");
}

// --- show --------------------------------------------------------------------------------

struct ShowArgs {
  int64_t trial = 0;
  bool as_json = false;
};

// Samples of a trial, summarised: time span, rate, voltage levels, deflection range.
nlohmann::json SampleSummary(const StoredTrial& stored) {
  const size_t n = stored.utime.size();
  nlohmann::json out = {{"samples", n}};
  if (n == 0) return out;
  const double duration_s = 1e-6 * static_cast<double>(stored.utime.back() - stored.utime.front());
  out["first_utime"] = stored.utime.front();
  out["last_utime"] = stored.utime.back();
  out["duration_s"] = duration_s;
  out["sample_rate_Hz"] =
      duration_s > 0 ? nlohmann::json(static_cast<double>(n - 1) / duration_s) : nlohmann::json();
  const auto [vmin, vmax] = std::minmax_element(stored.voltage_V.begin(), stored.voltage_V.end());
  const auto [dmin, dmax] =
      std::minmax_element(stored.deflection_mm.begin(), stored.deflection_mm.end());
  out["voltage_min_V"] = *vmin;
  out["voltage_max_V"] = *vmax;
  out["deflection_min_mm"] = *dmin;
  out["deflection_max_mm"] = *dmax;
  // Levels as identification sees them (model/core/levels.h): the voltages held on plateaus.
  nlohmann::json levels = nlohmann::json::array();
  if (n >= 2) {
    try {
      const model::Recording rec = RecordingOf(stored);
      for (const model::VoltageLevel& level : model::DetectLevels(rec.t_s, rec.voltage_V).levels)
        levels.push_back(level.level_V);
    } catch (const std::exception&) {
      // No plateau structure to report; the range above still says what was applied.
    }
  }
  out["voltage_levels_V"] = levels;
  return out;
}

void RunShow(const ShowArgs& args) {
  CheckTrialId(args.trial);
  Progress progress("load trial " + std::to_string(args.trial));
  const StoredTrial stored =
      LoadTrial(args.trial, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  progress.Finish();
  const nlohmann::json summary = SampleSummary(stored);
  if (args.as_json) return PrintJson({{"trial", stored.trial}, {"summary", summary}});
  const storage::Trial t = TrialFromJson(stored.trial);
  auto line = [](const std::string& key, const std::string& value) {
    std::cout << "  " << key << std::string(key.size() < 21 ? 21 - key.size() : 1, ' ') << value
              << "\n";
  };
  auto number = [&summary](const char* key) {
    return summary[key].is_number() ? FormatNumber(summary[key].get<double>(), 6) : "-";
  };
  std::cout << "trial " << t.id << " of " << t.actuator_id << "\n";
  line("protocol", t.protocol);
  line("state", storage::TrialStateName(t.state));
  line("start", FormatUtcTime(t.start_utime) + " (utime " + std::to_string(t.start_utime) + ")");
  line("end", t.end_utime == 0
                  ? "-"
                  : FormatUtcTime(t.end_utime) + " (utime " + std::to_string(t.end_utime) + ")");
  line("samples", std::to_string(stored.utime.size()));
  if (stored.utime.empty()) return;
  line("duration_s", number("duration_s"));
  line("sample rate_Hz", number("sample_rate_Hz"));
  std::string levels;
  for (const auto& level : summary["voltage_levels_V"])
    levels += (levels.empty() ? "" : ", ") + FormatNumber(level.get<double>(), 4);
  line("voltage levels_V", levels.empty() ? "none held" : levels);
  line("voltage range_V", number("voltage_min_V") + " .. " + number("voltage_max_V"));
  line("deflection range_mm", number("deflection_min_mm") + " .. " + number("deflection_max_mm"));
}

// --- start, stop -------------------------------------------------------------------------

struct ControlArgs {
  std::string actuator;
  std::optional<std::string> protocol;
  bool as_json = false;
};

void RunControl(const ControlArgs& args, bool start) {
  CheckActuatorId(args.actuator);
  nlohmann::json request = {{"actuator", args.actuator}};
  if (start && args.protocol) request["protocol"] = *args.protocol;
  const nlohmann::json reply =
      CallOnline(start ? "trial_start" : "trial_stop", request, kQueryTimeout_s);
  if (args.as_json) return PrintJson(reply);
  std::cout << "trial " << reply.value("trial", int64_t{0}) << " of "
            << reply.value("actuator", args.actuator) << (start ? " started" : " stopped") << "\n";
}

void AddListCommand(CLI::App& trials) {
  auto list = std::make_shared<ListArgs>();
  CLI::App* list_cmd = trials.add_subcommand("list", "Stored trials, newest first");
  list_cmd->add_option("--actuator", list->actuator, "Only this actuator's trials");
  list_cmd->add_option("--limit", list->limit, "At most this many (1 .. 10000, default 100)");
  list_cmd->add_flag("--json", list->as_json, "Print the list as JSON");
  list_cmd->footer(
      "Examples:\n  flexid trials list\n  flexid --db var/flexid.db trials list "
      "--actuator S1 --limit 5 --json");
  list_cmd->callback([list] { RunList(*list); });
}

void AddShowCommand(CLI::App& trials) {
  auto show = std::make_shared<ShowArgs>();
  CLI::App* show_cmd =
      trials.add_subcommand("show", "A trial's metadata and a summary of its samples");
  show_cmd->add_option("ID", show->trial, "Trial id")->required();
  show_cmd->add_flag("--json", show->as_json, "Print {\"trial\": ..., \"summary\": ...} as JSON");
  show_cmd->footer(
      "Example:\n  flexid trials show 3\n  flexid --db var/flexid.db trials show 3 --json");
  show_cmd->callback([show] { RunShow(*show); });
}

// start and stop.
void AddControlCommands(CLI::App& trials) {
  auto start = std::make_shared<ControlArgs>();
  CLI::App* start_cmd = trials.add_subcommand("start", "Ask flexidd to start a trial (online)");
  start_cmd->add_option("--actuator", start->actuator, "Actuator")->required();
  start_cmd->add_option("--protocol", start->protocol, "Protocol text (default \"manual\")");
  start_cmd->add_flag("--json", start->as_json, "Print {\"actuator\", \"trial\"} as JSON");
  start_cmd->footer("Example:\n  flexid trials start --actuator S1 --protocol \"step 5 V, 600 s\"");
  start_cmd->callback([start] { RunControl(*start, true); });

  auto stop = std::make_shared<ControlArgs>();
  CLI::App* stop_cmd =
      trials.add_subcommand("stop", "Ask flexidd to end the actuator's trial (online)");
  stop_cmd->add_option("--actuator", stop->actuator, "Actuator")->required();
  stop_cmd->add_flag("--json", stop->as_json, "Print {\"actuator\", \"trial\"} as JSON");
  stop_cmd->footer("Example:\n  flexid trials stop --actuator S1");
  stop_cmd->callback([stop] { RunControl(*stop, false); });
}

}  // namespace
}  // namespace trials

void RegisterTrialsCommand(CLI::App& app) {
  CLI::App* command =
      app.add_subcommand("trials", "List, show, export, import, start and stop trials");
  command->require_subcommand(1);
  command->footer(
      "Online forms ask flexidd (--lcm URL); with --db PATH they read the database file.\n"
      "Examples:\n  flexid trials list --actuator S1\n  flexid --db var/flexid.db trials export 3 "
      "--out trial3.csv");
  trials::AddListCommand(*command);
  trials::AddShowCommand(*command);
  trials::AddExportCommand(*command);
  trials::AddImportCommand(*command);
  trials::AddControlCommands(*command);
}

}  // namespace flexid::cli
