// Effects of the virtual rig (flexid-rig --effect NAME[:KEY=VALUE,...]): behaviour of a
// real gel that the T-S model leaves out, added to the simulated actuator so that the
// daemon's residual monitor and `flexid diagnose` have something known to find.
//
// An effect may act at two places of the sample stream, both called once per sample in
// strictly increasing time (the first call is the first sample, from rest), effects in the order
// given on the command line:
//   applied voltage --DriveVoltage--> T-S model --Deflection--> (+ sensor noise) --> bus
// DriveVoltage changes the voltage the gel responds to (the published voltage stays the
// applied one), e.g. a saturation of the electrochemistry; Deflection changes the output,
// e.g. a slow relaxation or a drift. The defaults leave the stream unchanged.
//
// Effect names follow the diagnosis contract (DESIGN.md, "Diagnosis result"). This first
// version has back_relaxation.
#pragma once

#include <memory>
#include <string>
#include <string_view>
#include <vector>

namespace flexid::rig {

class Effect {
 public:
  virtual ~Effect() = default;

  // The canonical specification with every parameter, e.g.
  // "back_relaxation:fraction=0.3,tau=60".
  virtual std::string Describe() const = 0;

  // The voltage (V) the gel responds to at t_s (s) when applied_V is applied.
  virtual double DriveVoltage(double t_s, double applied_V) {
    static_cast<void>(t_s);
    return applied_V;
  }

  // The deflection (mm) at t_s (s), given the applied voltage and the deflection the
  // stages before this one produced (the model's output, after earlier effects).
  virtual double Deflection(double t_s, double applied_V, double deflection_mm) {
    static_cast<void>(t_s);
    static_cast<void>(applied_V);
    return deflection_mm;
  }
};

// Back-relaxation: under a sustained voltage an ionic gel first bends, then slowly bends
// part of the way back, and when the voltage is removed it overshoots past rest before
// settling at 0. The cause: the voltage drives mobile cations (with their hydration water)
// towards one electrode, so one side of the beam swells (Donnan osmotic pressure) and the
// beam bends; while the voltage holds, ions and solvent keep redistributing by diffusion
// through the gel and across its surfaces, which relaxes the osmotic pressure difference
// that the fast bending built up and bends the beam back. The paper this project builds on
// attributes its T-S model's drift over long tests to this effect.
//
// Model, with y the deflection of the stages before this one and s a first-order low-pass
// of it (time constant tau):
//   d(t) = y(t) - fraction * s(t),   tau s'(t) = y(t) - s(t),   s = 0 at rest     (1)
// or in the Laplace domain D(s) = Y(s) (tau s + 1 - fraction) / (tau s + 1): one extra
// zero at -(1 - fraction)/tau and pole at -1/tau, DC gain scaled by (1 - fraction). After
// a step that y follows quickly, d rises to y, then falls back by fraction * y as
// exp(-t / tau), and settles at (1 - fraction) y; at rest it returns to 0.
//
// Discretisation: y is taken as linear between samples (first-order hold, right for the
// model's continuous output); Eq. (1) is then solved exactly over a step h, with
// r = h / tau and a = exp(-r):
//   s_{k+1} = a s_k + (1 - a) y_k + (1 - (1 - a) / r) (y_{k+1} - y_k)             (2)
class BackRelaxation : public Effect {
 public:
  struct Params {
    double fraction = 0.3;  // share of the deflection that relaxes back, in [0, 1]
    double tau_s = 60.0;    // relaxation time constant, s (> 0)
  };
  explicit BackRelaxation(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double Deflection(double t_s, double applied_V, double deflection_mm) override;

 private:
  Params params_;
  bool started_ = false;
  double previous_t_s_ = 0.0;
  double previous_y_mm_ = 0.0;
  double slow_mm_ = 0.0;  // s in Eq. (1)
};

// Parses NAME[:KEY=VALUE,...] into an effect:
//   back_relaxation[:fraction=0.3,tau=60]   fraction in [0, 1], tau in s (> 0)
// Throws model::InputError with one line, e.g.
//   effect "back_relaxation:tau=0": tau must be > 0 s (got 0)
std::unique_ptr<Effect> ParseEffect(std::string_view spec);

// The names ParseEffect knows.
std::vector<std::string> EffectNames();

}  // namespace flexid::rig
