// flexid-control: makes one actuator follow a reference deflection with the identified
// model (issue 17), on the bus.
//
//   flexid-control --lcm URL [--channel-prefix FLEXID] --actuator ID
//                  (--reference REF.csv | --protocol SPEC) [--model MODEL.json]
//                  [--controller predictive|pi|open_loop] [--rate-hz 10]
//                  [--min-voltage -8] [--max-voltage 8] [--rate-limit 5]
//                  [--max-charge 1200] [--charge-window 220] [--horizon 60]
//                  [--move-weight 1e-5] [--effort-weight 1e-6]
//                  [--stale-after 0.5] [--start-timeout 10] [--key-file PATH]
//                  [--controller-id ID] [--out RUN.csv]
//
// The reference: a CSV t_s,deflection_mm, or a protocol of flexid-rig's read in mm
// (reference_input.h). The model: --model, else the actuator's active model asked of
// flexidd (the `model` RPC). The controller (model/control/controller.h) is built before
// anything is sent: an invalid limit or a reference outside the model's reachable range
// is refused then, with exit 2 and one line naming it.
//
// On the bus: every deflection sample on PREFIX/<ID>/DEFLECTION is answered with a signed
// voltage_command_t on PREFIX/<ID>/COMMAND for the next sample, carrying the reference at
// that deflection sample (session.h; signed with flexidd's key, --key-file, as trial
// control; flexid-dashboard draws the reference from it). The run stops when the reference
// ends, on a stale measurement (--stale-after seconds of wall time without a deflection), on
// a critical alert about the actuator on PREFIX/ALERT (but not one of model mismatch, which
// the feedback corrects: AlertStopsControl, session.h), or on SIGTERM/SIGINT: each stop
// sends a 0 V command (mode kStop) and publishes an alert of kind control_stop on
// PREFIX/ALERT (severity info when the reference ended, warning on a signal, critical
// otherwise).
//
// Prints one summary line on stdout; --out writes the run as CSV
// t_s,reference_mm,measured_mm,voltage_V,model_mm. Exit 0 when the reference was followed to
// its end, 1 when the run stopped early or failed (bus, no measurement within
// --start-timeout), 2 bad usage or bad input.
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cmath>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/voltage_command_t.hpp>
#include <fstream>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/fan_out.h"
#include "bus/ids.h"
#include "bus/lcm_url.h"
#include "clients/cli/command.h"
#include "clients/control/reference_input.h"
#include "clients/control/session.h"
#include "flexid/version.h"
#include "lcmtypes/message_auth.h"
#include "lcmtypes/wire_check.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"

