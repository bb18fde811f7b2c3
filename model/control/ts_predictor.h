// A T-S model stepped one sample at a time on a uniform grid, whose state can be copied:
// the prediction engine of the controllers (model/control/). A controller keeps one
// predictor driven by the voltages it applied; to look ahead it copies it and steps the
// copy with a candidate plan, as many times as it likes, without touching the original.
//
// The maths is model/core/simulate.h's uniform-grid simulation, sample for sample (the
// same frozen blend realised in the output-derivative form, the same exact zero-order-hold
// discretisation with fractional dead time, the same re-expression of the state at a
// change of operating point, the parallel realisation rule by rule on its share of the
// voltage); tests/control_test.cc checks that both give the same output to rounding. The
// core's streaming simulator cannot be copied (its state points into its own caches), and
// its batch form needs the whole input in advance.
//
// Notation (seed Eq. 18 per rule, Eqs. 16-17 and 19 for the blend): Ts the sample period,
// u_k the voltage held on [t_k, t_{k+1}), y_k the model's deflection at t_k, d and theta
// the dead time's whole samples and fraction (discretise.h):
//   y_k     = C x_k + D u(t_k - T)
//   x_{k+1} = Phi x_k + Gamma0 u_{k-d} + Gamma1 u_{k-d-1}
// with Phi, Gamma0, Gamma1, C, D those of the frozen model at the operating point z_k
// (kFrozen), or a sum of such systems, one per rule, each driven by mu_i(z_k) u_k
// (kParallel).
#pragma once

#include <Eigen/Dense>
#include <memory>
#include <vector>

#include "model/core/ts_fuzzy.h"

namespace flexid::model::control {

class TsPredictor {
 public:
  // Precondition (checked, std::invalid_argument): IsValid(model), sample_period_s > 0 and
  // finite, resolution_V > 0. Before the first sample the model rests in the steady state
  // of initial_voltage_V. The operating point follows the scheduling value rounded to
  // resolution_V (simulate.h's kSchedulingResolution_V by default).
  TsPredictor(const TsModel& model, double sample_period_s, double initial_voltage_V = 0.0,
              double resolution_V = 1e-3);

  // Applies voltage_V from the current sample on and returns the model's deflection at it
  // (mm); the next call is the next sample. A non-finite voltage throws
  // std::invalid_argument.
  double Step(double voltage_V);

  TsPredictor(const TsPredictor&);
  TsPredictor& operator=(const TsPredictor&);
  TsPredictor(TsPredictor&&) noexcept;
  TsPredictor& operator=(TsPredictor&&) noexcept;
  ~TsPredictor();

  // The voltage applied at the last Step (initial_voltage_V before the first).
  double last_voltage_V() const { return last_voltage_V_; }
  double sample_period_s() const { return sample_period_s_; }
  // The largest dead time of any rule, s.
  double max_delay_s() const;

 private:
  struct Shared;   // the model, its prepared rules and the discretisations, shared by copies
  struct Entry;    // one discretised linear system
  struct Channel;  // one linear system with its state and the inputs its dead time needs

  static std::shared_ptr<const Entry> MakeEntry(const TransferFunction& tf, double dt_s);
  std::shared_ptr<const Entry> FrozenEntryAt(double z) const;
  const std::vector<double>& MembershipsAt(double z) const;
  double RoundedZ(double premise_V);
  double StepFrozen(double voltage_V);
  double StepParallel(double voltage_V);

  std::shared_ptr<Shared> shared_;
  std::vector<Channel> channels_;  // kFrozen: one; kParallel: one per rule
  std::vector<double> premise_V_;  // ring of applied voltages for the premise's delay
  Scheduler scheduler_;
  double sample_period_s_ = 0.0;
  double last_voltage_V_ = 0.0;
  double last_premise_V_ = 0.0;
  uint64_t last_key_ = ~uint64_t{0};
  long k_ = 0;  // the next sample's index
};

}  // namespace flexid::model::control
