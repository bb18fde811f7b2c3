// flexid-rig: a virtual actuator on the bus (DESIGN.md, "Command lines").
//
//   flexid-rig --lcm URL --actuator ID --protocol SPEC [--speed X] [--rate-hz 10]
//              [--model MODEL.json] [--effect NAME[:k=v,...]]... [--noise-mm SIGMA]
//              [--seed N] [--start-utime U] [--trial-control]
//
// Simulates the actuator's deflection for a voltage protocol (protocol.h) with the seed's
// T-S model or a model file, adds effects (effects.h) and sensor noise (rig.h), and
// publishes flexid::voltage_sample_t on FLEXID/<ID>/VOLTAGE and flexid::deflection_sample_t
// on FLEXID/<ID>/DEFLECTION in message time (runner.h); with --trial-control also
// flexid::trial_control_t start and stop on FLEXID/TRIAL. Prints one summary line on
// stdout. Errors are one line on stderr; exit 0 success, 1 the run failed (bus, unstable
// model, a message not sent, interrupted by SIGINT/SIGTERM), 2 bad usage or bad input.
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

namespace flexid::rig {
namespace {

using cli::OperationError;
using cli::UsageError;

std::atomic<bool> stop_requested{false};

void OnStopSignal(int) { stop_requested.store(true); }

struct RigArgs {
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

// Returns the exit code (0 or 1); throws UsageError / model::InputError for bad input.
int RunRigCommand(const RigArgs& args) {
  if (!IsValidActuatorId(args.actuator_id))
    throw UsageError("--actuator must be 1 to 64 of A-Z a-z 0-9 _ - (got \"" + args.actuator_id +
                     "\")");
  if (!(args.speed == 0.0 || (args.speed >= 1e-3 && std::isfinite(args.speed))))
    throw UsageError("--speed must be 0 (as fast as possible) or a finite number >= 0.001");

  const Protocol protocol = ParseProtocol(args.protocol);
  std::vector<std::unique_ptr<Effect>> effects;
  for (const std::string& spec : args.effects) effects.push_back(ParseEffect(spec));
  const model::TsModel model = args.model_path.empty()
                                   ? model::SeedTsModel()
                                   : model::AsTsModel(model::ReadModelFile(args.model_path));
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
  CLI::App app{"flexid-rig: a virtual ionic gel actuator publishing voltage and deflection on LCM"};
  app.set_version_flag("--version", flexid::kVersion);
  RigArgs args;
  app.add_option("--lcm", args.lcm_url, "LCM URL, e.g. udpm://239.255.76.67:7667?ttl=0")
      ->required();
  app.add_option("--actuator", args.actuator_id, "Actuator id, e.g. S1 (names the channels)")
      ->required();
  app.add_option("--protocol", args.protocol,
                 "Voltage protocol: step:level=V,duration=S[,delay=S] | "
                 "square:level=V,period=S[,duty=0.5],cycles=N | "
                 "staircase:levels=2/4/6/8,dwell=S | hold:level=V,duration=S")
      ->required();
  app.add_option("--speed", args.speed, "Times faster than real time; 0: as fast as possible")
      ->capture_default_str();
  app.add_option("--rate-hz", args.rate_Hz, "Samples per second of message time")
      ->capture_default_str();
  app.add_option("--model", args.model_path,
                 "Model file (flexid.model/1 JSON); default: the seed's two-rule T-S model");
  app.add_option("--effect", args.effects,
                 "Effect NAME[:k=v,...], repeatable: back_relaxation[:fraction=0.3,tau=60]")
      ->allow_extra_args(false);
  app.add_option("--noise-mm", args.noise_mm, "Standard deviation of white sensor noise, mm")
      ->capture_default_str();
  app.add_option("--seed", args.seed, "Seed of the noise generator")->capture_default_str();
  CLI::Option* start_utime = app.add_option(
      "--start-utime", args.start_utime, "utime of the first sample, microseconds (default: now)");
  app.add_flag("--trial-control", args.trial_control,
               "Publish trial start and stop on FLEXID/TRIAL");
  app.footer(
      "Example:\n  flexid-rig --lcm 'udpm://239.255.76.67:7667?ttl=0' --actuator S1 \\\n"
      "    --protocol square:level=5,period=220,cycles=5 --speed 100 --effect back_relaxation");
  try {
    app.parse(argc, argv);
    args.start_utime_given = start_utime->count() > 0;
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