namespace flexid::control {
namespace {

using cli::OperationError;
using cli::UsageError;

std::atomic<bool> stop_requested{false};
void OnStopSignal(int) { stop_requested.store(true); }

struct ControlArgs {
  std::string lcm_url;
  std::string channel_prefix = bus::kDefaultPrefix;
  std::string actuator_id;
  std::string reference_path;
  std::string protocol;
  std::string model_path;
  std::string controller = "predictive";
  double rate_Hz = 10.0;
  model::control::ControlLimits limits;
  model::control::MpcOptions mpc;  // --horizon, --move-weight, --effort-weight; the rest default
  SessionOptions session;
  std::string key_file;
  std::string controller_id;
  std::string out_path;
};

// The model: --model, else flexidd's active model of the actuator. *source names it.
model::TsModel LoadControlModel(const ControlArgs& args, lcm::LCM& lcm,
                                const bus::Channels& channels, std::string* source) {
  if (!args.model_path.empty()) {
    *source = args.model_path;
    return model::AsTsModel(model::ReadModelFile(args.model_path));
  }
  // Every flexidd on the bus answers a read-only request (bus/fan_out.h); the one that
  // records the actuator answers with its model, the others "not found".
  const nlohmann::json request = {{"actuator", args.actuator_id}};
  bus::FanOutOptions fan_out;
  fan_out.timeout = std::chrono::milliseconds(2000);
  const bus::FanOutResult answers =
      bus::FanOut(lcm, channels, args.controller_id + "-rpc", "model", request.dump(), {}, fan_out);
  if (answers.replies.empty())
    throw OperationError("no flexidd answered the model request within 2 s (give --model) [url: " +
                         args.lcm_url + "]");
  std::vector<const flexid::rpc_reply_t*> models;
  std::string errors;
  for (const flexid::rpc_reply_t& r : answers.replies) {
    if (r.status == flexid::rpc_reply_t::kOk)
      models.push_back(&r);
    else
      errors += (errors.empty() ? "" : "; ") + r.daemon_id + ": " + r.error;
  }
  if (models.empty())
    throw OperationError("flexidd has no model for " + args.actuator_id + ": " + errors +
                         " (identify one, or give --model)");
  if (models.size() > 1) {
    std::string daemons;
    for (const flexid::rpc_reply_t* r : models)
      daemons += (daemons.empty() ? "" : ", ") + r->daemon_id;
    throw OperationError("several daemons hold a model of " + args.actuator_id + " (" + daemons +
                         "): configure the actuator on one daemon only, or give --model");
  }
  const flexid::rpc_reply_t* reply = models.front();
  const nlohmann::json result = nlohmann::json::parse(reply->result_json, nullptr, false);
  if (!result.is_object() || !result.contains("model"))
    throw OperationError("flexidd's model reply carries no model");
  *source = "flexidd " + reply->daemon_id + "'s active model of " + args.actuator_id + " (v" +
            result.value("version", nlohmann::json(0)).dump() + ")";
  return model::AsTsModel(model::ParseModelJson(result.at("model").dump(), *source));
}

model::control::ControllerOptions OptionsFrom(const ControlArgs& args) {
  model::control::ControllerOptions options;
  if (!model::control::ParseControllerKind(args.controller, &options.kind))
    throw UsageError("--controller must be predictive, pi or open_loop (got \"" + args.controller +
                     "\")");
  if (!(args.rate_Hz > 0.0 && args.rate_Hz <= 1000.0))
    throw UsageError("--rate-hz must be > 0 and <= 1000 (the deflection's sample rate)");
  options.sample_period_s = 1.0 / args.rate_Hz;
  options.limits = args.limits;
  for (const auto& [name, weight] : {std::pair{"--move-weight", args.mpc.move_weight},
                                     std::pair{"--effort-weight", args.mpc.effort_weight}})
    if (!(weight >= 0.0 && std::isfinite(weight)))
      throw UsageError(std::string(name) + " must be finite and >= 0 mm^2 per V^2 (got " +
                       std::to_string(weight) + ")");
  options.mpc = args.mpc;
  std::string why;
  if (!options.IsValid(&why)) throw UsageError(why);
  return options;
}

// The bus side of a run: handlers, commands, the stop alert.
class ControlLoop {
 public:
  ControlLoop(lcm::LCM& lcm, const bus::Channels& channels, const ControlArgs& args,
              const auth::Key& key, ControlSession& session)
      : lcm_(lcm),
        args_(args),
        key_(key),
        session_(session),
        command_channel_(channels.Command(args.actuator_id)),
        alert_channel_(channels.Alert()) {
    // subscribeFunction, as flexidd subscribes (tests/lcm_subscribe.h says why).
    lcm_.subscribeFunction(bus::Exactly(channels.Deflection(args.actuator_id)),
                           &ControlLoop::OnDeflectionThunk, this);
    lcm_.subscribeFunction(bus::Exactly(alert_channel_), &ControlLoop::OnAlertThunk, this);
  }

  // Handles the bus until the session stops; returns the reason (nullopt: no measurement
  // came within the start timeout).
  std::optional<StopReason> Run() {
    while (!session_.stopped()) {
      lcm_.handleTimeout(20);
      const int64_t now = bus::WallClockUtime();
      if (session_.finished())
        StopWith(StopReason::kFinished, "the reference ended");
      else if (stop_requested.load())
        StopWith(StopReason::kSignal, "SIGTERM or SIGINT");
      else if (session_.StaleAt(now))
        StopWith(StopReason::kStaleMeasurement,
                 "no deflection for more than " + Seconds(args_.session.stale_after_s));
      else if (session_.StartTimedOut(now))
        return std::nullopt;
    }
    return session_.stop_reason();
  }

