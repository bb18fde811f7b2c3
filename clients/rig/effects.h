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
// Effect names follow the diagnosis contract (DESIGN.md, "Diagnosis result"):
//   output side: back_relaxation, hysteresis, sensor_drift
//   drive side:  cycle_degradation, electrolysis_saturation, polarity_asymmetry, dead_zone
// Each class below gives the physics, the model with units, and its parameters (the
// specification's keys, defaults and valid ranges). Notation: t time since the first
// sample (s), v the voltage reaching the effect (V: the applied voltage, after earlier
// drive-side effects), y the deflection reaching the effect (mm: the model's output, after
// earlier output-side effects), k the sample index.
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

// Cycle degradation: the gain lost with the charge moved through the gel. Repeated
// actuation wears the gel/electrode interface (the electrode delaminates, the mobile ions
// are depleted), so each volt moves the beam less than it did in the first cycle.
//
// Model, drive side, with the charge proxy Q(t) = integral_0^t |v(u)| du in V*s:
//   drive(t) = v(t) exp(-Q(t) / Q0),   Q0 = -charge_Vs / ln(1 - loss)               (3)
// i.e. drive = v (1 - loss)^(Q / charge_Vs): the gain has lost the fraction `loss` once
// charge_Vs V*s have been applied, and keeps falling geometrically after that.
// The voltage is held between samples (zero-order hold, like the protocol), so
// Q(t_k) = sum_{j<k} |v_j| (t_{j+1} - t_j) exactly; the factor of sample k is held with
// it over its interval.
//
// Parameters: loss in [0, 1) (default 0.2; 0 leaves the stream unchanged), charge in V*s
// (> 0, default 5000; a 5 V square wave of 50 % duty applies 2.5 V*s per second).
class CycleDegradation : public Effect {
 public:
  struct Params {
    double loss = 0.2;          // fraction of the gain lost after charge_Vs, in [0, 1)
    double charge_Vs = 5000.0;  // charge proxy at which `loss` is reached, V*s (> 0)
  };
  explicit CycleDegradation(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double DriveVoltage(double t_s, double applied_V) override;

 private:
  Params params_;
  bool started_ = false;
  double previous_t_s_ = 0.0;
  double previous_abs_V_ = 0.0;
  double charge_Vs_ = 0.0;  // Q(t) of Eq. (3) at the current sample
};

// Hysteresis: a rate-independent lag that depends on the direction of motion. Stick-slip
// friction of the beam in its holder and inside the gel network holds the tip until the
// driving deflection has moved `width` past it in the new direction; how fast the input
// changes does not matter, only where it turns.
//
// Model, output side: the play (backlash) operator of total play 2 * width_mm,
//   out_0 = y_0,   out_k = min(y_k + width_mm, max(y_k - width_mm, out_{k-1}))      (4)
// The output follows y at a distance width_mm behind it (below while y rises, above while
// it falls) and stays put while y reverses within the play. After an excursion to +Y and
// back to rest it stays at +width_mm.
//
// Parameters: width in mm (>= 0, default 0.5; 0 leaves the stream unchanged).
class Hysteresis : public Effect {
 public:
  struct Params {
    double width_mm = 0.5;  // half the play of the operator, mm (>= 0)
  };
  explicit Hysteresis(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double Deflection(double t_s, double applied_V, double deflection_mm) override;

 private:
  Params params_;
  bool started_ = false;
  double output_mm_ = 0.0;  // out_{k-1} of Eq. (4)
};

// Electrolysis saturation: above the decomposition voltage of the electrolyte, extra
// voltage splits water at the electrodes (gas, current) instead of driving ions into the
// gel, so the deflection grows more slowly with the voltage than below it.
//
// Model, drive side, with a = |v|:
//   drive = sign(v) * (a <= onset_V ? a : onset_V + slope * (a - onset_V))          (5)
// A slope of 1 leaves the stream unchanged, 0 clips the voltage at onset_V.
//
// Parameters: onset in V (> 0, default 4), slope, the share of the voltage above the onset
// that still acts, in [0, 1] (default 0.3).
class ElectrolysisSaturation : public Effect {
 public:
  struct Params {
    double onset_V = 4.0;  // decomposition voltage, V (> 0)
    double slope = 0.3;    // effective share of the voltage above onset_V, in [0, 1]
  };
  explicit ElectrolysisSaturation(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double DriveVoltage(double t_s, double applied_V) override;

 private:
  Params params_;
};

// Sensor drift: the baseline of the displacement sensor moves on its own, whatever the
// voltage (thermal drift of a laser triangulation sensor and its mount): a steady drift,
// plus an optional warm-up that settles exponentially after switch-on.
//
// Model, output side:
//   out(t) = y(t) + rate_mm_s * t + warmup_mm * (1 - exp(-t / tau_s))               (6)
//
// Parameters: rate in mm/s (any finite number, default 0.001), warmup in mm (any finite
// number, default 0), tau in s (> 0, default 600), the warm-up time constant.
class SensorDrift : public Effect {
 public:
  struct Params {
    double rate_mm_s = 0.001;  // steady drift, mm/s (any finite)
    double warmup_mm = 0.0;    // final size of the warm-up offset, mm (any finite)
    double tau_s = 600.0;      // warm-up time constant, s (> 0)
  };
  explicit SensorDrift(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double Deflection(double t_s, double applied_V, double deflection_mm) override;

 private:
  Params params_;
};

// Polarity asymmetry: a negative voltage acts with another gain than a positive one. The
// two electrodes differ (printed on different sides, aged differently), and reversing the
// field makes a different ion species migrate into the gel, with its own mobility and
// hydration.
//
// Model, drive side:
//   drive = v >= 0 ? v : ratio * v                                                 (7)
//
// Parameters: ratio, the gain of negative voltages relative to positive ones, in (0, 2]
// (default 0.7; 1 leaves the stream unchanged).
class PolarityAsymmetry : public Effect {
 public:
  struct Params {
    double ratio = 0.7;  // negative-to-positive gain ratio, in (0, 2]
  };
  explicit PolarityAsymmetry(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double DriveVoltage(double t_s, double applied_V) override;

 private:
  Params params_;
};

// Dead zone: no response below a threshold voltage. Ions only start to move into the gel
// once the electrochemical onset (double-layer charging, electrode overpotential) is
// overcome; below it the beam does not bend.
//
// Model, drive side, with a = |v|:
//   drive = sign(v) * max(a - threshold_V, 0)                                      (8)
//
// Parameters: threshold in V (>= 0, default 0.5; 0 leaves the stream unchanged).
class DeadZone : public Effect {
 public:
  struct Params {
    double threshold_V = 0.5;  // onset voltage, V (>= 0)
  };
  explicit DeadZone(const Params& params) : params_(params) {}

  std::string Describe() const override;
  double DriveVoltage(double t_s, double applied_V) override;

 private:
  Params params_;
};

// Parses NAME[:KEY=VALUE,...] into an effect (defaults and ranges at each class above):
//   back_relaxation[:fraction=0.3,tau=60]          fraction in [0, 1], tau in s (> 0)
//   cycle_degradation[:loss=0.2,charge=5000]       loss in [0, 1), charge in V*s (> 0)
//   hysteresis[:width=0.5]                         width in mm (>= 0)
//   electrolysis_saturation[:onset=4,slope=0.3]    onset in V (> 0), slope in [0, 1]
//   sensor_drift[:rate=0.001,warmup=0,tau=600]     rate in mm/s, warmup in mm (finite),
//                                                  tau in s (> 0)
//   polarity_asymmetry[:ratio=0.7]                 ratio in (0, 2]
//   dead_zone[:threshold=0.5]                      threshold in V (>= 0)
// Throws model::InputError with one line naming the effect and the parameter, e.g.
//   effect "back_relaxation:tau=0": tau must be > 0 s (got 0)
std::unique_ptr<Effect> ParseEffect(std::string_view spec);

// The names ParseEffect knows.
std::vector<std::string> EffectNames();

}  // namespace flexid::rig
