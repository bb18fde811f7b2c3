// Residual tests of prediction-error validation (Ljung, System Identification, 2nd ed.,
// section 16.6): is the residual e(t) white, and is it independent of past inputs u(t)?
//
// Notation: N samples; means are removed first; for two series x, y
//   R_xy(tau) = (1/N) sum_t x(t + tau) y(t)   (biased estimate, Ljung Eq. 16.58),
//   rho_x(k) = R_xx(k) / R_xx(0),
// and z_p = Phi^-1(p) is the standard normal quantile.
//
// Whiteness (Ljung Eqs. 16.55-16.57, Ljung-Box form): for a white residual the
// normalised autocorrelations are asymptotically independent N(0, 1/N), and
//   Q = N (N + 2) sum_{k=1}^{M} rho_e(k)^2 / (N - k)  ~  chi^2(M),
// so the residual passes if Q < chi^2_{confidence}(M). The pointwise bound
// z_{(1+c)/2} / sqrt(N) is reported for plots.
//
// Input-residual independence (Ljung Eqs. 16.59-16.60): if e and u are independent,
// sqrt(N) R_eu(tau) is asymptotically N(0, P) with P = sum_{k=-inf}^{inf} R_e(k) R_u(k);
// normalised by sqrt(R_e(0) R_u(0)), the variance of sqrt(N) times the normalised
// correlation is P_n = 1 + 2 sum_{k>=1} rho_e(k) rho_u(k). flexid estimates
//   P_n = 1 + 2 sum_{k=1}^{K} (1 - k/(K+1)) rho_e(k) rho_u(k),   K = min(N - 1, 4 M),
// with a Bartlett taper, which keeps the estimate non-negative (the tapered product of
// two biased autocorrelation sequences is positive semidefinite) and damps the noise of
// the estimated autocorrelations at long lags; 4 M lags cover a residual whose
// autocorrelation dies out within the tested window with margin, at O(N M) cost. The
// bound never drops below the independence bound: it uses max(1, P_n).
//
// Multiple lags. `passed` is "every |correlation| <= bound" over the 2M+1 lags. With the
// pointwise quantile z_{(1+c)/2} that would reject a perfectly independent pair with
// probability 1 - c^{2M+1} (93 % for M = 25, c = 0.95), so `bound` is the simultaneous
// bound at `confidence`: the Sidak-adjusted quantile z_{(1 + c^{1/(2M+1)})/2}, exact for
// independent lags and conservative otherwise. pointwise_bound holds the per-lag bound
// z_{(1+c)/2} sqrt(max(1, P_n)) / sqrt(N) for plots.
#pragma once

#include <span>
#include <vector>

namespace flexid::model {

struct WhitenessTest {
  int max_lag = 0;                      // M
  std::vector<double> autocorrelation;  // rho_e(1..M), normalised by R_e(0)
  double bound = 0;                     // pointwise z_{(1+conf)/2} / sqrt(N)
  double ljung_box_q = 0;               // Q
  double chi2_threshold = 0;            // chi^2 quantile with M dof at `confidence`
  bool passed = false;                  // Q < chi2_threshold
};

struct CrossCorrelationTest {
  int max_lag = 0;                  // M
  std::vector<int> lags;            // -M..M
  std::vector<double> correlation;  // R_eu(tau) / sqrt(R_e(0) R_u(0)); positive lag = input leads
  double bound = 0;                 // simultaneous bound over the 2M+1 lags (header)
  double max_abs = 0;               // max |correlation|
  bool passed = false;              // max_abs <= bound
  double pointwise_bound = 0;       // per-lag bound z_{(1+conf)/2} sqrt(max(1, P_n)) / sqrt(N)
  double variance_factor = 1;       // P_n (header), before max(1, .)
};

// Ljung-Box whiteness test of `residual` over lags 1..max_lag. Throws
// std::invalid_argument if max_lag < 1, confidence is not in (0, 1), residual has
// max_lag or fewer samples, holds a non-finite value, or has zero variance.
WhitenessTest TestWhiteness(std::span<const double> residual, int max_lag = 25,
                            double confidence = 0.95);

// Cross-correlation test of input and residual over lags -max_lag..max_lag, where lag
// tau > 0 correlates u(t) with e(t + tau) (the input leads). Throws std::invalid_argument
// as TestWhiteness, and if the lengths differ or the input has zero variance.
CrossCorrelationTest TestInputResidualCorrelation(std::span<const double> input,
                                                  std::span<const double> residual,
                                                  int max_lag = 25, double confidence = 0.95);

// Inverse standard normal CDF: Acklam's rational approximation (relative error 1.2e-9)
// refined by one Halley step on erfc, |error| ~ 1e-15 in the central region. Returns
// -inf at 0 and +inf at 1; throws std::invalid_argument outside [0, 1] or for NaN.
double NormalQuantile(double p);

// Quantile of the chi-square distribution with `dof` degrees of freedom: Wilson-Hilferty
// start, then safeguarded Newton iterations on the regularised lower incomplete gamma
// function P(dof/2, x/2) = p (series / continued fraction, Numerical Recipes 6.2) to a
// relative accuracy of 1e-12. Returns 0 at p = 0 and +inf at p = 1; throws
// std::invalid_argument if dof < 1 or p is outside [0, 1] or NaN.
double ChiSquareQuantile(double p, int dof);

}  // namespace flexid::model
