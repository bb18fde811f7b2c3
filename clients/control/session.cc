#include "clients/control/session.h"

#include <cmath>

namespace flexid::control {

const char* StopReasonName(StopReason reason) {
  switch (reason) {
    case StopReason::kFinished:
      return "finished";
    case StopReason::kStaleMeasurement:
      return "stale_measurement";
    case StopReason::kCriticalAlert:
      return "critical_alert";
    case StopReason::kSignal:
      return "signal";
  }
  return "?";
}

bool AlertStopsControl(const std::string& kind, bool feedback) {
  if (kind == "control_stop") return false;
  const bool model_mismatch = kind == "residual" || kind == "drift" || kind == "back_relaxation";
  return !(model_mismatch && feedback);
}

ControlSession::ControlSession(model::control::Controller controller, const SessionOptions& options,
                               int64_t start_wall_utime)
    : controller_(std::move(controller)),
      options_(options),
      sample_period_us_(std::llround(controller_.options().sample_period_s * 1e6)),
      created_wall_utime_(start_wall_utime) {}

std::optional<Command> ControlSession::OnDeflection(int64_t utime, double deflection_mm,
                                                    int64_t wall_utime) {
  if (stopped() || finished_ || !std::isfinite(deflection_mm)) return std::nullopt;
  if (!started_) {
    started_ = true;
    start_utime_ = utime;
  }
  const double samples =
      static_cast<double>(utime - start_utime_) / static_cast<double>(sample_period_us_);
  const long k = std::lround(samples);
  if (k <= last_k_) return std::nullopt;
  last_wall_utime_ = wall_utime;
  last_utime_ = utime;
  if (controller_.Finished(k)) {
    finished_ = true;
    return std::nullopt;
  }
  const model::control::ControlStep step = controller_.Next(k, deflection_mm);
  last_k_ = k;
  rows_.push_back({.t_s = static_cast<double>(k) * controller_.options().sample_period_s,
                   .reference_mm = step.reference_mm,
                   .measured_mm = deflection_mm,
                   .voltage_V = in_force_V_,
                   .model_mm = step.model_mm});
  in_force_V_ = step.voltage_V;
  return Command{.utime = utime + sample_period_us_,
                 .voltage_V = step.voltage_V,
                 .sequence = ++sequence_,
                 .stop = false,
                 .reference_mm = step.reference_mm,
                 .reference_utime = utime};
}

std::optional<StopReason> ControlSession::StaleAt(int64_t wall_utime) const {
  if (!started_ || stopped()) return std::nullopt;
  const double silent_s = 1e-6 * static_cast<double>(wall_utime - last_wall_utime_);
  if (silent_s > options_.stale_after_s) return StopReason::kStaleMeasurement;
  return std::nullopt;
}

bool ControlSession::StartTimedOut(int64_t wall_utime) const {
  return !started_ &&
         1e-6 * static_cast<double>(wall_utime - created_wall_utime_) > options_.start_timeout_s;
}

std::optional<Command> ControlSession::Stop(StopReason reason) {
  if (stopped()) return std::nullopt;
  stop_reason_ = reason;
  if (!started_) return std::nullopt;
  in_force_V_ = 0.0;
  return Command{.utime = last_utime_ + sample_period_us_,
                 .voltage_V = 0.0,
                 .sequence = ++sequence_,
                 .stop = true};
}

double ControlSession::TrackingRmse() const {
  if (rows_.empty()) return 0.0;
  double squares = 0.0;
  for (const RunRow& row : rows_)
    squares += (row.measured_mm - row.reference_mm) * (row.measured_mm - row.reference_mm);
  return std::sqrt(squares / static_cast<double>(rows_.size()));
}

}  // namespace flexid::control
