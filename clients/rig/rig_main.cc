// flexid-rig: a virtual actuator on the bus (DESIGN.md, "Command lines"), or offline.
//
//   flexid-rig --lcm URL [--channel-prefix FLEXID] --actuator ID[,ID...]... --protocol SPEC
//              [--speed X] [--rate-hz 10]
//              [--model MODEL.json] [--effect [ID/]NAME[:k=v,...]]... [--noise-mm SIGMA]
//              [--seed N] [--start-utime U] [--trial-control [--key-file PATH]]
//   flexid-rig --lcm URL [--channel-prefix FLEXID] --actuator ID --closed-loop --duration S
//              [--command-timeout 0.5] [--speed X] [--rate-hz 10] [--model MODEL.json]
//              [--effect NAME[:k=v,...]]... [--noise-mm SIGMA] [--seed N] [--start-utime U]
//              [--trial-control] [--key-file PATH]
//   flexid-rig --out FILE.csv [--actuator ID[,ID...]]... --protocol SPEC [--rate-hz 10]
//              [--model MODEL.json] [--effect [ID/]NAME[:k=v,...]]... [--noise-mm SIGMA]
//              [--seed N]
//
// Simulates the actuator's deflection for a voltage protocol (protocol.h) with the seed's
// T-S model or a model file, adds effects (effects.h) and sensor noise (rig.h), and
// publishes flexid::voltage_sample_t on PREFIX/<ID>/VOLTAGE and flexid::deflection_sample_t
// on PREFIX/<ID>/DEFLECTION in message time (runner.h; bus/sample_publisher.h); with
// --trial-control also flexid::trial_control2_t start and stop on PREFIX/TRIAL, signed with
// flexidd's key (lcmtypes/message_auth.h; --key-file, else $FLEXID_KEY_FILE, else
// var/flexidd.key). Its sent_utime is the wall clock, whatever --speed and --start-utime do
// to message time. PREFIX is flexidd's channel_prefix, given with --channel-prefix (default
// FLEXID).
//
// Message time: the first sample is at --start-utime; without it, at the wall clock or, if
// later, just after the latest sample flexidd has seen or stored (its status reply's
// latest_utime, asked for on the bus with a 0.5 s timeout). So a run after an accelerated
// one (or after flexidd restarted) continues its message time instead of going back,
// which flexidd would take for a clock jump (runner.h, ContinuedStartUtime). When no
// flexidd answers, the wall clock; a line on stderr says so, and another when the start
// moved after flexidd's latest sample.
//
// Closed loop (--closed-loop, closed_loop.h): one actuator's voltage is what a controller
// (flexid-control) commands on PREFIX/<ID>/COMMAND, for --duration seconds of message time,
// instead of a protocol. Commands must be signed with the shared key (--key-file, as for
// trial control) and fresh: unsigned, badly signed, replayed or stale ones are refused,
// counted and logged (at most once a second per reason); with no accepted command for
// --command-timeout seconds of wall time (default 0.5) the voltage goes to 0 V. The summary
// line then adds the commands accepted and refused.
//
// Several actuators: --actuator may be repeated or hold a comma-separated list. Every
// actuator plays the same protocol on its own channels, with its own noise stream (seed +
// i for the i-th actuator, from 0) and its own trial start and stop; all advance together
// in message time (RunRigs). --effect NAME[:k=v,...] acts on every actuator, --effect
// ID/NAME[:k=v,...] on actuator ID only (MakeActuatorRigs).
//
// Offline (--out): the same sample stream (the same seed gives the same noise) is written at
// once, without the bus and without pacing, as a recording CSV t_s,voltage_V,deflection_mm
// (model/core/recording.h) with t_s = k / rate_Hz from 0. With two or more actuators the file
// has a first column `actuator` (actuator,t_s,voltage_V,deflection_mm), one row per
// actuator and sample, in time order and the actuators in the order given within a time;
// such a file is not a recording CSV (its time repeats): select one actuator's rows first.
// The bus options (--lcm, --channel-prefix, --speed, --start-utime, --trial-control,
// --key-file) are rejected with --out.
//
// Prints one summary line on stdout. Errors are one line on stderr; exit 0 success, 1 the
// run failed (bus, unstable model, a message not sent, the file not written, interrupted by
// SIGINT/SIGTERM), 2 bad usage or bad input.
#include <signal.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <flexid/voltage_command_t.hpp>
#include <fstream>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "bus/lcm_url.h"
#include "bus/rpc_client.h"
#include "bus/sample_publisher.h"
#include "clients/cli/command.h"
#include "clients/rig/closed_loop.h"
#include "clients/rig/effects.h"
#include "clients/rig/protocol.h"
#include "clients/rig/rig.h"
#include "clients/rig/runner.h"
#include "flexid/version.h"
#include "lcmtypes/message_auth.h"
#include "lcmtypes/wire_check.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"
#include "model/core/presets.h"
#include "model/core/recording.h"

