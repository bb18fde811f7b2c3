// Tests of the seed's physics chain (model/physics/physics.h) against truths computed here
// independently: the complex tanh from <complex>, the Mittag-Leffler series summed
// directly, closed forms of the arc geometry, and the scaling laws worked out by hand.
#include "model/physics/physics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/core/polynomial.h"
#include "model/core/transfer_function.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;
constexpr double kPi = std::numbers::pi;

double RelativeError(Complex value, Complex truth) {
  return std::abs(value - truth) / std::abs(truth);
}

// A parameter set unlike the S1 defaults, so that no test depends on the default choices.
PhysicalParameters OtherParameters() {
  PhysicalParameters p;
  p.D_m2_per_s = 2.5e-9;
  p.delta_m = 3e-5;
  p.C_dl_F = 2e-3;
  p.R_s_ohm = 120.0;
  p.alpha_m3_per_C = 2e-8;
  p.E_Pa = 3e5;
  p.L_m = 0.03;
  p.W_m = 0.006;
  p.h_m = 1.5e-3;
  return p;
}

// sqrt(D)/(delta sqrt(s)) tanh(h sqrt(s/D)) written exactly as in Eq. (11), with the
// standard library's complex functions.
Complex DirectDiffusionTerm(const PhysicalParameters& p, Complex s) {
  return std::sqrt(p.D_m2_per_s) / (p.delta_m * std::sqrt(s)) *
         std::tanh(p.h_m * std::sqrt(s / p.D_m2_per_s));
}

// The series of SEED-NOTES item 6 summed over n < M (smallest terms first), plus the
// Euler-Maclaurin estimate of the static part of the tail n >= M:
//   sum_{n>=M} (2n+1)^-2 = 1/(2(2M+1)) + 1/(2(2M+1)^2) + 1/(3(2M+1)^3) + O(M^-5).
// The tail's frequency-dependent part is ~ |s|/p_M times the tail, negligible here.
Complex SeriesDiffusionTerm(const PhysicalParameters& p, Complex s, int M) {
  const double a = 2.0 * p.D_m2_per_s / (p.h_m * p.delta_m);
  const double p_unit = kPi * kPi * p.D_m2_per_s / (4.0 * p.h_m * p.h_m);
  Complex sum = 0.0;
  for (int n = M - 1; n >= 0; --n) {
    const double odd = 2.0 * n + 1.0;
    sum += a / (s + odd * odd * p_unit);
  }
  const double m = 2.0 * M + 1.0;
  const double tail = 1.0 / (2.0 * m) + 1.0 / (2.0 * m * m) + 1.0 / (3.0 * m * m * m);
  return sum + a / p_unit * tail;
}

TEST(PhysicsSeries, MittagLefflerSeriesEqualsComplexTanh) {
  // 200000 terms plus the tail estimate. Rounding: 2e5 additions of terms smaller than the
  // running sum, at most ~2e5 * 1.1e-16 = 2e-11 relative; the neglected tail terms are far
  // smaller. Tolerance 1e-9.
  const std::vector<Complex> points = {
      {0.0, 1e-3}, {0.0, 0.05}, {0.0, 1.0},     {0.0, 10.0}, {1e-6, 0.0},
      {2.0, 0.0},  {0.05, 0.2}, {-0.003, 0.01}, {0.3, -0.7},
  };
  for (const PhysicalParameters& p : {SeedS1Parameters(), OtherParameters()}) {
    for (Complex s : points) {
      const Complex direct = DirectDiffusionTerm(p, s);
      EXPECT_LT(RelativeError(SeriesDiffusionTerm(p, s, 200000), direct), 1e-9) << "s = " << s;
      // The library's numerically safe form agrees with the direct formula to rounding.
      EXPECT_LT(RelativeError(DiffusionTerm(p, s), direct), 1e-12) << "s = " << s;
    }
  }
}

TEST(PhysicsSeries, DiffusionTermLimits) {
  const PhysicalParameters p = OtherParameters();
  const double h_over_delta = p.h_m / p.delta_m;
  // s -> 0: tanh(x)/x -> 1, Z -> h/delta (exactly at s = 0; x^2/3 ~ 1e-11 at s = 1e-14).
  EXPECT_EQ(DiffusionTerm(p, 0.0), Complex(h_over_delta, 0.0));
  EXPECT_NEAR(std::abs(DiffusionTerm(p, Complex(0.0, 1e-14)) / h_over_delta - 1.0), 0.0, 1e-9);
  // Large |s|: tanh -> 1, Z -> (h/delta)/x = sqrt(D)/(delta sqrt s); no overflow, no NaN.
  for (Complex s : {Complex(0.0, 1e8), Complex(1e12, 0.0), Complex(0.0, 1e300)}) {
    const Complex z = DiffusionTerm(p, s);
    ASSERT_TRUE(std::isfinite(z.real()) && std::isfinite(z.imag())) << "s = " << s;
    const Complex asymptote = std::sqrt(p.D_m2_per_s) / (p.delta_m * std::sqrt(s));
    EXPECT_LT(RelativeError(z, asymptote), 1e-14) << "s = " << s;
  }
}

