// flexid status, flexid actuators: what flexidd is doing (online, --lcm URL) or what a
// database file holds (offline, --db PATH).
//
//   flexid status [--json]      online: each daemon's counters (RPC "status"), a column each;
//                               offline: each file's summary (actuators, trials, samples, ...)
//   flexid actuators [--json]   every daemon's (or file's) actuators: the daemon, its claim,
//                               geometry, material and electrolyte, active model version,
//                               trial being recorded
#include <algorithm>
#include <flexid/rpc_reply_t.hpp>
#include <iostream>
#include <iterator>

#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"

namespace flexid::cli {
namespace {

// The order the status table lists its items in (the daemon's and the file's); anything
// else a reply carries follows, alphabetically.
constexpr const char* kStatusOrder[] = {"daemon_id",
                                        "version",
                                        "database",
                                        "schema_version",
                                        "actuators",
                                        "trials",
                                        "trials_recording",
                                        "messages_received",
                                        "samples_accepted",
                                        "samples_stored",
                                        "rejected_malformed",
                                        "rejected_nonfinite",
                                        "rejected_out_of_order",
                                        "rejected_unknown_actuator",
                                        "dropped_queue_full",
                                        "predictions_published",
                                        "models",
                                        "alerts",
                                        "alerts_raised",
                                        "identification_running"};

std::string Cell(const nlohmann::json& value) {
  if (value.is_string()) return value.get<std::string>();
  if (value.is_boolean()) return value.get<bool>() ? "yes" : "no";
  if (value.is_number_float()) return FormatNumber(value.get<double>(), 6);
  if (value.is_null()) return "-";
  // The daemons a daemon heard ("peers"): "lab-a (0.4 s ago)".
  if (value.is_object() && value.contains("daemon_id") && value.contains("last_heard_s"))
    return Cell(value["daemon_id"]) + " (" +
           (value["last_heard_s"].is_number() ? FormatNumber(value["last_heard_s"].get<double>(), 2)
                                              : std::string("?")) +
           " s ago)";
  if (value.is_array()) {  // "S1, S2"; "-" when empty
    std::string text;
    for (const nlohmann::json& item : value) text += (text.empty() ? "" : ", ") + Cell(item);
    return text.empty() ? "-" : text;
  }
  return value.dump();
}

struct StatusArgs {
  bool as_json = false;
};

// One column per source: each daemon's counters (or each file's summary) side by side.
void RunStatus(const StatusArgs& args) {
  const Gathered gathered = Gather("status", nlohmann::json::object());
  PrintNotes(gathered);
  nlohmann::json statuses = nlohmann::json::array();
  std::vector<std::string> header = {"item"};
  for (const SourceAnswer& a : gathered.answers) {
    if (a.status != flexid::rpc_reply_t::kOk) continue;
    if (!a.result.is_object()) throw OperationError("status: unexpected reply " + a.result.dump());
    nlohmann::json status = a.result;
    if (a.database.empty()) status["daemon_id"] = a.daemon_id;
    statuses.push_back(status);
    header.push_back(a.Name());
  }
  if (statuses.empty()) ThrowNoResult(gathered);
  if (args.as_json) {
    std::cout << MergedDocument(gathered, "status", statuses).dump(2) << "\n";
    return;
  }
  std::cout << (Offline() ? "database file" : "flexidd on " + LcmUrl()) << "\n";
  std::vector<std::string> keys(std::begin(kStatusOrder), std::end(kStatusOrder));
  for (const nlohmann::json& status : statuses)
    for (const auto& item : status.items())
      if (std::find(keys.begin(), keys.end(), item.key()) == keys.end()) keys.push_back(item.key());
  std::sort(keys.begin() + static_cast<std::ptrdiff_t>(std::size(kStatusOrder)), keys.end());
  Table table(header);
  for (const std::string& key : keys) {
    std::vector<std::string> row = {key};
    bool any = false;
    for (const nlohmann::json& status : statuses) {
      any = any || status.contains(key);
      row.push_back(status.contains(key) ? Cell(status.at(key)) : "-");
    }
    if (any) table.AddRow(row);
  }
  table.Print(std::cout);
}

struct ActuatorsArgs {
  bool as_json = false;
};

// Every source's actuators, each row naming its daemon (or file) and, online, its claim:
// "configured" or "adopted" where that daemon records it, "none" where its file only knows
// it ("owner" then names the daemon that records it, when one is heard claiming it).
void RunActuators(const ActuatorsArgs& args) {
  const Gathered gathered = Gather("actuators", nlohmann::json::object());
  PrintNotes(gathered);
  nlohmann::json list = MergedRows(gathered);
  std::stable_sort(list.begin(), list.end(), [](const nlohmann::json& a, const nlohmann::json& b) {
    return a.value("id", "") < b.value("id", "");
  });
  if (args.as_json) {
    std::cout << MergedDocument(gathered, "actuators", list).dump(2) << "\n";
    return;
  }
  if (list.empty()) {
    std::cout << "no actuators\n";
    return;
  }
  Table table({SourceHeader(), "id", "claim", "geometry_mm (LxWxh)", "material", "electrolyte",
               "model", "recording"});
  for (const nlohmann::json& a : list) {
    const std::string geometry = FormatNumber(a.value("length_mm", 0.0), 4) + " x " +
                                 FormatNumber(a.value("width_mm", 0.0), 4) + " x " +
                                 FormatNumber(a.value("thickness_mm", 0.0), 4);
    const std::string electrolyte =
        a.value("electrolyte", "") + " " + FormatNumber(a.value("concentration_M", 0.0), 4) + " M";
    const int64_t version = a.value("model_version", int64_t{0});
    const int64_t trial = a.value("trial", int64_t{0});
    std::string claim = a.value("claim", "-");
    const nlohmann::json owner = a.value("owner", nlohmann::json());
    if (claim == "none" && owner.is_string()) claim = "none (" + owner.get<std::string>() + "'s)";
    table.AddRow({SourceCell(gathered, a), a.value("id", ""), claim, geometry,
                  a.value("material", ""), electrolyte,
                  version > 0 ? "v" + std::to_string(version) : "none",
                  trial > 0 ? "trial " + std::to_string(trial) : "-"});
  }
  table.Print(std::cout, "");
}

}  // namespace

void RegisterStatusCommands(CLI::App& app) {
  auto status = std::make_shared<StatusArgs>();
  CLI::App* status_cmd = app.add_subcommand(
      "status", "flexidd's counters, or with --db a summary of the database file");
  status_cmd->add_flag("--json", status->as_json, "Print the status as JSON");
  status_cmd->footer("Examples:\n  flexid status\n  flexid --db var/flexid.db status --json");
  status_cmd->callback([status] { RunStatus(*status); });

  auto actuators = std::make_shared<ActuatorsArgs>();
  CLI::App* actuators_cmd = app.add_subcommand(
      "actuators", "Actuators: geometry, material, active model, trial being recorded");
  actuators_cmd->add_flag("--json", actuators->as_json, "Print the list as JSON");
  actuators_cmd->footer(
      "Examples:\n  flexid actuators\n  flexid --db var/flexid.db actuators --json");
  actuators_cmd->callback([actuators] { RunActuators(*actuators); });
}

}  // namespace flexid::cli
