#include "model/core/residual_tests.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <numbers>
#include <random>
#include <vector>

#include "gaussian.h"

namespace flexid::model {
namespace {

using testing::Gaussian;

std::vector<double> WhiteNoise(size_t n, Gaussian& normal) {
  std::vector<double> x(n);
  for (double& v : x) v = normal();
  return x;
}

// x(t) = phi x(t-1) + w(t), started from the stationary distribution.
std::vector<double> Ar1(size_t n, double phi, Gaussian& normal) {
  std::vector<double> x(n);
  x[0] = normal() / std::sqrt(1 - phi * phi);
  for (size_t t = 1; t < n; ++t) x[t] = phi * x[t - 1] + normal();
  return x;
}

// Standard normal CDF from the C library's erfc: an independent check of the quantile.
double NormalCdf(double x) { return 0.5 * std::erfc(-x / std::numbers::sqrt2); }

TEST(NormalQuantile, KnownValues) {
  // Tabulated quantiles (Abramowitz & Stegun 26.2; R qnorm).
  EXPECT_NEAR(NormalQuantile(0.975), 1.959963984540054, 1e-6);
  EXPECT_NEAR(NormalQuantile(0.975), 1.959963984540054, 1e-12);
  EXPECT_EQ(NormalQuantile(0.5), 0.0);
  EXPECT_NEAR(NormalQuantile(0.95), 1.644853626951472, 1e-12);
  EXPECT_NEAR(NormalQuantile(0.001), -3.090232306167813, 1e-12);
  EXPECT_NEAR(NormalQuantile(1e-10), -6.361340902404056, 1e-9);
  EXPECT_EQ(NormalQuantile(0.0), -INFINITY);
  EXPECT_EQ(NormalQuantile(1.0), INFINITY);
  EXPECT_THROW(NormalQuantile(1.5), std::invalid_argument);
  EXPECT_THROW(NormalQuantile(NAN), std::invalid_argument);
}

TEST(NormalQuantile, InvertsTheCdfAndIsSymmetric) {
  for (double p = 1e-6; p < 1.0; p += 0.0137) {
    const double x = NormalQuantile(p);
    // Symmetry up to the rounding of 1 - p (half an ulp of 1, divided by the density).
    const double density = std::exp(-0.5 * x * x) / std::sqrt(2 * std::numbers::pi);
    EXPECT_NEAR(NormalQuantile(1 - p), -x, 1e-12 + 1.2e-16 / density);
    // |error in x| = |error in Phi| / density; 1e-8 is the required accuracy.
    EXPECT_NEAR(NormalCdf(x), p, 1e-8 * density) << "p = " << p;
  }
}

TEST(ChiSquareQuantile, KnownValues) {
  // Tabulated values (NIST/SEMATECH e-Handbook 1.3.6.7.4; R qchisq).
  EXPECT_NEAR(ChiSquareQuantile(0.95, 25), 37.6525, 1e-2);
  EXPECT_NEAR(ChiSquareQuantile(0.95, 25), 37.65248413348277, 1e-9);
  EXPECT_NEAR(ChiSquareQuantile(0.99, 10), 23.20925115, 1e-7);
  EXPECT_NEAR(ChiSquareQuantile(0.05, 100), 77.92946517, 1e-7);
  EXPECT_NEAR(ChiSquareQuantile(0.5, 3), 2.365973884, 1e-8);
  // Closed forms: dof 1 is z^2, dof 2 is exponential with mean 2.
  for (double p : {1e-6, 0.01, 0.3, 0.95, 0.999999}) {
    const double z = NormalQuantile(0.5 + 0.5 * p);
    EXPECT_NEAR(ChiSquareQuantile(p, 1), z * z, 1e-10 * (1 + z * z)) << p;
    EXPECT_NEAR(ChiSquareQuantile(p, 2), -2 * std::log1p(-p), 1e-10 * (1 - std::log1p(-p))) << p;
  }
  EXPECT_EQ(ChiSquareQuantile(0.0, 5), 0.0);
  EXPECT_EQ(ChiSquareQuantile(1.0, 5), INFINITY);
  EXPECT_THROW(ChiSquareQuantile(0.5, 0), std::invalid_argument);
  EXPECT_THROW(ChiSquareQuantile(-0.1, 3), std::invalid_argument);
}

TEST(ChiSquareQuantile, LargeDofMatchesTheNormalLimit) {
  // chi^2(k) ~ N(k, 2k); at k = 10^4 the Wilson-Hilferty value is accurate to ~1e-4.
  const int k = 10000;
  const double h = 2.0 / (9.0 * k);
  const double wilson_hilferty = k * std::pow(1 - h + NormalQuantile(0.9) * std::sqrt(h), 3);
  EXPECT_NEAR(ChiSquareQuantile(0.9, k), wilson_hilferty, 1e-2);
}

TEST(Whiteness, WhiteNoiseIsRejectedAboutFivePercentOfTheTime) {
  Gaussian normal(20240611);
  int rejected = 0;
  const int trials = 200;
  for (int trial = 0; trial < trials; ++trial) {
    const WhitenessTest test = TestWhiteness(WhiteNoise(1000, normal));
    ASSERT_EQ(test.autocorrelation.size(), 25u);
    if (!test.passed) ++rejected;
  }
  // Binomial(200, 0.05): mean 10, standard deviation 3.1; 1 % .. 12 % is 2 .. 24.
  EXPECT_GE(rejected, 2);
  EXPECT_LE(rejected, 24);
}

TEST(Whiteness, FieldsMatchTheDefinitions) {
  Gaussian normal(1);
  const std::vector<double> e = WhiteNoise(500, normal);
  const WhitenessTest test = TestWhiteness(e, 10, 0.99);
  EXPECT_EQ(test.max_lag, 10);
  EXPECT_NEAR(test.bound, 2.5758293035489 / std::sqrt(500.0), 1e-12);
  EXPECT_NEAR(test.chi2_threshold, 23.20925115, 1e-7);
  // Q recomputed here from its definition.
  double mean = 0;
  for (double v : e) mean += v / 500;
  double r0 = 0;
  for (double v : e) r0 += (v - mean) * (v - mean);
  double q = 0;
  for (int k = 1; k <= 10; ++k) {
    double r = 0;
    for (size_t t = static_cast<size_t>(k); t < e.size(); ++t)
      r += (e[t] - mean) * (e[t - static_cast<size_t>(k)] - mean);
    EXPECT_NEAR(test.autocorrelation[static_cast<size_t>(k - 1)], r / r0, 1e-12);
    q += (r / r0) * (r / r0) / (500.0 - k);
  }
  EXPECT_NEAR(test.ljung_box_q, 500.0 * 502.0 * q, 1e-9);
  EXPECT_EQ(test.passed, test.ljung_box_q < test.chi2_threshold);
}

TEST(Whiteness, Ar1ResidualFails) {
  Gaussian normal(99);
  const WhitenessTest test = TestWhiteness(Ar1(1000, 0.5, normal));
  EXPECT_FALSE(test.passed);
  // rho(1) = phi = 0.5 with standard error ~ sqrt((1 - phi^2) / N) = 0.027.
  EXPECT_NEAR(test.autocorrelation[0], 0.5, 0.1);
  EXPECT_GT(test.ljung_box_q, 5 * test.chi2_threshold);
}

TEST(Whiteness, DegenerateInputs) {
  EXPECT_THROW(TestWhiteness(std::vector<double>(100, 3.0)), std::invalid_argument);
  EXPECT_THROW(TestWhiteness(std::vector<double>(100, 0.1)), std::invalid_argument);
  Gaussian normal(2);
  EXPECT_THROW(TestWhiteness(WhiteNoise(25, normal), 25), std::invalid_argument);
  EXPECT_NO_THROW(TestWhiteness(WhiteNoise(26, normal), 25));
  EXPECT_THROW(TestWhiteness(WhiteNoise(100, normal), 0), std::invalid_argument);
  EXPECT_THROW(TestWhiteness(WhiteNoise(100, normal), 5, 1.0), std::invalid_argument);
  std::vector<double> bad = WhiteNoise(100, normal);
  bad[10] = NAN;
  EXPECT_THROW(TestWhiteness(bad), std::invalid_argument);
}

TEST(CrossCorrelation, FilteredInputResidualFails) {
  Gaussian normal(5);
  const size_t n = 2000;
  const std::vector<double> u = WhiteNoise(n, normal);
  // e(t) = 0.3 u(t - 3) + 0.2 u(t - 4) + w(t): what an unmodelled delayed path leaves.
  std::vector<double> e(n);
  for (size_t t = 0; t < n; ++t) e[t] = normal() + (t >= 4 ? 0.3 * u[t - 3] + 0.2 * u[t - 4] : 0.0);
  const CrossCorrelationTest test = TestInputResidualCorrelation(u, e);
  EXPECT_FALSE(test.passed);
  ASSERT_EQ(test.lags.size(), 51u);
  EXPECT_EQ(test.lags.front(), -25);
  EXPECT_EQ(test.lags[25], 0);
  // Positive lag = input leads: the peak is at +3 with 0.3 / sqrt(1.13) = 0.28.
  const size_t peak = 25 + 3;
  EXPECT_NEAR(test.correlation[peak], 0.3 / std::sqrt(1.13), 0.05);
  EXPECT_NEAR(test.max_abs, std::abs(test.correlation[peak]), 1e-12);
  EXPECT_NEAR(test.correlation[25 - 3], 0.0, 0.08);
}

TEST(CrossCorrelation, IndependentWhiteSignalsPassAtTheStatedRate) {
  Gaussian normal(77);
  int rejected = 0;
  const int trials = 200;
  for (int trial = 0; trial < trials; ++trial) {
    const std::vector<double> u = WhiteNoise(1000, normal);
    const std::vector<double> e = WhiteNoise(1000, normal);
    const CrossCorrelationTest test = TestInputResidualCorrelation(u, e);
    if (!test.passed) ++rejected;
    // Variance factor ~ 1 for white signals; the simultaneous bound is wider than the
    // pointwise one (Sidak over 51 lags: z = 3.29 against 1.96).
    EXPECT_NEAR(test.variance_factor, 1.0, 0.4);
    EXPECT_NEAR(test.bound / test.pointwise_bound, 3.2905 / 1.95996, 2e-3);
  }
  // Family-wise rate 5 %: 1 % .. 12 % of 200 trials.
  EXPECT_GE(rejected, 2);
  EXPECT_LE(rejected, 24);
}

TEST(CrossCorrelation, AutocorrelatedIndependentSignalsPass) {
  // Both AR(1) with phi = 0.9: P_n = (1 + phi^2) / (1 - phi^2) = 9.5, so the independence
  // bound alone would reject most independent pairs.
  Gaussian normal(123);
  int rejected = 0, rejected_without_factor = 0;
  const int trials = 200;
  for (int trial = 0; trial < trials; ++trial) {
    const std::vector<double> u = Ar1(2000, 0.9, normal);
    const std::vector<double> e = Ar1(2000, 0.9, normal);
    const CrossCorrelationTest test = TestInputResidualCorrelation(u, e);
    EXPECT_GT(test.variance_factor, 4.0);
    EXPECT_LT(test.variance_factor, 14.0);
    if (!test.passed) ++rejected;
    if (test.max_abs > test.bound / std::sqrt(test.variance_factor)) ++rejected_without_factor;
  }
  EXPECT_LE(rejected, 24);
  EXPECT_GT(rejected_without_factor, 60);
}

TEST(CrossCorrelation, DegenerateInputs) {
  Gaussian normal(8);
  const std::vector<double> e = WhiteNoise(100, normal);
  EXPECT_THROW(TestInputResidualCorrelation(std::vector<double>(100, 5.0), e),
               std::invalid_argument);
  EXPECT_THROW(TestInputResidualCorrelation(WhiteNoise(99, normal), e), std::invalid_argument);
  EXPECT_THROW(TestInputResidualCorrelation(WhiteNoise(100, normal), e, 100),
               std::invalid_argument);
  EXPECT_THROW(TestInputResidualCorrelation(WhiteNoise(100, normal), e, 10, 0.0),
               std::invalid_argument);
}

}  // namespace
}  // namespace flexid::model
