// One run of flexid-control, without the bus: measured deflections in, voltage commands
// out, and when the run must stop. control_main.cc connects it to LCM.
//
// Time. The first deflection sample received is t = 0 of the reference, at message time
// start_utime; sample k is the one at start_utime + k Ts (rounded to the nearest k; a sample
// at or before the last one is ignored). The command answering sample k applies from the
// next sample, utime_k + Ts (model/control/controller.h: the command of sample k acts one
// sample later).
//
// Stops (StopReason), each ending the run with a 0 V command from the sample after the last
// one measured, and an alert (control_main.cc):
//   finished           the reference has ended
//   stale_measurement  no deflection for stale_after_s of wall time (default 0.5 s)
//   critical_alert     a critical alert about the actuator on the ALERT channel that
//                      stops control (AlertStopsControl)
//   signal             SIGTERM or SIGINT
// Before the first deflection nothing is sent; none within start_timeout_s is an error
// without a command.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "model/control/controller.h"

namespace flexid::control {

enum class StopReason { kFinished, kStaleMeasurement, kCriticalAlert, kSignal };
const char* StopReasonName(StopReason reason);  // "finished", "stale_measurement", ...

// Whether a critical alert of this kind about the actuator stops control. Every kind does
// (sensor_dropout, a daemon's failure, a kind added later: failing safe) except:
//   - control_stop: a controller's own stop, not a finding about the actuator;
//   - residual, drift, back_relaxation, when the controller has feedback (predictive, pi):
//     they say the measured deflection departs from flexidd's model of it, which is what
//     the feedback corrects (issue 17: "model error and effects such as back-relaxation
//     are corrected"). Their severity is statistical, a multiple of the model's own
//     residual noise (critical beyond 5 thresholds: 11 sigmas of the model's residual
//     for the residual test, about 20 for the line tests; 0.23 mm on a model that fits to
//     0.02 mm), not a hazard; the hazards are bounded
//     by the voltage, rate and charge limits and by the stale-measurement stop. Open-loop
//     inversion has no feedback, so for it they stop control.
bool AlertStopsControl(const std::string& kind, bool feedback);

struct SessionOptions {
  double stale_after_s = 0.5;     // wall clock, s (> 0)
  double start_timeout_s = 10.0;  // wall clock, s (> 0)
};

struct Command {
  int64_t utime = 0;  // message time from which voltage_V applies, microseconds
  double voltage_V = 0.0;
  int64_t sequence = 0;  // 1, 2, ...
  bool stop = false;
  // The reference at the deflection sample this command answers (r_k at that sample's
  // message time); a stop carries none (0 and 0).
  double reference_mm = 0.0;
  int64_t reference_utime = 0;
};

// One line of the run's log (control_main.cc --out).
struct RunRow {
  double t_s = 0.0;
  double reference_mm = 0.0;
  double measured_mm = 0.0;
  double voltage_V = 0.0;  // in force over the sample (u_k)
  double model_mm = 0.0;   // the controller's model (NaN for pi)
};

class ControlSession {
 public:
  // start_wall_utime: when the session began waiting for its first measurement.
  ControlSession(model::control::Controller controller, const SessionOptions& options,
                 int64_t start_wall_utime);

  // A deflection measured at message time utime, received at wall time wall_utime. Returns
  // the command for the next sample, or nothing (ignored: not after the last sample, or
  // the session stopped). When the reference has ended, returns nothing and finished()
  // turns true: the caller stops with kFinished.
  std::optional<Command> OnDeflection(int64_t utime, double deflection_mm, int64_t wall_utime);

  // The stop due at wall time wall_utime for a stale measurement, if any.
  std::optional<StopReason> StaleAt(int64_t wall_utime) const;
  // No deflection yet, and start_timeout_s has passed.
  bool StartTimedOut(int64_t wall_utime) const;

  // Ends the session: the 0 V command from the sample after the last one measured (before
  // the first measurement: nullopt, nothing to stop).
  std::optional<Command> Stop(StopReason reason);

  bool started() const { return started_; }
  bool finished() const { return finished_; }
  bool stopped() const { return stop_reason_.has_value(); }
  std::optional<StopReason> stop_reason() const { return stop_reason_; }
  int64_t start_utime() const { return start_utime_; }
  int64_t last_utime() const { return last_utime_; }
  const std::vector<RunRow>& rows() const { return rows_; }
  const model::control::Controller& controller() const { return controller_; }
  // RMSE of the measured deflection against the reference over the rows, mm (0: none).
  double TrackingRmse() const;

 private:
  model::control::Controller controller_;
  SessionOptions options_;
  int64_t sample_period_us_;
  int64_t created_wall_utime_;
  bool started_ = false, finished_ = false;
  std::optional<StopReason> stop_reason_;
  int64_t start_utime_ = 0, last_utime_ = 0, last_wall_utime_ = 0;
  long last_k_ = -1;
  int64_t sequence_ = 0;
  double in_force_V_ = 0.0;  // u of the last sample measured
  std::vector<RunRow> rows_;
};

}  // namespace flexid::control
