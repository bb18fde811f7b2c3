// flexid alerts list|follow: the residual monitor's and the diagnosis's alerts.
//
//   flexid alerts list [--actuator ID] [--since-utime U] [--limit N] [--json]
//       stored alerts, newest first, from every flexidd (online) or every --db file
//   flexid alerts follow [--actuator ID] [--kind K] [--seconds S] [--json]
//       online only: each alert on PREFIX/ALERT (--channel-prefix) as it arrives, one line each,
//       until S seconds have passed or SIGINT/SIGTERM (exit 0). With --json every line is one JSON
//       object (JSON Lines): the one exception to "--json prints one document", since the stream
//       has no end. Its objects have the shape of `alerts list --json` items without "id"
//       (a live alert has no stored id yet).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <flexid/alert_t.hpp>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <optional>

#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "lcmtypes/wire_check.h"
#include "storage/record_json.h"

namespace flexid::cli {
namespace {

const char* SeverityName(int64_t severity) {
  switch (severity) {
    case 0:
      return "info";
    case 1:
      return "warning";
    case 2:
      return "critical";
    default:
      return "unknown";
  }
}

// An alert from the bus in the shape of a stored one (storage::AlertJson), without "id".
nlohmann::json AlertMessageJson(const flexid::alert_t& a) {
  const storage::AlertRecord record{
      0,           a.actuator_id,  a.kind,         a.severity, a.utime, a.start_utime,
      a.end_utime, a.magnitude_mm, a.threshold_mm, a.text};
  nlohmann::json out = storage::AlertJson(record);
  out.erase("id");
  return out;
}

// time, actuator, kind, severity, magnitude_mm, text: a table row of `list`, a line of
// `follow`.
std::vector<std::string> AlertCells(const nlohmann::json& a) {
  const nlohmann::json& magnitude = a.contains("magnitude_mm") ? a["magnitude_mm"] : nullptr;
  return {FormatUtcTime(a.value("utime", int64_t{0})),
          a.value("actuator", ""),
          a.value("kind", ""),
          SeverityName(a.value("severity", int64_t{-1})),
          magnitude.is_number() ? FormatNumber(magnitude.get<double>(), 4) : "-",
          a.value("text", "")};
}

// --- list --------------------------------------------------------------------------------

struct ListArgs {
  std::string actuator;
  int64_t since_utime = 0;
  std::optional<int> limit;  // none: the default (100)
  bool as_json = false;
};

void RunList(const ListArgs& args) {
  nlohmann::json query = nlohmann::json::object();
  if (!args.actuator.empty()) query["actuator"] = args.actuator;
  if (args.since_utime < 0) throw UsageError("--since-utime must be >= 0");
  if (args.since_utime > 0) query["since_utime"] = args.since_utime;
  if (args.limit) {
    if (*args.limit < 1 || *args.limit > 10000) throw UsageError("--limit must be 1 .. 10000");
    query["limit"] = *args.limit;
  }
  // Every source's alerts, newest first, at most --limit of them in all.
  const Gathered gathered = Gather("alerts", query);
  PrintNotes(gathered);
  const nlohmann::json list = NewestFirst(MergedRows(gathered), "utime", args.limit.value_or(100));
  if (args.as_json) {
    std::cout << MergedDocument(gathered, "alerts", list).dump(2) << "\n";
    return;
  }
  if (list.empty()) {
    std::cout << "no alerts" << (args.actuator.empty() ? "" : " of " + args.actuator) << "\n";
    return;
  }
  Table table(
      {SourceHeader(), "time (UTC)", "actuator", "kind", "severity", "magnitude_mm", "text"});
  for (const nlohmann::json& a : list) {
    std::vector<std::string> cells = AlertCells(a);
    cells.insert(cells.begin(), SourceCell(gathered, a));
    table.AddRow(cells);
  }
  table.Print(std::cout, "");
}

// --- follow ------------------------------------------------------------------------------

struct FollowArgs {
  std::string actuator;
  std::string kind;
  std::optional<double> seconds;  // none: until a signal
  bool as_json = false;
};

struct Follower {
  FollowArgs args;
  int64_t printed = 0;
  static void OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string&, Follower* self) {
    // As `watch` (bus_commands.cc): the structure is checked before lcm-gen's decoder runs.
    flexid::alert_t a;
    if (!wire::WellFormed(rbuf->data, rbuf->data_size, wire::kAlert) ||
        a.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0)
      return;
    if (!self->args.actuator.empty() && a.actuator_id != self->args.actuator) return;
    if (!self->args.kind.empty() && a.kind != self->args.kind) return;
    const nlohmann::json alert = AlertMessageJson(a);
    if (self->args.as_json) {
      std::cout << alert.dump() << std::endl;
    } else {
      std::string line;
      for (const std::string& cell : AlertCells(alert)) line += (line.empty() ? "" : "  ") + cell;
      std::cout << line << std::endl;
    }
    ++self->printed;
  }
};

void RunFollow(const FollowArgs& args) {
  if (Offline())
    throw UsageError(
        "\"alerts follow\" listens to flexidd on the bus; it cannot run on a --db file");
  if (args.seconds && !(*args.seconds > 0.0 && std::isfinite(*args.seconds)))
    throw UsageError("--seconds must be > 0 (or left out: until SIGINT/SIGTERM)");
  lcm::LCM lcm(LcmUrl());
  if (!lcm.good()) throw OperationError("cannot join the LCM bus at " + LcmUrl());
  Follower follower{args, 0};
  const StopOnSignal stop;
  lcm.subscribeFunction(bus::Exactly(BusChannels().Alert()), &Follower::OnAlert, &follower)
      ->setQueueCapacity(1000);
  const auto end = std::chrono::steady_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(args.seconds.value_or(0) * 1000));
  while (!stop.requested() && (!args.seconds || std::chrono::steady_clock::now() < end))
    lcm.handleTimeout(100);
}

}  // namespace