TEST(PhysicsExact, DcValueAndHighFrequencyLimit) {
  const PhysicalParameters p = OtherParameters();
  // Independent DC value: rho = Q/(W L h), Q = C_dl (1 + h/delta) V, K = (3 alpha/h) rho.
  const double dc = 3.0 * p.alpha_m3_per_C / p.h_m * p.C_dl_F * (1.0 + p.h_m / p.delta_m) /
                    (p.W_m * p.L_m * p.h_m);
  EXPECT_NEAR(DcCurvaturePerVolt(p) / dc, 1.0, 1e-14);
  EXPECT_NEAR(std::abs(CurvaturePerVoltExact(p, 0.0) / dc - 1.0), 0.0, 1e-14);
  EXPECT_NEAR(std::abs(CurvaturePerVoltExact(p, Complex(0.0, 1e-12)) / dc - 1.0), 0.0, 1e-9);
  // Far above 1/(R_s C_dl) the cell is resistive: K/V -> phi/(W L h) / (s R_s). At
  // s = 1e6 j the neglected 1/C_eff is 1/(w R_s C_dl) ~ 4e-6 of s R_s.
  const double k = 3.0 * p.alpha_m3_per_C / (p.W_m * p.L_m * p.h_m * p.h_m);
  const Complex s(0.0, 1e6);
  EXPECT_LT(RelativeError(CurvaturePerVoltExact(p, s), k / (s * p.R_s_ohm)), 1e-5);
  const Complex huge = CurvaturePerVoltExact(p, Complex(0.0, 1e300));
  EXPECT_TRUE(std::isfinite(huge.real()) && std::isfinite(huge.imag()));
}

// Transfer-function degrees after Normalised(): trailing coefficients are kept.
int Degree(const std::vector<double>& poly) { return static_cast<int>(poly.size()) - 1; }

TEST(PhysicsTruncation, NTermModelHasNRealNegativeZerosAndNPlusOnePoles) {
  // Polynomial roots from the companion matrix: good to ~1e-9 relative up to N = 15 and
  // ~1e-6 at N = 20 = kMaxTransferFunctionTerms (physics.h), still enough for the signs and
  // the ordering of roots that are far apart.
  for (const PhysicalParameters& p : {SeedS1Parameters(), OtherParameters()}) {
    for (int terms : {1, 2, 3, 5, 8, kMaxTransferFunctionTerms}) {
      const TransferFunction tf = CurvatureTransferFunction(p, terms);
      std::string error;
      ASSERT_TRUE(IsValid(tf, &error)) << error;
      EXPECT_EQ(Degree(tf.num), terms);
      EXPECT_EQ(Degree(tf.den), terms + 1);
      EXPECT_EQ(tf.den.front(), 1.0);
      const auto poles = Poles(tf);
      const auto zeros = Zeros(tf);
      ASSERT_EQ(poles.size(), static_cast<size_t>(terms + 1));
      ASSERT_EQ(zeros.size(), static_cast<size_t>(terms));
      for (const auto& root : poles) {
        EXPECT_LT(root.real(), 0.0);
        EXPECT_LE(std::abs(root.imag()), 1e-9 * std::abs(root.real())) << "pole " << root;
      }
      for (const auto& root : zeros) {
        EXPECT_LT(root.real(), 0.0);
        EXPECT_LE(std::abs(root.imag()), 1e-9 * std::abs(root.real())) << "zero " << root;
      }
      // RC network (Foster): poles and zeros alternate along the negative real axis,
      // starting with the slowest pole. PolynomialRoots sorts by decreasing real part.
      for (int i = 0; i < terms; ++i) {
        EXPECT_GT(poles[i].real(), zeros[i].real()) << "N = " << terms << ", i = " << i;
        EXPECT_GT(zeros[i].real(), poles[i + 1].real()) << "N = " << terms << ", i = " << i;
      }
      // The slowest pole sits near -p_0, slowed by the cell loading R_s (C_0 + ...).
      EXPECT_LT(poles[0].real(), 0.0);
      EXPECT_GT(poles[0].real(), -DiffusionPole_rad_s(p, 0));
    }
  }
}

TEST(PhysicsTruncation, TransferFunctionEqualsPoleResidueForm) {
  // Both are the same rational function; the polynomial form loses a little to rounding in
  // the coefficients (products of up to N+1 factors). Tolerance 1e-9.
  const PhysicalParameters p = SeedS1Parameters();
  for (SeriesRemainder remainder :
       {SeriesRemainder::kDropped, SeriesRemainder::kStaticCorrection}) {
    for (int terms : {1, 3, 10}) {
      const TransferFunction tf = CurvatureTransferFunction(p, terms, 0.0, remainder);
      for (double w : {0.0, 1e-3, 0.05, 1.0, 10.0, 300.0}) {
        EXPECT_LT(RelativeError(FrequencyResponse(tf, w),
                                CurvaturePerVoltTruncated(p, terms, Complex(0.0, w), remainder)),
                  1e-9)
            << "N = " << terms << ", w = " << w;
      }
    }
  }
}

TEST(PhysicsTruncation, DelayAndPreconditions) {
  const PhysicalParameters p = SeedS1Parameters();
  EXPECT_EQ(CurvatureTransferFunction(p, 3, 3.67).delay_s, 3.67);
  EXPECT_THROW(CurvatureTransferFunction(p, 0), std::invalid_argument);
  EXPECT_THROW(CurvatureTransferFunction(p, kMaxTransferFunctionTerms + 1), std::invalid_argument);
  EXPECT_THROW(CurvatureTransferFunction(p, 3, -1.0), std::invalid_argument);
  EXPECT_THROW(CurvatureTransferFunction(p, 3, std::nan("")), std::invalid_argument);
  PhysicalParameters bad = p;
  bad.R_s_ohm = 0.0;
  EXPECT_THROW(CurvatureTransferFunction(bad, 3), std::invalid_argument);
  EXPECT_THROW(CurvaturePerVoltExact(bad, 0.0), std::invalid_argument);
  EXPECT_THROW(TruncationErrors(p, {3}, {-1.0}), std::invalid_argument);
  EXPECT_THROW(TruncationErrors(p, {0}, {1.0}), std::invalid_argument);
}

// Static value of the dropped terms over C_dl, from the closed form sum 1/(2n+1)^2 = pi^2/8.
double DroppedStaticPart(const PhysicalParameters& p, int terms) {
  double partial = 0.0;
  for (int n = 0; n < terms; ++n) partial += 1.0 / ((2.0 * n + 1.0) * (2.0 * n + 1.0));
  return p.h_m / p.delta_m * 8.0 / (kPi * kPi) * (kPi * kPi / 8.0 - partial);
}

