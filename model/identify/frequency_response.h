// The frequency-response route to the seed's Eq. (18) (the seed's Figure 7): periodic
// (square-wave) recordings -> points of G(j omega) -> a rational model with dead time
//
//   G(s) = e^{-T s} (b0 s^m + ... + b_m) / (s^n + a1 s^{n-1} + ... + a_n),   m <= n,
//
// fitted to the points in the spirit of the seed's Golubev method.
//
// Notation: u_k, y_k = input (V) and output (mm) at t_k = k dt; f0 = fundamental (Hz),
// omega_h = 2 pi h f0 (rad/s) the h-th harmonic; P = 1 / f0 the period; s' = s / omega_ref
// the scaled Laplace variable (omega_ref = geometric mean of the smallest and largest
// omega, for conditioning).
//
// 1. Points (EstimateFrequencyResponse). The first `discard_periods` periods are dropped
//    as the start-up transient; the window is the largest whole number n >= 2 of periods
//    that follows, L = round(n P / dt) samples (P / dt need not be an integer; a recording
//    that ends less than one sample short of the last period still counts it).
//    Trend: what is left of the transient is taken out by a Legendre polynomial in time of
//    degree min(4, q (n - 1)), fitted to the means of quarter periods (q = 4 cells per
//    period; fewer when a period has under 16 samples) together with one free value per
//    quarter: a periodic signal, whatever its harmonics, measured or not, gives the same
//    quarter means in every period, so that pattern absorbs it and the polynomial takes
//    only the aperiodic part. (A joint least-squares fit of polynomials and a truncated set
//    of harmonics would not: a square wave's unmodelled harmonics leak through the
//    polynomials, 1 % errors observed; plain period means allow only degree n - 1, which
//    left the 8 V model's 115 s mode biasing the slowest points.) Modes much slower than a
//    period are smooth over the window; modes faster than a period have died in the
//    discarded periods. The same operator is applied to u and y.
//    Harmonics: least squares on the detrended u and y with a constant and cos / sin of
//    omega_h t for h = 1..max_harmonic (on whole periods: the DFT at the lines). The
//    harmonic h of a signal is X_h = alpha_h - j beta_h of alpha_h cos + beta_h sin, and
//    the sampled system's response is G_d(h) = Y_h / U_h. Harmonics with |U_h| < 1 % of
//    |U_1| (the even ones of a 50 % square wave) or omega_h > 0.8 pi / dt are skipped. A
//    square wave whose period is not a whole number of samples is not exactly periodic
//    once sampled: its duty cycle wanders by a sample (even harmonics of ~pi / (2 P / dt)
//    appear, and are used when above 1 %) and its harmonics above Nyquist alias to lines
//    near the measured ones. That costs ~0.1-1 % per point with 3 periods, and shows in
//    the point's uncertainty (below); whole-sample periods avoid it.
//
//    Zero-order hold: flexid's convention is that the recorded voltage u_k is held on
//    [t_k, t_{k+1}) (simulate.h). The ratio Y_h / U_h is then the frequency response of the
//    ZOH-sampled system,
//      G_d(e^{j w dt}) = sum_k G(j w_k) (1 - e^{-j w dt}) / (j w_k dt),  w_k = w + 2 pi k / dt,
//    and the points report G(j w) = G_d * j w dt / (1 - e^{-j w dt}) (the k = 0 term
//    inverted). This removes the half-sample lag e^{-j w dt / 2} (a dead-time error of
//    dt / 2 otherwise) and the droop (w dt / 2) / sin(w dt / 2). What remains is aliasing,
//    the k != 0 terms, of relative size at most
//      sum_{k != 0} |G(j w_k) / G(j w)| * w / |w_k|,
//    which for a plant that rolls off is ~ 2 (w dt / 2 pi) |G(j 2 pi / dt)| / |G(j w)|:
//    1.2e-4 for 2 / (3 s + 1) at 0.05 Hz and dt = 0.1 s (uncorrected: 1.6e-2), 2e-3 at its
//    5th harmonic. The fit does not model it, so on noise-free simulated data its chi^2
//    reports a misfit (the points' own uncertainty is then at rounding level). If the DAQ
//    sampled a continuous square wave instead, its edges lie up to one sample before the
//    recorded ones and the dead time carries a +-dt / 2 ambiguity.
//
//    Uncertainty: the noise near omega_h is measured off the harmonic lines. With r_u, r_y
//    the residuals of the harmonic fits and R(omega) = sum_k r_k e^{-j omega t_k}, the bins
//    omega_h + i delta (delta = 2 pi / (L dt), 0 < |i| < min(2 n, 13), i not a multiple of
//    n so no harmonic line, bin index above the trend degree) give e_i = R_y - G_d(h) R_u:
//    output noise plus input noise seen through G, plus whatever of the transient and of
//    the aliased input lines the model does not explain. sigma_h^2 = mean |e_i|^2 / L is
//    the equivalent white-noise variance near the line. The estimate is linear in the
//    signal, (alpha_h, beta_h) = rows r_a, r_b of W (I - T A) applied to it (W = the least-
//    squares operator, A the cell averaging, T the trend fit), so var(Y_h - G U_h) =
//    sigma_h^2 (|r_a|^2 + |r_b|^2) exactly, the trend's own noise included (for a long
//    period it is as large as the harmonic's), and var(G) = that / |U_h|^2 (times the ZOH
//    factor squared): a circular complex error with per-component standard deviation
//    s = sqrt(var(G) / 2) (FrequencyPoint::std_dev) and nu = 2 (number of bins) degrees of
//    freedom. Gain and phase half-widths (95 %) are q s and q s / |G| with q the Student-t
//    quantile; when the 95 % disc |G - G_hat| <= r (r^2 = 2 s^2 F_{2,nu}(0.95)) contains 0
//    the phase is not resolved: the gain half-width becomes r and the phase half-width pi.
//    Checked on the 8 V model at 0.0025 and 0.02 Hz (200 noise draws each): the spread of
//    the estimates matches s to within 10 %, biases are below s / 4.
//
// 2. Fit (FitFrequencyResponse), for each dead time T on a grid over [0, max_delay_s]:
//    H_k = G_k e^{+j omega_k T}; Levy's linear least squares min sum w_k |B(s'_k) -
//    H_k A(s'_k)|^2 over b', a' (A monic in s'), then Sanathanan-Koerner iterations with
//    w_k = 1 / (var_k |A_{i-1}(s'_k)|^2), which turn Levy's equation error into the output
//    error |B / A - H| / sd weighted by each point's variance (the spirit of the seed's
//    Golubev method). Every iterate's unstable poles are reflected into the left half-plane
//    (p -> -conj p, which keeps |A(j omega)|); the numerator is then refitted with A fixed
//    (linear). Columns are scaled to unit norm and solved by a complete orthogonal
//    decomposition. With chi^2 = 2 sum_k |G_model(j omega_k) - G_k|^2 / var_k:
//     a. every grid point's SK fit is polished by Levenberg-Marquardt on b', a' with T
//        fixed (the profile chi^2(T); SK's fixed point is near, not at, the optimum);
//     b. golden-section search of the SK chi^2(T) between the best SK grid point's
//        neighbours;
//     c. Levenberg-Marquardt on (b', a', T) jointly from the best of a and b (steps that
//        would destabilise or leave [0, max_delay_s] are rejected);
//     d. the profile again by continuation: sweeping outwards from the optimum, each grid
//        point starts from its neighbour's solution (this follows the valley that local
//        fits from SK starts miss); a profile point below the optimum restarts c (at most
//        three rounds).
//    Coefficient intervals come from the Jacobian at the optimum, cov = (J^T J)^{-1}
//    max(1, chi^2 / dof) (pseudo-inverse of the column-scaled J: +inf where a singular
//    value is below 1e-10 of the largest); DC gain and poles by the delta method. The
//    delay's interval is the profile's, {T : chi^2(T) <= chi^2_min + 3.84 max(1,
//    chi^2 / dof)}, ends interpolated between grid points: the profile, not the Jacobian,
//    because chi^2(T) is far from quadratic where the delay trades off against a fast mode.
//    Local minima of the profile outside that interval but within Delta chi^2 <= 9
//    max(1, chi^2 / dof) (3 sigma) are reported as competing delays (the interval is then
//    that of the best valley only; with the 8 V model under 1 % noise the true delay sat in
//    such a competing valley in 4 of the 5 draws in 20 whose interval missed it).
//
// Identifiability (SEED-NOTES.md): each point gives two real numbers; 3 zeros / 4 poles
// and a delay are 9 parameters, so fewer than 5 points is an error, and the report says
// when the data only just determine the model (dof < parameters), when the Jacobian is
// ill-conditioned or rank-deficient (naming the undetermined coefficients), when the
// points misfit (chi^2 / dof > 4), which poles lie outside the measured band (such poles
// are extrapolated, not measured), and which pairs are lightly damped. With the seed's
// 8 V model and its seven square waves (1.1 Hz sampled at 100 Hz, 3 analysed periods
// each), the DC gain and the two slow poles come back within 2 % even under 1 % output
// noise. The lightly damped pair at 19.2 rad/s lies between 6.9 and 20.7 rad/s, where the
// gain is 0.03-0.15 % of DC: noise-free it comes back (frequency 0.01 %, real part 2 %),
// at 0.3 % noise its frequency to ~1 rad/s and its damping not at all, at 1 % neither.
// The dead time: to +-0.1 s at 0.3 % noise, to +-1-2 s with competing valleys at 1 %
// (frequency_response_test.cc).

