// flexid-rig: a virtual actuator on the bus (DESIGN.md, "Command lines"), or offline.
//
//   flexid-rig --lcm URL --actuator ID --protocol SPEC [--speed X] [--rate-hz 10]
//              [--model MODEL.json] [--effect NAME[:k=v,...]]... [--noise-mm SIGMA]
//              [--seed N] [--start-utime U] [--trial-control]
//   flexid-rig --out FILE.csv --protocol SPEC [--rate-hz 10] [--model MODEL.json]
//              [--effect NAME[:k=v,...]]... [--noise-mm SIGMA] [--seed N]
//
// Simulates the actuator's deflection for a voltage protocol (protocol.h) with the seed's
// T-S model or a model file, adds effects (effects.h) and sensor noise (rig.h), and
// publishes flexid::voltage_sample_t on FLEXID/<ID>/VOLTAGE and flexid::deflection_sample_t
// on FLEXID/<ID>/DEFLECTION in message time (runner.h); with --trial-control also
// flexid::trial_control_t start and stop on FLEXID/TRIAL.
//
// Offline (--out): the same sample stream (the same seed gives the same noise) is written at
// once, without the bus and without pacing, as a recording CSV t_s,voltage_V,deflection_mm
// (model/recording.h) with t_s = k / rate_Hz from 0. The bus options (--lcm, --actuator,
// --speed, --start-utime, --trial-control) are rejected with --out.
//
// Prints one summary line on stdout. Errors are one line on stderr; exit 0 success, 1 the
// run failed (bus, unstable model, a message not sent, the file not written, interrupted by
// SIGINT/SIGTERM), 2 bad usage or bad input.
#include <signal.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <chrono>
#include <cmath>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <memory>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/rig/effects.h"
#include "clients/rig/protocol.h"
#include "clients/rig/rig.h"
#include "clients/rig/runner.h"
#include "flexid/version.h"
#include "model/errors.h"
#include "model/model_file.h"
#include "model/presets.h"
#include "model/recording.h"

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
  std::string actuator_id;
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
};