  void StopWith(StopReason reason, const std::string& why) {
    const std::optional<Command> command = session_.Stop(reason);
    if (!command) return;
    Publish(*command);
    flexid::alert_t alert;
    alert.utime = session_.last_utime();
    alert.actuator_id = args_.actuator_id;
    alert.kind = "control_stop";
    alert.severity = reason == StopReason::kFinished ? flexid::alert_t::kInfo
                     : reason == StopReason::kSignal ? flexid::alert_t::kWarning
                                                     : flexid::alert_t::kCritical;
    alert.start_utime = session_.start_utime();
    alert.end_utime = command->utime;
    alert.magnitude_mm = session_.TrackingRmse();
    alert.threshold_mm = 0.0;
    std::ostringstream text;
    text.precision(3);
    text << args_.actuator_id << ": control by " << args_.controller_id << " stopped ("
         << StopReasonName(reason) << "): " << why << "; voltage set to 0 V after "
         << session_.rows().size() << " samples, tracking RMSE " << session_.TrackingRmse()
         << " mm";
    alert.text = text.str();
    lcm_.publish(alert_channel_, &alert);
    std::cerr << "flexid-control: " << alert.text << "\n";
  }

 private:
  static std::string Seconds(double s) {
    std::ostringstream text;
    text << s << " s";
    return text.str();
  }

  void Publish(const Command& command) {
    flexid::voltage_command_t message;
    message.utime = command.utime;
    message.actuator_id = args_.actuator_id;
    message.voltage_V = command.voltage_V;
    message.sequence = command.sequence;
    message.controller_id = args_.controller_id;
    message.mode =
        command.stop ? flexid::voltage_command_t::kStop : flexid::voltage_command_t::kTrack;
    message.reference_mm = command.reference_mm;
    message.reference_utime = command.reference_utime;
    message.sent_utime = bus::WallClockUtime();
    auth::Sign(key_, &message);
    if (lcm_.publish(command_channel_, &message) != 0) ++failed_;
  }

  static void OnDeflectionThunk(const lcm::ReceiveBuffer* buffer, const std::string& channel,
                                ControlLoop* self) {
    self->OnDeflection(buffer, channel);
  }
  static void OnAlertThunk(const lcm::ReceiveBuffer* buffer, const std::string& channel,
                           ControlLoop* self) {
    self->OnAlert(buffer, channel);
  }

  void OnDeflection(const lcm::ReceiveBuffer* buffer, const std::string&) {
    try {
      flexid::deflection_sample_t sample;
      if (!wire::WellFormed(buffer->data, buffer->data_size, wire::kDeflectionSample) ||
          sample.decode(buffer->data, 0, static_cast<int>(buffer->data_size)) < 0 ||
          sample.actuator_id != args_.actuator_id)
        return;
      const std::optional<Command> command =
          session_.OnDeflection(sample.utime, sample.deflection_mm, bus::WallClockUtime());
      if (command) Publish(*command);
    } catch (const std::exception& e) {
      std::cerr << "flexid-control: a deflection sample could not be handled: " << e.what() << "\n";
      StopWith(StopReason::kCriticalAlert, std::string("the controller failed: ") + e.what());
    }
  }

  void OnAlert(const lcm::ReceiveBuffer* buffer, const std::string&) {
    flexid::alert_t alert;
    if (!wire::WellFormed(buffer->data, buffer->data_size, wire::kAlert) ||
        alert.decode(buffer->data, 0, static_cast<int>(buffer->data_size)) < 0)
      return;
    if (alert.severity != flexid::alert_t::kCritical) return;
    if (!alert.actuator_id.empty() && alert.actuator_id != args_.actuator_id) return;
    if (!session_.started()) return;
    const bool feedback =
        session_.controller().options().kind != model::control::ControllerKind::kOpenLoop;
    if (!AlertStopsControl(alert.kind, feedback)) {
      // Said once per kind: the operator sees it, and the feedback goes on correcting it.
      if (alert.kind != "control_stop" && noted_kinds_.insert(alert.kind).second)
        std::cerr << "flexid-control: critical " << alert.kind << " alert about "
                  << args_.actuator_id
                  << " (the deflection departs from flexidd's model; the feedback corrects "
                     "it, control goes on): "
                  << alert.text << "\n";
      return;
    }
    try {
      StopWith(StopReason::kCriticalAlert,
               "critical alert " + alert.kind + " (" + alert.text + ")");
    } catch (const std::exception& e) {
      std::cerr << "flexid-control: " << e.what() << "\n";
    }
  }

