// flexid status, flexid actuators: what flexidd is doing (online, --lcm URL) or what a
// database file holds (offline, --db PATH).
//
//   flexid status [--json]      online: the daemon's counters (RPC "status");
//                               offline: the file's summary (actuators, trials, samples, ...)
//   flexid actuators [--json]   id, geometry, material and electrolyte, active model version,
//                               trial being recorded
#include <iostream>

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
  return value.dump();
}

struct StatusArgs {
  bool as_json = false;
};

void RunStatus(const StatusArgs& args) {
  const nlohmann::json status = Query("status", nlohmann::json::object());
  if (args.as_json) {
    std::cout << status.dump(2) << "\n";
    return;
  }
  if (!status.is_object()) throw OperationError("status: unexpected reply " + status.dump());
  std::cout << (Offline() ? "database file " + DbPath() : "flexidd on " + LcmUrl()) << "\n";
  Table table({"item", "value"});
  for (const char* key : kStatusOrder)
    if (status.contains(key)) table.AddRow({key, Cell(status.at(key))});
  for (const auto& [key, value] : status.items()) {
    bool listed = false;
    for (const char* known : kStatusOrder) listed = listed || key == known;
    if (!listed) table.AddRow({key, Cell(value)});
  }
  table.Print(std::cout);
}

struct ActuatorsArgs {
  bool as_json = false;
};

void RunActuators(const ActuatorsArgs& args) {
  const nlohmann::json list = Query("actuators", nlohmann::json::object());
  if (args.as_json) {
    std::cout << list.dump(2) << "\n";
    return;
  }
  if (list.empty()) {
    std::cout << "no actuators\n";
    return;
  }
  Table table({"id", "geometry_mm (LxWxh)", "material", "electrolyte", "model", "recording"});
  for (const nlohmann::json& a : list) {
    const std::string geometry = FormatNumber(a.value("length_mm", 0.0), 4) + " x " +
                                 FormatNumber(a.value("width_mm", 0.0), 4) + " x " +
                                 FormatNumber(a.value("thickness_mm", 0.0), 4);
    const std::string electrolyte =
        a.value("electrolyte", "") + " " + FormatNumber(a.value("concentration_M", 0.0), 4) + " M";
    const int64_t version = a.value("model_version", int64_t{0});
    const int64_t trial = a.value("trial", int64_t{0});
    table.AddRow({a.value("id", ""), geometry, a.value("material", ""), electrolyte,
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
