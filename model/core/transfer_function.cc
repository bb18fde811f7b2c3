#include "model/core/transfer_function.h"

#include <cmath>
#include <limits>

#include "model/core/polynomial.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

bool AllFinite(const std::vector<double>& values) {
  for (double v : values)
    if (!std::isfinite(v)) return false;
  return true;
}

}  // namespace

bool IsValid(const TransferFunction& tf, std::string* error) {
  auto fail = [error](std::string message) {
    if (error) *error = std::move(message);
    return false;
  };
  if (tf.num.empty()) return fail("numerator has no coefficients");
  if (tf.den.empty()) return fail("denominator has no coefficients");
  if (!AllFinite(tf.num)) return fail("numerator has a non-finite coefficient");
  if (!AllFinite(tf.den)) return fail("denominator has a non-finite coefficient");
  const std::vector<double> den = TrimLeadingZeros(tf.den);
  if (den.size() == 1 && den[0] == 0.0) return fail("denominator is zero");
  const std::vector<double> num = TrimLeadingZeros(tf.num);
  if (num.size() > den.size())
    return fail("model is improper: numerator degree " + std::to_string(num.size() - 1) +
                " exceeds denominator degree " + std::to_string(den.size() - 1));
  if (!std::isfinite(tf.delay_s) || tf.delay_s < 0.0)
    return fail("delay_s must be finite and >= 0");
  return true;
}

TransferFunction Normalised(const TransferFunction& tf) {
  TransferFunction out;
  out.den = TrimLeadingZeros(tf.den);
  out.num = TrimLeadingZeros(tf.num);
  const double lead = out.den.front();
  for (double& c : out.den) c /= lead;
  for (double& c : out.num) c /= lead;
  out.delay_s = tf.delay_s;
  return out;
}

int Order(const TransferFunction& tf) {
  return static_cast<int>(TrimLeadingZeros(tf.den).size()) - 1;
}

std::vector<std::complex<double>> Poles(const TransferFunction& tf) {
  return PolynomialRoots(tf.den);
}

std::vector<std::complex<double>> Zeros(const TransferFunction& tf) {
  return PolynomialRoots(tf.num);
}

double DcGain(const TransferFunction& tf) {
  const double num0 = tf.num.back();
  const double den0 = tf.den.back();
  if (den0 == 0.0) {
    if (num0 == 0.0) return std::numeric_limits<double>::quiet_NaN();
    return std::copysign(std::numeric_limits<double>::infinity(), num0);
  }
  return num0 / den0;
}

bool IsStable(const TransferFunction& tf) {
  for (const auto& p : Poles(tf))
    if (!(p.real() < 0.0)) return false;
  return true;
}

std::vector<Mode> Modes(const TransferFunction& tf) {
  std::vector<Mode> modes;
  for (const auto& p : Poles(tf)) {
    // Scale-aware test for a real pole: companion-matrix roots of real poles carry
    // round-off imaginary parts of order eps * |p|.
    const bool real = std::abs(p.imag()) <= 1e-9 * std::max(1.0, std::abs(p));
    if (!real && p.imag() < 0.0) continue;  // the conjugate is reported
    Mode m;
    m.pole = real ? std::complex<double>(p.real(), 0.0) : p;
    m.natural_frequency_rad_s = std::abs(m.pole);
    m.damping_ratio =
        m.natural_frequency_rad_s > 0.0 ? -m.pole.real() / m.natural_frequency_rad_s : 0.0;
    m.time_constant_s =
        m.pole.real() != 0.0 ? -1.0 / m.pole.real() : std::numeric_limits<double>::infinity();
    m.oscillatory = !real;
    modes.push_back(m);
  }
  return modes;
}

std::complex<double> FrequencyResponse(const TransferFunction& tf, double omega_rad_s) {
  const std::complex<double> s(0.0, omega_rad_s);
  return EvaluatePolynomial(tf.num, s) / EvaluatePolynomial(tf.den, s) * std::exp(-s * tf.delay_s);
}

