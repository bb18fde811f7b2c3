// The frequency-response route's parts (internal to frequency_response.cc,
// frequency_points.cc and frequency_rational.cc): the shared constants and number format,
// and the rational fit with dead time to frequency points (FitData: the points in the
// scaled variable; Levy + Sanathanan-Koerner at a fixed delay; Levenberg-Marquardt:
// frequency_rational.cc). The maths is in frequency_response.h.
#pragma once

#include <Eigen/Dense>
#include <complex>
#include <limits>
#include <numbers>
#include <string>
#include <vector>

namespace flexid::model::frequency_fit {

using Complex = std::complex<double>;
inline constexpr double kPi = std::numbers::pi;
inline constexpr double kInf = std::numeric_limits<double>::infinity();
inline constexpr double kZ975 = 1.959963984540054;  // standard normal 97.5 % quantile

// value with `digits` significant digits.
std::string Format(double value, int digits = 4);

// -----------------------------------------------------------------------------------------
// Rational fit helpers. Polynomials here are Eigen vectors in ASCENDING powers of the
// scaled variable s' = s / omega_ref; the denominator is monic (a[n] = 1).
// -----------------------------------------------------------------------------------------

struct FitData {
  int m = 0, n = 0;
  std::vector<double> omega;  // rad/s
  std::vector<Complex> g;     // measured G(j omega_k)
  std::vector<double> var;    // E|G_k - G|^2 (= 2 s_k^2)
  std::vector<Complex> s;     // j omega_k / omega_ref
  double omega_ref = 1.0;
};

struct Rational {
  Eigen::VectorXd b;  // m + 1
  Eigen::VectorXd a;  // n + 1, a[n] = 1
};

struct DelayFit {
  Rational rational;
  double chi2 = kInf;
  int iterations = 0;
  int reflected = 0;
};

// Levy + Sanathanan-Koerner for a fixed delay (header, step 2).
DelayFit FitAtDelay(const FitData& d, double delay_s, int sk_iterations);

// Parameter vector theta for Levenberg-Marquardt: b_0..b_m, a_0..a_{n-1}, then delay_s
// when the delay is free. A fixed delay (the profile over the grid) is not in theta.
struct DelaySetting {
  bool free = false;
  double fixed_s = 0.0;  // used when !free
  double max_s = 0.0;    // range [0, max_s] when free
};

Rational Unpack(const FitData& d, const Eigen::VectorXd& theta);

// Residuals rho (2K) and Jacobian J (2K x p) of the normalised errors
// (G_model - G_k) / s_k, real and imaginary parts:
//   dG/db_i = s^i / A e^{-j w T},  dG/da_i = -B s^i / A^2 e^{-j w T},  dG/dT = -j w G.
void Residuals(const FitData& d, const Eigen::VectorXd& theta, const DelaySetting& delay_setting,
               Eigen::VectorXd* rho, Eigen::MatrixXd* jacobian);

// Levenberg-Marquardt with Marquardt's diagonal scaling; steps that would leave the delay
// range or make the denominator unstable are rejected like steps that raise the cost.
int LevenbergMarquardt(const FitData& d, const DelaySetting& delay_setting, int max_iterations,
                       Eigen::VectorXd* theta, double* final_cost);

}  // namespace flexid::model::frequency_fit