  lcm::LCM& lcm_;
  const ControlArgs& args_;
  const auth::Key& key_;
  ControlSession& session_;
  std::string command_channel_, alert_channel_;
  std::set<std::string> noted_kinds_;  // critical alerts that did not stop control
  int64_t failed_ = 0;
};

void WriteRun(const std::string& path, const ControlSession& session) {
  std::ofstream out(path, std::ios::trunc);
  if (!out) throw OperationError(path + ": cannot write the run");
  out << "t_s,reference_mm,measured_mm,voltage_V,model_mm\n";
  out.precision(10);
  for (const RunRow& row : session.rows())
    out << row.t_s << ',' << row.reference_mm << ',' << row.measured_mm << ',' << row.voltage_V
        << ',' << (std::isfinite(row.model_mm) ? row.model_mm : 0.0) << '\n';
  if (!out) throw OperationError(path + ": cannot write the run");
}

int RunControl(ControlArgs args) {
  if (args.lcm_url.empty()) throw UsageError("--lcm URL is required");
  if (!bus::IsValidId(args.actuator_id))
    throw UsageError(std::string("--actuator must be ") + bus::kIdRule + " (got \"" +
                     args.actuator_id + "\")");
  if (args.reference_path.empty() == args.protocol.empty())
    throw UsageError("give one reference: --reference REF.csv or --protocol SPEC");
  if (args.controller_id.empty()) args.controller_id = "control-" + std::to_string(getpid());
  if (!bus::IsValidId(args.controller_id))
    throw UsageError(std::string("--controller-id must be ") + bus::kIdRule);
  if (!(args.session.stale_after_s > 0.0 && args.session.start_timeout_s > 0.0))
    throw UsageError("--stale-after and --start-timeout must be > 0 s");
  const model::control::ControllerOptions options = OptionsFrom(args);
  model::control::Reference reference =
      args.reference_path.empty() ? ReferenceFromProtocol(args.protocol, options.sample_period_s)
                                  : model::control::ReadReferenceCsv(args.reference_path);
  // A deflection lost in the socket is a sample without a command: a larger receive buffer
  // than the kernel's default, as flexidd asks for.
  lcm::LCM lcm(bus::WithReceiveBuffer(args.lcm_url, 4 << 20));
  if (!lcm.good()) throw OperationError("cannot open the LCM bus [url: " + args.lcm_url + "]");
  const bus::Channels channels(args.channel_prefix);
  std::string model_source;
  const model::TsModel model = LoadControlModel(args, lcm, channels, &model_source);
  model::control::Controller controller(model, std::move(reference), options);
  auth::Key key;
  try {
    key = auth::ReadKeyFile(auth::ClientKeyFilePath(args.key_file));
  } catch (const auth::KeyError& e) {
    throw OperationError(std::string(e.what()) +
                         " (commands are signed with flexidd's key: --key-file PATH or "
                         "FLEXID_KEY_FILE)");
  }
  std::cerr << "flexid-control " << kVersion << ": " << args.actuator_id << " follows "
            << controller.reference().source() << " (" << controller.reference().duration_s()
            << " s) with the " << args.controller << " controller on " << model_source
            << "; limits " << args.limits.min_V << " .. " << args.limits.max_V << " V, "
            << args.limits.rate_V_per_s << " V/s, " << args.limits.max_charge_Vs << " V s per "
            << args.limits.charge_window_s << " s; stale after " << args.session.stale_after_s
            << " s [url: " << args.lcm_url << "]\n";
  if (const auto* tuning = controller.pi_tuning()) std::cerr << "  " << tuning->Describe() << "\n";

  struct sigaction action = {};
  action.sa_handler = OnStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);

