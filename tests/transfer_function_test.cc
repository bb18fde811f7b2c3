#include "model/core/transfer_function.h"

#include <gtest/gtest.h>

#include <cmath>
#include <complex>
#include <numbers>

#include "model/core/presets.h"
#include "model/core/state_space.h"
#include "test_util.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;

// Durand-Kerner iteration: roots of a monic polynomial found without a companion matrix,
// an independent check of PolynomialRoots.
std::vector<Complex> DurandKernerRoots(std::vector<double> p) {
  const double lead = p.front();
  for (double& c : p) c /= lead;
  const size_t n = p.size() - 1;
  // Start on a circle of the Cauchy bound 1 + max |a_i|, which encloses every root.
  double bound = 0.0;
  for (size_t i = 1; i < p.size(); ++i) bound = std::max(bound, std::abs(p[i]));
  std::vector<Complex> z(n);
  for (size_t i = 0; i < n; ++i)
    z[i] = std::pow(Complex(0.4, 0.9), static_cast<double>(i)) * (1.0 + bound);
  for (int iteration = 0; iteration < 5000; ++iteration) {
    for (size_t i = 0; i < n; ++i) {
      Complex value = 0.0, denominator = 1.0;
      for (double c : p) value = value * z[i] + c;
      for (size_t j = 0; j < n; ++j)
        if (j != i) denominator *= z[i] - z[j];
      z[i] -= value / denominator;
    }
  }
  return z;
}

void ExpectSameRootSet(std::vector<Complex> a, std::vector<Complex> b, double tolerance) {
  ASSERT_EQ(a.size(), b.size());
  for (const Complex& root : a) {
    auto nearest = std::min_element(b.begin(), b.end(), [&](Complex x, Complex y) {
      return std::abs(x - root) < std::abs(y - root);
    });
    EXPECT_LT(std::abs(*nearest - root), tolerance * std::max(1.0, std::abs(root)))
        << "root " << root << " nearest " << *nearest;
    b.erase(nearest);
  }
}

TEST(TransferFunction, SeedPolesMatchAnIndependentRootFinder) {
  for (const TransferFunction& tf : {SeedModel2V(), SeedModel8V()}) {
    ExpectSameRootSet(Poles(tf), DurandKernerRoots(tf.den), 1e-9);
    ExpectSameRootSet(Zeros(tf), DurandKernerRoots(tf.num), 1e-9);
    // Vieta: the sum of the poles is -b2, their product b5.
    Complex sum = 0.0, product = 1.0;
    for (const Complex& p : Poles(tf)) {
      sum += p;
      product *= p;
    }
    EXPECT_NEAR(sum.real(), -tf.den[1], 1e-10);
    EXPECT_NEAR(product.real(), tf.den[4], 1e-10);
  }
}

TEST(TransferFunction, SeedModelsHaveALightlyDampedPairAndTwoSlowRealPoles) {
  // SEED-NOTES: "a lightly damped pole pair near 15 rad/s and two slow real poles with
  // time constants of tens of seconds" (2 V model); the 8 V pair is near sqrt(367.2).
  for (const auto& [tf, pair_frequency] :
       {std::pair{SeedModel2V(), std::sqrt(225.5)}, std::pair{SeedModel8V(), std::sqrt(367.2)}}) {
    const auto modes = Modes(tf);
    ASSERT_EQ(modes.size(), 3u);
    int oscillatory = 0;
    for (const Mode& m : modes) {
      if (m.oscillatory) {
        ++oscillatory;
        EXPECT_NEAR(m.natural_frequency_rad_s, pair_frequency, 0.01 * pair_frequency);
        EXPECT_LT(m.damping_ratio, 0.02);
      } else {
        EXPECT_GT(m.time_constant_s, 10.0);
        EXPECT_LT(m.time_constant_s, 200.0);
      }
    }
    EXPECT_EQ(oscillatory, 1);
    EXPECT_TRUE(IsStable(tf));
  }
}

TEST(TransferFunction, DcGainAndFrequencyResponse) {
  const TransferFunction tf = SeedModel8V();
  EXPECT_DOUBLE_EQ(DcGain(tf), 1.97 / 0.2275);
  EXPECT_NEAR(std::abs(FrequencyResponse(tf, 0.0)), DcGain(tf), 1e-12);
  // The dead time only adds phase: |G(jw)| is unchanged, arg shifts by -w T.
  TransferFunction no_delay = tf;
  no_delay.delay_s = 0.0;
  const double w = 0.3;
  EXPECT_NEAR(std::abs(FrequencyResponse(tf, w)), std::abs(FrequencyResponse(no_delay, w)), 1e-12);
  const Complex ratio = FrequencyResponse(tf, w) / FrequencyResponse(no_delay, w);
  EXPECT_NEAR(std::arg(ratio), std::remainder(-w * tf.delay_s, 2 * std::numbers::pi), 1e-12);
}

