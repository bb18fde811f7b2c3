// The limits every voltage command of a controller obeys (issue 17, "The limits"): the
// voltage range, the rate limit and the maximum charge per cycle.
//
// Charge. The model has no current, so charge is measured as the seed's cycle-degradation
// effect and the rig measure it (clients/rig/effects.h, Eq. 3): the charge proxy
//   Q(t) = integral over the last charge_window_s of |u(s)| ds,   in V s,
// with u held between samples (zero-order hold), so Q_k = Ts sum_{j = k-W+1..k} |u_j|
// over the last W = round(charge_window_s / Ts) samples. A cycle is that window (the seed's
// repeatability protocol has a 220 s period, the default); Q may never exceed
// max_charge_Vs (default 1200 V s: 5.5 V on average). A 5 V square wave of 50 % duty
// moves 550 V s per 220 s.
//
// Order of the limits on a wanted voltage w (CommandLimiter::Apply):
//   1. range:  w clipped to [min_V, max_V];
//   2. rate:   to [u_prev - rate Ts, u_prev + rate Ts];
//   3. charge: with L = max_charge_Vs - Q of the W - 1 samples before, |u| such that the
//      sample and the ramp down to 0 V at the rate limit after it fit in L:
//        |u| Ts + |u|^2 / (2 rate) <= L,  i.e.  |u| <= rate (sqrt(Ts^2 + 2 L / rate) - Ts),
//      so the budget is approached within the rate limit; only if the ramp cannot stay
//      within L any more is the voltage cut faster (to L / Ts at most).
// Range and charge are hard; the rate limit yields to them only then (and a stop, which
// goes to 0 V at once).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace flexid::model::control {

struct ControlLimits {
  double min_V = -8.0;             // lowest voltage, V (finite, <= 0: a stop is 0 V)
  double max_V = 8.0;              // highest voltage, V (finite, >= 0, > min_V)
  double rate_V_per_s = 5.0;       // largest |du/dt|, V/s (> 0; infinity: none)
  double max_charge_Vs = 1200.0;   // largest charge proxy per window, V s (> 0; infinity: none)
  double charge_window_s = 220.0;  // the window ("cycle"), s (> 0, finite)

  // On failure returns false and writes one sentence naming the limit to *error.
  bool IsValid(std::string* error) const;
  // Clips a voltage to [min_V, max_V].
  double Clip(double voltage_V) const;
};

// Which limits changed the last command.
struct LimitsActed {
  bool range = false;
  bool rate = false;
  bool charge = false;
};

class CommandLimiter {
 public:
  // Precondition: limits.IsValid(), sample_period_s > 0 (checked: std::invalid_argument).
  // The voltage before the first command is initial_V (0 V: at rest).
  CommandLimiter(const ControlLimits& limits, double sample_period_s, double initial_V = 0.0);

  // The voltage to apply for the next sample, given the one wanted; remembers it.
  double Apply(double wanted_V, LimitsActed* acted = nullptr);
  // The last voltage returned (initial_V before the first).
  double last_V() const { return last_V_; }
  // The charge proxy over the window up to and including the last voltage, V s.
  double charge_Vs() const { return charge_Vs_; }
  // The charge |u_j| Ts of each of the last W samples, oldest first, V s.
  std::vector<double> WindowCharges() const;
  const ControlLimits& limits() const { return limits_; }

 private:
  ControlLimits limits_;
  double sample_period_s_;
  double last_V_;
  std::vector<double> window_;  // |u_j| Ts of the last W samples, a ring
  size_t next_ = 0;
  double charge_Vs_ = 0.0;
};

}  // namespace flexid::model::control
