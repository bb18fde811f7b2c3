// flexid-rig --closed-loop: the virtual actuator driven by a controller's voltage
// commands (voltage_command_t on PREFIX/<ID>/COMMAND) instead of a protocol. The plant is
// the rig's own (rig.h): the T-S model with the effects and the sensor noise, stepped
// sample by sample on the commanded voltage; the samples go out as in open loop (runner.h),
// so flexidd records the trial like any other.
//
// Sample k is at t_k = k / rate_Hz, utime_k as in rig.h. The voltage of sample k (held over
// [t_k, t_{k+1})) is the accepted command with the largest utime <= utime_k; a controller
// answers the deflection of sample k - 1 with a command for utime_k.
//
// Commands (CommandInbox). Each is refused, counted and logged unless:
//   - it is for this actuator, and its fields hold possible values
//     (lcmtypes/command_check.h: a finite voltage, a known mode, a reference at or before
//     its time, ...);
//   - it is signed with the shared key, its signature matches, its nonce is fresh and its
//     sent_utime is within command_timeout_s of this host's clock (auth::Verifier);
//   - it is not older in message time than the sample already played (a command for a
//     sample that has passed is stale), nor in sequence than one already accepted from its
//     controller.
// Watchdog: with no accepted command for command_timeout_s of wall time the voltage is
// 0 V (as before the first command).
//
// Pacing (RunClosedLoop): sample k goes out at wall time start + t_k / speed, as in open
// loop, but while a controller is attached (a command accepted within command_timeout_s)
// the rig waits up to half of command_timeout_s past that time for the command for utime_k,
// so that a controller slower than the playback still sees every sample answered in time,
// and a sample the controller never heard of goes on before the controller's own stale
// timeout (0.5 s by default) stops it.
#pragma once

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "clients/rig/effects.h"
#include "clients/rig/rig.h"
#include "clients/rig/runner.h"
#include "lcmtypes/message_auth.h"
#include "model/core/simulate.h"

namespace flexid {
class voltage_command_t;
}

namespace flexid::rig {

// The rig's plant stepped on a voltage given sample by sample.
class ClosedLoopPlant {
 public:
  // Throws model::InputError for invalid options, std::invalid_argument for an invalid
  // model.
  ClosedLoopPlant(const model::TsModel& model, std::vector<std::unique_ptr<Effect>> effects,
                  const RigOptions& options);

  // Sample k with voltage_V applied from t_k: the deflection at t_k through the effects,
  // plus noise. Throws std::runtime_error if the model's output is not finite.
  RigSample Next(double voltage_V);
  int64_t UtimeOf(int64_t k) const;
  const RigOptions& options() const { return options_; }
  // The deflection of the last sample before the noise, mm.
  double clean_mm() const { return clean_mm_; }
  void SetStartUtime(int64_t start_utime);  // before the first Next only

 private:
  model::StreamingSimulator model_;
  std::vector<std::unique_ptr<Effect>> effects_;
  RigOptions options_;
  GaussianNoise noise_;
  int64_t next_ = 0;
  int64_t last_voltage_utime_ = 0;
  double last_voltage_V_ = 0.0;
  double clean_mm_ = 0.0;
};

struct CommandCounts {
  int64_t accepted = 0;
  int64_t refused_unsigned = 0;       // no signature
  int64_t refused_bad_signature = 0;  // a signature that does not match, or a bad nonce
  int64_t refused_stale = 0;          // sent too long ago, replayed, or for a passed sample
  int64_t refused_other = 0;          // another actuator's, invalid fields, a full nonce cache
  int64_t timeouts = 0;               // times the watchdog went to 0 V
  int64_t Refused() const {
    return refused_unsigned + refused_bad_signature + refused_stale + refused_other;
  }
};

class CommandInbox {
 public:
  // `log` receives one line per refusal kind at most once a second (and per timeout).
  CommandInbox(const auth::Key& key, std::string actuator_id, double command_timeout_s,
               std::function<void(const std::string&)> log);

  // A decoded command, received at wall time now_utime. Returns "" when accepted,
  // otherwise why it was refused.
  std::string Receive(const flexid::voltage_command_t& command, int64_t now_utime);
  // The voltage of the sample at sample_utime, played at wall time now_utime; marks that
  // sample as played (later commands for it or before it are stale).
  double VoltageFor(int64_t sample_utime, int64_t now_utime);
  // A command accepted within the timeout.
  bool Attached(int64_t now_utime) const;
  // An accepted command is for sample_utime or later.
  bool Answered(int64_t sample_utime) const;
  const CommandCounts& counts() const { return counts_; }

 private:
  void Log(const std::string& kind, const std::string& line, int64_t now_utime);

  auth::Verifier verifier_;
  std::string actuator_id_;
  int64_t timeout_us_;
  std::function<void(const std::string&)> log_;
  std::deque<std::pair<int64_t, double>> pending_;  // accepted (utime, voltage), increasing
  std::map<std::string, int64_t> last_sequence_;    // per controller
  std::map<std::string, int64_t> last_logged_;      // per refusal kind, wall utime
  double voltage_V_ = 0.0;                          // in force
  int64_t played_utime_ = -1;
  int64_t last_accepted_wall_ = -1;
  bool timed_out_ = true;  // no command yet
  CommandCounts counts_;
};

struct ClosedLoopRunOptions {
  double speed = 1.0;                    // as RunOptions::speed
  bool trial_control = false;            // publish trial start and stop
  std::string protocol = "closed-loop";  // the trial's protocol text
  double command_timeout_s = 0.5;        // the watchdog and the wait for a command
};

// Plays `samples` samples of the plant on the sink, each with the inbox's voltage;
// pump(timeout_ms) handles incoming messages (the commands) for at most that long.
RunSummary RunClosedLoop(ClosedLoopPlant& plant, int64_t samples, CommandInbox& inbox,
                         BusSink& sink, const std::function<void(int)>& pump,
                         const ClosedLoopRunOptions& options,
                         const std::atomic<bool>* stop = nullptr);

}  // namespace flexid::rig