  ControlSession session(std::move(controller), args.session, bus::WallClockUtime());
  ControlLoop loop(lcm, channels, args, key, session);
  const std::optional<StopReason> reason = loop.Run();
  if (!reason)
    throw OperationError("no deflection from " + args.actuator_id + " within " +
                         std::to_string(args.session.start_timeout_s) +
                         " s; nothing was sent [url: " + args.lcm_url + "]");
  if (!args.out_path.empty()) WriteRun(args.out_path, session);
  std::cout << "control " << args.actuator_id << " (" << args.controller
            << "): " << StopReasonName(*reason) << " after " << session.rows().size()
            << " samples, tracking RMSE " << session.TrackingRmse() << " mm" << std::endl;
  return *reason == StopReason::kFinished ? 0 : 1;
}

}  // namespace
}  // namespace flexid::control

int main(int argc, char** argv) {
  using flexid::control::ControlArgs;
  CLI::App app{"flexid-control: makes an actuator follow a reference deflection with its model"};
  app.set_version_flag("--version", flexid::kVersion);
  ControlArgs args;
  app.add_option("--lcm", args.lcm_url, "LCM URL, e.g. udpm://239.255.76.67:7667?ttl=0");
  app.add_option("--channel-prefix", args.channel_prefix, "flexidd's channel_prefix")
      ->capture_default_str()
      ->check([](const std::string& prefix) { return flexid::bus::PrefixProblem(prefix); });
  app.add_option("--actuator", args.actuator_id, "Actuator id, e.g. S1")->required();
  app.add_option("--reference", args.reference_path, "Reference CSV: t_s,deflection_mm");
  app.add_option("--protocol", args.protocol,
                 "Reference as a rig protocol in mm, e.g. "
                 "random:levels=5/10/20,dwell_min=100,dwell_max=200,duration=1000 or "
                 "sine:level=15,amplitude=3,frequency=0.01,duration=600");
  app.add_option("--model", args.model_path,
                 "Model file (flexid.model/1); default: flexidd's active model of the actuator");
  app.add_option("--controller", args.controller, "predictive | pi | open_loop")
      ->capture_default_str();
  app.add_option("--rate-hz", args.rate_Hz, "Sample rate of the deflection, Hz")
      ->capture_default_str();
  app.add_option("--min-voltage", args.limits.min_V, "Lowest voltage, V (<= 0)")
      ->capture_default_str();
  app.add_option("--max-voltage", args.limits.max_V, "Highest voltage, V (>= 0)")
      ->capture_default_str();
  app.add_option("--rate-limit", args.limits.rate_V_per_s, "Largest |dV/dt|, V/s")
      ->capture_default_str();
  app.add_option("--max-charge", args.limits.max_charge_Vs,
                 "Largest charge proxy (integral of |V| dt) per window, V s")
      ->capture_default_str();
  app.add_option("--charge-window", args.limits.charge_window_s, "The charge window (cycle), s")
      ->capture_default_str();
  app.add_option("--horizon", args.mpc.horizon_s,
                 "Prediction horizon of the predictive controller, s")
      ->capture_default_str();
  app.add_option("--move-weight", args.mpc.move_weight,
                 "Predictive controller: penalty on voltage moves, mm^2 per V^2")
      ->capture_default_str();
  app.add_option("--effort-weight", args.mpc.effort_weight,
                 "Predictive controller: penalty on voltage beyond what holds the reference, "
                 "mm^2 per V^2")
      ->capture_default_str();
  app.add_option("--stale-after", args.session.stale_after_s,
                 "Stop (0 V) after this long without a deflection, s (wall clock)")
      ->capture_default_str();
  app.add_option("--start-timeout", args.session.start_timeout_s,
                 "Give up when no deflection arrives within this long, s")
      ->capture_default_str();
  app.add_option("--key-file", args.key_file,
                 "flexidd's key, to sign the commands (default $FLEXID_KEY_FILE, else "
                 "var/flexidd.key)");
  app.add_option("--controller-id", args.controller_id,
                 "Names this controller in its commands (default control-<pid>)");
  app.add_option("--out", args.out_path,
                 "Write the run: t_s,reference_mm,measured_mm,voltage_V,model_mm");
  return flexid::cli::RunMain(app, "flexid-control", [&] {
    app.parse(argc, argv);
    return flexid::control::RunControl(args);
  });
}