namespace flexid::rig {
namespace {

using cli::OperationError;
using cli::UsageError;

std::atomic<bool> stop_requested{false};

void OnStopSignal(int) { stop_requested.store(true); }

struct RigArgs {
  std::string out_path;                        // offline: the recording CSV; empty: on the bus
  std::vector<std::string> bus_options_given;  // bus-only flags given, e.g. "--lcm"
  std::string lcm_url;
  std::string channel_prefix = bus::kDefaultPrefix;
  std::vector<std::string> actuator_ids;  // as given; "S1,S2" is split by CLI11
  std::string protocol;
  double speed = 1.0;
  double rate_Hz = 10.0;
  std::string model_path;
  std::vector<std::string> effects;
  double noise_mm = 0.0;
  uint64_t seed = 1;
  int64_t start_utime = 0;
  bool start_utime_given = false;  // otherwise: wall clock now
  bool trial_control = false;
  std::string key_file;  // signs trial control (empty: $FLEXID_KEY_FILE, else var/flexidd.key)
  bool closed_loop = false;
  double duration_s = 0.0;                 // closed loop: message time to play
  double command_timeout_s = 0.5;          // closed loop: the watchdog and the freshness window
  bool closed_loop_options_given = false;  // --duration or --command-timeout
};

// The runner's sink on the bus: bus::SamplePublisher builds, signs and publishes.
class LcmSink : public BusSink {
 public:
  // `key` is null without --trial-control.
  LcmSink(lcm::LCM& lcm, const bus::Channels& channels, const std::string& actuator_id,
          const flexid::auth::Key* key)
      : publisher_(lcm, channels, actuator_id, key) {}

  bool PublishVoltage(int64_t utime, double voltage_V) override {
    return publisher_.PublishVoltage(utime, voltage_V);
  }
  bool PublishDeflection(int64_t utime, double deflection_mm) override {
    return publisher_.PublishDeflection(utime, deflection_mm);
  }
  bool PublishTrialControl(int64_t utime, TrialAction action,
                           const std::string& protocol) override {
    return publisher_.PublishTrialControl(
        utime, action == TrialAction::kStart ? bus::TrialAction::kStart : bus::TrialAction::kStop,
        protocol);
  }

