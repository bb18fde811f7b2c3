#include "model/control/simc.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

#include "model/core/transfer_function.h"

namespace flexid::model::control {
namespace {

constexpr int kFitPoints = 600;

// Sum of squares of g(t) - FOPDT(t; theta, tau) over the points.
double FitError(const std::vector<double>& t_s, const std::vector<double>& g, double theta_s,
                double tau_s) {
  double sum = 0.0;
  for (size_t i = 0; i < t_s.size(); ++i) {
    const double fopdt = t_s[i] < theta_s ? 0.0 : 1.0 - std::exp(-(t_s[i] - theta_s) / tau_s);
    sum += (g[i] - fopdt) * (g[i] - fopdt);
  }
  return sum;
}

// Golden-section search of a unimodal f on [low, high]; returns the argument.
template <typename F>
double GoldenMinimum(F&& f, double low, double high, int iterations = 60) {
  const double ratio = (std::sqrt(5.0) - 1.0) / 2.0;
  double a = low, b = high;
  double c = b - ratio * (b - a), d = a + ratio * (b - a);
  double fc = f(c), fd = f(d);
  for (int i = 0; i < iterations; ++i) {
    if (fc < fd) {
      b = d;
      d = c;
      fd = fc;
      c = b - ratio * (b - a);
      fc = f(c);
    } else {
      a = c;
      c = d;
      fc = fd;
      d = a + ratio * (b - a);
      fd = f(d);
    }
  }
  return 0.5 * (a + b);
}

}  // namespace

FirstOrderPlusDeadTime FitFirstOrderPlusDeadTime(const TsModel& model, double voltage_V,
                                                 double slope_mm_per_V) {
  const TransferFunction frozen = FrozenModelAt(model, SchedulingValue(model, voltage_V));
  const double dc_gain = DcGain(frozen);
  if (!IsStable(frozen) || !std::isfinite(dc_gain) || dc_gain == 0.0)
    throw std::invalid_argument(
        "FOPDT fit: the frozen model at the operating point is unstable or has no DC gain");
  double slowest_s = 0.0;
  for (const Mode& mode : Modes(frozen)) slowest_s = std::max(slowest_s, mode.time_constant_s);
  const double end_s = std::min(frozen.delay_s + 5.0 * slowest_s, 1e6);
  std::vector<double> t_s(kFitPoints);
  for (int i = 0; i < kFitPoints; ++i) t_s[i] = end_s * i / (kFitPoints - 1);
  std::vector<double> g = StepResponse(frozen, t_s);
  for (double& value : g) value /= dc_gain;

  auto best_tau = [&](double theta_s) {
    return GoldenMinimum([&](double tau) { return FitError(t_s, g, theta_s, tau); }, end_s * 1e-4,
                         end_s);
  };
  // theta on a grid over the first half, then refined around the best grid point.
  constexpr int kGrid = 100;
  double best_theta = 0.0, best = INFINITY;
  for (int i = 0; i <= kGrid; ++i) {
    const double theta = 0.5 * end_s * i / kGrid;
    const double error = FitError(t_s, g, theta, best_tau(theta));
    if (error < best) {
      best = error;
      best_theta = theta;
    }
  }
  const double cell = 0.5 * end_s / kGrid;
  const double theta = GoldenMinimum(
      [&](double candidate) { return FitError(t_s, g, candidate, best_tau(candidate)); },
      std::max(0.0, best_theta - cell), best_theta + cell, 40);
  FirstOrderPlusDeadTime fit;
  fit.gain_mm_per_V = slope_mm_per_V;
  fit.dead_time_s = theta;
  fit.time_constant_s = best_tau(theta);
  fit.fit_rms = std::sqrt(FitError(t_s, g, theta, fit.time_constant_s) / kFitPoints);
  return fit;
}

PiTuning SimcTuning(const FirstOrderPlusDeadTime& fopdt, double closed_loop_time_constant_s) {
  if (!(std::isfinite(fopdt.gain_mm_per_V) && fopdt.gain_mm_per_V != 0.0))
    throw std::invalid_argument("SIMC: the process gain is zero or not finite");
  PiTuning tuning;
  tuning.fopdt = fopdt;
  const double theta = fopdt.dead_time_s, tau = fopdt.time_constant_s;
  const double tau_c = closed_loop_time_constant_s > 0.0 ? closed_loop_time_constant_s : theta;
  tuning.closed_loop_time_constant_s = tau_c;
  // Skogestad (2003), first-order process with delay: K_c = tau / (k (tau_c + theta)),
  // tau_I = min(tau, 4 (tau_c + theta)).
  tuning.gain_V_per_mm = tau / (fopdt.gain_mm_per_V * (tau_c + theta));
  tuning.integral_time_s = std::min(tau, 4.0 * (tau_c + theta));
  return tuning;
}

std::string PiTuning::Describe() const {
  std::ostringstream text;
  text.precision(3);
  text << "SIMC PI at " << operating_voltage_V << " V: FOPDT k " << fopdt.gain_mm_per_V
       << " mm/V, tau " << fopdt.time_constant_s << " s, theta " << fopdt.dead_time_s
       << " s (fit RMS " << fopdt.fit_rms << "); tau_c " << closed_loop_time_constant_s
       << " s -> K_c " << gain_V_per_mm << " V/mm, tau_I " << integral_time_s << " s";
  return text.str();
}

}  // namespace flexid::model::control