// Actuator ids name LCM channels: [A-Za-z0-9_-]{1,64}, as rpc_request_t's client_id.
bool IsValidActuatorId(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  for (const char c : id) {
    const bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

class LcmSink : public BusSink {
 public:
  LcmSink(lcm::LCM& lcm, std::string actuator_id)
      : lcm_(&lcm),
        actuator_id_(std::move(actuator_id)),
        voltage_channel_("FLEXID/" + actuator_id_ + "/VOLTAGE"),
        deflection_channel_("FLEXID/" + actuator_id_ + "/DEFLECTION") {}

  bool PublishVoltage(int64_t utime, double voltage_V) override {
    flexid::voltage_sample_t message;
    message.utime = utime;
    message.actuator_id = actuator_id_;
    message.voltage_V = voltage_V;
    return lcm_->publish(voltage_channel_, &message) == 0;
  }
  bool PublishDeflection(int64_t utime, double deflection_mm) override {
    flexid::deflection_sample_t message;
    message.utime = utime;
    message.actuator_id = actuator_id_;
    message.deflection_mm = deflection_mm;
    return lcm_->publish(deflection_channel_, &message) == 0;
  }
  bool PublishTrialControl(int64_t utime, TrialAction action,
                           const std::string& protocol) override {
    flexid::trial_control_t message;
    message.utime = utime;
    message.actuator_id = actuator_id_;
    message.action = action == TrialAction::kStart ? flexid::trial_control_t::kStart
                                                   : flexid::trial_control_t::kStop;
    message.protocol = protocol;
    return lcm_->publish("FLEXID/TRIAL", &message) == 0;
  }

 private:
  lcm::LCM* lcm_;
  std::string actuator_id_;
  std::string voltage_channel_;
  std::string deflection_channel_;
};

int64_t WallClockUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

std::vector<std::unique_ptr<Effect>> ParseEffects(const std::vector<std::string>& specs) {
  std::vector<std::unique_ptr<Effect>> effects;
  for (const std::string& spec : specs) effects.push_back(ParseEffect(spec));
  return effects;
}

model::TsModel LoadModel(const std::string& path) {
  return path.empty() ? model::SeedTsModel() : model::AsTsModel(model::ReadModelFile(path));
}

// --out: the whole run as a recording CSV, at once. Returns the exit code (0).
int WriteRecording(const RigArgs& args) {
  if (!args.bus_options_given.empty())
    throw UsageError("--out and " + args.bus_options_given.front() +
                     " cannot be combined (--out writes the recording to a file, without the bus)");
  const Protocol protocol = ParseProtocol(args.protocol);
  std::vector<std::unique_ptr<Effect>> effects = ParseEffects(args.effects);
  const model::TsModel model = LoadModel(args.model_path);
  RigOptions options;
  options.rate_Hz = args.rate_Hz;
  options.noise_mm = args.noise_mm;
  options.seed = args.seed;
  std::string why;
  if (!options.IsValid(&why)) throw UsageError(why);
  Rig rig(model, protocol, std::move(effects), options);

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

// Returns the exit code (0 or 1); throws UsageError / model::InputError for bad input.
int RunRigCommand(const RigArgs& args) {
  if (!args.out_path.empty()) return WriteRecording(args);
  if (args.lcm_url.empty())
    throw UsageError("--lcm URL (on the bus) or --out FILE.csv is required");
  if (args.actuator_id.empty()) throw UsageError("--actuator is required with --lcm");
  if (!IsValidActuatorId(args.actuator_id))
    throw UsageError("--actuator must be 1 to 64 of A-Z a-z 0-9 _ - (got \"" + args.actuator_id +
                     "\")");
  if (!(args.speed == 0.0 || (args.speed >= 1e-3 && std::isfinite(args.speed))))
    throw UsageError("--speed must be 0 (as fast as possible) or a finite number >= 0.001");

  const Protocol protocol = ParseProtocol(args.protocol);
  std::vector<std::unique_ptr<Effect>> effects = ParseEffects(args.effects);
  const model::TsModel model = LoadModel(args.model_path);
  RigOptions options;
  options.rate_Hz = args.rate_Hz;
  options.start_utime = args.start_utime_given ? args.start_utime : WallClockUtime();
  options.noise_mm = args.noise_mm;
  options.seed = args.seed;
  std::string why;
  if (!options.IsValid(&why)) throw UsageError(why);
  Rig rig(model, protocol, std::move(effects), options);

  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) throw OperationError("cannot open the LCM bus [url: " + args.lcm_url + "]");
  LcmSink sink(lcm, args.actuator_id);

  struct sigaction action = {};
  action.sa_handler = OnStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);

  const RunSummary summary = RunRig(
      rig, sink, {.speed = args.speed, .trial_control = args.trial_control}, &stop_requested);
  std::cout << SummaryLine(summary) << std::endl;
  if (summary.failed_messages > 0) {
    std::cerr << "flexid-rig: " << summary.failed_messages
              << " messages could not be sent [url: " << args.lcm_url << "]\n";
    return 1;
  }
  if (summary.interrupted) {
    std::cerr << "flexid-rig: interrupted after " << summary.samples << " of " << rig.sample_count()
              << " samples\n";
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
                 "deflection_mm) at once, without the bus");
  CLI::Option* lcm = app.add_option(
      "--lcm", args.lcm_url, "LCM URL, e.g. udpm://239.255.76.67:7667?ttl=0 (not with --out)");
  CLI::Option* actuator = app.add_option("--actuator", args.actuator_id,
                                         "Actuator id, e.g. S1 (names the channels; with --lcm)");
  app.add_option("--protocol", args.protocol,
                 "Voltage protocol: step:level=V,duration=S[,delay=S] | "
                 "square:level=V,period=S[,duty=0.5],cycles=N[,polarity=alternate] | "
                 "staircase:levels=2/4/6/8,dwell=S | hold:level=V,duration=S")
      ->required();
  CLI::Option* speed =
      app.add_option("--speed", args.speed, "Times faster than real time; 0: as fast as possible")
          ->capture_default_str();
  app.add_option("--rate-hz", args.rate_Hz, "Samples per second of message time")
      ->capture_default_str();
  app.add_option("--model", args.model_path,
                 "Model file (flexid.model/1 JSON); default: the seed's two-rule T-S model");
  app.add_option("--effect", args.effects,
                 "Effect NAME[:k=v,...], repeatable: back_relaxation[:fraction=0.3,tau=60] | "
                 "cycle_degradation[:loss=0.2,charge=5000] | hysteresis[:width=0.5] | "
                 "electrolysis_saturation[:onset=4,slope=0.3] | "
                 "sensor_drift[:rate=0.001,warmup=0,tau=600] | polarity_asymmetry[:ratio=0.7] | "
                 "dead_zone[:threshold=0.5]")
      ->allow_extra_args(false);
  app.add_option("--noise-mm", args.noise_mm, "Standard deviation of white sensor noise, mm")
      ->capture_default_str();
  app.add_option("--seed", args.seed, "Seed of the noise generator")->capture_default_str();
  CLI::Option* start_utime = app.add_option(
      "--start-utime", args.start_utime, "utime of the first sample, microseconds (default: now)");
  CLI::Option* trial_control = app.add_flag("--trial-control", args.trial_control,
                                            "Publish trial start and stop on FLEXID/TRIAL");
  app.footer(
      "Examples:\n  flexid-rig --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator S1 \\\n"
      "    --protocol square:level=5,period=220,cycles=5 --speed 100 --effect back_relaxation\n"
      "  flexid-rig --out square-5V.csv --model examples/seed-8V.json \\\n"
      "    --protocol square:level=5,period=220,cycles=5 --noise-mm 0.02 --seed 7 \\\n"
      "    --effect hysteresis:width=0.04");
  try {
    app.parse(argc, argv);
    args.start_utime_given = start_utime->count() > 0;
    for (const CLI::Option* option : {lcm, actuator, speed, start_utime, trial_control})
      if (option->count() > 0) args.bus_options_given.push_back(option->get_name());
    return flexid::rig::RunRigCommand(args);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "flexid-rig: " << e.what() << '\n';
    return 2;
  } catch (const flexid::cli::UsageError& e) {
    std::cerr << "flexid-rig: " << e.what() << '\n';
    return 2;
  } catch (const flexid::model::InputError& e) {
    std::cerr << "flexid-rig: " << e.what() << '\n';
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "flexid-rig: " << e.what() << '\n';
    return 1;
  }
}
