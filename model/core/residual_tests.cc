#include "model/core/residual_tests.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>

namespace flexid::model {
namespace {

// Cross-correlation variance factor: Bartlett-tapered sum over K = kVarianceLagsPerLag * M
// lags (header).
constexpr int kVarianceLagsPerLag = 4;

void CheckConfidence(double confidence) {
  if (!(confidence > 0.0 && confidence < 1.0))
    throw std::invalid_argument("residual test: confidence must be in (0, 1) (is " +
                                std::to_string(confidence) + ")");
}

void CheckLag(int max_lag, size_t n) {
  if (max_lag < 1)
    throw std::invalid_argument("residual test: max_lag must be >= 1 (is " +
                                std::to_string(max_lag) + ")");
  if (n <= static_cast<size_t>(max_lag))
    throw std::invalid_argument("residual test: " + std::to_string(n) +
                                " samples are too few for max_lag " + std::to_string(max_lag) +
                                " (need more than max_lag)");
}

// x - mean(x); throws if x holds a non-finite value or has zero variance.
std::vector<double> Centred(std::span<const double> x, const char* name) {
  double sum = 0, scale = 0;
  for (double value : x) {
    if (!std::isfinite(value))
      throw std::invalid_argument(std::string("residual test: ") + name +
                                  " holds a non-finite value");
    sum += value;
    scale = std::max(scale, std::abs(value));
  }
  const double mean = sum / static_cast<double>(x.size());
  std::vector<double> centred(x.size());
  double spread = 0;
  for (size_t t = 0; t < x.size(); ++t) {
    centred[t] = x[t] - mean;
    spread = std::max(spread, std::abs(centred[t]));
  }
  // Rounding in the mean leaves ~1e-16 relative residue on a constant series.
  if (spread <= 1e-12 * scale || spread == 0.0)
    throw std::invalid_argument(std::string("residual test: ") + name +
                                " has zero variance (constant at " + std::to_string(mean) + ")");
  return centred;
}

// R_xy(tau) = (1/N) sum_t x(t + tau) y(t) for tau >= 0.
double Covariance(const std::vector<double>& x, const std::vector<double>& y, size_t tau) {
  double sum = 0;
  for (size_t t = 0; t + tau < x.size(); ++t) sum += x[t + tau] * y[t];
  return sum / static_cast<double>(x.size());
}

// z such that a two-sided N(0,1) interval [-z, z] has probability 1 - alpha.
double TwoSidedZ(double alpha) { return -NormalQuantile(0.5 * alpha); }

// log Gamma(a) for a = dof / 2 (integer or half-integer), exact up to rounding, without
// the global state that std::lgamma may write (signgam).
double LogGammaHalfInteger(int dof) {
  double sum = 0;
  if (dof % 2 == 0) {
    for (int j = 2; j < dof / 2; ++j) sum += std::log(static_cast<double>(j));
  } else {
    sum = 0.5 * std::log(std::numbers::pi);
    for (int j = 0; j < dof / 2; ++j) sum += std::log(j + 0.5);
  }
  return sum;
}

struct IncompleteGamma {
  double lower = 0;  // P(a, x)
  double upper = 1;  // Q(a, x) = 1 - P(a, x)
};

// Regularised incomplete gamma functions (Numerical Recipes, 3rd ed., section 6.2): the
// series for x < a + 1, Lentz's continued fraction for Q otherwise.
IncompleteGamma RegularisedGamma(double a, double x, double log_gamma_a) {
  if (x <= 0) return {0.0, 1.0};
  constexpr double kEpsilon = 1e-16;
  constexpr double kTiny = 1e-300;
  constexpr int kMaxIterations = 100000;
  const double prefactor = std::exp(-x + a * std::log(x) - log_gamma_a);
  if (x < a + 1) {
    double term = 1.0 / a, sum = term, ap = a;
    for (int i = 0; i < kMaxIterations; ++i) {
      ap += 1;
      term *= x / ap;
      sum += term;
      if (std::abs(term) < std::abs(sum) * kEpsilon) break;
    }
    const double lower = std::min(1.0, sum * prefactor);
    return {lower, 1.0 - lower};
  }
  double b = x + 1 - a, c = 1 / kTiny, d = 1 / b, h = d;
  for (int i = 1; i < kMaxIterations; ++i) {
    const double an = -i * (i - a);
    b += 2;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1) < kEpsilon) break;
  }
  const double upper = std::min(1.0, prefactor * h);
  return {1.0 - upper, upper};
}