TEST(PhysicsTruncation, ConvergesToExactModel) {
  // Bound. With C = C_dl(1 + Z), C_N = C_dl(1 + Z - T_N), T_N(s) = sum_{n>=N} a/(s + p_n):
  //   G_N - G = k (C_N - C) / ((1 + s R_s C_N)(1 + s R_s C)),
  // and on s = jw every term of C has Re > 0, Im < 0, so Re(s R_s C) >= 0 and
  // |1 + s R_s C_N| >= 1. Hence |G_N - G|/|G| <= |T_N(jw)|/|1 + Z(jw)| <= T_N(0)/|1 + Z(jw)|.
  // The bound is ~1/N (terms fall off as 1/n^2) and largest at the top of the grid, where
  // |1 + Z| is smallest: at N = 100 it is 0.0995 for S1, so "small at N = 100" means
  // below 10 % up to 10 rad/s (the actual maximum is about half the bound).
  const PhysicalParameters p = SeedS1Parameters();
  const std::vector<double> grid = DefaultTruncationGrid_rad_s();
  const std::vector<int> terms = {1, 3, 10, 30, 100};
  const std::vector<TruncationErrorRow> rows = TruncationErrors(p, terms, grid);
  ASSERT_EQ(rows.size(), terms.size());
  for (size_t i = 0; i < rows.size(); ++i) {
    const int n_terms = rows[i].terms;
    EXPECT_EQ(n_terms, terms[i]);
    double bound = 0.0;
    for (double w : grid)
      bound = std::max(bound, DroppedStaticPart(p, n_terms) /
                                  std::abs(1.0 + DirectDiffusionTerm(p, Complex(0.0, w))));
    EXPECT_LE(rows[i].max_relative_error, bound * (1.0 + 1e-9)) << "N = " << n_terms;
    if (i > 0) {
      EXPECT_LT(rows[i].max_relative_error, rows[i - 1].max_relative_error);
    }
    // DC: the N-term model is low by exactly the dropped static part.
    const double dc_expected = -DroppedStaticPart(p, n_terms) / (1.0 + p.h_m / p.delta_m);
    EXPECT_NEAR(rows[i].dc_relative_error / dc_expected, 1.0, 1e-9) << "N = " << n_terms;
    EXPECT_LT(rows[i].dc_truncated_per_m_V, rows[i].dc_exact_per_m_V);
    EXPECT_EQ(rows[i].dc_exact_per_m_V, DcCurvaturePerVolt(p));
    if (n_terms == 100) {
      EXPECT_LT(bound, 0.1);
    }
  }
  EXPECT_LT(rows.back().max_relative_error, 0.1);
  // Asymptotically the DC deficit is (8/pi^2)/(4N) of the diffusion part (the tail of
  // sum 1/(2n+1)^2 is 1/(4N) - 1/(48 N^3) + ...): 2/(pi^2 N) * (h/delta)/(1 + h/delta).
  const double h_over_delta = p.h_m / p.delta_m;
  EXPECT_NEAR(-rows.back().dc_relative_error /
                  (2.0 / (kPi * kPi * 100.0) * h_over_delta / (1.0 + h_over_delta)),
              1.0, 1e-4);
  // DC gain of the N-term transfer function (polynomial form) approaches the exact value.
  const double dc_exact = DcCurvaturePerVolt(p);
  double previous_gap = 1.0;
  for (int n_terms : {1, 3, 10, kMaxTransferFunctionTerms}) {
    const double gap = 1.0 - DcGain(CurvatureTransferFunction(p, n_terms)) / dc_exact;
    EXPECT_GT(gap, 0.0);
    EXPECT_LT(gap, previous_gap);
    previous_gap = gap;
  }
  EXPECT_LT(previous_gap, 2.0 / (kPi * kPi * kMaxTransferFunctionTerms) * 1.01);  // ~1 % at N = 20
}

TEST(PhysicsTruncation, StaticCorrectionMakesDcExactAndConvergesFaster) {
  const PhysicalParameters p = SeedS1Parameters();
  const double dc_exact = DcCurvaturePerVolt(p);
  for (int terms : {1, 3, 10}) {
    const TransferFunction tf =
        CurvatureTransferFunction(p, terms, 0.0, SeriesRemainder::kStaticCorrection);
    EXPECT_EQ(Degree(tf.num), terms);
    EXPECT_EQ(Degree(tf.den), terms + 1);
    for (const auto& root : Poles(tf)) EXPECT_LT(root.real(), 0.0);
    EXPECT_NEAR(DcGain(tf) / dc_exact, 1.0, 1e-12);
    EXPECT_NEAR(
        CurvaturePerVoltTruncated(p, terms, 0.0, SeriesRemainder::kStaticCorrection).real() /
            dc_exact,
        1.0, 1e-13);
  }
  // Error bound of the corrected model: C_N - C = -(T_N(jw) - T_N(0)) and
  // |T_N(jw) - T_N(0)| = |sum a jw/(p_n (jw + p_n))| <= w sum_{n>=N} a/p_n^2, so the relative
  // error is <= w a sum_{n>=N} p_n^-2 / |1 + Z(jw)| (same argument as above).
  const std::vector<double> grid = DefaultTruncationGrid_rad_s();
  const std::vector<TruncationErrorRow> rows = TruncationErrors(p, {3, 10, 30, 100}, grid);
  const double a = 2.0 * p.D_m2_per_s / (p.h_m * p.delta_m);
  for (size_t i = 0; i < rows.size(); ++i) {
    double inverse_square_sum = 0.0;  // sum_{n>=N} p_n^-2 (terms ~n^-4: 1e6 terms suffice)
    for (int n = 1000000; n >= rows[i].terms; --n) {
      const double pole = DiffusionPole_rad_s(p, n);
      inverse_square_sum += 1.0 / (pole * pole);
    }
    double bound = 0.0;
    for (double w : grid)
      bound = std::max(bound, w * a * inverse_square_sum /
                                  std::abs(1.0 + DirectDiffusionTerm(p, Complex(0.0, w))));
    EXPECT_LE(rows[i].max_relative_error_static_correction, bound * (1.0 + 1e-6));
    // From N = 3 on, the corrected model is better than Eq. (13) everywhere on the grid.
    EXPECT_LT(rows[i].max_relative_error_static_correction, rows[i].max_relative_error);
    if (i > 0) {
      EXPECT_LT(rows[i].max_relative_error_static_correction,
                rows[i - 1].max_relative_error_static_correction);
    }
  }
  EXPECT_LT(rows.back().max_relative_error_static_correction, 1e-3);
}