 private:
  bus::SamplePublisher publisher_;
};

// Checks the ids (each valid, none twice); throws UsageError.
void CheckActuatorIds(const std::vector<std::string>& ids) {
  for (size_t i = 0; i < ids.size(); ++i) {
    if (!bus::IsValidId(ids[i]))
      throw UsageError(std::string("--actuator must be ") + bus::kIdRule + " (got \"" + ids[i] +
                       "\")");
    for (size_t j = 0; j < i; ++j)
      if (ids[j] == ids[i]) throw UsageError("--actuator \"" + ids[i] + "\" given twice");
  }
}

std::string CsvNumber(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

// Several actuators offline: actuator,t_s,voltage_V,deflection_mm, written to PATH.tmp and
// renamed over PATH. Returns the rows written; throws OperationError if it cannot write.
int64_t WriteActuatorsCsv(const std::string& path, const std::vector<std::string>& ids,
                          std::vector<Rig>& rigs) {
  const std::string temporary = path + ".tmp";
  std::ofstream out(temporary, std::ios::binary | std::ios::trunc);
  if (!out) throw OperationError(path + ": cannot write (" + std::strerror(errno) + ")");
  out << "actuator,t_s,voltage_V,deflection_mm\n";
  int64_t rows = 0;
  RigSample sample;
  for (int64_t k = 0; k < rigs.front().sample_count(); ++k)
    for (size_t i = 0; i < rigs.size(); ++i) {
      rigs[i].Next(&sample);
      out << ids[i] << ',' << CsvNumber(sample.t_s) << ',' << CsvNumber(sample.voltage_V) << ','
          << CsvNumber(sample.deflection_mm) << '\n';
      ++rows;
    }
  out.close();
  if (!out || std::rename(temporary.c_str(), path.c_str()) != 0) {
    std::remove(temporary.c_str());
    throw OperationError(path + ": cannot write");
  }
  return rows;
}

model::TsModel LoadModel(const std::string& path) {
  return path.empty() ? model::SeedTsModel() : model::AsTsModel(model::ReadModelFile(path));
}

// --out: the whole run as a recording CSV, at once. Returns the exit code (0).
int WriteRecording(const RigArgs& args) {
  if (!args.bus_options_given.empty())
    throw UsageError("--out and " + args.bus_options_given.front() +
                     " cannot be combined (--out writes the recording to a file, without the bus)");
  CheckActuatorIds(args.actuator_ids);
  const Protocol protocol = ParseProtocol(args.protocol);
  const model::TsModel model = LoadModel(args.model_path);
  RigOptions options;
  options.rate_Hz = args.rate_Hz;
  options.noise_mm = args.noise_mm;
  options.seed = args.seed;
  std::string why;
  if (!options.IsValid(&why)) throw UsageError(why);
  // Without --actuator: one actuator without a name.
  const std::vector<std::string> ids =
      args.actuator_ids.empty() ? std::vector<std::string>{""} : args.actuator_ids;
  std::vector<Rig> rigs = MakeActuatorRigs(model, protocol, ids, args.effects, options);

  if (rigs.size() > 1) {
    const int64_t rows = WriteActuatorsCsv(args.out_path, ids, rigs);
    std::cout << "wrote " << rows << " rows (" << rigs.front().sample_count()
              << " samples for each of " << rigs.size() << " actuators, 0 .. "
              << static_cast<double>(rigs.front().sample_count() - 1) / options.rate_Hz << " s) to "
              << args.out_path << std::endl;
    return 0;
  }
  Rig& rig = rigs.front();
  model::Recording recording;
  const auto n = static_cast<size_t>(rig.sample_count());
  recording.t_s.reserve(n);
  recording.voltage_V.reserve(n);
  recording.deflection_mm.reserve(n);
  RigSample sample;
  while (rig.Next(&sample)) {
    recording.t_s.push_back(sample.t_s);
    recording.voltage_V.push_back(sample.voltage_V);
    recording.deflection_mm.push_back(sample.deflection_mm);
  }
  try {
    model::WriteRecordingCsv(args.out_path, recording);
  } catch (const model::InputError& error) {
    throw OperationError(error.what());  // the input was fine; the file could not be written
  }
  std::cout << "wrote " << recording.t_s.size() << " samples (0 .. " << recording.t_s.back()
            << " s) to " << args.out_path << std::endl;
  return 0;
}

// How long flexid-rig waits for flexidd's status before it starts at the wall clock: a
// flexidd on the bus answers within milliseconds.
constexpr auto kStatusTimeout = std::chrono::milliseconds(500);

// flexidd's latest sample time from its status reply; nullopt, with a line on stderr, when
// no flexidd answers or the reply carries no usable time (null: flexidd has seen none).
std::optional<int64_t> LatestUtimeOnTheBus(lcm::LCM& lcm, const bus::Channels& channels,
                                           const RigArgs& args) {
  const std::string client_id =
      "rig-" + std::to_string(getpid()) + "-" + bus::RandomRequestId().substr(0, 8);
  bus::RpcClient client(lcm, channels, client_id);
  const std::optional<bus::RpcReply> reply = client.Call("status", "{}", kStatusTimeout);
  if (!reply) {
    std::cerr << "flexid-rig: no flexidd answered status within "
              << std::chrono::duration<double>(kStatusTimeout).count()
              << " s: message time starts at the wall clock [url: " << args.lcm_url << "]\n";
    return std::nullopt;
  }
  const nlohmann::json status = nlohmann::json::parse(reply->message.result_json, nullptr, false);
  if (reply->message.status != flexid::rpc_reply_t::kOk || !status.is_object() ||
      !status.contains("latest_utime")) {
    std::cerr << "flexid-rig: flexidd's status reply carries no latest_utime: message time "
                 "starts at the wall clock\n";
    return std::nullopt;
  }
  const nlohmann::json& latest = status["latest_utime"];
  if (latest.is_null()) return std::nullopt;  // flexidd has seen no sample yet
  if (!latest.is_number_integer() || latest.get<int64_t>() < 0) {
    std::cerr << "flexid-rig: flexidd's status reply has latest_utime " << latest.dump()
              << ", not an integer >= 0: message time starts at the wall clock\n";
    return std::nullopt;
  }
  return latest.get<int64_t>();
}

// Where message time starts without --start-utime: after the latest sample flexidd has
// seen, or at the wall clock (ContinuedStartUtime in runner.h says why).
int64_t StartUtimeOnTheBus(lcm::LCM& lcm, const bus::Channels& channels, const RigArgs& args) {
  const std::optional<int64_t> latest_utime = LatestUtimeOnTheBus(lcm, channels, args);
  const int64_t wall_utime = bus::WallClockUtime();
  const int64_t start_utime = ContinuedStartUtime(wall_utime, latest_utime, args.rate_Hz);
  if (start_utime != wall_utime)
    std::cerr << "flexid-rig: message time continues after flexidd's latest sample [latest_utime: "
              << *latest_utime << ", start_utime: " << start_utime << "]\n";
  return start_utime;
}

// The options of a run on the bus. Without --start-utime, the wall clock until flexidd is
// asked (StartUtimeOnTheBus). Throws UsageError.
RigOptions BusRigOptions(const RigArgs& args) {
  RigOptions options;
  options.rate_Hz = args.rate_Hz;
  options.start_utime = args.start_utime_given ? args.start_utime : bus::WallClockUtime();
  options.noise_mm = args.noise_mm;
  options.seed = args.seed;
  std::string why;
  if (!options.IsValid(&why)) throw UsageError(why);
  return options;
}

// SIGINT and SIGTERM stop the run between samples.
void InstallStopSignals() {
  struct sigaction action = {};
  action.sa_handler = OnStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);
}

// flexidd's key (--key-file, else $FLEXID_KEY_FILE, else var/flexidd.key); `use` says
// what it is for, in the error. Throws OperationError.
flexid::auth::Key ReadSharedKey(const RigArgs& args, const std::string& use) {
  try {
    return flexid::auth::ReadKeyFile(flexid::auth::ClientKeyFilePath(args.key_file));
  } catch (const flexid::auth::KeyError& e) {
    throw OperationError(std::string(e.what()) + " (" + use +
                         " with flexidd's key: --key-file PATH or FLEXID_KEY_FILE)");
  }
}

// Hands each message on the command channel to the inbox; nothing throws into LCM.
class CommandHandler {
 public:
  explicit CommandHandler(CommandInbox& inbox) : inbox_(inbox) {}
  // For lcm.subscribeFunction (tests/lcm_subscribe.h says why not a member subscription).
  static void OnCommandThunk(const lcm::ReceiveBuffer* buffer, const std::string& channel,
                             CommandHandler* self) {
    self->OnCommand(buffer, channel);
  }
  void OnCommand(const lcm::ReceiveBuffer* buffer, const std::string&) {
    try {
      flexid::voltage_command_t command;
      if (!wire::WellFormed(buffer->data, buffer->data_size, wire::kVoltageCommand) ||
          command.decode(buffer->data, 0, static_cast<int>(buffer->data_size)) < 0) {
        ++malformed_;
        return;
      }
      inbox_.Receive(command, bus::WallClockUtime());
    } catch (const std::exception& e) {
      std::cerr << "flexid-rig: a voltage command could not be handled: " << e.what() << "\n";
    }
  }
  int64_t malformed() const { return malformed_; }

