// Simulation of transfer functions with dead time and of T-S fuzzy models, for a
// voltage recorded at sample times t_k and held constant until the next sample (zero-
// order hold). Results are exact for that input: every interval is propagated with the
// matrix exponential (discretise.h), dead time included to fractions of a sample.
//
// Uniform grids (|dt_k - dt| <= 1e-7 dt) take a fixed-size fast path; any other grid is
// integrated event by event (sample times, and sample times shifted by the dead time).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::model {

// The operating point (memberships, frozen model) follows the scheduling value rounded to
// this resolution, so that a continuously varying voltage visits at most ~10^4 distinct
// operating points between 0 and 10 V and each is discretised once. The voltage driving
// the dynamics is not rounded. At 1 mV the memberships move by at most 1e-3 / (distance
// between neighbouring levels), far below any identified model's uncertainty.
inline constexpr double kSchedulingResolution_V = 1e-3;

struct SimulationOptions {
  // Before the first sample the system is in steady state under initial_voltage_V, held
  // since long before (0 V: at rest, the usual recording) ...
  double initial_voltage_V = 0.0;
  // ... or, when this is set, under the first sample's voltage.
  bool start_in_steady_state = false;
  // Resolution of the operating point (kSchedulingResolution_V). Identification uses a
  // coarser one on inputs that vary continuously, so that a simulation inside a fit
  // discretises a few hundred operating points rather than thousands.
  double scheduling_resolution_V = kSchedulingResolution_V;
  // The voltage the operating point follows, sample by sample (as long as the voltage);
  // empty: the voltage itself. An effect that scales the drive (wear: the gel answers each
  // volt with less bending) leaves the operating point where the applied voltage puts it,
  // so a model is driven with the worn voltage and scheduled on the applied one. Before the
  // first sample it is the voltage before it (initial_voltage_V, or the first premise
  // sample with start_in_steady_state).
  std::span<const double> premise_V = {};
};

// The scheduling resolution for an input whose largest |u| is max_abs_V:
// kSchedulingResolution_V for an input held on plateaus; for one that varies continuously
// (a chirp, a ramp) a 256th of max_abs_V when that is coarser, so that a simulation
// discretises a few hundred operating points rather than one per sample (a 77,000-sample
// chirp in kV spent three quarters of its diagnosis discretising). Identification and
// diagnosis both use it, so that a model is simulated as it was fitted.
double SchedulingResolutionFor(double max_abs_V, bool plateau_input);

// Predicted output at each t_s[k] for voltage_V[k] held on [t_k, t_{k+1}).
// Preconditions (checked, std::invalid_argument): IsValid(model); equal lengths;
// t_s strictly increasing and finite; voltages finite.
std::vector<double> Simulate(const TransferFunction& tf, std::span<const double> t_s,
                             std::span<const double> voltage_V,
                             const SimulationOptions& options = {});

// As above; if memberships is given, it receives mu(t_k) row by row (k-major,
// rules.size() values per sample).
std::vector<double> Simulate(const TsModel& model, std::span<const double> t_s,
                             std::span<const double> voltage_V,
                             const SimulationOptions& options = {},
                             std::vector<double>* memberships = nullptr);

// Uniform grid with step dt_s, first sample at t = 0.
std::vector<double> SimulateUniform(const TransferFunction& tf, double dt_s,
                                    std::span<const double> voltage_V,
                                    const SimulationOptions& options = {});
std::vector<double> SimulateUniform(const TsModel& model, double dt_s,
                                    std::span<const double> voltage_V,
                                    const SimulationOptions& options = {},
                                    std::vector<double>* memberships = nullptr);

// Streaming form of the exact any-grid simulator, for live prediction: feed samples one
// at a time in increasing time. Step(t, u) advances the model to t, applies u from t on,
// and returns the predicted output at t.
class StreamingSimulator {
 public:
  explicit StreamingSimulator(const TsModel& model, const SimulationOptions& options = {});
  ~StreamingSimulator();
  StreamingSimulator(StreamingSimulator&&) noexcept;
  StreamingSimulator& operator=(StreamingSimulator&&) noexcept;

  // Preconditions: t_s > previous t_s; both finite.
  double Step(double t_s, double voltage_V);
  // As above, the operating point following premise_V rather than the voltage
  // (SimulationOptions::premise_V).
  double Step(double t_s, double voltage_V, double premise_V);
  // Normalised memberships in force after the last Step.
  const std::vector<double>& memberships() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// True if t_s is uniform to 1e-7 of its mean step; writes the step.
bool IsUniformGrid(std::span<const double> t_s, double* dt_s);

}  // namespace flexid::model