TEST(PhysicsArc, SmallCurvatureHalfCircleAndSymmetry) {
  const double L = 0.04;
  // Small bending: y = K L^2/2 (1 - (K L)^2/12 + ...); at K L = 4e-6 the correction is 1e-12.
  EXPECT_NEAR(TipDeflectionFromCurvature_m(1e-4, L) / (1e-4 * L * L / 2.0), 1.0, 1e-11);
  EXPECT_EQ(TipDeflectionFromCurvature_m(0.0, L), 0.0);
  // Half circle: K L = pi, the tip is a diameter 2/K away from the tangent line.
  const double K = kPi / L;
  EXPECT_NEAR(TipDeflectionFromCurvature_m(K, L) / (2.0 / K), 1.0, 1e-15);
  // Moderate bending against the textbook formula evaluated directly.
  for (double angle : {1e-3, 0.3, 1.0, 2.0, 3.0}) {
    const double curvature = angle / L;
    EXPECT_NEAR(TipDeflectionFromCurvature_m(curvature, L) / ((1.0 - std::cos(angle)) / curvature),
                1.0, angle < 0.01 ? 1e-9 : 1e-14)
        << "K L = " << angle;  // 1 - cos loses ~1e-10 to cancellation at K L = 1e-3
    EXPECT_EQ(TipDeflectionFromCurvature_m(-curvature, L),
              -TipDeflectionFromCurvature_m(curvature, L));
  }
  // Continuity where the series takes over (|K L| = 1e-4).
  const double below = TipDeflectionFromCurvature_m(1e-4 * (1.0 - 1e-9) / L, L);
  const double above = TipDeflectionFromCurvature_m(1e-4 * (1.0 + 1e-9) / L, L);
  EXPECT_NEAR(above / below, 1.0, 1e-8);
}

TEST(PhysicsArc, InverseRoundTripAndReach) {
  const double L = 0.02;
  for (double angle : {1e-9, 1e-5, 0.1, 0.296, 1.5, 2.3}) {
    const double y = TipDeflectionFromCurvature_m(angle / L, L);
    EXPECT_NEAR(CurvatureFromTipDeflection_per_m(y, L) * L / angle, 1.0, 1e-12) << angle;
    EXPECT_NEAR(CurvatureFromTipDeflection_per_m(-y, L) * L / angle, -1.0, 1e-12) << angle;
  }
  // An arc's tip is at most 0.7246 L from its tangent line (at K L = 2.3311).
  EXPECT_NO_THROW(CurvatureFromTipDeflection_per_m(0.7246 * L, L));
  EXPECT_THROW(CurvatureFromTipDeflection_per_m(0.7247 * L, L), std::invalid_argument);
  EXPECT_THROW(CurvatureFromTipDeflection_per_m(0.001, 0.0), std::invalid_argument);
}

TEST(PhysicsCalibration, RecoversAlphaUsedToGenerateADeflection) {
  for (double alpha : {3e-9, 2.9e-8}) {  // K L = 0.2 (small bending) and K L = 2.0 (large)
    PhysicalParameters p = OtherParameters();
    p.alpha_m3_per_C = alpha;
    const double deflection_mm = SteadyTipDeflection_mm(p, 3.0);
    p.alpha_m3_per_C = 123.0;  // ignored by the calibration
    EXPECT_NEAR(CalibrateAlpha(p, 3.0, deflection_mm) / alpha, 1.0, 1e-12) << deflection_mm;
  }
  const PhysicalParameters p = OtherParameters();
  EXPECT_THROW(CalibrateAlpha(p, 0.0, 1.0), std::invalid_argument);
  EXPECT_THROW(CalibrateAlpha(p, 5.0, -1.0), std::invalid_argument);
  EXPECT_THROW(CalibrateAlpha(p, 5.0, 1e3 * p.L_m), std::invalid_argument);  // unreachable
}

TEST(PhysicsSeedS1, ParametersMeetTheirStatedChoices) {
  const PhysicalParameters p = SeedS1Parameters();
  std::string error;
  ASSERT_TRUE(IsValid(p, &error)) << error;
  EXPECT_EQ(p.L_m, 0.040);
  EXPECT_EQ(p.W_m, 0.008);
  EXPECT_EQ(p.h_m, 0.002);
  // (a) slowest diffusion mode ~100 s.
  EXPECT_NEAR(SlowestDiffusionTimeConstant_s(p), 4.0 * p.h_m * p.h_m / (kPi * kPi * p.D_m2_per_s),
              1e-9);
  EXPECT_GT(SlowestDiffusionTimeConstant_s(p), 50.0);
  EXPECT_LT(SlowestDiffusionTimeConstant_s(p), 150.0);
  // (b) R_s C_dl a few seconds at most.
  EXPECT_LT(p.R_s_ohm * p.C_dl_F, 3.0);
  // The N = 3 model's slowest pole has a time constant in the seed's range (tens to ~120 s).
  const double slowest = -Poles(CurvatureTransferFunction(p, 3)).front().real();
  EXPECT_GT(1.0 / slowest, 20.0);
  EXPECT_LT(1.0 / slowest, 120.0);
  // (c) alpha is the calibration to Table 1, S1: 5.92 mm at 5 V.
  EXPECT_NEAR(SteadyTipDeflection_mm(p, 5.0), 5.92, 1e-12);
  EXPECT_NEAR(CalibrateAlpha(p, 5.0, 5.92) / p.alpha_m3_per_C, 1.0, 1e-14);
  // The value quoted in physics.h, and the small-bending estimate alpha ~ (2 y/L^2) /
  // (3 C_dl (1 + h/delta) V/(W L h^2)), which is low by about (K L)^2/12 = 0.75 %.
  EXPECT_NEAR(p.alpha_m3_per_C, 4.97e-9, 0.01e-9);
  const double small_bending_alpha = 2.0 * 5.92e-3 / (p.L_m * p.L_m) * p.W_m * p.L_m * p.h_m *
                                     p.h_m / (3.0 * p.C_dl_F * (1.0 + p.h_m / p.delta_m) * 5.0);
  EXPECT_NEAR(p.alpha_m3_per_C / small_bending_alpha, 1.0075, 0.001);
}

