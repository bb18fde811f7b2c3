// What a controller is asked to do: a reference deflection over time, and whether the
// model can reach it at all.
//
// Reference. Samples (t_s, deflection_mm) with t_s strictly increasing from the start of
// the run (t = 0 is the first measurement the controller acts on); between samples the
// reference is interpolated linearly, before the first and after the last it holds the
// end value. A CSV reference has the columns t_s,deflection_mm (the recording CSV's
// syntax, model/core/recording.h, with voltage_V not required).
//
// Steady state. Under a voltage u held long enough, the T-S model settles at
//   y_ss(u) = K(z(u)) u,   K(z) = G_z(0),
// the DC gain of the frozen model at the operating point z(u) = |u| (or u) (ts_fuzzy.h:
// Eqs. 16, 17 and 19 at s = 0; for the parallel realisation sum_i mu_i(z) K_i). The
// reachable range of a model under a voltage range [min_V, max_V] is
// [min y_ss, max y_ss] over that range: a reference outside it could only be held by a
// voltage the limits forbid, and is refused before anything is sent
// (ReachabilityProblem).
#pragma once

#include <string>
#include <vector>

#include "model/core/ts_fuzzy.h"

namespace flexid::model::control {

class Reference {
 public:
  // Throws model::InputError naming `source` when there are no samples, the lengths
  // differ, a value is not finite, time is not strictly increasing or starts below 0.
  Reference(std::vector<double> t_s, std::vector<double> deflection_mm, std::string source);

  double At(double t_s) const;
  // The time of the last sample, s.
  double duration_s() const { return t_s_.back(); }
  const std::vector<double>& t_s() const { return t_s_; }
  const std::vector<double>& deflection_mm() const { return deflection_mm_; }
  const std::string& source() const { return source_; }

 private:
  std::vector<double> t_s_;
  std::vector<double> deflection_mm_;
  std::string source_;
};

// Reads a reference CSV (t_s,deflection_mm; see above). Throws model::InputError.
Reference ReadReferenceCsv(const std::string& path);

// y_ss(u) of a model on [min_V, max_V], tabulated every step_V and interpolated linearly.
class SteadyStateMap {
 public:
  // Precondition (checked, std::invalid_argument): IsValid(model), min_V < max_V finite,
  // step_V > 0.
  SteadyStateMap(const TsModel& model, double min_V, double max_V, double step_V = 0.01);

  double DeflectionAt(double voltage_V) const;  // y_ss(u), mm; u clipped to the range
  double SlopeAt(double voltage_V) const;       // d y_ss / du, mm/V (central difference)
  // The voltage of the range whose steady state is nearest deflection_mm; among equally
  // near ones the smallest |u|.
  double VoltageFor(double deflection_mm) const;
  double lowest_mm() const { return lowest_mm_; }
  double highest_mm() const { return highest_mm_; }
  double min_V() const { return min_V_; }
  double max_V() const { return max_V_; }

 private:
  double min_V_, max_V_, step_V_;
  std::vector<double> deflection_mm_;  // at min_V + i step_V
  double lowest_mm_ = 0.0, highest_mm_ = 0.0;
};

// Empty when every reference sample lies within the map's reachable range (to 1e-9 mm);
// otherwise one sentence naming the first sample outside it, e.g. "the reference is 80 mm
// at t = 120 s, outside what the model reaches in steady state within -8 .. 8 V
// (-69.3 .. 69.3 mm)".
std::string ReachabilityProblem(const Reference& reference, const SteadyStateMap& map);

}  // namespace flexid::model::control