 private:
  CommandInbox& inbox_;
  int64_t malformed_ = 0;
};

// The effects of --effect for the one actuator of a closed loop. Throws model::InputError.
std::vector<std::unique_ptr<Effect>> ClosedLoopEffects(const RigArgs& args) {
  std::vector<std::unique_ptr<Effect>> effects;
  for (const std::string& spec : args.effects) {
    const ActuatorEffect effect = ParseActuatorEffect(spec);
    if (!effect.actuator_id.empty() && effect.actuator_id != args.actuator_ids.front())
      throw model::InputError("effect \"" + spec + "\": no actuator \"" + effect.actuator_id +
                              "\" (actuators: " + args.actuator_ids.front() + ")");
    effects.push_back(ParseEffect(effect.effect));
  }
  return effects;
}

// --closed-loop: one actuator driven by signed voltage commands. Returns the exit code.
int RunClosedLoopCommand(const RigArgs& args) {
  if (!args.out_path.empty())
    throw UsageError("--out and --closed-loop cannot be combined (a closed loop needs the bus)");
  if (args.lcm_url.empty()) throw UsageError("--closed-loop needs --lcm URL");
  if (args.actuator_ids.size() != 1)
    throw UsageError("--closed-loop drives one actuator: give one --actuator");
  CheckActuatorIds(args.actuator_ids);
  if (!args.protocol.empty())
    throw UsageError(
        "--closed-loop and --protocol cannot be combined (the controller's "
        "commands are the voltage)");
  if (!(args.duration_s > 0.0 && std::isfinite(args.duration_s)))
    throw UsageError("--closed-loop needs --duration S, finite and > 0 s");
  if (!(args.command_timeout_s > 0.0 && args.command_timeout_s <= 60.0))
    throw UsageError("--command-timeout must be > 0 and <= 60 s");
  if (!(args.speed == 0.0 || (args.speed >= 1e-3 && std::isfinite(args.speed))))
    throw UsageError("--speed must be 0 (as fast as possible) or a finite number >= 0.001");
  const RigOptions options = BusRigOptions(args);
  const double samples = std::ceil(args.duration_s * args.rate_Hz - 1e-9);
  if (samples > static_cast<double>(kMaxRigSamples))
    throw UsageError("--duration at --rate-hz needs more than " + std::to_string(kMaxRigSamples) +
                     " samples");
  const std::string& id = args.actuator_ids.front();
  ClosedLoopPlant plant(LoadModel(args.model_path), ClosedLoopEffects(args), options);
  const flexid::auth::Key key = ReadSharedKey(args, "--closed-loop checks the signed commands");

  lcm::LCM lcm(bus::WithReceiveBuffer(args.lcm_url, 4 << 20));  // commands come every sample
  if (!lcm.good()) throw OperationError("cannot open the LCM bus [url: " + args.lcm_url + "]");
  const bus::Channels channels(args.channel_prefix);
  if (!args.start_utime_given) plant.SetStartUtime(StartUtimeOnTheBus(lcm, channels, args));
  CommandInbox inbox(key, id, args.command_timeout_s,
                     [](const std::string& line) { std::cerr << line << "\n"; });
  CommandHandler handler(inbox);
  lcm.subscribeFunction(bus::Exactly(channels.Command(id)), &CommandHandler::OnCommandThunk,
                        &handler);
  LcmSink sink(lcm, channels, id, args.trial_control ? &key : nullptr);

  InstallStopSignals();

  ClosedLoopRunOptions run;
  run.speed = args.speed;
  run.trial_control = args.trial_control;
  run.command_timeout_s = args.command_timeout_s;
  std::ostringstream protocol;
  protocol << "closed-loop:duration=" << args.duration_s;
  run.protocol = protocol.str();
  const RunSummary summary = RunClosedLoop(
      plant, static_cast<int64_t>(samples), inbox, sink,
      [&lcm](int timeout_ms) { lcm.handleTimeout(timeout_ms); }, run, &stop_requested);
  const CommandCounts& counts = inbox.counts();
  std::cout << SummaryLine(summary) << "; commands: " << counts.accepted << " accepted, "
            << counts.Refused() + handler.malformed() << " refused (" << counts.refused_unsigned
            << " unsigned, " << counts.refused_bad_signature << " bad signature, "
            << counts.refused_stale << " stale, " << counts.refused_other + handler.malformed()
            << " other), " << counts.timeouts << " timeouts to 0 V" << std::endl;
  if (summary.failed_messages > 0) {
    std::cerr << "flexid-rig: " << summary.failed_messages
              << " messages could not be sent [url: " << args.lcm_url << "]\n";
    return 1;
  }
  if (summary.interrupted) {
    std::cerr << "flexid-rig: interrupted after " << summary.samples << " of " << samples
              << " samples\n";
    return 1;
  }
  return 0;
}

// Returns the exit code (0 or 1); throws UsageError / model::InputError for bad input.
int RunRigCommand(const RigArgs& args) {
  if (args.closed_loop) return RunClosedLoopCommand(args);
  if (args.closed_loop_options_given)
    throw UsageError("--duration and --command-timeout belong to --closed-loop");
  if (args.protocol.empty()) throw UsageError("--protocol SPEC is required (or --closed-loop)");
  if (!args.out_path.empty()) return WriteRecording(args);
  if (args.lcm_url.empty())
    throw UsageError("--lcm URL (on the bus) or --out FILE.csv is required");
  if (args.actuator_ids.empty()) throw UsageError("--actuator is required with --lcm");
  CheckActuatorIds(args.actuator_ids);
  if (!(args.speed == 0.0 || (args.speed >= 1e-3 && std::isfinite(args.speed))))
    throw UsageError("--speed must be 0 (as fast as possible) or a finite number >= 0.001");

  const Protocol protocol = ParseProtocol(args.protocol);
  const model::TsModel model = LoadModel(args.model_path);
  const RigOptions options = BusRigOptions(args);
  std::vector<Rig> rigs =
      MakeActuatorRigs(model, protocol, args.actuator_ids, args.effects, options);

  // Trial control changes data, so it is signed: the key is read before anything is sent.
  std::optional<flexid::auth::Key> key;
  if (args.trial_control) key = ReadSharedKey(args, "--trial-control signs");
  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) throw OperationError("cannot open the LCM bus [url: " + args.lcm_url + "]");
  const bus::Channels channels(args.channel_prefix);
  if (!args.start_utime_given) {
    const int64_t start_utime = StartUtimeOnTheBus(lcm, channels, args);
    try {
      for (Rig& rig : rigs) rig.SetStartUtime(start_utime);
    } catch (const model::InputError& e) {  // not the user's input: flexidd's time
      throw OperationError(std::string(e.what()) + " [start_utime: " + std::to_string(start_utime) +
                           ", after flexidd's latest sample; give --start-utime]");
    }
  }
  std::vector<std::unique_ptr<LcmSink>> sinks;
  std::vector<ActuatorOnBus> actuators;
  for (size_t i = 0; i < rigs.size(); ++i) {
    sinks.push_back(
        std::make_unique<LcmSink>(lcm, channels, args.actuator_ids[i], key ? &*key : nullptr));
    actuators.push_back({.rig = &rigs[i], .sink = sinks.back().get()});
  }

