// Closed loops of model/control's Controller (the one flexid-control runs on the bus)
// against the independent test plants, stepped sample by sample with their own
// integrators: the T-S plant of ts_plant.h and the effect lab of effect_plant.h. Used by
// tests/control_plant_test.cc and bench/control_bench.cc.
//
// The loop (model/control/controller.h): at t_k = k Ts the plant gets u_k (decided at
// k - 1; 0 V at k = 0) and its deflection is measured (noise added); the controller decides
// u_{k+1}. The plant holds u_k over [t_k, t_{k+1}), and the applied voltage reaches it a
// dead time later, as in the plants' own protocols.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <deque>
#include <memory>
#include <vector>

#include "effect_plant.h"
#include "model/control/controller.h"
#include "ts_plant.h"

namespace flexid::testing {

// A plant stepped one sample at a time.
class LoopPlant {
 public:
  virtual ~LoopPlant() = default;
  // Sample k: voltage_V is applied from t_k (held to t_{k+1}); returns the measured
  // deflection at t_k (clean_mm() plus the sensor noise), mm. The next call is sample k + 1.
  virtual double Sample(double voltage_V) = 0;
  // The noise-free deflection of the last sample, mm.
  virtual double clean_mm() const = 0;
};

// The T-S plant and the effect lab sample their output, then integrate over the interval.
class IntegratedPlant : public LoopPlant {
 public:
  double Sample(double voltage_V) override {
    clean_mm_ = Clean();
    const double measured = Measured();
    Advance(voltage_V);
    return measured;
  }
  double clean_mm() const override { return clean_mm_; }

 protected:
  virtual double Clean() const = 0;
  virtual double Measured() = 0;  // Clean() plus the sensor noise
  virtual void Advance(double voltage_V) = 0;

 private:
  double clean_mm_ = 0.0;
};

// ts_plant.h's plant: each rule in observer canonical form integrated by RK4, the
// memberships on the delayed voltage, the applied voltage reaching the rules a dead time
// later (between samples, where the switch falls).
class TsPlantLoop : public IntegratedPlant {
 public:
  TsPlantLoop(const TsPlant& plant, uint64_t noise_seed)
      : plant_(plant), noise_(noise_seed), states_(plant.rules.size()) {
    SetVoltage(0.0);
  }

  TsPlantLoop(const TsPlantLoop&) = delete;
  TsPlantLoop& operator=(const TsPlantLoop&) = delete;

 protected:
  double Clean() const override {
    double sum_mm = 0.0;
    for (size_t r = 0; r < states_.size(); ++r)
      sum_mm += (plant_.blend == TsBlend::kInputBlend ? 1.0 : mu_[r]) * states_[r][0];
    return sum_mm;
  }
  double Measured() override { return Clean() + plant_.noise_std_mm * noise_.Normal(); }

  void Advance(double voltage_V) override {
    const double start_s = static_cast<double>(k_) * kTsPlantSamplePeriod_s;
    const double end_s = static_cast<double>(k_ + 1) * kTsPlantSamplePeriod_s;
    if (voltage_V != applied_V_) pending_.push_back({start_s + plant_.delay_s, voltage_V});
    applied_V_ = voltage_V;
    double t_s = start_s;
    while (!pending_.empty() && pending_.front().first <= end_s) {
      Integrate(pending_.front().first - t_s);
      t_s = pending_.front().first;
      SetVoltage(pending_.front().second);
      pending_.pop_front();
    }
    Integrate(end_s - t_s);
    ++k_;
  }

 private:
  void SetVoltage(double v_V) {
    mu_ = plant_.Memberships(std::abs(v_V));
    inputs_.assign(states_.size(), 0.0);
    for (size_t r = 0; r < states_.size(); ++r)
      inputs_[r] = plant_.blend == TsBlend::kInputBlend ? mu_[r] * v_V : v_V;
  }
  void Integrate(double span_s) {
    for (size_t r = 0; r < states_.size(); ++r)
      ts_plant_detail::Advance(plant_.rules[r], inputs_[r], span_s, &states_[r]);
  }

  TsPlant plant_;
  TsPlantRandom noise_;
  std::vector<ts_plant_detail::RuleState> states_;
  std::vector<double> mu_, inputs_;
  std::deque<std::pair<double, double>> pending_;  // (when the plant sees it, level)
  double applied_V_ = 0.0;
  long k_ = 0;
};

// effect_plant.h's lab: the plant and its effect integrated by RK4 (lab_detail::Dynamics)
// on a voltage waveform that grows with every command (a first-order slew of
// run.waveform's time constant towards each commanded level). Only the commands a dead
// time and a few seconds back are kept in the waveform: older ones have settled.
class EffectPlantLoop : public IntegratedPlant {
 public:
  // run.plant, run.effect, run.sample_period_s, run.noise_std_mm, run.max_step_s and
  // run.noise_seed are used; run.waveform gives only the slew time constant.
  explicit EffectPlantLoop(const LabRun& run)
      : run_(run), slew_tau_s_(run.waveform.slew_tau_s()), dynamics_(run_), noise_(run.noise_seed) {
    run_.waveform = Waveform({}, slew_tau_s_);
  }
  EffectPlantLoop(const EffectPlantLoop&) = delete;
  EffectPlantLoop& operator=(const EffectPlantLoop&) = delete;