void RegisterAlertsCommand(CLI::App& app) {
  CLI::App* alerts = app.add_subcommand("alerts", "Stored alerts, or follow them live");
  alerts->require_subcommand(1);
  alerts->footer("Examples:\n  flexid alerts list --actuator S1\n  flexid alerts follow --json");

  auto list = std::make_shared<ListArgs>();
  CLI::App* list_cmd = alerts->add_subcommand("list", "Stored alerts, newest first");
  list_cmd->add_option("--actuator", list->actuator, "Only this actuator's alerts");
  list_cmd->add_option("--since-utime", list->since_utime,
                       "Only alerts raised at or after this utime, us");
  list_cmd->add_option("--limit", list->limit, "At most this many (1 .. 10000, default 100)");
  list_cmd->add_flag("--json", list->as_json, "Print the list as JSON");
  list_cmd->footer(
      "Examples:\n  flexid alerts list --actuator S1 --limit 20\n"
      "  flexid --db var/flexid.db alerts list --since-utime 1700000000000000 --json");
  list_cmd->callback([list] { RunList(*list); });

  auto follow = std::make_shared<FollowArgs>();
  CLI::App* follow_cmd =
      alerts->add_subcommand("follow", "Print alerts from the bus as they arrive (online)");
  follow_cmd->add_option("--actuator", follow->actuator, "Only this actuator's alerts");
  follow_cmd->add_option("--kind", follow->kind,
                         "Only this kind (back_relaxation, drift, residual, sensor_dropout, ...)");
  follow_cmd->add_option("--seconds", follow->seconds,
                         "Stop after this many seconds (default: until SIGINT/SIGTERM)");
  follow_cmd->add_flag("--json", follow->as_json,
                       "One JSON object per line (JSON Lines), as the items of `alerts list "
                       "--json` without \"id\"");
  follow_cmd->footer(
      "Examples:\n  flexid alerts follow --actuator S1\n"
      "  flexid alerts follow --kind back_relaxation --seconds 600 --json >> alerts.jsonl");
  follow_cmd->callback([follow] { RunFollow(*follow); });
}

}  // namespace flexid::cli