TEST(PhysicsTable1, PredictionsFollowTheScalingAssumption) {
  const PhysicalParameters s1 = SeedS1Parameters();
  const std::vector<Table1Row> rows = PredictTable1(s1);
  ASSERT_EQ(rows.size(), 4u);
  // Measured values: Table 1 of the seed paper.
  const double measured[] = {5.92, 8.27, 5.38, 1.83};
  for (size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(rows[i].measured_deflection_mm, measured[i]);
    EXPECT_NEAR(rows[i].measured_ratio_to_s1, measured[i] / 5.92, 1e-15);
  }
  EXPECT_EQ(rows[0].name, "S1");
  EXPECT_NEAR(rows[0].predicted_deflection_mm, 5.92, 1e-12);
  EXPECT_EQ(rows[0].predicted_ratio_to_s1, 1.0);

  // By hand: with C_dl = c W L, K = 3 alpha c (1 + h/delta) V / h^2, so relative to S1
  //   K_i / K_1 = (h_1/h_i)^2 (1 + h_i/delta)/(1 + h_1/delta),
  // independent of W and L, and y_i = (1 - cos K_i L_i)/K_i.
  const double K1 = rows[0].predicted_curvature_per_m;
  const double y1 = (1.0 - std::cos(K1 * 0.040)) / K1;
  const struct {
    double L_m, h_m;
  } geometry[] = {{0.040, 0.002}, {0.040, 0.001}, {0.040, 0.002}, {0.020, 0.002}};
  for (size_t i = 0; i < 4; ++i) {
    const double Ki = K1 * (0.002 / geometry[i].h_m) * (0.002 / geometry[i].h_m) *
                      (1.0 + geometry[i].h_m / s1.delta_m) / (1.0 + 0.002 / s1.delta_m);
    const double yi = (1.0 - std::cos(Ki * geometry[i].L_m)) / Ki;
    EXPECT_NEAR(rows[i].predicted_curvature_per_m / Ki, 1.0, 1e-12) << rows[i].name;
    EXPECT_NEAR(rows[i].predicted_ratio_to_s1 / (yi / y1), 1.0, 1e-9) << rows[i].name;
  }
  // Width has no effect at any voltage (S3 has half the width of S1).
  EXPECT_NEAR(rows[2].predicted_ratio_to_s1, 1.0, 1e-14);

  // Small-bending limit (1 mV: K L ~ 6e-5): y = K L^2/2, so the length ratio S1/S4 -> 4 and
  // the thickness ratio S2/S1 -> K_2/K_1 = 4 (1 + 1000)/(1 + 2000).
  const std::vector<Table1Row> small = PredictTable1(s1, 1e-3);
  EXPECT_NEAR(small[3].predicted_ratio_to_s1, 0.25, 1e-9);
  EXPECT_NEAR(small[1].predicted_ratio_to_s1, 4.0 * 1001.0 / 2001.0, 1e-8);
  EXPECT_NEAR(small[2].predicted_ratio_to_s1, 1.0, 1e-14);
  EXPECT_THROW(PredictTable1(s1, 0.0), std::invalid_argument);
}

TEST(PhysicsGeometry, WithGeometryScalesOnlyTheCapacitance) {
  const PhysicalParameters reference = OtherParameters();
  const PhysicalParameters p = WithGeometry(reference, 0.06, 0.003, 0.5e-3);
  EXPECT_NEAR(p.C_dl_F / reference.C_dl_F, (0.06 * 0.003) / (0.03 * 0.006), 1e-15);
  EXPECT_EQ(p.R_s_ohm, reference.R_s_ohm);
  EXPECT_EQ(p.D_m2_per_s, reference.D_m2_per_s);
  EXPECT_EQ(p.delta_m, reference.delta_m);
  EXPECT_EQ(p.alpha_m3_per_C, reference.alpha_m3_per_C);
  EXPECT_EQ(p.E_Pa, reference.E_Pa);
  EXPECT_EQ(p.L_m, 0.06);
  EXPECT_EQ(p.W_m, 0.003);
  EXPECT_EQ(p.h_m, 0.5e-3);
  EXPECT_THROW(WithGeometry(reference, 0.0, 0.003, 0.001), std::invalid_argument);
}

