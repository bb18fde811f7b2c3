#include "model/control/controller.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>

#include "model/core/errors.h"

namespace flexid::model::control {

const char* ControllerKindName(ControllerKind kind) {
  switch (kind) {
    case ControllerKind::kPredictive:
      return "predictive";
    case ControllerKind::kPi:
      return "pi";
    case ControllerKind::kOpenLoop:
      return "open_loop";
  }
  return "?";
}

bool ParseControllerKind(const std::string& name, ControllerKind* kind) {
  for (ControllerKind candidate :
       {ControllerKind::kPredictive, ControllerKind::kPi, ControllerKind::kOpenLoop})
    if (name == ControllerKindName(candidate)) {
      *kind = candidate;
      return true;
    }
  return false;
}

bool ControllerOptions::IsValid(std::string* error) const {
  if (!(sample_period_s > 0.0 && std::isfinite(sample_period_s))) {
    *error = "the sample period must be finite and > 0 s";
    return false;
  }
  if (!(pi_closed_loop_time_constant_s >= 0.0 && std::isfinite(pi_closed_loop_time_constant_s))) {
    *error = "the PI's closed-loop time constant must be finite and >= 0 s";
    return false;
  }
  return limits.IsValid(error) && mpc.IsValid(error);
}

namespace {

ControllerOptions Checked(const ControllerOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw InputError("control options: " + why);
  return options;
}

}  // namespace

Controller::Controller(const TsModel& model, Reference reference, const ControllerOptions& options)
    : reference_(std::move(reference)),
      options_(Checked(options)),
      limiter_(options.limits, options.sample_period_s) {
  const SteadyStateMap steady(model, options.limits.min_V, options.limits.max_V);
  reachable_low_mm_ = steady.lowest_mm();
  reachable_high_mm_ = steady.highest_mm();
  const std::string unreachable = ReachabilityProblem(reference_, steady);
  if (!unreachable.empty()) throw InputError(reference_.source() + ": " + unreachable);
  if (options.kind == ControllerKind::kPi) {
    // The operating point: the voltage that holds the middle of the reference's range.
    const auto [low, high] =
        std::minmax_element(reference_.deflection_mm().begin(), reference_.deflection_mm().end());
    const double u0 = steady.VoltageFor(0.5 * (*low + *high));
    const FirstOrderPlusDeadTime fopdt = FitFirstOrderPlusDeadTime(model, u0, steady.SlopeAt(u0));
    pi_ = std::make_unique<PiTuning>(SimcTuning(fopdt, options.pi_closed_loop_time_constant_s));
    pi_->operating_voltage_V = u0;
    return;
  }
  predictive_ = std::make_unique<PredictiveController>(model, reference_, options.limits,
                                                       options.sample_period_s, options.mpc,
                                                       options.kind == ControllerKind::kPredictive);
}

Controller::~Controller() = default;
Controller::Controller(Controller&&) noexcept = default;

const PiTuning* Controller::pi_tuning() const { return pi_.get(); }

bool Controller::Finished(long k) const {
  return static_cast<double>(k) * options_.sample_period_s > reference_.duration_s() + 1e-9;
}

ControlStep Controller::Next(long k, double measured_mm) {
  if (k <= last_k_)
    throw std::invalid_argument("Controller::Next: sample " + std::to_string(k) + " after sample " +
                                std::to_string(last_k_));
  // Samples missed: the voltage in force held over them, nothing measured.
  for (long missed = last_k_ + 1; missed < k; ++missed)
    Step(missed, std::numeric_limits<double>::quiet_NaN());
  return Step(k, measured_mm);
}

ControlStep Controller::Step(long k, double measured_mm) {
  last_k_ = k;
  const double t_s = static_cast<double>(k) * options_.sample_period_s;
  const bool missed = !std::isfinite(measured_mm);
  ControlStep step;
  step.reference_mm = reference_.At(t_s);
  step.model_mm = std::numeric_limits<double>::quiet_NaN();
  if (predictive_) {
    step.wanted_V = predictive_->Next(k, limiter_, measured_mm, &step.model_mm);
  } else if (missed) {
    step.wanted_V = last_wanted_V_;  // the PI waits for a measurement
  } else {
    // PI: u = K_c (e + (1 / tau_I) integral of e), the integral in volts; conditional
    // integration: not while the last command was held at a limit the error pushes into.
    const double error_mm = step.reference_mm - measured_mm;
    const double push = pi_->gain_V_per_mm * error_mm;
    const bool held = last_acted_.range || last_acted_.rate || last_acted_.charge;
    const bool into_limit = held && (push > 0.0) == (last_wanted_V_ > limiter_.last_V());
    if (!into_limit) integral_V_ += push * options_.sample_period_s / pi_->integral_time_s;
    step.wanted_V = push + integral_V_;
  }
  last_wanted_V_ = step.wanted_V;
  step.voltage_V = limiter_.Apply(step.wanted_V, &step.limits);
  last_acted_ = step.limits;
  return step;
}

}  // namespace flexid::model::control
