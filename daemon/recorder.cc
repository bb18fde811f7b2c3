// The trial recorder (DESIGN.md): trials start and end (automatically on the voltage, or as
// asked on the bus and by RPC) under ids handed out on the loop, and each deflection sample
// of a trial goes to the writer with the voltage in force at its time. Never waits for the
// disk: the writer stores the rows, or retries.
#include <spdlog/spdlog.h>

#include <cmath>

#include "daemon/service.h"

namespace flexid::daemon {

// Automatic trials: one ends after trial_idle_stop_s without voltage (checked on every
// voltage message, also the first after a long gap); one starts when an idle actuator gets
// a voltage.
void Service::FollowVoltage(ActuatorState* state, int64_t utime, double voltage_V) {
  const bool active = std::abs(voltage_V) > config.alerts.rest_band_V;
  if (state->automatic_trial && state->last_active_utime != kNoTime &&
      utime - state->last_active_utime > static_cast<int64_t>(config.trial_idle_stop_s * 1e6))
    StopTrial(state, utime, storage::TrialState::kComplete);
  if (active) state->last_active_utime = utime;
  if (config.auto_trials && active && state->trial_id == 0)
    StartTrial(state, "automatic", utime, true);
}

// A deflection sample of the trial recording goes to the writer, paired with the voltage
// in force at its time (held since its last message); one the writer's queue cannot take
// is dropped and counted.
void Service::RecordSample(ActuatorState* state, int64_t utime, double deflection_mm) {
  if (state->trial_id == 0) return;
  if (writer->Enqueue(state->trial_id, {utime, state->voltage_V, deflection_mm}))
    state->last_sample_utime = utime;
  else
    ++counters.dropped_queue_full;
}

// Starts a trial under the next id; returns the ticket of its write. Never waits for the
// disk, never throws for it: the writer stores the trial, or retries.
uint64_t Service::StartTrial(ActuatorState* state, const std::string& protocol, int64_t utime,
                             bool automatic) {
  state->trial_id = next_trial_id++;
  const uint64_t ticket =
      Store(storage::TrialStart{state->trial_id, state->info.id, protocol, utime});
  on_written.emplace(ticket, [id = state->trial_id,
                              actuator = state->info.id](const storage::WriteOutcome& written) {
    if (written.error.empty() && written.trial_id != id)
      spdlog::warn(
          "trial stored under another id: another program took its id [actuator: {}, "
          "trial: {}, stored as: {}]",
          actuator, id, written.trial_id);
  });
  state->trial_start_utime = utime;
  state->trial_protocol = protocol;
  state->last_heard = loop_now;  // input silence counts from the start of a trial
  state->automatic_trial = automatic;
  state->last_sample_utime = kNoTime;
  state->policy_alerts = 0;
  spdlog::info("trial started [actuator: {}, trial: {}, protocol: {}]", state->info.id,
               state->trial_id, protocol);
  return ticket;
}

// Ends the trial recording; returns the ticket of its write (as StartTrial).
uint64_t Service::StopTrial(ActuatorState* state, int64_t utime, storage::TrialState how) {
  // A trial ends at its last sample; one without samples ends where it started (message
  // time; 0 would read as "still recording").
  const int64_t end = state->last_sample_utime != kNoTime ? state->last_sample_utime
                      : utime > state->trial_start_utime  ? utime
                                                          : state->trial_start_utime;
  const uint64_t ticket = Store(storage::TrialEnd{state->trial_id, end, how});
  spdlog::info("trial ended [actuator: {}, trial: {}, state: {}]", state->info.id, state->trial_id,
               storage::TrialStateName(how));
  const int64_t ended = state->trial_id;
  const int alerted = state->policy_alerts;
  state->trial_id = 0;
  state->automatic_trial = false;
  state->policy_alerts = 0;
  // A finished trial the model did not explain: the on_alert policy acts on it.
  if (alerted > 0 && how == storage::TrialState::kComplete)
    ApplyPolicy(state, ended, state->trial_start_utime, end);
  return ticket;
}

}  // namespace flexid::daemon