// Acklam's approximation for 0 < p <= 0.5.
double AcklamLowerHalf(double p) {
  constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,  -2.759285104469687e+02,
                          1.383577518672690e+02,  -3.066479806614716e+01, 2.506628277459239e+00};
  constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
                          6.680131188771972e+01, -1.328068155288572e+01};
  constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
                          -2.549732539343734e+00, 4.374664141464968e+00,  2.938163982698783e+00};
  constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
                          3.754408661907416e+00};
  constexpr double kLowRegion = 0.02425;
  if (p < kLowRegion) {
    const double q = std::sqrt(-2 * std::log(p));
    return (((((c[0] * q + c[1]) * q + c[2]) * q + c[3]) * q + c[4]) * q + c[5]) /
           ((((d[0] * q + d[1]) * q + d[2]) * q + d[3]) * q + 1);
  }
  const double q = p - 0.5, r = q * q;
  return (((((a[0] * r + a[1]) * r + a[2]) * r + a[3]) * r + a[4]) * r + a[5]) * q /
         (((((b[0] * r + b[1]) * r + b[2]) * r + b[3]) * r + b[4]) * r + 1);
}

}  // namespace

double NormalQuantile(double p) {
  if (!(p >= 0.0 && p <= 1.0))
    throw std::invalid_argument("NormalQuantile: p must be in [0, 1] (is " + std::to_string(p) +
                                ")");
  if (p == 0.0) return -std::numeric_limits<double>::infinity();
  if (p == 1.0) return std::numeric_limits<double>::infinity();
  // Work in the lower half, where p is exact; 1 - p is exact for p in [0.5, 1].
  if (p > 0.5) return -NormalQuantile(1.0 - p);
  double x = AcklamLowerHalf(p);
  // One Halley step on Phi(x) = p, Phi(x) = erfc(-x / sqrt 2) / 2.
  const double density = std::exp(-0.5 * x * x) / std::sqrt(2 * std::numbers::pi);
  if (density > 0) {
    const double u = (0.5 * std::erfc(-x / std::numbers::sqrt2) - p) / density;
    x -= u / (1 + 0.5 * x * u);
  }
  return x;
}

double ChiSquareQuantile(double p, int dof) {
  if (dof < 1)
    throw std::invalid_argument("ChiSquareQuantile: dof must be >= 1 (is " + std::to_string(dof) +
                                ")");
  if (!(p >= 0.0 && p <= 1.0))
    throw std::invalid_argument("ChiSquareQuantile: p must be in [0, 1] (is " + std::to_string(p) +
                                ")");
  if (p == 0.0) return 0.0;
  if (p == 1.0) return std::numeric_limits<double>::infinity();
  const double k = dof;
  const double a = 0.5 * k;
  const double log_gamma_a = LogGammaHalfInteger(dof);
  // Wilson-Hilferty: (X / k)^(1/3) is nearly normal with mean 1 - h and variance h.
  const double h = 2.0 / (9.0 * k);
  double x = k * std::pow(1 - h + NormalQuantile(p) * std::sqrt(h), 3);
  if (!(x > 0)) {
    // Small-x limit P(a, x/2) ~ (x/2)^a / Gamma(a + 1).
    x = 2 * std::exp((std::log(p) + log_gamma_a + std::log(a)) / a);
  }
  // Safeguarded Newton on f(x) = P(a, x/2) - p (or p' - Q with p' = 1 - p in the upper
  // half, which keeps the tail accurate); f' is the chi-square density.
  const bool upper_half = p > 0.5;
  const double target = upper_half ? 1.0 - p : p;
  double low = 0, high = std::numeric_limits<double>::infinity();
  for (int iteration = 0; iteration < 200; ++iteration) {
    const IncompleteGamma g = RegularisedGamma(a, 0.5 * x, log_gamma_a);
    const double f = upper_half ? target - g.upper : g.lower - target;
    if (f == 0) return x;
    (f < 0 ? low : high) = x;
    const double density = 0.5 * std::exp((a - 1) * std::log(0.5 * x) - 0.5 * x - log_gamma_a);
    double next = density > 0 ? x - f / density : NAN;
    if (!(next > low && next < high)) next = std::isfinite(high) ? 0.5 * (low + high) : 2 * x;
    if (std::abs(next - x) <= 1e-12 * x) return next;
    x = next;
  }
  return x;
}

