// Global identification of a T-S fuzzy model: one output-error fit of the whole blended
// model on every given recording at once, with the blend simulated in the loop (the
// "global approach" of LPV identification), and its structure chosen on held-out data.
//
// Model (seed Eqs. 16-19 with the blend of ts_fuzzy.h). R rules sit at knot voltages
// c_1 < ... < c_R. Between two knots the memberships interpolate linearly; below the
// first and above the last they hold (shoulders). So every local parameter is a linear
// spline in the premise z, and a level between knots gets no model of its own. Or (few
// rules, each with its own dynamics) Gaussian memberships whose centres and common width
// are parameters of the fit: a smooth hand-over of estimated place and width. Rule i is
//   G_i(s) = K_i (beta_im s^m + ... + beta_i1 s + 1) / D_i(s) * D_i(0) * e^{-T s},
//   D_i(s) = prod_q (s^2 + c1_iq s + c0_iq) [* (s + c_i) for odd n],  every c > 0,
// with one dead time T shared by all rules (Eq. 18 with b5/a4 as the DC gain K_i). The
// premise z is |u(t - T)| (the voltage as it reaches the actuator), |u(t)|, or |u|
// held through rest (ts_fuzzy.h). Or the rules run in parallel, each driven by its share
// mu_i(|u|) u of the voltage (ts_fuzzy.h's kParallel; with one set of dynamics a
// Hammerstein model).
//
// Physical plausibility is built into the parameters and the selection, not noted after
// the fact:
//   - T in [0, max_delay_s];
//   - every factor has c = exp(parameter) > 0, so every local model and every frozen
//     blend (factors blend convexly) is stable, at, between and beyond the knots;
//   - every factor's natural frequency lies in [w_min, w_max]: w_max = 0.8 pi / dt (the
//     band the sampling resolves), w_min = 0.5 / (longest recording): a slower mode could
//     not be told from drift. A real pair's slower root is held at w_min or above too
//     (the box bounds alone let it approach s = 0: an integrator that turned a polarity
//     asymmetry into a drift with a DC gain of 366 mm/V). After the fit the frozen blend's poles
//     are checked on a grid of z from 0 to 1.25 c_R; a model with a pole beyond Nyquist is never
//     returned;
//   - switching: frozen stability does not make the blend behave when the premise jumps
//     across rules whose dynamics differ. From steady state at every knot (the visited
//     levels, when there are few) and at rest, a jump to every other one may swing beyond its start
//     and end values no further than the frozen model at the new level does on the same step, plus
//     a quarter of the step and three noise deviations. A fit that breaks this is never kept,
//     however well it fits (a staircase steps only between neighbouring levels and would not show
//     it).
//
// Fit: bounded Levenberg-Marquardt on the output error of every fitted sample, the
// Jacobian by forward differences of the exact simulation (simulate.h) kept up to date by
// secant updates (secant_lm.h: two simulations an iteration rather than one per
// parameter; 4 times faster than Ceres with differences at every iteration). A structure
// without a start of its own is started from a linear model of the same order fitted on
// all the data (identify.h, which also finds a dead time) and from generic starts: real
// poles at four time scales from three samples to a twentieth of the longest recording,
// each with the linear model's dead time, none and half the largest, the gains a static
// map of the data (a dead zone shows as gains near 0). Every start is fitted for a few
// iterations with its dead time held; the best go on to convergence until two switch
// plausibly, and the best of those is kept. (Fixed time scales and the linear model's
// dead time alone left a HASEL staircase, which settles in 0.2 s, in a basin with a 7 s
// dead time and a 19 s oscillation: 52 % in sample; now 98 %.)
//
// Dense data (more than twice kSelectionSamples = 4,000 usable samples): the structure is
// chosen on every f-th sample (f <= 5, the input averaged over each coarse interval so
// that a step acts when it happened), as long as the coarse rate is at least ten times
// the fastest pole of a linear 2/1 model of all the data; the chosen structure is then
// refitted on every sample, the dead time placed within a coarse sample by the sum of
// squares alone (the rest of the model is already close; one simulation per point).
// The structure is chosen again on every sample, and that choice kept, when the coarse
// grid was blind to the misfit (the residual above its Nyquist band, after its moving mean
// over f samples, more than 1.5 times the noise's share there) or its model does not
// carry over (the error on every sample above twice the coarse held-out error).
//
// Structure, chosen on held-out data (each recording cut into ten blocks in time,
// alternately fitted and held out, in turn: both folds see every recording's protocol;
// each fold starts from the all-data fit):
//   1. a pilot: orders 2/1 (unless given), a gain per visited level, one set of dynamics,
//      premise |u(t - T)|; where no such fit switches plausibly, one linear model (and
//      stage 6 then offers few smooth rules against it);
//   2. where the dynamics change: the split between two neighbouring knots that helps
//      most in sample, kept while it predicts held-out data better (below);
//   3. the realisation, when the dynamics change with the voltage: the rules switched as
//      one frozen model, or run in parallel, each driven by its share of the voltage
//      (ts_fuzzy.h); the parallel candidate from the current fit and from generic starts;
//   4. the dead time: the profile of the fit over T, every second from 0 to max_delay_s
//      and then every sample within a second of the best, each point half a sample off
//      the grid (the premise's delay is a whole number of samples and jumps at multiples
//      of the sample period, so a free fit does not cross them reliably), walked outwards
//      from the current T with each point started from its neighbour's fit; the best point
//      refitted with T free, kept if the held-out error falls. A zero trades off against
//      T, and a fit started at the wrong T stays in that basin;
//   5. the orders (1/0, 2/1, 3/2, 4/3) at the chosen knots, higher orders also started
//      from the current fit with a cancelling pole and zero added;
//   6. fewer rules: two and three rules with their own dynamics and Gaussian memberships
//      (centres within 0.45 of the spacing to their neighbours and the width fitted), at
//      the (i + 1/2) / n quantiles of the active |u| samples, against the current one
//      rule per knot; each also in the realisation stage 3 did not choose (stage 3 chose
//      where the rules shared their dynamics or sat on every level; not under
//      rules_at_most);
//   7. the premise, at the chosen structure (frozen rules only: parallel rules read the
//      voltage as it is applied and delay their share with it).
// The premise and the orders are compared only once the model is close to the data:
// compared on the pilot, whose error is what it cannot represent, they would be chosen by
// noise. Among candidates as good as the best on held-out data the one with fewest
// parameters wins, "as good" unless the best is better block after block: the Wilcoxon
// signed-rank statistic of the held-out blocks' log ratios of mean squared error (five
// blocks per recording left out, or the ten alternating blocks) within one standard
// deviation of its null mean, or the pooled error within 2 % of the best; between
// alternatives with as many parameters, the lower held-out error, except that the
// structure the stage started from stays unless beaten by more than 2 %. A structure already
// fitted and held out is not fitted again in a later stage. Fixed orders or premise skip
// their stage.
//
// Status (`flexid identify` uses this by default; figures in the README's
// "Identification"): on the independent simulator's recordings that visit every level
// the model predicts fresh data within the noise. Two 6,600-sample square waves take
// 0.7 s on one core, a 20,000-sample staircase of the seed's model 2.2 s
// (bench/identify_bench). On the own test plant (tests/ts_plant.h: rules driven by their
// share of the voltage) 17 of 24 draws fitted on a staircase and 19 of 24 fitted on
// random levels predict fresh data within 1.5 times the noise, all with few smooth rules
// (bench/own_plant); a staircase of 1 V steps does not determine the response to larger
// jumps.