TEST(TransferFunction, RealisationHasTheSameFrequencyResponse) {
  for (const TransferFunction& tf :
       {SeedModel2V(), SeedModel8V(), TransferFunction{{3, 1, 2}, {2, 1, 5}, 0}}) {
    const StateSpace ss = RealiseOutputDerivativeForm(tf);
    for (double w : {0.0, 0.01, 0.5, 15.0, 100.0}) {
      const Complex s(0.0, w);
      const Eigen::MatrixXcd resolvent =
          (s * Eigen::MatrixXcd::Identity(ss.A.rows(), ss.A.cols()) - ss.A.cast<Complex>())
              .inverse();
      const Complex g = (ss.C.cast<Complex>() * resolvent * ss.B.cast<Complex>())(0) + ss.D;
      TransferFunction no_delay = tf;
      no_delay.delay_s = 0.0;
      const Complex expected = FrequencyResponse(no_delay, w);
      EXPECT_LT(std::abs(g - expected), 1e-9 * std::abs(expected)) << "w = " << w;
    }
  }
}

// StepFallBack reads the step response from its partial fractions; the share at the peak
// it finds, and the time it takes to fall by 1/e, are the simulated step response's.
TEST(TransferFunction, FallBackMatchesTheSimulatedStepResponse) {
  // A slow zero (0.005 rad/s) under poles at 0.015 and 0.135 rad/s: an overshoot; and a
  // 3-zero / 4-pole model with a slow zero and a lightly damped pair.
  const TransferFunction relaxing{{1.0, 0.005}, {1.0, 0.15, 0.002}, 2.0};
  const TransferFunction seed_like{{0.001, 0.02, 0.3, 0.0015}, {1.0, 0.5, 0.3, 0.04, 0.0003}, 3.5};
  for (const TransferFunction& tf : {relaxing, seed_like}) {
    const FallBack fall = StepFallBack(tf);
    ASSERT_GT(fall.share, 0.1);
    const double K = DcGain(tf);
    const std::vector<double> y =
        StepResponse(tf, {fall.peak_time_s, fall.peak_time_s + 1.0, fall.peak_time_s + fall.tau_s});
    EXPECT_NEAR((y[0] - K) / K, fall.share, 1e-9);
    EXPECT_LE(y[1], y[0]);  // (before it may lie a fast transient, which StepFallBack leaves out)
    EXPECT_NEAR((y[2] - K) / K, fall.share / std::exp(1.0), 0.01 * fall.share);
  }
  // No overshoot: none read.
  EXPECT_EQ(StepFallBack(TransferFunction{{2.0, 0.3}, {1.0, 0.15, 0.002}, 1.0}).share, 0.0);
}

TEST(TransferFunction, FirstOrderStepResponseIsAnalytic) {
  // G = K / (tau s + 1): y(t) = K (1 - exp(-t / tau)).
  const double gain = 2.5, tau_s = 4.0;
  const TransferFunction tf{{gain}, {tau_s, 1.0}, 0.0};
  std::vector<double> t_s;
  for (int k = 0; k <= 40; ++k) t_s.push_back(0.5 * k);
  const auto y = StepResponse(tf, t_s);
  for (size_t k = 0; k < t_s.size(); ++k)
    EXPECT_NEAR(y[k], gain * (1.0 - std::exp(-t_s[k] / tau_s)), 1e-12) << "t = " << t_s[k];
}

TEST(TransferFunction, SecondOrderStepResponseIsAnalytic) {
  // G = wn^2 / (s^2 + 2 zeta wn s + wn^2), zeta < 1:
  // y(t) = 1 - exp(-zeta wn t) / sqrt(1 - zeta^2) sin(wd t + acos(zeta)).
  const double wn = 3.0, zeta = 0.2, wd = wn * std::sqrt(1 - zeta * zeta);
  const TransferFunction tf{{wn * wn}, {1.0, 2 * zeta * wn, wn * wn}, 0.0};
  std::vector<double> t_s;
  for (int k = 0; k <= 300; ++k) t_s.push_back(0.013 * k);  // not a multiple of anything nice
  const auto y = StepResponse(tf, t_s);
  for (size_t k = 0; k < t_s.size(); ++k) {
    const double t = t_s[k];
    const double expected = 1.0 - std::exp(-zeta * wn * t) / std::sqrt(1 - zeta * zeta) *
                                      std::sin(wd * t + std::acos(zeta));
    EXPECT_NEAR(y[k], expected, 1e-11) << "t = " << t;
  }
  const auto modes = Modes(tf);
  ASSERT_EQ(modes.size(), 1u);
  EXPECT_NEAR(modes[0].natural_frequency_rad_s, wn, 1e-12);
  EXPECT_NEAR(modes[0].damping_ratio, zeta, 1e-12);
  EXPECT_NEAR(modes[0].time_constant_s, 1.0 / (zeta * wn), 1e-12);
}

TEST(TransferFunction, RejectsInvalidModels) {
  std::string why;
  EXPECT_FALSE(IsValid({{1, 2, 3}, {1, 2}, 0}, &why));
  EXPECT_NE(why.find("improper"), std::string::npos);
  EXPECT_FALSE(IsValid({{1}, {0, 0}, 0}, &why));
  EXPECT_NE(why.find("zero"), std::string::npos);
  EXPECT_FALSE(IsValid({{1}, {1, 1}, -1}, &why));
  EXPECT_FALSE(IsValid({{NAN}, {1, 1}, 0}, &why));
  EXPECT_FALSE(IsValid({{1}, {}, 0}, &why));
  EXPECT_TRUE(IsValid(SeedModel8V(), &why));
}

}  // namespace
}  // namespace flexid::model