  InstallStopSignals();

  const RunSummary summary = RunRigs(
      actuators, {.speed = args.speed, .trial_control = args.trial_control}, &stop_requested);
  std::cout << SummaryLine(summary) << std::endl;
  if (summary.failed_messages > 0) {
    std::cerr << "flexid-rig: " << summary.failed_messages
              << " messages could not be sent [url: " << args.lcm_url << "]\n";
    return 1;
  }
  if (summary.interrupted) {
    std::cerr << "flexid-rig: interrupted after " << summary.samples << " of "
              << rigs.front().sample_count() << " samples\n";
    return 1;
  }
  return 0;
}

}  // namespace
}  // namespace flexid::rig

int main(int argc, char** argv) {
  using flexid::rig::RigArgs;
  CLI::App app{
      "flexid-rig: a virtual ionic gel actuator publishing voltage and deflection on LCM, or "
      "writing them to a recording CSV (--out)"};
  app.set_version_flag("--version", flexid::kVersion);
  RigArgs args;
  app.add_option("--out", args.out_path,
                 "Offline: write the whole run to this recording CSV (t_s,voltage_V,"
                 "deflection_mm) at once, without the bus; with two or more actuators "
                 "actuator,t_s,voltage_V,deflection_mm");
  CLI::Option* lcm = app.add_option(
      "--lcm", args.lcm_url, "LCM URL, e.g. udpm://239.255.76.67:7667?ttl=0 (not with --out)");
  CLI::Option* channel_prefix =
      app.add_option("--channel-prefix", args.channel_prefix,
                     "Channel prefix, flexidd's channel_prefix (not with --out)")
          ->capture_default_str()
          ->check([](const std::string& prefix) { return flexid::bus::PrefixProblem(prefix); });
  app.add_option("--actuator", args.actuator_ids,
                 "Actuator id, e.g. S1 (names the channels); repeatable or S1,S2: several "
                 "actuators, same protocol, own noise (seed + i) and channels; with --out and "
                 "two or more: an actuator column")
      ->delimiter(',')
      ->allow_extra_args(false);
  app.add_option("--protocol", args.protocol,
                 "Voltage protocol: step:level=V,duration=S[,delay=S] | "
                 "square:level=V,period=S[,duty=0.5],cycles=N[,polarity=alternate] | "
                 "staircase:levels=2/4/6/8,dwell=S | hold:level=V,duration=S | "
                 "sweep:level=V[,frequencies=0.0025/0.02/0.031/0.054/0.11/0.15/1.1][,cycles=3]"
                 "[,duty=0.5] | "
                 "random:levels=V1/V2/...,dwell_min=S,dwell_max=S,duration=S[,seed=1]"
                 " (required unless --closed-loop)");
  CLI::Option* speed =
      app.add_option("--speed", args.speed, "Times faster than real time; 0: as fast as possible")
          ->capture_default_str();
  app.add_option("--rate-hz", args.rate_Hz, "Samples per second of message time")
      ->capture_default_str();
  app.add_option("--model", args.model_path,
                 "Model file (flexid.model/1 JSON); default: the seed's two-rule T-S model");
  app.add_option("--effect", args.effects,
                 "Effect [ID/]NAME[:k=v,...], repeatable; ID/: on that actuator only: "
                 "back_relaxation[:fraction=0.3,tau=60] | "
                 "cycle_degradation[:loss=0.2,charge=5000] | hysteresis[:width=0.5] | "
                 "electrolysis_saturation[:onset=4,slope=0.3] | "
                 "sensor_drift[:rate=0.001,warmup=0,tau=600] | polarity_asymmetry[:ratio=0.7] | "
                 "dead_zone[:threshold=0.5]")
      ->allow_extra_args(false);
  app.add_option("--noise-mm", args.noise_mm, "Standard deviation of white sensor noise, mm")
      ->capture_default_str();
  app.add_option("--seed", args.seed, "Seed of the noise generator")->capture_default_str();
  CLI::Option* start_utime = app.add_option(
      "--start-utime", args.start_utime,
      "utime of the first sample, microseconds (default: now, or just after the latest sample "
      "flexidd has seen if that is later)");
  CLI::Option* trial_control = app.add_flag("--trial-control", args.trial_control,
                                            "Publish trial start and stop on PREFIX/TRIAL");
  CLI::Option* key_file = app.add_option(
      "--key-file", args.key_file,
      "flexidd's key, to sign trial control (default $FLEXID_KEY_FILE, else var/flexidd.key)");
  CLI::Option* closed_loop = app.add_flag(
      "--closed-loop", args.closed_loop,
      "One actuator driven by a controller's signed voltage commands on PREFIX/<ID>/COMMAND "
      "(flexid-control) for --duration seconds, instead of --protocol");
  CLI::Option* duration =
      app.add_option("--duration", args.duration_s, "--closed-loop: message time to play, s");
  CLI::Option* command_timeout =
      app.add_option("--command-timeout", args.command_timeout_s,
                     "--closed-loop: with no accepted command for this long (wall clock, s) the "
                     "voltage goes to 0 V; also how old a command may be when it arrives")
          ->capture_default_str();
  app.footer(
      "Examples:\n  flexid-rig --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator S1 \\\n"
      "    --protocol square:level=5,period=220,cycles=5 --speed 100 --effect back_relaxation\n"
      "  flexid-rig --out square-5V.csv --model examples/seed-8V.json \\\n"
      "    --protocol square:level=5,period=220,cycles=5 --noise-mm 0.02 --seed 7 \\\n"
      "    --effect hysteresis:width=0.04\n"
      "  flexid-rig --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator S1,S2 \\\n"
      "    --protocol sweep:level=5 --speed 20 --noise-mm 0.02 \\\n"
      "    --effect S2/back_relaxation:fraction=0.3,tau=60\n"
      "  flexid-rig --out random.csv --protocol "
      "random:levels=2/4/6/8,dwell_min=20,dwell_max=60,duration=1200,seed=3");
  return flexid::cli::RunMain(app, "flexid-rig", [&] {
    app.parse(argc, argv);
    args.start_utime_given = start_utime->count() > 0;
    args.closed_loop_options_given = duration->count() > 0 || command_timeout->count() > 0;
    for (const CLI::Option* option : {lcm, channel_prefix, speed, start_utime, trial_control,
                                      key_file, closed_loop, command_timeout})
      if (option->count() > 0) args.bus_options_given.push_back(option->get_name());
    return flexid::rig::RunRigCommand(args);
  });
}