#pragma once

#include <complex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/ts_fuzzy.h"
#include "model/identify/identify.h"

namespace flexid::model {

struct GlobalStructure {
  int num_zeros = 1;
  int num_poles = 2;
  SchedulingVariable premise = SchedulingVariable::kAbsVoltageDelayed;
  std::vector<double> knots_V;  // rule centres (gain knots), ascending; one: a linear model
  // Where the dynamics (poles and zeros) may change: a subset of knots_V; one knot: the
  // same dynamics at every voltage, only the gain varies.
  std::vector<double> dynamics_knots_V;
  // kParallel: each rule driven by its share of u (ts_fuzzy.h); the premise is then |u|
  // read as the voltage is applied, its share delayed with it by T.
  TsRealisation realisation = TsRealisation::kFrozen;
  // The hand-over between rules. kTriangular: gains and dynamics interpolated linearly
  // between neighbouring knots, each rule alone at its own knot. kGaussian: Gaussian
  // memberships centred on the knots with one width, fitted with the rest: a smooth
  // hand-over of estimated width, every rule firing everywhere.
  MembershipShape membership = MembershipShape::kTriangular;
  // kGaussian: each rule's centre fitted too, within 0.45 of the spacing to its
  // neighbouring knots (knots_V then name the rules; the model holds the centres).
  bool centres_fitted = false;
  int Parameters() const;  // free parameters (dead time included)
  std::string Describe() const;
};

struct GlobalEstimate;
struct GlobalIdentifyOptions {
  // Orders: both >= 0 to fix them (num_zeros < num_poles <= 6); -1 chooses them.
  int num_zeros = -1;
  int num_poles = -1;
  std::optional<SchedulingVariable> premise;  // fixed premise; chosen when absent
  std::optional<TsRealisation> realisation;   // fixed realisation; chosen when absent
  int max_rules = 8;                          // knots at most (levels beyond are spread)
  // Rules in the result at most (0: max_rules alone decides). Where more levels are
  // visited, the "rules" stage then chooses between one rule and two to rules_at_most
  // (at most 3) rules with smooth hand-overs; the structure with a knot per level is not
  // a candidate. The diagnosis uses 2, the seed's blend (Eq. 19): a knot per level would
  // give every level a gain of its own and absorb a static map (saturation, a dead zone)
  // or a gain that changes between levels visited at different times (degradation, drift).
  int rules_at_most = 0;
  double max_delay_s = 10.0;
  std::optional<double> fixed_delay_s;  // the dead time, when known
  int max_iterations = 60;              // per fit
  // Dense data: the structure is chosen on every f-th sample, f at most this (1: every
  // sample). If the result stays above three times the noise (estimated from the data's
  // second differences), the choice is made again on every sample.
  int max_selection_factor = 5;
  int correlation_lags = 25;
  // Samples with t_s in [first, second) are simulated but never fitted (diagnosis's
  // held-out samples).
  std::vector<std::pair<double, double>> excluded_spans_s;
  // Not chosen but raised: this estimate's structure with one more pole and one more zero
  // at every dynamics knot, every other choice kept (knots, hand-over, premise,
  // realisation, its dead time fixed), started near where it ended with a cancelling
  // pole-zero pair added (fast, and at a thirtieth, a tenth and a third of the longest
  // recording; the best of the four fits is kept), fitted on every usable sample, no
  // selection and no decimation. Its in-sample error may end slightly above the
  // estimate's (RaiseOrder in global_fit.h says why).
  // The orders, premise, realisation and dead time above are then ignored. The estimate
  // must come from IdentifyGlobalTs on the same recordings and excluded spans, and
  // outlive the call. The diagnosis asks this way whether free dynamics fall back: a
  // second selection would cost as much as the first (a minute on 77,000 samples).
  const GlobalEstimate* raise_order_of = nullptr;
  // The physics chain's prior (Eqs. 11-13): a step response rises to its final value
  // without falling back. Above 0, a structure whose fit at any rule falls back by more
  // than this share of its final value (StepFallBack) is not admissible, as one that
  // swings on switching is not; so is such a refit on every sample after a choice on a
  // coarser grid, and such a fit of raise_order_of's structure. 0: any step response.
  double max_fall_back = 0.0;
  bool IsValid(std::string* error) const;
};

// One structure tried during selection.
struct StructureTrial {
  std::string stage;  // "premise", "orders", "rules"
  GlobalStructure structure;
  double held_out_rmse_mm = 0.0;  // pooled over the folds; +inf if a fold failed
  // Mean squared held-out error (mm^2) in each block of every fold, in one order for every
  // structure: structures are compared block by block (a signed-rank test).
  std::vector<double> block_mse_mm2;
  std::string problem;  // why it was not usable, if it was not
};

struct RuleReport {
  double knot_V = 0.0;
  ParameterEstimate dc_gain;  // mm/V
  std::vector<std::complex<double>> poles;
};

struct GlobalEstimate {
  TsModel model;
  GlobalStructure structure;
  std::string reason;  // why this structure, in words
  std::vector<StructureTrial> trials;
  FitFigures fit;  // in sample, every fitted sample
  double held_out_rmse_mm = 0.0;
  double noise_std_mm = 0.0;  // sqrt(SSR / (N - p))
  // The dead time; its 95 % interval from the profile of the fit over T (the chosen
  // structure refitted with T fixed every half second), not the Jacobian, which misses
  // the ridge along which a zero trades off against T.
  ParameterEstimate delay_s;
  std::vector<RuleReport> rules;
  std::vector<std::string> undetermined;  // parameters the data do not determine
  std::vector<double> levels_V;           // |voltage| levels the data visit (plateau input)
  bool plateau_input = true;
  std::vector<std::string> warnings;  // what the data cannot decide, in plain words
  std::vector<std::string> notes;     // resampling and similar
  double dt_s = 0.0;
  int fits = 0;  // output-error fits run, selection included
  // The fitted parameters in the structure's internal order (for raise_order_of).
  std::vector<double> theta;
};

// Throws InputError (one line naming the recording and the problem) for unusable data,
// std::invalid_argument for invalid options.
GlobalEstimate IdentifyGlobalTs(const std::vector<Recording>& recordings,
                                const GlobalIdentifyOptions& options = {});

// The model file document of an estimate (model_file.h): the model (a transfer function
// when there is one rule), each rule's DC gain with its interval in local_extra, and in
// extra the structure with the reason for it, the fit figures, the held-out RMSE, the
// noise, the dead time with its interval, the levels, and the warnings, undetermined
// parameters and notes. Non-finite figures are written as null.
ModelDocument ToModelDocument(const GlobalEstimate& estimate);

}  // namespace flexid::model
