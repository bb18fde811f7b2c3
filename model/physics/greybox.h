// Grey-box identification (`--structure physics`): the seed's physics chain (physics.h,
// Eqs. 4-13) with its physical parameters fitted to recorded deflection, instead of the
// free coefficients of Eq. (18) (identify.h).
//
// Model. For a voltage V(t) held between samples (zero-order hold) the curvature is
//
//   K(s) = G_N(s) V(s),  G_N = CurvatureTransferFunction(p, N, T, kStaticCorrection)
//
// (Eqs. 11-13 with the dead time e^{-T s}, the seed's e^{beta s}), simulated exactly on the
// segment's grid from steady state under its initial voltage; the tip deflection is the
// arc map applied sample by sample (a static nonlinearity, SEED-NOTES item 5):
//
//   y_mm(t_k) = 1000 (1 - cos(K(t_k) L)) / K(t_k).
//
// There is no output offset: 0 mm is the straight beam.
//
// Free: D, delta, R_s, alpha (log-parameterised, so they stay positive) and T >= 0.
// Fixed: L, W, h (the beam is measured), C_dl (as in `start`, normally the reference areal
// capacitance 0.2 F/m^2 times W L, see SeedS1Parameters) and E (cancels, physics.h).
//
// Identifiability. With H = h/delta and G_D(s) the diffusion series normalised to
// G_D(0) = 1 (poles p_n = (2n+1)^2 pi^2 D/(4 h^2): D and h only; with the static remainder
// G_D(inf) = r/H = 1 - (8/pi^2) sum_{n<N} 1/(2n+1)^2, 0.067 for N = 3), Eqs. (6, 9, 11)
// read
//
//   K/V = k f(s) / (s tau f(s) + 1),   f(s) = G_D(s) + eps (1 - G_D(s)),
//   k   = 3 alpha C_dl (1 + H) / (W L h^2)   (the DC curvature per volt),
//   tau = R_s C_dl (1 + H)                   (R_s charging the whole DC capacitance),
//   eps = 1/(1 + H) ~ delta/h                (the double layer's share of it).
//
//  - C_dl appears only in the products alpha C_dl and R_s C_dl: (C_dl, alpha, R_s) ->
//    (c C_dl, alpha/c, R_s/c) leaves K(t) unchanged for every c > 0. So C_dl and alpha,
//    or C_dl and R_s, cannot both be identified from one geometry, and C_dl is fixed. The
//    reported alpha and R_s are "given this C_dl": if the true areal capacitance is c
//    times the assumed one, the true alpha and R_s are the reported ones divided by c.
//    Predictions for another beam (WithGeometry: C_dl proportional to W L, alpha and R_s
//    kept) do not depend on c (tested). E cancels and is not identifiable at all.
//  - Well determined: D (the diffusion poles; slowest time constant 4 h^2/(pi^2 D)), k,
//    tau and T. These are reported, with intervals, in GreyBoxEstimate::combinations.
//    tau is visible at 10 Hz although R_s C_dl is only ~3 ms: it multiplies the whole
//    capacitance C_dl (1 + H) (6.4 s for SeedS1Parameters), which moves the slow modes
//    and the cell pole.
//  - Not determined in practice: delta, and with it alpha and R_s separately (the data
//    fix alpha (1 + H) and R_s (1 + H)). delta acts on its own only through eps, which
//    changes f by eps (1 - G_D) against G_D >= r/H, i.e. by ~ (delta/h)/(r/H) = 0.4 % of
//    the fast part for the test gel: moving delta from 1 um to 0.6 um with k, tau, D and
//    T refitted changes the deflection by 2.6e-5 mm RMS (~5e-6 of it). Noise-free 3-term
//    data recover delta (the model is locally identifiable: four groups D, H, k, tau for
//    four parameters), but with 1 % noise the half-widths of delta, alpha and R_s are
//    120 % to 10^6 % of their values and delta often ends at its lower bound, while the
//    half-widths are ~4 % for D, 0.05 % for k, 20-28 % for tau and 0.05-0.07 s for T (3
//    periods of the 220 s square wave at 10 Hz; tests/greybox_test.cc, 12 noise seeds
//    tried). The absolute half-width of delta (~35 um) says what the data do say: delta/h
//    is below ~2 %. Moreover the handle itself is a truncation artefact: in the exact
//    chain (tanh) G_D -> 0 at high frequency and eps only matters where |G_D| ~ eps, i.e.
//    near D H^2/h^2 ~ 2e4 rad/s for SeedS1Parameters, far above any sampling rate; only
//    the N-term model's constant remainder capacitance makes it visible at 10 Hz. Treat
//    delta, alpha and R_s as undetermined and use k, tau, D and T.
//
// Method. (1) Data checks (InputError) before anything reaches Ceres. (2) Start delay: a
// grid over [0, max_delay_s] in steps of max(dt, 0.25 s) with the start parameters; at each
// delay the deflection scale is solved in closed form (the deflection is nearly
// proportional to alpha for small bending); the best delay and scale give the start T and
// alpha. (3) Levenberg-Marquardt (Ceres, DENSE_QR) on the output error of all segments
// jointly, in the coordinates x = (ln D, ln[alpha (1 + H)], ln[R_s (1 + H)], ln delta, T):
// the second and third are ln k and ln tau up to constants, so the Jacobian's columns are
// not nearly collinear as those of (ln delta, ln alpha, ln R_s) are. First with delta fixed
// at its start, then with delta free within a factor 1e3 of it (in a flat direction an
// unbounded step strands delta at ~0, where its derivative vanishes); the first solve
// leaves only delta's weak effect in the residual. T is bounded to [0, max_delay_s] (fixed
// at 0 if max_delay_s = 0). The Jacobian is numeric: central differences of the exact
// simulation, steps 1e-4 in the logarithms and dt/100 in T (one-sided at T = 0). (4)
// Uncertainty: covariance sigma^2 (J^T J)^{-1} in x, sigma^2 = SSR/(N - q) with q free
// unknowns, mapped to (ln D, ln delta, ln R_s, ln alpha) with the Jacobian of the change
// of coordinates (ln alpha = x_1 - ln(1 + H), d ln(1 + H)/d ln delta = -H/(1 + H), and
// likewise for R_s), and to k, tau and 4 h^2/(pi^2 D); the 95 % half-width in natural
// units is the delta method, value * 1.96 sigma_ln. That is symmetric, while the
// log-normal interval it approximates is not: it is accurate for small relative widths
// and, for wide ones, its lower end goes below zero and its upper end is too low (read a
// half-width above the value as "not determined"). +inf when J^T J is numerically
// singular. All intervals assume white residuals: check fit.whiteness first.
#pragma once