 protected:
  double Clean() const override { return dynamics_.Output(t_s_, state_); }
  double Measured() override { return Clean() + run_.noise_std_mm * noise_.Normal(); }

  void Advance(double voltage_V) override {
    const double start_s = static_cast<double>(k_) * run_.sample_period_s;
    const double end_s = static_cast<double>(k_ + 1) * run_.sample_period_s;
    const double delay_s = run_.plant.delay_s;
    if (voltage_V != level_V_) commands_.push_back({start_s, voltage_V});
    level_V_ = voltage_V;
    Rewave(start_s - delay_s);
    std::vector<double> breaks;
    for (const VoltageStep& step : commands_)
      if (step.t_s + delay_s > start_s && step.t_s + delay_s < end_s)
        breaks.push_back(step.t_s + delay_s);
    breaks.push_back(end_s);
    double t = start_s;
    for (double target : breaks) {
      if (target - t <= 1e-12) continue;
      lab_detail::IntegrateSpan(dynamics_, run_, t, target, &state_);
      t = target;
    }
    t_s_ = end_s;
    ++k_;
  }

 private:
  // The waveform from the commands after `earliest_s` - 5 s (older ones have settled, at
  // 40 slew time constants and more), led by one step to the level in force before them.
  void Rewave(double earliest_s) {
    const double cutoff_s = earliest_s - 5.0;
    while (!commands_.empty() && commands_.front().t_s <= cutoff_s) {
      settled_V_ = commands_.front().level_V;
      commands_.pop_front();
    }
    std::vector<VoltageStep> steps;
    steps.reserve(commands_.size() + 1);
    if (settled_V_ != 0.0) steps.push_back({cutoff_s - 5.0, settled_V_});
    for (const VoltageStep& step : commands_) steps.push_back(step);
    run_.waveform = Waveform(std::move(steps), slew_tau_s_);
  }

  LabRun run_;
  double slew_tau_s_;
  lab_detail::Dynamics dynamics_;  // reads run_ (and its waveform) by reference
  LabRandom noise_;
  lab_detail::State state_{};
  std::deque<VoltageStep> commands_;
  double level_V_ = 0.0, settled_V_ = 0.0, t_s_ = 0.0;
  long k_ = 0;
};

// The figures are over the samples from score_from_s on (RunLoop), the peak window charge
// and the largest step over the whole run.
struct LoopResult {
  std::vector<double> t_s, reference_mm, clean_mm, measured_mm, voltage_V, model_mm;
  double rmse_mm = 0.0;           // clean deflection against the reference
  double measured_rmse_mm = 0.0;  // measured deflection against the reference
  double voltage_rms_V = 0.0;
  double charge_Vs = 0.0;              // integral of |u| dt over the run
  double peak_window_charge_Vs = 0.0;  // the largest charge over any window of the limits
  double largest_step_V = 0.0;         // the largest |u_{k+1} - u_k|
};

// Runs the controller on the plant until its reference ends.
inline LoopResult RunLoop(model::control::Controller& controller, LoopPlant& plant,
                          double score_from_s = 0.0) {
  LoopResult result;
  const double dt_s = controller.options().sample_period_s;
  double applied_V = 0.0;  // u_k
  for (long k = 0; !controller.Finished(k); ++k) {
    const double measured = plant.Sample(applied_V);
    const model::control::ControlStep step = controller.Next(k, measured);
    result.t_s.push_back(static_cast<double>(k) * dt_s);
    result.reference_mm.push_back(step.reference_mm);
    result.clean_mm.push_back(plant.clean_mm());
    result.measured_mm.push_back(measured);
    result.voltage_V.push_back(applied_V);
    result.model_mm.push_back(step.model_mm);
    result.largest_step_V = std::max(result.largest_step_V, std::abs(step.voltage_V - applied_V));
    applied_V = step.voltage_V;
  }
  const auto window = static_cast<size_t>(
      std::max(1.0, std::round(controller.options().limits.charge_window_s / dt_s)));
  double squares = 0.0, measured_squares = 0.0, volts = 0.0, in_window = 0.0, n = 0.0;
  for (size_t k = 0; k < result.t_s.size(); ++k) {
    in_window += std::abs(result.voltage_V[k]) * dt_s;
    if (k >= window) in_window -= std::abs(result.voltage_V[k - window]) * dt_s;
    result.peak_window_charge_Vs = std::max(result.peak_window_charge_Vs, in_window);
    if (result.t_s[k] < score_from_s - 1e-9) continue;
    const double error = result.clean_mm[k] - result.reference_mm[k];
    const double measured_error = result.measured_mm[k] - result.reference_mm[k];
    squares += error * error;
    measured_squares += measured_error * measured_error;
    volts += result.voltage_V[k] * result.voltage_V[k];
    result.charge_Vs += std::abs(result.voltage_V[k]) * dt_s;
    n += 1.0;
  }
  result.rmse_mm = std::sqrt(squares / n);
  result.measured_rmse_mm = std::sqrt(measured_squares / n);
  result.voltage_rms_V = std::sqrt(volts / n);
  return result;
}

}  // namespace flexid::testing
