#include "model/control/limits.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

namespace flexid::model::control {

bool ControlLimits::IsValid(std::string* error) const {
  std::ostringstream why;
  if (!std::isfinite(min_V) || !std::isfinite(max_V) || !(min_V <= 0.0 && 0.0 <= max_V) ||
      !(min_V < max_V))
    why << "the voltage range must be finite and hold 0 V, min_V < max_V (got " << min_V << " .. "
        << max_V << " V)";
  else if (!(rate_V_per_s > 0.0))
    why << "the rate limit must be > 0 V/s (got " << rate_V_per_s << ")";
  else if (!(max_charge_Vs > 0.0))
    why << "the maximum charge per cycle must be > 0 V s (got " << max_charge_Vs << ")";
  else if (!(charge_window_s > 0.0 && std::isfinite(charge_window_s)))
    why << "the charge window must be finite and > 0 s (got " << charge_window_s << ")";
  else
    return true;
  *error = why.str();
  return false;
}

double ControlLimits::Clip(double voltage_V) const { return std::clamp(voltage_V, min_V, max_V); }

CommandLimiter::CommandLimiter(const ControlLimits& limits, double sample_period_s,
                               double initial_V)
    : limits_(limits), sample_period_s_(sample_period_s), last_V_(initial_V) {
  std::string why;
  if (!limits.IsValid(&why)) throw std::invalid_argument("CommandLimiter: " + why);
  if (!(sample_period_s > 0.0 && std::isfinite(sample_period_s)))
    throw std::invalid_argument("CommandLimiter: the sample period must be finite and > 0 s");
  const double samples = std::round(limits.charge_window_s / sample_period_s);
  window_.assign(static_cast<size_t>(std::clamp(samples, 1.0, 1e7)), 0.0);
}

double CommandLimiter::Apply(double wanted_V, LimitsActed* acted) {
  LimitsActed flags;
  double u = std::isfinite(wanted_V) ? wanted_V : 0.0;
  const double ranged = limits_.Clip(u);
  flags.range = ranged != u;
  u = ranged;
  const double step_V = limits_.rate_V_per_s * sample_period_s_;
  const double rated = std::clamp(u, last_V_ - step_V, last_V_ + step_V);
  flags.rate = rated != u;
  u = limits_.Clip(rated);
  // The charge of the W - 1 samples before this one, and what is left for it and for the
  // ramp down to 0 V at the rate limit after it (|u|^2 / (2 rate)): the largest |u| with
  // |u| Ts + |u|^2 / (2 rate) <= left.
  const double before_Vs = charge_Vs_ - window_[next_];
  const double left_Vs = std::max(0.0, limits_.max_charge_Vs - before_Vs);
  const double rate = limits_.rate_V_per_s, dt = sample_period_s_;
  double allowed_V =
      std::isinf(rate) ? left_Vs / dt : rate * (std::sqrt(dt * dt + 2.0 * left_Vs / rate) - dt);
  // Coming down faster than the rate limit only when even that is not enough.
  allowed_V = std::max(allowed_V, std::min(std::abs(last_V_) - step_V, left_Vs / dt));
  if (std::abs(u) > allowed_V) {
    u = std::copysign(std::max(allowed_V, 0.0), u);  // towards 0 V, inside the range
    flags.charge = true;
  }
  const double charge = std::abs(u) * sample_period_s_;
  charge_Vs_ += charge - window_[next_];
  window_[next_] = charge;
  next_ = (next_ + 1) % window_.size();
  // Summed afresh once per window, so that rounding cannot accumulate over a long run.
  if (next_ == 0) {
    charge_Vs_ = 0.0;
    for (double part : window_) charge_Vs_ += part;
  }
  last_V_ = u;
  if (acted) *acted = flags;
  return u;
}

}  // namespace flexid::model::control

namespace flexid::model::control {

std::vector<double> CommandLimiter::WindowCharges() const {
  std::vector<double> oldest_first(window_.begin() + static_cast<long>(next_), window_.end());
  oldest_first.insert(oldest_first.end(), window_.begin(),
                      window_.begin() + static_cast<long>(next_));
  return oldest_first;
}

}  // namespace flexid::model::control
