// Low-level bus commands: `flexid rpc METHOD [ARGS_JSON]` sends any request to flexidd and
// prints the first reply (with --daemon ID, that daemon's); `flexid watch` prints live predictions
// and alerts, then a summary.
#include <cmath>
#include <flexid/alert_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <map>

#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "lcmtypes/wire_check.h"

namespace flexid::cli {
namespace {

struct RpcArgs {
  std::string method;
  std::string args_json = "{}";
  double timeout_s = 120.0;
};

void RunRpc(const RpcArgs& args) {
  const nlohmann::json parsed = nlohmann::json::parse(args.args_json, nullptr, false);
  if (parsed.is_discarded() || !parsed.is_object())
    throw UsageError("ARGS: expected a JSON object, got " + args.args_json);
  if (!(args.timeout_s > 0.0) || !std::isfinite(args.timeout_s))
    throw UsageError("--timeout must be > 0");
  if (DaemonIds().size() > 1)
    throw UsageError("rpc sends one request to one daemon: give --daemon once");
  const RpcResult r = CallDaemon(
      args.method, parsed, std::chrono::milliseconds(static_cast<int64_t>(args.timeout_s * 1000)),
      DaemonIds().empty() ? "" : DaemonIds().front());
  if (r.status == flexid::rpc_reply_t::kOk) {
    std::cout << r.result.dump(2) << "\n";
    return;
  }
  if (r.status == flexid::rpc_reply_t::kBadRequest || r.status == flexid::rpc_reply_t::kNotFound)
    throw UsageError(r.daemon_id + ": " + r.error);
  throw OperationError(r.daemon_id + ": " + r.error);
}

struct WatchArgs {
  double seconds = 10.0;
  std::string actuator;
  double every_s = 1.0;
};

// What one actuator showed while watched: the live residual and the alerts by kind.
struct WatchTally {
  int64_t predictions = 0;
  double residual_sum_squares_mm2 = 0.0;
  std::map<int32_t, int64_t> versions;  // model version -> predictions made with it
  std::map<std::string, int64_t> alerts;
};

struct Watcher {
  WatchArgs args;
  std::map<std::string, int64_t> last_printed;  // per actuator, message time
  std::map<std::string, WatchTally> tally;      // per actuator
  static void OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string&, Watcher* self) {
    flexid::prediction_t p;
    if (!wire::WellFormed(rbuf->data, rbuf->data_size, wire::kPrediction) ||
        p.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0)
      return;
    if (!self->args.actuator.empty() && p.actuator_id != self->args.actuator) return;
    if (std::isfinite(p.residual_mm)) {
      WatchTally& t = self->tally[p.actuator_id];
      ++t.predictions;
      t.residual_sum_squares_mm2 += p.residual_mm * p.residual_mm;
      ++t.versions[p.model_version];
    }
    int64_t& last = self->last_printed[p.actuator_id];
    if (last != 0 && p.utime - last < static_cast<int64_t>(self->args.every_s * 1e6)) return;
    last = p.utime;
    std::cout << "prediction " << p.actuator_id << " t "
              << FormatNumber(1e-6 * static_cast<double>(p.utime), 12) << " s  V "
              << FormatNumber(p.voltage_V, 4) << "  measured " << FormatNumber(p.measured_mm, 4)
              << " mm  predicted " << FormatNumber(p.predicted_mm, 4) << " mm  residual "
              << FormatNumber(p.residual_mm, 3) << " mm  model v" << p.model_version << "\n";
  }
  static void OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string&, Watcher* self) {
    flexid::alert_t a;
    if (!wire::WellFormed(rbuf->data, rbuf->data_size, wire::kAlert) ||
        a.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0)
      return;
    if (!self->args.actuator.empty() && a.actuator_id != self->args.actuator) return;
    ++self->tally[a.actuator_id].alerts[a.kind];
    std::cout << "ALERT " << a.actuator_id << " " << a.kind << ": " << a.text << "\n";
  }
  // One line per actuator: "summary S1: 4400 predictions (model v2), residual RMS 0.0199 mm;
  // alerts: none".
  void PrintSummary() const {
    for (const auto& [id, t] : tally) {
      std::cout << "summary " << id << ": " << t.predictions << " predictions";
      if (t.predictions > 0) {
        std::string versions;
        for (const auto& [version, count] : t.versions)
          versions += (versions.empty() ? "v" : ", v") + std::to_string(version);
        std::cout << " (model " << versions << "), residual RMS "
                  << FormatNumber(
                         std::sqrt(t.residual_sum_squares_mm2 / static_cast<double>(t.predictions)),
                         3)
                  << " mm";
      }
      std::string alerts;
      for (const auto& [kind, count] : t.alerts)
        alerts += (alerts.empty() ? "" : ", ") + std::to_string(count) + " " + kind;
      std::cout << "; alerts: " << (alerts.empty() ? "none" : alerts) << "\n";
    }
  }
};

void RunWatch(const WatchArgs& args) {
  if (!(args.seconds > 0.0) || !(args.every_s >= 0.0))
    throw UsageError("--seconds must be > 0 and --every >= 0");
  lcm::LCM lcm(LcmUrl());
  if (!lcm.good()) throw OperationError("cannot join the LCM bus at " + LcmUrl());
  Watcher watcher{args, {}, {}};
  const bus::Channels channels = BusChannels();
  lcm.subscribeFunction(channels.AllPredictions(), &Watcher::OnPrediction, &watcher)
      ->setQueueCapacity(1 << 16);
  lcm.subscribeFunction(bus::Exactly(channels.Alert()), &Watcher::OnAlert, &watcher)
      ->setQueueCapacity(1000);
  const auto end = std::chrono::steady_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(args.seconds * 1000));
  while (std::chrono::steady_clock::now() < end) lcm.handleTimeout(50);
  watcher.PrintSummary();
}

}  // namespace

void RegisterBusCommands(CLI::App& app) {
  auto rpc = std::make_shared<RpcArgs>();
  CLI::App* call =
      app.add_subcommand("rpc", "Send one request to flexidd and print its JSON reply");
  call->add_option("METHOD", rpc->method,
                   "status, actuators, trials, trial_samples, models, model, "
                   "model_activate, alerts, identify, trial_start, trial_stop")
      ->required();
  call->add_option("ARGS", rpc->args_json, "Arguments as a JSON object (default {})");
  call->add_option("--timeout", rpc->timeout_s, "Seconds to wait for the reply (default 120)");
  call->footer(
      "Examples:\n  flexid rpc status\n  flexid rpc identify '{\"actuator\": \"S1\", \"latest\": "
      "2}'");
  call->callback([rpc] { RunRpc(*rpc); });

  auto watch = std::make_shared<WatchArgs>();
  CLI::App* follow = app.add_subcommand("watch", "Print live predictions and alerts from the bus");
  follow->add_option("--seconds", watch->seconds, "How long to watch (default 10)");
  follow->add_option("--actuator", watch->actuator, "Only this actuator");
  follow->add_option(
      "--every", watch->every_s,
      "At most one prediction line per actuator per this many seconds of message time (default 1)");
  follow->footer(
      "At the end, one summary line per actuator: predictions seen, the model versions that\n"
      "made them, the live residual's RMS and the alerts by kind.\n"
      "Example:\n  flexid watch --seconds 30 --actuator S1");
  follow->callback([watch] { RunWatch(*watch); });
}

}  // namespace flexid::cli