TEST(PhysicsParameters, InvalidParametersAreNamed) {
  std::string error;
  EXPECT_TRUE(IsValid(OtherParameters(), &error));
  EXPECT_TRUE(IsValid(OtherParameters(), nullptr));
  const struct {
    const char* name;
    double PhysicalParameters::*member;
  } fields[] = {
      {"D_m2_per_s", &PhysicalParameters::D_m2_per_s},
      {"delta_m", &PhysicalParameters::delta_m},
      {"C_dl_F", &PhysicalParameters::C_dl_F},
      {"R_s_ohm", &PhysicalParameters::R_s_ohm},
      {"alpha_m3_per_C", &PhysicalParameters::alpha_m3_per_C},
      {"E_Pa", &PhysicalParameters::E_Pa},
      {"L_m", &PhysicalParameters::L_m},
      {"W_m", &PhysicalParameters::W_m},
      {"h_m", &PhysicalParameters::h_m},
  };
  for (const auto& field : fields) {
    for (double bad : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
      PhysicalParameters p = OtherParameters();
      p.*field.member = bad;
      error.clear();
      EXPECT_FALSE(IsValid(p, &error)) << field.name << " = " << bad;
      EXPECT_NE(error.find(field.name), std::string::npos) << error;
      EXPECT_FALSE(IsValid(p, nullptr));
    }
  }
  EXPECT_FALSE(IsValid(PhysicalParameters{}, &error));
}

TEST(PhysicsTruncation, DefaultGridIsLogSpaced) {
  const std::vector<double> grid = DefaultTruncationGrid_rad_s(6);
  ASSERT_EQ(grid.size(), 6u);
  for (size_t i = 0; i < grid.size(); ++i)
    EXPECT_NEAR(grid[i] / std::pow(10.0, -4.0 + static_cast<double>(i)), 1.0, 1e-14);
  EXPECT_THROW(DefaultTruncationGrid_rad_s(1), std::invalid_argument);
}

// ---- Step response (Talbot inversion of Eq. 11) ----

TEST(PhysicsStep, MatchesTheDiffusionSeriesWhenTheCellResistanceIsNegligible) {
  // With R_s -> 0 the stored charge after a step is, term by term of the series of
  // SEED-NOTES item 6, Q(t)/V = C_dl [1 + h/delta - sum_n (a/p_n) e^{-p_n t}] (sum a/p_n =
  // h/delta), and K = 3 alpha Q/(W L h^2). The sum converges fast for t > 0.
  PhysicalParameters p = OtherParameters();
  p.R_s_ohm = 1e-9;  // R_s C_dl = 2e-12 s
  const double a = 2.0 * p.D_m2_per_s / (p.h_m * p.delta_m);
  const double tau_s = SlowestDiffusionTimeConstant_s(p);  // 365 s
  for (double t_s : {1e-3 * tau_s, 0.01 * tau_s, 0.1 * tau_s, tau_s, 5.0 * tau_s}) {
    double transient = 0.0;
    for (int n = 200000; n >= 0; --n) {
      const double odd = 2.0 * n + 1.0;
      const double p_n = odd * odd * kPi * kPi * p.D_m2_per_s / (4.0 * p.h_m * p.h_m);
      transient += a / p_n * std::exp(-p_n * t_s);
    }
    const double truth = CurvaturePerCharge_per_m_C(p) * p.C_dl_F *
                         (1.0 + p.h_m / p.delta_m - transient) * 2.0;  // 2 V
    // Observed agreement ~1e-11; the fixed Talbot rule with 24 nodes promises ~1e-9.
    EXPECT_NEAR(StepCurvature_per_m(p, 2.0, t_s) / truth, 1.0, 1e-8) << t_s;
  }
}

TEST(PhysicsStep, IsAnRcChargeWhenTheGelStoresNothing) {
  // delta >> h: Z(s) = (h/delta) tanh(x)/x <= 1.5e-6, so C_eff = C_dl to that accuracy and
  // the cell is R_s in series with C_dl: K(t) = 3 alpha C_dl V (1 - e^{-t/(R_s C_dl)})/(W L h^2).
  PhysicalParameters p = OtherParameters();
  p.delta_m = 1e3;
  const double rc_s = p.R_s_ohm * p.C_dl_F;  // 0.24 s
  for (double t_s : {0.2 * rc_s, rc_s, 4.0 * rc_s}) {
    const double truth =
        CurvaturePerCharge_per_m_C(p) * p.C_dl_F * 3.0 * (1.0 - std::exp(-t_s / rc_s));
    EXPECT_NEAR(StepCurvature_per_m(p, 3.0, t_s) / truth, 1.0, 1e-6) << t_s;
  }
}

TEST(PhysicsStep, RisesMonotonicallyToTheDcCurvature) {
  const PhysicalParameters p = SeedS1Parameters();
  const double tau_s = SlowestDiffusionTimeConstant_s(p);
  double previous = 0.0;
  for (double t_s = 1e-3; t_s < 30.0 * tau_s; t_s *= 1.5) {
    const double K = StepCurvature_per_m(p, 5.0, t_s);
    EXPECT_GT(K, previous) << t_s;
    previous = K;
  }
  EXPECT_NEAR(StepCurvature_per_m(p, 5.0, 30.0 * tau_s) / (DcCurvaturePerVolt(p) * 5.0), 1.0, 1e-9);
  EXPECT_NEAR(StepCurvature_per_m(p, -5.0, tau_s), -StepCurvature_per_m(p, 5.0, tau_s), 1e-15);
  EXPECT_THROW(StepCurvature_per_m(p, 5.0, 0.0), std::invalid_argument);
  EXPECT_THROW(StepCurvature_per_m(p, 5.0, -1.0), std::invalid_argument);
  EXPECT_THROW(StepCurvature_per_m(p, std::nan(""), 1.0), std::invalid_argument);
  EXPECT_THROW(StepCurvature_per_m(PhysicalParameters{}, 5.0, 1.0), std::invalid_argument);
}

