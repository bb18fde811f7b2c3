// The PI baseline's tuning by a standard rule: Skogestad's SIMC rule (S. Skogestad,
// "Simple analytic rules for model reduction and PID controller tuning", Journal of
// Process Control 13 (2003) 291-309) on a first-order-plus-dead-time (FOPDT) fit of the
// T-S model's step response.
//
// 1. Operating point: u0 = the voltage whose steady state is the reference's mid-range
//    value (reference.h's SteadyStateMap).
// 2. FOPDT fit: the frozen model at z(u0) (ts_fuzzy.h), its exact unit step response
//    g(t) (transfer_function.h's StepResponse) normalised by its DC gain, fitted by least
//    squares on 600 points of [0, t_end], t_end = T + 5 tau_max (the dead time and five
//    times the slowest mode's time constant: g has settled), with
//      g(t) ~ 0                          for t < theta,
//      g(t) ~ 1 - exp(-(t - theta)/tau)  for t >= theta;
//    theta on a grid, tau by golden section for each.
//    The process gain is the incremental steady-state gain k = d y_ss / du at u0 (mm/V):
//    the slope of the T-S model's steady state, which is what a small PI correction
//    around u0 meets.
// 3. SIMC (Skogestad 2003, its PI rule for a first-order process with delay), with the closed-loop
// time
//    constant tau_c (default theta, the rule's "tight control" choice):
//      K_c   = tau / (k (tau_c + theta))      (V per mm of error)
//      tau_I = min(tau, 4 (tau_c + theta))    (s)
#pragma once

#include <string>

#include "model/core/ts_fuzzy.h"

namespace flexid::model::control {

struct FirstOrderPlusDeadTime {
  double gain_mm_per_V = 0.0;    // k
  double time_constant_s = 0.0;  // tau
  double dead_time_s = 0.0;      // theta
  double fit_rms = 0.0;          // RMS error of the normalised fit, in shares of the step
};

struct PiTuning {
  double gain_V_per_mm = 0.0;                // K_c
  double integral_time_s = 0.0;              // tau_I
  double closed_loop_time_constant_s = 0.0;  // tau_c
  double operating_voltage_V = 0.0;          // u0
  FirstOrderPlusDeadTime fopdt;
  std::string Describe() const;  // one line, for logs and the benchmark
};

// FOPDT fit of the frozen model at operating voltage u0 (gain: slope_mm_per_V).
// Precondition: IsValid(model); the frozen model is stable with a non-zero DC gain
// (otherwise std::invalid_argument naming the problem).
FirstOrderPlusDeadTime FitFirstOrderPlusDeadTime(const TsModel& model, double voltage_V,
                                                 double slope_mm_per_V);

// SIMC from the FOPDT fit; tau_c <= 0 takes theta. Throws std::invalid_argument if the
// fit's gain is 0.
PiTuning SimcTuning(const FirstOrderPlusDeadTime& fopdt, double closed_loop_time_constant_s = 0.0);

}  // namespace flexid::model::control
