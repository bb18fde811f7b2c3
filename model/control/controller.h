// One controller of an actuator's deflection, whichever law it uses: what flexid-control
// runs on the bus and what the benchmark and the tests run against their plants, through
// the same calls.
//
// The loop, sample by sample on a uniform grid t_k = k Ts from the start of the run:
// the deflection y_k is measured at t_k, the controller decides u_{k+1}, and the voltage
// applied from t_{k+1} on is u_{k+1} after the limits (limits.h). The command of sample
// k thus acts one sample later (the time to compute and send it); u_0 is 0 V.
//
// Laws (ControllerKind):
//   predictive  model predictive control with the T-S model over its dead time, the
//               mismatch between the measured and the modelled deflection fed back
//               (mpc.h): the model-based controller
//   pi          PI on the measured error r_k - y_k, tuned by SIMC on the model (simc.h),
//               with conditional integration: the integral holds while the command is
//               held at a limit in the direction the error pushes
//   open_loop   the predictive controller without feedback: the constrained inversion
//               of the model over the reference, blind to the measurement
// Every law needs the reference within the model's reachable range (reference.h): the
// constructor refuses it otherwise.
#pragma once

#include <memory>
#include <string>

#include "model/control/limits.h"
#include "model/control/mpc.h"
#include "model/control/reference.h"
#include "model/control/simc.h"

namespace flexid::model::control {

enum class ControllerKind { kPredictive, kPi, kOpenLoop };
const char* ControllerKindName(ControllerKind kind);  // "predictive", "pi", "open_loop"
bool ParseControllerKind(const std::string& name, ControllerKind* kind);

struct ControllerOptions {
  ControllerKind kind = ControllerKind::kPredictive;
  double sample_period_s = 0.1;  // Ts, s (> 0)
  ControlLimits limits;
  MpcOptions mpc;
  // SIMC's closed-loop time constant tau_c, s; 0: the fit's dead time theta (simc.h).
  double pi_closed_loop_time_constant_s = 0.0;

  bool IsValid(std::string* error) const;
};

struct ControlStep {
  double voltage_V = 0.0;     // u_{k+1}, after the limits
  double wanted_V = 0.0;      // u_{k+1} before the limits
  double reference_mm = 0.0;  // r_k
  double model_mm = 0.0;      // the model's m_k (NaN for pi)
  LimitsActed limits;
};

class Controller {
 public:
  // Throws model::InputError for invalid options (naming the option) or a reference the
  // model cannot reach (ReachabilityProblem); std::invalid_argument for an invalid model.
  Controller(const TsModel& model, Reference reference, const ControllerOptions& options);
  ~Controller();
  Controller(Controller&&) noexcept;

  // Sample k: k strictly increasing (a gap means samples without a measurement; the
  // voltage in force held over them); measured_mm is y_k (NaN: none).
  ControlStep Next(long k, double measured_mm);
  // True once t_k is past the reference's last sample.
  bool Finished(long k) const;

  const Reference& reference() const { return reference_; }
  const ControllerOptions& options() const { return options_; }
  // The PI's tuning (kind pi), else nullptr.
  const PiTuning* pi_tuning() const;
  // The model's reachable range within the voltage limits (reference.h), mm.
  double reachable_low_mm() const { return reachable_low_mm_; }
  double reachable_high_mm() const { return reachable_high_mm_; }

 private:
  ControlStep Step(long k, double measured_mm);

  Reference reference_;
  ControllerOptions options_;
  CommandLimiter limiter_;
  std::unique_ptr<PredictiveController> predictive_;
  std::unique_ptr<PiTuning> pi_;
  double integral_V_ = 0.0;
  LimitsActed last_acted_;
  double last_wanted_V_ = 0.0;
  long last_k_ = -1;
  double reachable_low_mm_ = 0.0, reachable_high_mm_ = 0.0;
};

}  // namespace flexid::model::control