TEST(PhysicsTable1, AfterHoldTendsToSteadyAndToChargeLimitedScalingForShortHolds) {
  const PhysicalParameters s1 = SeedS1Parameters();
  const std::vector<Table1Row> steady = PredictTable1(s1);
  const std::vector<Table1Row> long_hold =
      PredictTable1AfterHold(s1, 100.0 * SlowestDiffusionTimeConstant_s(s1));
  ASSERT_EQ(long_hold.size(), steady.size());
  for (size_t i = 0; i < steady.size(); ++i) {
    EXPECT_NEAR(long_hold[i].predicted_deflection_mm / steady[i].predicted_deflection_mm, 1.0,
                1e-9);
    EXPECT_EQ(long_hold[i].measured_deflection_mm, steady[i].measured_deflection_mm);
  }
  // By hand, for K L << 1 (so y = K L^2/2):
  // t = 1 s << h^2/D (100 s) but sqrt(D t) = 0.13 mm << h: S1 and S2 (same face) have stored
  // the same charge in a surface layer, so K ~ 1/h^2 and the thickness exponent is -2.
  const std::vector<Table1Scaling> one_second =
      AnalyseTable1Scaling(PredictTable1AfterHold(s1, 1.0));
  ASSERT_EQ(one_second.size(), 3u);
  EXPECT_EQ(one_second[0].dimension, BeamDimension::kThickness);
  EXPECT_NEAR(one_second[0].predicted_exponent, -2.0, 1e-3);
  // t = 1e-5 s << R_s C_dl (3.2 ms): every beam has drawn the same charge V t / R_s through
  // the cell, so K ~ 1/(W L h^2): exponents -2 (h), -1 (W) and 2 - 1 = 1 (L), up to
  // t/(2 R_s C_dl) ~ 0.3 %.
  const std::vector<Table1Scaling> cell_limited =
      AnalyseTable1Scaling(PredictTable1AfterHold(s1, 1e-5));
  ASSERT_EQ(cell_limited.size(), 3u);
  EXPECT_NEAR(cell_limited[0].predicted_exponent, -2.0, 1e-3);
  EXPECT_EQ(cell_limited[1].dimension, BeamDimension::kWidth);
  EXPECT_NEAR(cell_limited[1].predicted_exponent, -1.0, 0.01);
  EXPECT_EQ(cell_limited[2].dimension, BeamDimension::kLength);
  EXPECT_NEAR(cell_limited[2].predicted_exponent, 1.0, 0.01);
  EXPECT_THROW(PredictTable1AfterHold(s1, 0.0), std::invalid_argument);
}

// ---- Power laws and the Table 1 scaling analysis ----

TEST(PhysicsScaling, PowerLawExponentOfSyntheticPowerLaws) {
  EXPECT_NEAR(PowerLawExponent(3.0 * std::pow(2.0, 1.5), 3.0 * std::pow(5.0, 1.5), 2.0, 5.0), 1.5,
              1e-14);
  EXPECT_NEAR(PowerLawExponent(4.0, 1.0, 1.0, 2.0), -2.0, 1e-15);
  EXPECT_NEAR(PowerLawExponent(1.0, 4.0, 2.0, 1.0), -2.0, 1e-15);  // order of the points
  EXPECT_EQ(PowerLawExponent(7.0, 7.0, 1.0, 3.0), 0.0);
  EXPECT_THROW(PowerLawExponent(1.0, 2.0, 3.0, 3.0), std::invalid_argument);
  EXPECT_THROW(PowerLawExponent(0.0, 2.0, 1.0, 3.0), std::invalid_argument);
  EXPECT_THROW(PowerLawExponent(1.0, std::nan(""), 1.0, 3.0), std::invalid_argument);
}

TEST(PhysicsScaling, ExponentRangeEvaluatesTheRatioAtTheEnds) {
  // y from 4 to 2 as x doubles, each y +- 0.1: by hand the ends are ln(2.1/3.9)/ln 2 and
  // ln(1.9/4.1)/ln 2.
  const ExponentRange range = PowerLawExponentRange(4.0, 2.0, 1.0, 2.0, 0.1);
  EXPECT_NEAR(range.low, std::log(1.9 / 4.1) / std::log(2.0), 1e-15);
  EXPECT_NEAR(range.high, std::log(2.1 / 3.9) / std::log(2.0), 1e-15);
  // x decreasing: ln(x_b/x_a) < 0 swaps which end is low.
  const ExponentRange swapped = PowerLawExponentRange(2.0, 4.0, 2.0, 1.0, 0.1);
  EXPECT_NEAR(swapped.low, std::log(4.1 / 1.9) / std::log(0.5), 1e-15);
  EXPECT_NEAR(swapped.high, std::log(3.9 / 2.1) / std::log(0.5), 1e-15);
  const ExponentRange exact = PowerLawExponentRange(4.0, 2.0, 1.0, 2.0, 0.0);
  EXPECT_EQ(exact.low, -1.0);
  EXPECT_EQ(exact.high, -1.0);
  EXPECT_THROW(PowerLawExponentRange(4.0, 2.0, 1.0, 2.0, 2.0), std::invalid_argument);
  EXPECT_THROW(PowerLawExponentRange(4.0, 2.0, 1.0, 2.0, -0.1), std::invalid_argument);
}

Table1Row SyntheticRow(std::string name, double L_mm, double W_mm, double h_mm, double predicted_mm,
                       double measured_mm) {
  Table1Row row;
  row.name = std::move(name);
  row.L_mm = L_mm;
  row.W_mm = W_mm;
  row.h_mm = h_mm;
  row.predicted_deflection_mm = predicted_mm;
  row.measured_deflection_mm = measured_mm;
  return row;
}

