// The on_alert policy (config.h PolicyConfig, README "Proposals"): a trial whose residual
// the monitor found unexplained is diagnosed once it ends, and its augmented model
// proposed or adopted, as configured. The diagnosis runs on the worker like a requested
// one (SubmitDiagnosis) with nobody to answer; its results are the usual alerts
// (the effect's, model_proposed, model_changed), and every step of the policy itself is an
// info alert of kind "policy" with its log line.
#include <spdlog/spdlog.h>

#include <cmath>

#include "daemon/service.h"

namespace flexid::daemon {

void Service::SayPolicy(ActuatorState* state, int64_t start_utime, int64_t end_utime,
                        const std::string& text) {
  Alert alert;
  alert.kind = "policy";
  alert.severity = 0;
  alert.start_utime = start_utime;
  alert.end_utime = end_utime;
  alert.text = state->info.id + ": " + text;
  Raise(state, {alert});
}

void Service::ApplyPolicy(ActuatorState* state, int64_t trial_id, int64_t start_utime,
                          int64_t end_utime) {
  const PolicyConfig& policy = config.policy;
  if (policy.on_alert == "none") return;
  const std::string trial = "trial " + std::to_string(trial_id);
  const auto now = std::chrono::steady_clock::now();
  if (state->last_policy_diagnosis) {
    const double since_s =
        std::chrono::duration<double>(now - *state->last_policy_diagnosis).count();
    if (since_s < policy.min_interval_s) {
      SayPolicy(
          state, start_utime, end_utime,
          trial + " raised alerts but is not diagnosed: the last diagnosis after alerts was " +
              std::to_string(static_cast<int64_t>(since_s)) + " s ago (policy.min_interval_s " +
              std::to_string(static_cast<int64_t>(policy.min_interval_s)) + ")");
      return;
    }
  }
  DiagnosisJob job{config.database,
                   state->info.id,
                   {trial_id},
                   true,
                   config.identification.max_diagnosis_samples};
  if (policy.on_alert != "diagnose") job.propose_by = "policy";
  if (policy.on_alert == "adopt") job.adopt_min_gain = policy.adopt_min_gain;
  if (!SubmitDiagnosis(job, {})) {
    SayPolicy(state, start_utime, end_utime,
              trial +
                  " raised alerts but is not diagnosed: an identification or diagnosis is "
                  "running");
    return;
  }
  state->last_policy_diagnosis = now;
  SayPolicy(state, start_utime, end_utime,
            trial + " raised residual or back-relaxation alerts: diagnosing it (policy.on_alert " +
                policy.on_alert + ")");
}

}  // namespace flexid::daemon