WhitenessTest TestWhiteness(std::span<const double> residual, int max_lag, double confidence) {
  CheckConfidence(confidence);
  CheckLag(max_lag, residual.size());
  const std::vector<double> e = Centred(residual, "residual");
  const auto n = static_cast<double>(e.size());
  WhitenessTest test;
  test.max_lag = max_lag;
  const double r0 = Covariance(e, e, 0);
  double sum = 0;
  for (int k = 1; k <= max_lag; ++k) {
    const double rho = Covariance(e, e, static_cast<size_t>(k)) / r0;
    test.autocorrelation.push_back(rho);
    sum += rho * rho / (n - k);
  }
  test.bound = TwoSidedZ(1 - confidence) / std::sqrt(n);
  test.ljung_box_q = n * (n + 2) * sum;
  test.chi2_threshold = ChiSquareQuantile(confidence, max_lag);
  test.passed = test.ljung_box_q < test.chi2_threshold;
  return test;
}

CrossCorrelationTest TestInputResidualCorrelation(std::span<const double> input,
                                                  std::span<const double> residual, int max_lag,
                                                  double confidence) {
  if (input.size() != residual.size())
    throw std::invalid_argument("residual test: input and residual differ in length (" +
                                std::to_string(input.size()) + " and " +
                                std::to_string(residual.size()) + ")");
  CheckConfidence(confidence);
  CheckLag(max_lag, residual.size());
  const std::vector<double> u = Centred(input, "input");
  const std::vector<double> e = Centred(residual, "residual");
  const auto n = static_cast<double>(e.size());
  const double ru0 = Covariance(u, u, 0), re0 = Covariance(e, e, 0);
  const double norm = std::sqrt(ru0 * re0);

  CrossCorrelationTest test;
  test.max_lag = max_lag;
  for (int tau = -max_lag; tau <= max_lag; ++tau) {
    // tau >= 0: (1/N) sum_t e(t + tau) u(t); tau < 0: (1/N) sum_t u(t + |tau|) e(t).
    const auto lag = static_cast<size_t>(std::abs(tau));
    const double r = tau >= 0 ? Covariance(e, u, lag) : Covariance(u, e, lag);
    test.lags.push_back(tau);
    test.correlation.push_back(r / norm);
    test.max_abs = std::max(test.max_abs, std::abs(r / norm));
  }

  // P_n = 1 + 2 sum_{k=1}^{K} (1 - k / (K + 1)) rho_e(k) rho_u(k) (header).
  const size_t lags = std::min(
      e.size() - 1, static_cast<size_t>(kVarianceLagsPerLag) * static_cast<size_t>(max_lag));
  double factor = 1;
  for (size_t k = 1; k <= lags; ++k) {
    const double taper = 1.0 - static_cast<double>(k) / static_cast<double>(lags + 1);
    factor += 2 * taper * (Covariance(e, e, k) / re0) * (Covariance(u, u, k) / ru0);
  }
  test.variance_factor = factor;
  const double scale = std::sqrt(std::max(1.0, factor) / n);
  // Sidak: each of the 2M+1 lags at level c^{1/(2M+1)}, alpha = 1 - c^{1/(2M+1)}.
  const double per_lag_alpha = -std::expm1(std::log(confidence) / (2 * max_lag + 1));
  test.bound = TwoSidedZ(per_lag_alpha) * scale;
  test.pointwise_bound = TwoSidedZ(1 - confidence) * scale;
  test.passed = test.max_abs <= test.bound;
  return test;
}

}  // namespace flexid::model
