// Model predictive control with the T-S model over its dead time (issue 17): the
// model-based controller, and with its feedback switched off the open-loop model
// inversion.
//
// Notation: Ts the sample period; at sample k the deflection y_k is measured and the
// voltage u_k (decided at k-1) is in force; the controller decides u_{k+1}. r the
// reference, H = horizon_s / Ts the prediction horizon in samples, T the model's dead
// time (T < horizon_s).
//
// Model and feedback (the Smith predictor's structure). A TsPredictor (ts_predictor.h)
// driven by the voltages applied gives the model's deflection m_k, dead time included.
// The mismatch e_k = y_k - m_k (model error, effects such as back-relaxation, an offset
// at the start) is low-pass filtered,
//   d_k = d_{k-1} + a (e_k - d_{k-1}),  a = Ts / (tau_d + Ts),  d_0 = e_0,
// and assumed to hold over the horizon: the prediction of the deflection is
//   yhat_{k+j} = m_{k+j}(u_{k+1}, ..., u_{k+j}) + d_k,   j = 1..H,
// with m_{k+j} the model stepped ahead from its state at k (a copy of the predictor). The
// first samples of the horizon (j <= T / Ts) are already decided by the voltages in
// flight through the dead time; the voltages decided now act only after it, and are
// chosen for the reference there: the dead time is handled by predicting through it.
// Without feedback (open-loop inversion), d = 0.
//
// Decision variables: the voltage on B blocks of the horizon, each held over its block
// ("move blocking"): blocks of R = replan_s / Ts samples (the plan is made again at the
// end of the first) through the dead time and fine_horizon_s beyond it, where the
// voltage decided now acts first, then 2R, 2R, 4R, 4R, ... samples up to H. U_b is block
// b's voltage.
//
// Cost (mm^2), with m linearised around the previous plan U0 (Gauss-Newton, one step per
// replan):
//   J(U) = (R/H) sum_{j = R, 2R, .. H} (yhat_{k+j}(U) - r_{k+j})^2   tracking, every R
//        + w_term (y_ss(U_{B-1}) + d_k - r_{k+H})^2          steady state after the horizon
//        + w_move sum_b (U_b - U_{b-1})^2,  U_{-1} = u_k          moves
//        + w_effort sum_b (L_b / H) (U_b - u_ss,b)^2              voltage beyond the need
// where u_ss,b is the voltage whose steady state is r - d where block b acts (its middle,
// a dead time on): the effort term pulls towards what holds the reference, not towards
// 0 V, so it leaves no offset.
//   yhat(U) ~ yhat(U0) + S (U - U0),  S_{jb} = g(j - a_b + 1) - g(j - a_{b+1} + 1),
// where a_b is block b's first sample (from 1), g(n) the model's response n samples after
// a unit step of the voltage (zero for n <= 0), taken by finite difference (probe_V) at
// the voltage in force u_k, and y_ss the model's steady state (reference.h), linearised at
// U0_{B-1}. The base trajectory yhat(U0) is the T-S model's own; only the
// correction is linear, and replanning every replan_s takes it further (scaling S by the
// incremental gain at each block's voltage was tried and tracked worse on the rig). Each block is
// bounded by the voltage range, by what the rate limit reaches from u_k by the block's end (the
// limits ramp to it within the block), and by the charge limit: |U_b| L_b Ts at most what is left
// of max_charge_Vs in the window ending with block b, after the applied voltages still in it and
// the earlier blocks of U0. A plan is simulated as the limits (limits.h) will apply it, sample by
// sample. The bounded least-squares problem is solved by box_qp.h.
#pragma once

#include <string>
#include <vector>

#include "model/control/limits.h"
#include "model/control/reference.h"
#include "model/control/ts_predictor.h"

namespace flexid::model::control {

struct MpcOptions {
  double horizon_s = 60.0;       // prediction horizon, s (> the model's dead time + replan_s)
  double replan_s = 0.5;         // how often the plan is made again (its first block), s (>= Ts)
  double move_weight = 1e-5;     // w_move, mm^2 per V^2
  double effort_weight = 1e-6;   // w_effort, mm^2 per V^2
  double terminal_weight = 1.0;  // w_term (dimensionless)
  double disturbance_time_constant_s = 2.0;  // tau_d, s (>= 0)
  double fine_horizon_s = 10.0;  // blocks of replan_s this long past the dead time, s (>= 0)
  double probe_V = 0.05;         // finite-difference step of g, V (> 0)

  bool IsValid(std::string* error) const;
};

class PredictiveController {
 public:
  // Throws std::invalid_argument for invalid options (IsValid), an invalid model, or a
  // horizon not longer than the model's dead time plus replan_s.
  PredictiveController(const TsModel& model, const Reference& reference,
                       const ControlLimits& limits, double sample_period_s,
                       const MpcOptions& options, bool feedback);

  // Sample k (strictly increasing by 1): `limiter` has applied u_k (its last_V) and holds
  // the charge of the window before; measured_mm is y_k (NaN: no measurement, the mismatch
  // is not updated). Returns the wanted u_{k+1}; *model_mm receives m_k.
  double Next(long k, const CommandLimiter& limiter, double measured_mm, double* model_mm);

  double mismatch_mm() const { return mismatch_mm_; }  // d_k
  int replans() const { return replans_; }

 private:
  void Replan(long k, const CommandLimiter& limiter);
  // The plan's voltages for samples k+1..k+H as the limits will apply them.
  std::vector<double> Expand(const std::vector<double>& blocks,
                             const CommandLimiter& limiter) const;
  // Each block's bounds: the range, what the rate limit reaches by the block's end, and
  // the charge left in the window at its end once the earlier blocks of plan U0 are spent.
  void Bounds(const CommandLimiter& limiter, const Eigen::VectorXd& U0, Eigen::VectorXd* lo,
              Eigen::VectorXd* hi) const;
  std::vector<double> Simulate(const std::vector<double>& voltages_V) const;

  Reference reference_;
  ControlLimits limits_;
  double sample_period_s_;
  MpcOptions options_;
  bool feedback_;
  TsPredictor model_;
  SteadyStateMap steady_;
  long horizon_ = 0;                // H
  std::vector<long> block_starts_;  // a_b (from 1), and H + 1 at the end
  double mismatch_mm_ = 0.0;
  bool have_mismatch_ = false;
  std::vector<double> plan_V_;  // u for samples plan_start_ + 1 .. plan_start_ + H
  long plan_start_ = -1;
  int replans_ = 0;
};

}  // namespace flexid::model::control