std::vector<double> StepResponse(const TransferFunction& tf, const std::vector<double>& t_s) {
  // A unit step from t = 0 held by the zero-order hold is exact for any grid, so the
  // general-grid simulator gives the exact step response (to matrix-exponential accuracy).
  std::vector<double> grid;
  grid.reserve(t_s.size() + 1);
  const bool need_origin = t_s.empty() || t_s.front() > 0.0;
  if (need_origin) grid.push_back(0.0);
  grid.insert(grid.end(), t_s.begin(), t_s.end());
  const std::vector<double> ones(grid.size(), 1.0);
  std::vector<double> y = Simulate(tf, grid, ones);
  if (need_origin) y.erase(y.begin());
  return y;
}

namespace {

// The unit step response at times t_s (all past the dead time T) from the partial
// fractions of N(s) / (s D(s)) (poles p_i distinct and stable):
//   y(t) = K + sum_i N(p_i) / (p_i D'(p_i)) exp(p_i (t - T)),
// a few exponentials a point rather than a simulation (StepFallBack is evaluated inside
// fits). Repeated or unstable poles: the simulation (StepResponse).
std::vector<double> StepResponseAfterDelay(const TransferFunction& tf, double K,
                                           const std::vector<double>& t_s) {
  const std::vector<std::complex<double>> poles = Poles(tf);
  bool distinct = true;
  for (size_t i = 0; i < poles.size(); ++i) {
    distinct &= poles[i].real() < 0.0;
    for (size_t j = 0; j < i; ++j)
      distinct &= std::abs(poles[i] - poles[j]) > 1e-4 * std::max(std::abs(poles[i]), 1e-9);
  }
  if (!distinct || poles.empty()) return StepResponse(tf, t_s);
  // D'(s), coefficients highest power first as tf.den.
  std::vector<double> derivative;
  const size_t order = tf.den.size() - 1;
  for (size_t j = 0; j < order; ++j)
    derivative.push_back(static_cast<double>(order - j) * tf.den[j]);
  std::vector<std::complex<double>> residue;
  for (const std::complex<double>& p : poles)
    residue.push_back(EvaluatePolynomial(tf.num, p) / (p * EvaluatePolynomial(derivative, p)));
  std::vector<double> y(t_s.size(), K);
  for (size_t k = 0; k < t_s.size(); ++k)
    for (size_t i = 0; i < poles.size(); ++i)
      y[k] += (residue[i] * std::exp(poles[i] * (t_s[k] - tf.delay_s))).real();
  return y;
}

}  // namespace

FallBack StepFallBack(const TransferFunction& tf) {
  FallBack result;
  const double K = DcGain(tf);
  if (!std::isfinite(K) || K == 0.0) return result;
  double fast = 2.0, slowest = 0.0;
  for (const Mode& m : Modes(tf)) {
    slowest = std::max(slowest, m.time_constant_s);
    if (m.oscillatory || m.time_constant_s < 5.0) fast = std::max(fast, m.time_constant_s);
  }
  const double begin = tf.delay_s + 5.0 * fast, end = tf.delay_s + 6.0 * std::max(slowest, fast);
  if (!(end > begin)) return result;
  std::vector<double> t;
  for (int i = 0; i <= 2000; ++i) t.push_back(begin + (end - begin) * i / 2000.0);
  const std::vector<double> s = StepResponseAfterDelay(tf, K, t);
  size_t peak = 0;
  for (size_t i = 0; i < s.size(); ++i)
    if ((s[i] - K) / K > (s[peak] - K) / K) peak = i;
  result.share = std::max(0.0, (s[peak] - K) / K);
  result.peak_time_s = t[peak];
  // Time to fall to 1/e of the excess.
  for (size_t i = peak; i < s.size(); ++i)
    if ((s[i] - K) / K <= result.share / std::exp(1.0)) {
      result.tau_s = t[i] - t[peak];
      break;
    }
  if (result.tau_s == 0.0) result.share = 0.0;  // still rising at the end: no fall-back
  return result;
}

}  // namespace flexid::model