TEST(PhysicsScaling, AnalyseTable1ScalingOnSyntheticRows) {
  const std::vector<Table1Row> rows = {
      SyntheticRow("R", 10.0, 5.0, 1.0, 2.0, 2.0),
      SyntheticRow("H", 10.0, 5.0, 2.0, 1.0, 1.5),     // thickness only
      SyntheticRow("LW", 20.0, 10.0, 1.0, 8.0, 8.0),   // two dimensions: skipped
      SyntheticRow("W", 10.0, 2.5, 1.0, 2.0, 2.004),   // width only, within reading
      SyntheticRow("same", 10.0, 5.0, 1.0, 2.0, 2.0),  // none: skipped
  };
  const std::vector<Table1Scaling> scaling = AnalyseTable1Scaling(rows, 0.005);
  ASSERT_EQ(scaling.size(), 2u);

  const Table1Scaling& h = scaling[0];
  EXPECT_EQ(h.dimension, BeamDimension::kThickness);
  EXPECT_EQ(h.reference_name, "R");
  EXPECT_EQ(h.varied_name, "H");
  EXPECT_EQ(h.reference_mm, 1.0);
  EXPECT_EQ(h.varied_mm, 2.0);
  EXPECT_NEAR(h.predicted_ratio, 0.5, 1e-15);
  EXPECT_NEAR(h.measured_ratio, 0.75, 1e-15);
  EXPECT_NEAR(h.predicted_exponent, -1.0, 1e-15);
  EXPECT_NEAR(h.measured_exponent, std::log(0.75) / std::log(2.0), 1e-15);  // -0.415
  const double h_low = std::log(1.495 / 2.005) / std::log(2.0);
  const double h_high = std::log(1.505 / 1.995) / std::log(2.0);
  EXPECT_NEAR(h.measured_exponent_range.low, h_low, 1e-15);
  EXPECT_NEAR(h.measured_exponent_range.high, h_high, 1e-15);
  EXPECT_NEAR(h.exponent_uncertainty,
              std::max(h.measured_exponent - h_low, h_high - h.measured_exponent), 1e-15);
  EXPECT_NEAR(h.departure, std::log(0.75) / std::log(2.0) + 1.0, 1e-15);
  EXPECT_TRUE(h.departs);

  // 2.004 vs 2.0 read to +-0.005: the range ln((2.004 -+ 0.005)/(2.0 +- 0.005))/ln(0.5)
  // contains the predicted 0, so no departure.
  const Table1Scaling& w = scaling[1];
  EXPECT_EQ(w.dimension, BeamDimension::kWidth);
  EXPECT_EQ(w.varied_name, "W");
  EXPECT_EQ(w.predicted_exponent, 0.0);
  EXPECT_NEAR(w.measured_exponent, std::log(1.002) / std::log(0.5), 1e-15);
  EXPECT_LT(w.measured_exponent_range.low, 0.0);
  EXPECT_GT(w.measured_exponent_range.high, 0.0);
  EXPECT_FALSE(w.departs);

  EXPECT_TRUE(AnalyseTable1Scaling({}).empty());
  EXPECT_THROW(AnalyseTable1Scaling(rows, 1.5), std::invalid_argument);  // not below H's 1.5
  EXPECT_EQ(Name(BeamDimension::kLength), "length");
  EXPECT_EQ(Name(BeamDimension::kWidth), "width");
  EXPECT_EQ(Name(BeamDimension::kThickness), "thickness");
}

TEST(PhysicsScaling, SeedTable1DepartsInEveryDimensionBeyondReadingPrecision) {
  const std::vector<Table1Row> rows = PredictTable1(SeedS1Parameters());
  const std::vector<Table1Scaling> scaling = AnalyseTable1Scaling(rows);
  ASSERT_EQ(scaling.size(), 3u);
  // Hand calculation from the paper's numbers (S1 40/8/2 5.92, S2 h = 1 8.27, S3 W = 4 5.38,
  // S4 L = 20 1.83), each deflection +-0.005 mm.
  const struct {
    BeamDimension dimension;
    const char* varied;
    size_t row;
    double x_ratio, measured_mm;
  } expected[] = {{BeamDimension::kThickness, "S2", 1, 0.5, 8.27},
                  {BeamDimension::kWidth, "S3", 2, 0.5, 5.38},
                  {BeamDimension::kLength, "S4", 3, 0.5, 1.83}};
  for (size_t i = 0; i < 3; ++i) {
    const Table1Scaling& s = scaling[i];
    const auto& e = expected[i];
    EXPECT_EQ(s.dimension, e.dimension);
    EXPECT_EQ(s.reference_name, "S1");
    EXPECT_EQ(s.varied_name, e.varied);
    const double ln_x = std::log(e.x_ratio);
    EXPECT_NEAR(s.measured_exponent, std::log(e.measured_mm / 5.92) / ln_x, 1e-14);
    EXPECT_NEAR(
        s.predicted_exponent,
        std::log(rows[e.row].predicted_deflection_mm / rows[0].predicted_deflection_mm) / ln_x,
        1e-14);
    const double one = std::log((e.measured_mm + 0.005) / (5.92 - 0.005)) / ln_x;
    const double other = std::log((e.measured_mm - 0.005) / (5.92 + 0.005)) / ln_x;
    EXPECT_NEAR(
        s.exponent_uncertainty,
        std::max(std::abs(one - s.measured_exponent), std::abs(other - s.measured_exponent)),
        1e-14);
    EXPECT_TRUE(s.departs) << Name(s.dimension);
  }
  // The sizes quoted in the report: thickness -0.48 vs -0.97 (+-0.002), width 0.14 vs 0
  // (+-0.003), length 1.69 vs 1.99 (+-0.005).
  EXPECT_NEAR(scaling[0].measured_exponent, -0.482, 0.001);
  EXPECT_NEAR(scaling[0].predicted_exponent, -0.969, 0.001);
  EXPECT_LT(scaling[0].exponent_uncertainty, 0.0025);
  EXPECT_NEAR(scaling[1].measured_exponent, 0.138, 0.001);
  EXPECT_NEAR(scaling[2].measured_exponent, 1.694, 0.001);
  EXPECT_NEAR(scaling[2].predicted_exponent, 1.992, 0.001);
  EXPECT_LT(scaling[2].exponent_uncertainty, 0.006);
}

}  // namespace
}  // namespace flexid::model