#include <string>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/identify/identify.h"
#include "model/physics/physics.h"

namespace flexid::model {

struct GreyBoxOptions {
  int terms = 3;              // N of Eq. (13), 1..kMaxTransferFunctionTerms
  double max_delay_s = 10.0;  // dead time searched in [0, max_delay_s]; 0: no dead time
  int max_iterations = 100;   // Levenberg-Marquardt iterations
  int correlation_lags = 25;  // residual tests
  bool IsValid(std::string* error) const;
};

struct GreyBoxEstimate {
  // Fitted D, delta, R_s, alpha; C_dl, E and the geometry as in `start`.
  PhysicalParameters parameters;
  double delay_s = 0.0;
  // D_m2_per_s, delta_m, R_s_ohm, alpha_m3_per_C, delay_s (in this order), 95 %
  // half-widths by the delta method from ln-space (header); +inf when not determined.
  std::vector<ParameterEstimate> estimates;
  // The well-determined groups (header), 95 % half-widths by the delta method:
  //   dc_curvature_per_m_V       k = K(0)/V = 3 alpha C_dl (1 + h/delta)/(W L h^2), 1/(m V)
  //   cell_time_constant_s       tau = R_s C_dl (1 + h/delta), s
  //   diffusion_time_constant_s  4 h^2/(pi^2 D), s
  std::vector<ParameterEstimate> combinations;
  // Curvature per volt, 1/(m V), with the dead time: CurvatureTransferFunction(parameters,
  // terms, delay_s, kStaticCorrection). Deflection needs the arc map on top.
  TransferFunction curvature_tf;
  FitFigures fit;             // on the fitted samples of all segments, mm
  double noise_std_mm = 0.0;  // sqrt(SSR / (N - q))
  int iterations = 0;         // of both solves
  // One line: the brief reports of both Ceres solves (delta fixed, delta free), and a
  // note when delta or T stopped at a bound.
  std::string solver_report;
};

// Fits the physics chain to the segments (all jointly; each is simulated on its own grid,
// so sample periods may differ), starting from `start` (which also gives the geometry and
// the fixed C_dl and E). Samples before a segment's fit_begin are simulated, not fitted.
// Throws InputError for unusable data (empty,
// unequal lengths, non-finite values, invalid sample period or initial voltage, nothing to
// fit after the lead-in, too short, constant input), std::invalid_argument for invalid
// options or start parameters, and std::runtime_error if the solver finds no usable point.
GreyBoxEstimate IdentifyPhysics(const std::vector<DataSegment>& segments,
                                const PhysicalParameters& start,
                                const GreyBoxOptions& options = {});

// Deflection in mm predicted by the chain for the segment's voltage (its deflection is not
// used), from steady state under segment.initial_voltage_V, with kStaticCorrection. For
// another beam pass WithGeometry(fitted, L, W, h). Preconditions (checked,
// std::invalid_argument): IsValid(p), delay_s finite and >= 0, 1 <= terms <=
// kMaxTransferFunctionTerms, dt_s finite and > 0, voltages finite.
std::vector<double> PredictDeflection_mm(const PhysicalParameters& p, double delay_s, int terms,
                                         const DataSegment& segment);

}  // namespace flexid::model