#pragma once

#include <complex>
#include <string>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/identify/identify.h"

namespace flexid::model {

struct FrequencyPoint {
  double frequency_Hz = 0.0;  // h f0
  double omega_rad_s = 0.0;   // 2 pi h f0
  // G(j omega) of the continuous plant (ZOH-corrected, header), dead time included; output
  // units per volt (mm/V).
  std::complex<double> response;
  double gain_half_width_95 = 0.0;       // on |G|, mm/V
  double phase_half_width_95_rad = 0.0;  // on arg G; pi when the point is not resolved from 0
  int periods = 0;                       // whole periods in the analysis window
  int harmonic = 1;                      // h
  // Standard deviation s of Re and of Im of `response` (mm/V), the fit's weight. 0 (points
  // from elsewhere): FitFrequencyResponse takes s = gain_half_width_95 / 1.96, and if that
  // is 0 too, the median variance of the other points (unweighted if none has one).
  double std_dev = 0.0;
};

// Points at f0 and its harmonics up to max_harmonic (header, step 1). Uses every sample
// of the segment (fit_begin and initial_voltage_V play no part: the transient is dropped
// instead). Throws std::invalid_argument for fundamental_Hz not finite and > 0,
// max_harmonic < 1 or discard_periods < 0; InputError (one line) for a bad segment (sample
// period, lengths, non-finite values), a fundamental above 0.8 Nyquist, fewer than
// discard_periods + 2 whole periods, a constant input or output over the window (the
// latter: a dead time longer than the recording), or an input without a component at f0.
std::vector<FrequencyPoint> EstimateFrequencyResponse(const DataSegment& segment,
                                                      double fundamental_Hz, int max_harmonic = 5,
                                                      int discard_periods = 1);

// Fundamental of a periodic input (Hz), from the crossings of its mid level (halfway
// between the 2nd and 98th percentiles) with a hysteresis of 10 % of that range,
// interpolated linearly between samples: the period is the least-squares slope of the
// crossing times against their cycle index (rising and falling edges, one intercept
// each), so edges quantised to the sample grid average out (error ~dt / (periods P)).
// Throws InputError naming the problem if the input is constant, crosses its mid level
// fewer than three times upwards (not two periods), or its crossing intervals vary by
// more than max(5 % of the period, 1.5 dt) (not periodic).
double DetectFundamental_Hz(const DataSegment& segment);

struct FrequencyFitOptions {
  int num_zeros = 3;           // m (0 <= m <= n)
  int num_poles = 4;           // n (>= 1); lower orders are what few points support
  double max_delay_s = 10.0;   // dead-time search range [0, max_delay_s]; 0: no delay
  int sk_iterations = 20;      // Sanathanan-Koerner iterations per grid delay (>= 1)
  double delay_step_s = 0.05;  // grid step of the dead-time search (> 0)
  bool refine = true;          // profile polish, golden section, Levenberg-Marquardt (header, 2a-d)
  // True if every field is finite and in range; otherwise false with a one-line reason
  // in *error (if error is not null).
  bool IsValid(std::string* error) const;
};

struct FrequencyFit {
  TransferFunction tf;  // normalised (den monic), stable
  std::vector<FrequencyPoint> points;
  // sqrt(mean_k |G_model(j omega_k) - G_k|^2 / var_k), var_k = E|G_k - G|^2 = 2 s_k^2:
  // about 1 when the model fits within the noise, >> 1 for a misfit.
  double weighted_rms_error = 0.0;
  std::vector<ParameterEstimate> coefficients;  // b0..b_m, a1..a_n, delay_s
  ParameterEstimate dc_gain;                    // G(0) = b_m / a_n, mm/V, delta method
  // Poles (Poles(tf) order) with 95 % half-widths by the delta method,
  // dp/da_i = -p^{n-i} / A'(p); +inf where the coefficients are not determined.
  std::vector<PoleEstimate> poles;
  std::string method_report;  // orders, grid, conditioning, warnings
};

// Fits the model of the header (step 2). Throws std::invalid_argument for invalid options
// and InputError for points that are not usable (none, non-finite, omega <= 0) or too few
// for the order: 2 * points must be at least the number of real parameters
// (m + 1 + n, plus 1 for the delay when max_delay_s > 0).
FrequencyFit FitFrequencyResponse(const std::vector<FrequencyPoint>& points,
                                  const FrequencyFitOptions& options = {});

struct SquareWaveOptions {
  int max_harmonic = 5;     // harmonics per recording (those of the input that exist)
  int discard_periods = 1;  // start-up periods dropped per recording ...
  // ... and at least this long (dead time plus settling): a recording of period P drops
  // max(discard_periods, ceil(min_discard_s / P)) periods.
  double min_discard_s = 0.0;
  bool IsValid(std::string* error) const;
};

// DetectFundamental_Hz and EstimateFrequencyResponse on every recording, then
// FitFrequencyResponse on all the points together. Errors name the recording by index.
FrequencyFit IdentifyFromSquareWaves(const std::vector<DataSegment>& recordings,
                                     const FrequencyFitOptions& options = {},
                                     const SquareWaveOptions& square_wave = {});

}  // namespace flexid::model
