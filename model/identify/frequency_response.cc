#include "model/identify/frequency_response.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numbers>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/polynomial.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;
constexpr double kPi = std::numbers::pi;
constexpr double kInf = std::numeric_limits<double>::infinity();

constexpr int kTrendDegree = 4;                   // trend: Legendre polynomials up to degree 4 ...
constexpr int kTrendPartsPerPeriod = 4;           // ... fitted to the means of quarter periods
constexpr double kMinHarmonicRatio = 0.01;        // |U_h| / |U_1| below this: not excited
constexpr double kMaxNyquistFraction = 0.8;       // omega_h <= 0.8 pi / dt
constexpr int kMaxNoiseBinOffset = 12;            // noise bins at most 12 bins from the line
constexpr double kZ975 = 1.959963984540054;       // standard normal 97.5 % quantile
constexpr double kChi2One95 = 3.841458820694124;  // chi^2_1 95 % quantile
constexpr double kCompetingChi2 = 9.0;  // a competing delay valley: Delta chi^2 <= 9 (3 sigma)

std::string Format(double value, int digits = 4) {
  char text[64];
  std::snprintf(text, sizeof text, "%.*g", digits, value);
  return text;
}

// Student-t 97.5 % quantile for nu degrees of freedom (Cornish-Fisher expansion about the
// normal quantile; better than 1e-3 for nu >= 4, which every caller has).
double StudentT975(double nu) {
  const double z = kZ975, z3 = z * z * z, z5 = z3 * z * z, z7 = z5 * z * z;
  return z + (z3 + z) / (4.0 * nu) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * nu * nu) +
         (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * nu * nu * nu);
}

// F_{2,nu} 95 % quantile, closed form: P(F <= x) = 1 - (1 + 2 x / nu)^{-nu / 2}.
double F2Quantile95(double nu) { return 0.5 * nu * (std::pow(0.05, -2.0 / nu) - 1.0); }

void CheckSegment(const DataSegment& segment) {
  if (!(segment.dt_s > 0.0) || !std::isfinite(segment.dt_s))
    throw InputError("sample period must be finite and > 0, got " + Format(segment.dt_s));
  if (segment.voltage_V.size() != segment.deflection_mm.size())
    throw InputError("voltage and deflection differ in length (" +
                     std::to_string(segment.voltage_V.size()) + " vs " +
                     std::to_string(segment.deflection_mm.size()) + ")");
  if (segment.voltage_V.size() < 10)
    throw InputError("recording too short: " + std::to_string(segment.voltage_V.size()) +
                     " samples");
  for (size_t k = 0; k < segment.voltage_V.size(); ++k)
    if (!std::isfinite(segment.voltage_V[k]) || !std::isfinite(segment.deflection_mm[k]))
      throw InputError("non-finite value at sample " + std::to_string(k));
}

// Legendre polynomials P_0..P_degree at x in [-1, 1] (Bonnet's recursion), written to
// out[0], out[stride], ... (a row of a column-major matrix).
void Legendre(double x, int degree, double* out, Eigen::Index stride) {
  auto at = [out, stride](int d) -> double& { return out[d * stride]; };
  at(0) = 1.0;
  if (degree >= 1) at(1) = x;
  for (int d = 2; d <= degree; ++d)
    at(d) = ((2.0 * d - 1.0) * x * at(d - 1) - (d - 1.0) * at(d - 2)) / d;
}

// sum_i r_i e^{-j omega dt i} for both columns of r at once. The phasor is advanced by
// multiplication and reset exactly every 256 samples, so rounding cannot accumulate.
std::pair<Complex, Complex> Dtft(const Eigen::MatrixXd& r, double omega_dt) {
  const Complex step = std::polar(1.0, -omega_dt);
  Complex phasor = 1.0, sum0 = 0.0, sum1 = 0.0;
  for (Eigen::Index i = 0; i < r.rows(); ++i) {
    if (i % 256 == 0) phasor = std::polar(1.0, -omega_dt * static_cast<double>(i));
    sum0 += r(i, 0) * phasor;
    sum1 += r(i, 1) * phasor;
    phasor *= step;
  }
  return {sum0, sum1};
}

// -----------------------------------------------------------------------------------------
// Rational fit helpers. Polynomials here are Eigen vectors in ASCENDING powers of the
// scaled variable s' = s / omega_ref; the denominator is monic (a[n] = 1).
// -----------------------------------------------------------------------------------------

Complex Horner(const Eigen::VectorXd& ascending, Complex s) {
  Complex value = 0.0;
  for (Eigen::Index i = ascending.size() - 1; i >= 0; --i) value = value * s + ascending(i);
  return value;
}

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

std::vector<Complex> RootsOf(const Eigen::VectorXd& ascending) {
  std::vector<double> descending(static_cast<size_t>(ascending.size()));
  for (size_t i = 0; i < descending.size(); ++i)
    descending[i] = ascending(ascending.size() - 1 - static_cast<Eigen::Index>(i));
  return PolynomialRoots(descending);
}

bool StableDenominator(const Eigen::VectorXd& a) {
  for (const Complex& p : RootsOf(a))
    if (!(p.real() < 0.0)) return false;
  return true;
}

// Reflects roots with Re >= 0 into the left half-plane (p -> -conj p; a root on the
// imaginary axis moves to Re = -1e-9 omega_ref). |A(j omega)| is unchanged by the
// reflection, so the fit's magnitude is kept and only the phase changes.
Eigen::VectorXd Stabilised(const Eigen::VectorXd& a, int* reflected) {
  std::vector<Complex> roots = RootsOf(a);
  int count = 0;
  for (Complex& p : roots)
    if (!(p.real() < 0.0)) {
      p = Complex(-std::max(std::abs(p.real()), 1e-9), p.imag());
      ++count;
    }
  if (reflected) *reflected += count;
  if (count == 0) return a;
  const std::vector<double> descending = PolynomialFromRoots(roots);
  Eigen::VectorXd out(a.size());
  for (Eigen::Index i = 0; i < out.size(); ++i)
    out(i) = descending[static_cast<size_t>(out.size() - 1 - i)];
  return out;
}

// Least squares with columns scaled to unit norm (the powers of s' span decades) and a
// complete orthogonal decomposition (minimum-norm solution if the columns are dependent).
Eigen::VectorXd SolveScaled(Eigen::MatrixXd m, const Eigen::VectorXd& rhs) {
  Eigen::VectorXd scale(m.cols());
  for (Eigen::Index j = 0; j < m.cols(); ++j) {
    const double norm = m.col(j).norm();
    scale(j) = norm > 0.0 ? 1.0 / norm : 1.0;
    m.col(j) *= scale(j);
  }
  Eigen::VectorXd x = m.completeOrthogonalDecomposition().solve(rhs);
  return x.cwiseProduct(scale);
}

// Numerator for a fixed denominator: min sum_k |B(s_k) / A(s_k) - h_k|^2 / var_k, linear in b.
Eigen::VectorXd RefitNumerator(const FitData& d, const std::vector<Complex>& h,
                               const Eigen::VectorXd& a) {
  const size_t points = d.g.size();
  Eigen::MatrixXd m(2 * points, d.m + 1);
  Eigen::VectorXd rhs(2 * points);
  for (size_t k = 0; k < points; ++k) {
    const double w = 1.0 / std::sqrt(d.var[k]);
    const Complex inv_a = 1.0 / Horner(a, d.s[k]);
    Complex power = 1.0;
    for (int i = 0; i <= d.m; ++i, power *= d.s[k]) {
      const Complex c = w * power * inv_a;
      m(2 * k, i) = c.real();
      m(2 * k + 1, i) = c.imag();
    }
    rhs(2 * k) = w * h[k].real();
    rhs(2 * k + 1) = w * h[k].imag();
  }
  return SolveScaled(m, rhs);
}

// chi^2 = 2 sum_k |G_model(j omega_k) - G_k|^2 / var_k: the sum of squares of the real and
// imaginary residuals, each divided by its standard deviation s_k = sqrt(var_k / 2).
double ChiSquared(const FitData& d, const Rational& r, double delay_s) {
  double sum = 0.0;
  for (size_t k = 0; k < d.g.size(); ++k) {
    const Complex model =
        Horner(r.b, d.s[k]) / Horner(r.a, d.s[k]) * std::polar(1.0, -d.omega[k] * delay_s);
    sum += std::norm(model - d.g[k]) / d.var[k];
  }
  return 2.0 * sum;
}

struct DelayFit {
  Rational rational;
  double chi2 = kInf;
  int iterations = 0;
  int reflected = 0;
};

// Levy + Sanathanan-Koerner for a fixed delay (header, step 2).
DelayFit FitAtDelay(const FitData& d, double delay_s, int sk_iterations) {
  const size_t points = d.g.size();
  std::vector<Complex> h(points);
  for (size_t k = 0; k < points; ++k) h[k] = d.g[k] * std::polar(1.0, d.omega[k] * delay_s);

  DelayFit fit;
  Eigen::VectorXd a = Eigen::VectorXd::Zero(d.n + 1);
  a(d.n) = 1.0;
  std::vector<double> sk_weight(points, 1.0);  // 1 / |A_{i-1}(s_k)|^2; 1 for Levy's step
  const int unknowns = d.m + 1 + d.n;
  for (int iteration = 0; iteration < sk_iterations; ++iteration) {
    // Rows: sqrt(w_k) [B(s_k) - h_k (A(s_k) - s_k^n)] = sqrt(w_k) h_k s_k^n, real and
    // imaginary parts, unknowns b_0..b_m, a_0..a_{n-1}.
    Eigen::MatrixXd m(2 * points, unknowns);
    Eigen::VectorXd rhs(2 * points);
    for (size_t k = 0; k < points; ++k) {
      const double w = std::sqrt(sk_weight[k] / d.var[k]);
      Complex power = 1.0;
      for (int i = 0; i <= std::max(d.m, d.n); ++i, power *= d.s[k]) {
        if (i <= d.m) {
          m(2 * k, i) = w * power.real();
          m(2 * k + 1, i) = w * power.imag();
        }
        if (i < d.n) {
          const Complex c = -w * h[k] * power;
          m(2 * k, d.m + 1 + i) = c.real();
          m(2 * k + 1, d.m + 1 + i) = c.imag();
        }
        if (i == d.n) {
          const Complex c = w * h[k] * power;
          rhs(2 * k) = c.real();
          rhs(2 * k + 1) = c.imag();
        }
      }
    }
    const Eigen::VectorXd x = SolveScaled(m, rhs);
    Eigen::VectorXd a_next(d.n + 1);
    a_next.head(d.n) = x.tail(d.n);
    a_next(d.n) = 1.0;
    a_next = Stabilised(a_next, &fit.reflected);
    const double change = (a_next - a).norm() / std::max(1.0, a_next.norm());
    a = a_next;
    fit.iterations = iteration + 1;
    for (size_t k = 0; k < points; ++k) sk_weight[k] = 1.0 / std::norm(Horner(a, d.s[k]));
    if (iteration > 0 && change < 1e-12) break;
  }
  fit.rational.a = a;
  fit.rational.b = RefitNumerator(d, h, a);
  fit.chi2 = ChiSquared(d, fit.rational, delay_s);
  return fit;
}

// Parameter vector theta for Levenberg-Marquardt: b_0..b_m, a_0..a_{n-1}, then delay_s
// when the delay is free. A fixed delay (the profile over the grid) is not in theta.
struct DelaySetting {
  bool free = false;
  double fixed_s = 0.0;  // used when !free
  double max_s = 0.0;    // range [0, max_s] when free
};

Rational Unpack(const FitData& d, const Eigen::VectorXd& theta) {
  Rational r;
  r.b = theta.head(d.m + 1);
  r.a.resize(d.n + 1);
  r.a.head(d.n) = theta.segment(d.m + 1, d.n);
  r.a(d.n) = 1.0;
  return r;
}

// Residuals rho (2K) and Jacobian J (2K x p) of the normalised errors
// (G_model - G_k) / s_k, real and imaginary parts:
//   dG/db_i = s^i / A e^{-j w T},  dG/da_i = -B s^i / A^2 e^{-j w T},  dG/dT = -j w G.
void Residuals(const FitData& d, const Eigen::VectorXd& theta, const DelaySetting& delay_setting,
               Eigen::VectorXd* rho, Eigen::MatrixXd* jacobian) {
  const Rational r = Unpack(d, theta);
  const bool with_delay = delay_setting.free;
  const double delay_s = with_delay ? theta(theta.size() - 1) : delay_setting.fixed_s;
  const size_t points = d.g.size();
  rho->resize(2 * points);
  if (jacobian) jacobian->resize(2 * points, theta.size());
  for (size_t k = 0; k < points; ++k) {
    const double inv_sd = std::sqrt(2.0 / d.var[k]);
    const Complex delay = std::polar(1.0, -d.omega[k] * delay_s);
    const Complex a = Horner(r.a, d.s[k]), b = Horner(r.b, d.s[k]);
    const Complex model = b / a * delay;
    const Complex e = (model - d.g[k]) * inv_sd;
    (*rho)(2 * k) = e.real();
    (*rho)(2 * k + 1) = e.imag();
    if (!jacobian) continue;
    Complex power = 1.0;
    for (int i = 0; i <= std::max(d.m, d.n - 1); ++i, power *= d.s[k]) {
      if (i <= d.m) {
        const Complex c = power / a * delay * inv_sd;
        (*jacobian)(2 * k, i) = c.real();
        (*jacobian)(2 * k + 1, i) = c.imag();
      }
      if (i < d.n) {
        const Complex c = -b * power / (a * a) * delay * inv_sd;
        (*jacobian)(2 * k, d.m + 1 + i) = c.real();
        (*jacobian)(2 * k + 1, d.m + 1 + i) = c.imag();
      }
    }
    if (with_delay) {
      const Complex c = Complex(0.0, -d.omega[k]) * model * inv_sd;
      (*jacobian)(2 * k, theta.size() - 1) = c.real();
      (*jacobian)(2 * k + 1, theta.size() - 1) = c.imag();
    }
  }
}

// Levenberg-Marquardt with Marquardt's diagonal scaling; steps that would leave the delay
// range or make the denominator unstable are rejected like steps that raise the cost.
int LevenbergMarquardt(const FitData& d, const DelaySetting& delay_setting, int max_iterations,
                       Eigen::VectorXd* theta, double* final_cost) {
  const bool with_delay = delay_setting.free;
  Eigen::VectorXd rho;
  Eigen::MatrixXd jacobian;
  Residuals(d, *theta, delay_setting, &rho, &jacobian);
  double cost = rho.squaredNorm();
  double lambda = 1e-3;
  int iteration = 0;
  for (; iteration < max_iterations; ++iteration) {
    const Eigen::MatrixXd jtj = jacobian.transpose() * jacobian;
    const Eigen::VectorXd gradient = jacobian.transpose() * rho;
    Eigen::VectorXd diagonal = jtj.diagonal().cwiseMax(1e-12 * jtj.diagonal().maxCoeff());
    bool accepted = false;
    while (lambda < 1e12) {
      Eigen::MatrixXd lhs = jtj;
      lhs.diagonal() += lambda * diagonal;
      const Eigen::VectorXd step = lhs.ldlt().solve(-gradient);
      Eigen::VectorXd candidate = *theta + step;
      const bool in_range = !with_delay || (candidate(candidate.size() - 1) >= 0.0 &&
                                            candidate(candidate.size() - 1) <= delay_setting.max_s);
      if (in_range && candidate.allFinite() && StableDenominator(Unpack(d, candidate).a)) {
        Eigen::VectorXd candidate_rho;
        Residuals(d, candidate, delay_setting, &candidate_rho, nullptr);
        const double candidate_cost = candidate_rho.squaredNorm();
        if (candidate_cost < cost) {
          const double decrease = cost - candidate_cost;
          *theta = candidate;
          cost = candidate_cost;
          lambda = std::max(lambda / 3.0, 1e-12);
          accepted = true;
          Residuals(d, *theta, delay_setting, &rho, &jacobian);
          if (decrease < 1e-12 * (1.0 + cost)) {
            if (final_cost) *final_cost = cost;
            return iteration + 1;
          }
          break;
        }
      }
      lambda *= 10.0;
    }
    if (!accepted) break;
  }
  if (final_cost) *final_cost = cost;
  return iteration;
}

std::string Describe(const Complex& p) {
  if (p.imag() == 0.0) return Format(p.real());
  return Format(p.real()) + (p.imag() > 0 ? " + " : " - ") + Format(std::abs(p.imag())) + "j";
}

}  // namespace

// -----------------------------------------------------------------------------------------
// Options
// -----------------------------------------------------------------------------------------

bool FrequencyFitOptions::IsValid(std::string* error) const {
  auto fail = [error](std::string message) {
    if (error) *error = std::move(message);
    return false;
  };
  if (num_poles < 1) return fail("num_poles must be >= 1");
  if (num_zeros < 0 || num_zeros > num_poles)
    return fail("num_zeros must be in [0, num_poles] (a proper model)");
  if (!std::isfinite(max_delay_s) || max_delay_s < 0.0)
    return fail("max_delay_s must be finite and >= 0");
  if (sk_iterations < 1) return fail("sk_iterations must be >= 1");
  if (!std::isfinite(delay_step_s) || !(delay_step_s > 0.0))
    return fail("delay_step_s must be finite and > 0");
  if (max_delay_s / delay_step_s > 1e6) return fail("delay grid has more than 1e6 points");
  return true;
}

bool SquareWaveOptions::IsValid(std::string* error) const {
  if (max_harmonic < 1) {
    if (error) *error = "max_harmonic must be >= 1";
    return false;
  }
  if (discard_periods < 0) {
    if (error) *error = "discard_periods must be >= 0";
    return false;
  }
  if (!std::isfinite(min_discard_s) || min_discard_s < 0.0) {
    if (error) *error = "min_discard_s must be finite and >= 0";
    return false;
  }
  return true;
}

// -----------------------------------------------------------------------------------------
// Fundamental
// -----------------------------------------------------------------------------------------

double DetectFundamental_Hz(const DataSegment& segment) {
  CheckSegment(segment);
  const std::vector<double>& u = segment.voltage_V;
  const double dt_s = segment.dt_s;
  std::vector<double> sorted = u;
  auto quantile = [&sorted](double q) {
    const size_t index = static_cast<size_t>(q * static_cast<double>(sorted.size() - 1));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(index),
                     sorted.end());
    return sorted[index];
  };
  const double low_V = quantile(0.02), high_V = quantile(0.98);
  const double range_V = high_V - low_V;
  if (!(range_V > 1e-12 * std::max(1.0, std::abs(high_V))))
    throw InputError("input is not periodic: the voltage is constant at " + Format(high_V) + " V");
  const double mid_V = 0.5 * (low_V + high_V), hysteresis_V = 0.1 * range_V;

  // Schmitt trigger: the state flips when the voltage passes mid +- hysteresis; the
  // crossing time is where the signal last passed the mid level (linear interpolation).
  std::vector<double> rising_s, falling_s;
  int state = 0;  // 0 unknown, +1 high, -1 low
  for (size_t k = 0; k < u.size(); ++k) {
    const int next = u[k] > mid_V + hysteresis_V ? 1 : (u[k] < mid_V - hysteresis_V ? -1 : state);
    if (next != state && state != 0) {
      size_t j = k;  // first sample of the final run on the new side of mid
      while (j > 0 && (next > 0 ? u[j - 1] > mid_V : u[j - 1] < mid_V)) --j;
      double t_s = static_cast<double>(j) * dt_s;
      if (j > 0) {
        const double fraction = (mid_V - u[j - 1]) / (u[j] - u[j - 1]);
        t_s = (static_cast<double>(j - 1) + fraction) * dt_s;
      }
      (next > 0 ? rising_s : falling_s).push_back(t_s);
    }
    state = next;
  }
  if (rising_s.size() < 3)
    throw InputError("input is not periodic: it crosses its mid level " + Format(mid_V) +
                     " V upwards " + std::to_string(rising_s.size()) +
                     " times, two periods need three");
  const double rough_period_s =
      (rising_s.back() - rising_s.front()) / static_cast<double>(rising_s.size() - 1);
  const double tolerance_s = std::max(0.05 * rough_period_s, 1.5 * dt_s);
  for (const std::vector<double>* crossings : {&rising_s, &falling_s}) {
    for (size_t i = 1; i < crossings->size(); ++i) {
      const double interval_s = (*crossings)[i] - (*crossings)[i - 1];
      if (std::abs(interval_s - rough_period_s) > tolerance_s)
        throw InputError(
            "input is not periodic: " + std::string(crossings == &rising_s ? "rising" : "falling") +
            " crossings of the mid level " + Format(mid_V) + " V are " + Format(interval_s) +
            " s apart at t = " + Format((*crossings)[i]) + " s, the mean period is " +
            Format(rough_period_s) + " s");
    }
  }
  // Least squares over both edge types: t = t_edge + P c with one intercept per type and
  // a common period P (c = cycle index). Edge jitter of up to dt averages out.
  double sxy = 0.0, sxx = 0.0;
  for (const std::vector<double>* crossings : {&rising_s, &falling_s}) {
    if (crossings->size() < 2) continue;
    const double count = static_cast<double>(crossings->size());
    const double mean_c = 0.5 * (count - 1.0);
    double mean_t = 0.0;
    for (double t : *crossings) mean_t += t / count;
    for (size_t i = 0; i < crossings->size(); ++i) {
      const double c = std::round(((*crossings)[i] - crossings->front()) / rough_period_s);
      sxy += (c - mean_c) * ((*crossings)[i] - mean_t);
      sxx += (c - mean_c) * (c - mean_c);
    }
  }
  return sxx / sxy;
}

// -----------------------------------------------------------------------------------------
// Frequency response points
// -----------------------------------------------------------------------------------------

std::vector<FrequencyPoint> EstimateFrequencyResponse(const DataSegment& segment,
                                                      double fundamental_Hz, int max_harmonic,
                                                      int discard_periods) {
  if (!std::isfinite(fundamental_Hz) || !(fundamental_Hz > 0.0))
    throw std::invalid_argument("fundamental_Hz must be finite and > 0");
  if (max_harmonic < 1) throw std::invalid_argument("max_harmonic must be >= 1");
  if (discard_periods < 0) throw std::invalid_argument("discard_periods must be >= 0");
  CheckSegment(segment);
  const double dt_s = segment.dt_s;
  const double nyquist_Hz = 0.5 / dt_s;
  if (fundamental_Hz > kMaxNyquistFraction * nyquist_Hz)
    throw InputError("fundamental " + Format(fundamental_Hz) + " Hz is above 0.8 Nyquist (" +
                     Format(kMaxNyquistFraction * nyquist_Hz) + " Hz at dt = " + Format(dt_s) +
                     " s)");

  // Window: whole periods after the discarded ones.
  const double period_samples = 1.0 / (fundamental_Hz * dt_s);
  const auto total = static_cast<double>(segment.voltage_V.size());
  double start = std::round(discard_periods * period_samples);
  // A recording that ends less than one sample short of a whole period still counts it
  // (the fundamental is only known to about a sample per recording): the window then
  // starts up to a sample earlier, so that it always holds whole periods.
  const int periods =
      start < total ? static_cast<int>(std::floor((total - start + 1.0) / period_samples)) : 0;
  if (periods < 2)
    throw InputError("recording holds " + Format(total / period_samples, 3) + " periods of " +
                     Format(fundamental_Hz) + " Hz; need discard_periods + 2 = " +
                     std::to_string(discard_periods + 2) + " whole ones");
  const double window = std::min(std::round(periods * period_samples), total);
  start = std::max(0.0, std::min(start, total - window));
  const auto begin = static_cast<Eigen::Index>(start);
  const auto length = static_cast<Eigen::Index>(window);

  Eigen::MatrixXd signals(length, 2);  // u, y on the window
  for (Eigen::Index i = 0; i < length; ++i) {
    signals(i, 0) = segment.voltage_V[static_cast<size_t>(begin + i)];
    signals(i, 1) = segment.deflection_mm[static_cast<size_t>(begin + i)];
  }
  const double y_range_mm = signals.col(1).maxCoeff() - signals.col(1).minCoeff();
  if (!(y_range_mm > 0.0))
    throw InputError("output is constant over the analysis window (from t = " +
                     Format(static_cast<double>(begin) * dt_s) +
                     " s): is the dead time longer than the recording?");

  // Trend from sub-period means (header): each period is cut into `parts` cells of at
  // least 4 samples; the cell means are a periodic pattern (one value per part: whatever
  // the periodic signal is, measured harmonics or not) plus the trend's Legendre terms
  // 1..degree, fitted by least squares (parts * periods equations, parts + degree
  // unknowns). Sample i stands for [i, i + 1) in sample units from the window start;
  // samples on a cell boundary are shared by overlap.
  const int parts =
      std::clamp(static_cast<int>(std::floor(period_samples / 4.0)), 1, kTrendPartsPerPeriod);
  const int degree = std::min(kTrendDegree, parts * (periods - 1));
  const int cells = parts * periods;
  const double cell_samples = period_samples / parts;
  Eigen::MatrixXd legendre(length, degree + 1);
  for (Eigen::Index i = 0; i < length; ++i) {
    const double x = 2.0 * (static_cast<double>(i) + 0.5) / static_cast<double>(length) - 1.0;
    Legendre(x, degree, legendre.row(i).data(), length);
  }
  // Columns: Legendre 1..degree, then the signals u, y; rows: the cells' means.
  Eigen::MatrixXd cell_means = Eigen::MatrixXd::Zero(cells, degree + 2);
  Eigen::VectorXd cell_weight = Eigen::VectorXd::Zero(cells);
  for (Eigen::Index i = 0; i < length; ++i) {
    const double cell_begin = static_cast<double>(i);
    const int j = std::min(cells - 1, static_cast<int>(std::floor(cell_begin / cell_samples)));
    const double boundary = (j + 1) * cell_samples;
    const double w_first = std::clamp(boundary - cell_begin, 0.0, 1.0);
    for (int cell = j; cell <= std::min(j + 1, cells - 1); ++cell) {
      const double w = cell == j ? w_first : 1.0 - w_first;
      if (w <= 0.0) continue;
      cell_means.row(cell).head(degree) += w * legendre.row(i).tail(degree);
      cell_means.row(cell).tail(2) += w * signals.row(i);
      cell_weight(cell) += w;
    }
  }
  for (int j = 0; j < cells; ++j) cell_means.row(j) /= cell_weight(j);
  Eigen::MatrixXd design = Eigen::MatrixXd::Zero(cells, degree + parts);
  design.leftCols(degree) = cell_means.leftCols(degree);
  for (int j = 0; j < cells; ++j) design(j, degree + j % parts) = 1.0;
  const Eigen::MatrixXd solution = design.colPivHouseholderQr().solve(cell_means.rightCols(2));
  const Eigen::MatrixXd detrended = signals - legendre.rightCols(degree) * solution.topRows(degree);

  // Harmonics: least squares on the detrended signals with a constant and cos / sin of
  // every harmonic up to max_harmonic below 0.8 Nyquist (on whole periods these columns
  // are orthogonal, so this is the DFT at the lines; the constant takes the mean).
  const int harmonics = std::min(
      max_harmonic,
      static_cast<int>(std::floor(kMaxNyquistFraction * nyquist_Hz / fundamental_Hz + 1e-9)));
  constexpr int trend = 1;
  const int columns = trend + 2 * harmonics;
  const double omega0_rad_s = 2.0 * kPi * fundamental_Hz;
  Eigen::MatrixXd regressors(length, columns);
  for (Eigen::Index i = 0; i < length; ++i) {
    // Window time: G = Y / U does not depend on the time origin.
    const double t_s = static_cast<double>(i) * dt_s;
    regressors(i, 0) = 1.0;
    for (int h = 1; h <= harmonics; ++h) {
      regressors(i, trend + 2 * (h - 1)) = std::cos(h * omega0_rad_s * t_s);
      regressors(i, trend + 2 * (h - 1) + 1) = std::sin(h * omega0_rad_s * t_s);
    }
  }
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(regressors);
  const Eigen::MatrixXd coefficients = qr.solve(detrended);
  const Eigen::MatrixXd residuals = detrended - regressors * coefficients;
  // C = (M^T M)^{-1} = R^{-1} R^{-T}.
  const Eigen::MatrixXd r_upper = qr.matrixQR().topRows(columns).triangularView<Eigen::Upper>();
  const Eigen::MatrixXd r_inverse =
      r_upper.triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(columns, columns));
  const Eigen::MatrixXd covariance = r_inverse * r_inverse.transpose();

  // The whole estimate is linear in the signal: coefficients = W (I - T A) x, with
  // W = C M^T the least-squares operator, A (cells x L) the cell averaging and T (L x
  // cells) the trend fitted to cell means. Its rows r give the variance under white noise
  // exactly, trend noise included: var = sigma^2 |r|^2 (with C alone it would be missed;
  // for a long period and degree-4 trend it is comparable to the harmonic's own).
  const Eigen::MatrixXd design_inverse =
      design.colPivHouseholderQr().solve(Eigen::MatrixXd::Identity(cells, cells));
  const Eigen::MatrixXd least_squares = covariance * regressors.transpose();  // W, p x L
  const Eigen::MatrixXd w_trend =
      (least_squares * legendre.rightCols(degree)) * design_inverse.topRows(degree);  // p x cells
  Eigen::MatrixXd operator_rows = least_squares;                                      // W (I - T A)
  for (Eigen::Index i = 0; i < length; ++i) {
    const double cell_begin = static_cast<double>(i);
    const int j = std::min(cells - 1, static_cast<int>(std::floor(cell_begin / cell_samples)));
    const double w_first = std::clamp((j + 1) * cell_samples - cell_begin, 0.0, 1.0);
    for (int cell = j; cell <= std::min(j + 1, cells - 1); ++cell) {
      const double w = cell == j ? w_first : 1.0 - w_first;
      if (w > 0.0) operator_rows.col(i) -= w_trend.col(cell) * (w / cell_weight(cell));
    }
  }

  auto amplitude = [&](int column, int h) {
    const Eigen::Index c = trend + 2 * (h - 1);
    return Complex(coefficients(c, column), -coefficients(c + 1, column));
  };
  const double u_max_V = signals.col(0).maxCoeff(), u_min_V = signals.col(0).minCoeff();
  const double u_range_V = u_max_V - u_min_V;
  if (!(u_range_V > 1e-12 * std::max({1.0, std::abs(u_max_V), std::abs(u_min_V)})))
    throw InputError("input is constant over the analysis window: no component at " +
                     Format(fundamental_Hz) + " Hz");
  const double u1 = std::abs(amplitude(0, 1));
  if (!(u1 > kMinHarmonicRatio * u_range_V))
    throw InputError("input has no component at " + Format(fundamental_Hz) + " Hz (amplitude " +
                     Format(u1) + " V of a " + Format(u_range_V) + " V range)");

  const double bin_rad = 2.0 * kPi / static_cast<double>(length);  // delta * dt
  std::vector<FrequencyPoint> points;
  for (int h = 1; h <= harmonics; ++h) {
    const Complex u_h = amplitude(0, h), y_h = amplitude(1, h);
    if (std::abs(u_h) < kMinHarmonicRatio * u1) continue;
    const Complex g_sampled = y_h / u_h;
    const double omega_rad_s = h * omega0_rad_s;
    const double omega_dt = omega_rad_s * dt_s;

    // Noise near the line from the bins between the harmonic lines (header).
    double noise_power = 0.0;
    int bins = 0;
    const int max_offset = std::min(2 * periods - 1, kMaxNoiseBinOffset);
    for (int offset = -max_offset; offset <= max_offset; ++offset) {
      if (offset % periods == 0) continue;
      const int bin = h * periods + offset;
      // Bins 0..degree hold the trend's degrees of freedom; past Nyquist is nothing.
      if (bin <= degree || bin >= length / 2) continue;
      const auto [r_u, r_y] = Dtft(residuals, bin * bin_rad);
      noise_power += std::norm(r_y - g_sampled * r_u);
      ++bins;
    }

    const double sigma2 = bins > 0 ? noise_power / bins / static_cast<double>(length) : 0.0;
    const Eigen::Index c = trend + 2 * (h - 1);
    const double var_y =
        sigma2 * (operator_rows.row(c).squaredNorm() + operator_rows.row(c + 1).squaredNorm());

    // Zero-order-hold correction (header): G(j w) = G_d j w dt / (1 - e^{-j w dt}).
    const Complex zoh = Complex(0.0, omega_dt) / (1.0 - std::polar(1.0, -omega_dt));
    const Complex g = g_sampled * zoh;
    const double var_g = var_y / std::norm(u_h) * std::norm(zoh);

    FrequencyPoint point;
    point.frequency_Hz = h * fundamental_Hz;
    point.omega_rad_s = omega_rad_s;
    point.response = g;
    point.periods = periods;
    point.harmonic = h;
    point.std_dev = std::sqrt(0.5 * var_g);
    const double nu = std::max(2.0 * bins, 4.0);
    const double q = StudentT975(nu);
    const double disc = std::sqrt(2.0 * F2Quantile95(nu)) * point.std_dev;
    if (disc >= std::abs(g)) {  // the 95 % disc holds 0: phase not resolved
      point.gain_half_width_95 = disc;
      point.phase_half_width_95_rad = kPi;
    } else {
      point.gain_half_width_95 = q * point.std_dev;
      point.phase_half_width_95_rad = std::min(kPi, q * point.std_dev / std::abs(g));
    }
    points.push_back(point);
  }
  return points;
}

// -----------------------------------------------------------------------------------------
// Rational fit with dead time
// -----------------------------------------------------------------------------------------

FrequencyFit FitFrequencyResponse(const std::vector<FrequencyPoint>& points,
                                  const FrequencyFitOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) throw std::invalid_argument("FrequencyFitOptions: " + error);
  if (points.empty()) throw InputError("no frequency points to fit");
  const bool with_delay = options.max_delay_s > 0.0;
  const int m = options.num_zeros, n = options.num_poles;
  const int parameters = m + 1 + n + (with_delay ? 1 : 0);
  const int values = 2 * static_cast<int>(points.size());
  const std::string structure = std::to_string(m) + " zeros / " + std::to_string(n) + " poles" +
                                (with_delay ? " + delay" : "");
  if (values < parameters)
    throw InputError("too few frequency points: " + std::to_string(points.size()) +
                     " points give " + std::to_string(values) + " real values, fewer than the " +
                     std::to_string(parameters) + " parameters of " + structure +
                     "; add frequencies or lower num_zeros / num_poles");

  FitData d;
  d.m = m;
  d.n = n;
  double omega_min = kInf, omega_max = 0.0, g_max = 0.0;
  bool any_uncertainty = false;
  for (size_t k = 0; k < points.size(); ++k) {
    const FrequencyPoint& p = points[k];
    if (!std::isfinite(p.omega_rad_s) || !(p.omega_rad_s > 0.0) ||
        !std::isfinite(p.response.real()) || !std::isfinite(p.response.imag()) ||
        !std::isfinite(p.std_dev) || !std::isfinite(p.gain_half_width_95))
      throw InputError("frequency point " + std::to_string(k) +
                       " is not usable (omega must be > 0, values finite)");
    omega_min = std::min(omega_min, p.omega_rad_s);
    omega_max = std::max(omega_max, p.omega_rad_s);
    g_max = std::max(g_max, std::abs(p.response));
    const double sd = p.std_dev > 0.0 ? p.std_dev : p.gain_half_width_95 / kZ975;
    if (sd > 0.0) any_uncertainty = true;
    d.omega.push_back(p.omega_rad_s);
    d.g.push_back(p.response);
    d.var.push_back(2.0 * sd * sd);
  }
  std::string notes;
  // Points without an uncertainty take the median variance of the others (all of them
  // without: unweighted, variance 1); a floor at rounding level keeps every weight finite.
  std::vector<double> given;
  for (double v : d.var)
    if (v > 0.0) given.push_back(v);
  double median_var = 1.0;
  if (!given.empty()) {
    std::nth_element(given.begin(), given.begin() + static_cast<std::ptrdiff_t>(given.size() / 2),
                     given.end());
    median_var = given[given.size() / 2];
  }
  const size_t without = d.var.size() - given.size();
  for (size_t k = 0; k < d.var.size(); ++k) {
    if (!(d.var[k] > 0.0)) d.var[k] = median_var;
    const double floor = std::pow(1e-9 * std::abs(d.g[k]), 2) + std::pow(1e-12 * g_max, 2);
    d.var[k] = std::max(d.var[k], floor > 0.0 ? floor : 1e-300);
  }
  if (!any_uncertainty)
    notes += " The points carry no uncertainty: unweighted fit.";
  else if (without > 0)
    notes += " " + std::to_string(without) +
             " point(s) without an uncertainty took the median variance of the others.";
  d.omega_ref = std::sqrt(omega_min * omega_max);
  for (double omega : d.omega) d.s.emplace_back(0.0, omega / d.omega_ref);

  auto pack = [&](const Rational& r, double delay) {
    Eigen::VectorXd theta(parameters);
    theta.head(m + 1) = r.b;
    theta.segment(m + 1, n) = r.a.head(n);
    if (with_delay) theta(parameters - 1) = delay;
    return theta;
  };

  // 1. Delay grid: Levy + SK at every grid delay.
  std::vector<double> grid_s;
  if (with_delay) {
    const auto steps =
        static_cast<long>(std::floor(options.max_delay_s / options.delay_step_s + 1e-9));
    for (long i = 0; i <= steps; ++i)
      grid_s.push_back(static_cast<double>(i) * options.delay_step_s);
    if (options.max_delay_s - grid_s.back() > 1e-9) grid_s.push_back(options.max_delay_s);
  } else {
    grid_s.push_back(0.0);
  }
  std::vector<DelayFit> grid_fits(grid_s.size());
  std::vector<double> profile_chi2(grid_s.size());
  size_t best_index = 0;
  int sk_max_iterations = 0, reflected = 0;
  for (size_t i = 0; i < grid_s.size(); ++i) {
    grid_fits[i] = FitAtDelay(d, grid_s[i], options.sk_iterations);
    profile_chi2[i] = grid_fits[i].chi2;
    sk_max_iterations = std::max(sk_max_iterations, grid_fits[i].iterations);
    reflected += grid_fits[i].reflected;
    if (grid_fits[i].chi2 < grid_fits[best_index].chi2) best_index = i;
  }
  const double grid_chi2 = grid_fits[best_index].chi2;
  Eigen::VectorXd theta = pack(grid_fits[best_index].rational, grid_s[best_index]);
  double start_chi2 = grid_chi2;

  int lm_iterations = 0;
  const int rational_parameters = m + 1 + n;
  std::vector<Eigen::VectorXd> profile_theta(grid_s.size());
  // Profile point i: Levenberg-Marquardt on b, a with T = grid_s[i] fixed, from `start`;
  // kept if it lowers profile_chi2[i].
  // Returns the local solution (the next start of a continuation sweep).
  auto improve_profile = [&](size_t i, const Eigen::VectorXd& start) {
    Eigen::VectorXd candidate = start;
    double cost = kInf;
    LevenbergMarquardt(d, {false, grid_s[i], 0.0}, 30, &candidate, &cost);
    if (cost < profile_chi2[i]) {
      profile_chi2[i] = cost;
      profile_theta[i] = candidate;
    }
    return candidate;
  };
  if (with_delay && options.refine) {
    // 2. Profile: SK's fixed point is near, not at, the weighted least-squares optimum, and
    // the delay's interval needs the profile chi^2(T) = min over b, a.
    for (size_t i = 0; i < grid_s.size(); ++i) {
      profile_theta[i] = pack(grid_fits[i].rational, 0.0).head(rational_parameters);
      improve_profile(i, profile_theta[i]);
      if (profile_chi2[i] < start_chi2) {
        start_chi2 = profile_chi2[i];
        theta = pack(Unpack(d, profile_theta[i]), grid_s[i]);
      }
    }
    // 3. Golden-section search of the SK chi^2(T) between the best SK grid point's
    // neighbours; kept if it beats the best profile point.
    double lo = grid_s[best_index > 0 ? best_index - 1 : 0];
    double hi = grid_s[std::min(best_index + 1, grid_s.size() - 1)];
    const double ratio = 0.5 * (std::sqrt(5.0) - 1.0);
    double x1 = hi - ratio * (hi - lo), x2 = lo + ratio * (hi - lo);
    DelayFit f1 = FitAtDelay(d, x1, options.sk_iterations);
    DelayFit f2 = FitAtDelay(d, x2, options.sk_iterations);
    for (int i = 0; i < 40 && hi - lo > 1e-6 * (1.0 + options.max_delay_s); ++i) {
      if (f1.chi2 < f2.chi2) {
        hi = x2;
        x2 = x1;
        f2 = f1;
        x1 = hi - ratio * (hi - lo);
        f1 = FitAtDelay(d, x1, options.sk_iterations);
      } else {
        lo = x1;
        x1 = x2;
        f1 = f2;
        x2 = lo + ratio * (hi - lo);
        f2 = FitAtDelay(d, x2, options.sk_iterations);
      }
    }
    const bool first = f1.chi2 < f2.chi2;
    if ((first ? f1 : f2).chi2 < start_chi2) {
      start_chi2 = (first ? f1 : f2).chi2;
      theta = pack((first ? f1 : f2).rational, first ? x1 : x2);
    }
  }
  // 4. Levenberg-Marquardt on everything; then 5. the profile again by continuation from
  // the optimum (each grid point starts from its neighbour's solution, sweeping outwards),
  // which traces the valley the local fits from SK starts miss. If the profile finds a
  // lower point than the optimum, the free fit restarts there (at most three rounds).
  const DelaySetting free_delay{with_delay, 0.0, options.max_delay_s};
  for (int round = 0; round < 3 && options.refine; ++round) {
    lm_iterations += LevenbergMarquardt(d, free_delay, 100, &theta, nullptr);
    if (!with_delay) break;
    Eigen::VectorXd residual;
    Residuals(d, theta, free_delay, &residual, nullptr);
    const double optimum_chi2 = residual.squaredNorm();
    const size_t centre =
        static_cast<size_t>(std::clamp(std::llround(theta(parameters - 1) / options.delay_step_s),
                                       0LL, static_cast<long long>(grid_s.size()) - 1));
    const Eigen::VectorXd optimum = theta.head(rational_parameters);
    for (int direction : {1, -1}) {
      Eigen::VectorXd start = optimum;
      for (long long i = static_cast<long long>(centre);
           i >= 0 && i < static_cast<long long>(grid_s.size()); i += direction) {
        start = improve_profile(static_cast<size_t>(i), start);
      }
    }
    const size_t lowest = static_cast<size_t>(
        std::min_element(profile_chi2.begin(), profile_chi2.end()) - profile_chi2.begin());
    if (!(profile_chi2[lowest] < optimum_chi2 - 1e-9 * (1.0 + optimum_chi2))) break;
    theta = pack(Unpack(d, profile_theta[lowest]), grid_s[lowest]);
  }
  const Rational final_rational = Unpack(d, theta);
  const double delay_s = with_delay ? theta(parameters - 1) : 0.0;

  Eigen::VectorXd rho;
  Eigen::MatrixXd jacobian;
  Residuals(d, theta, free_delay, &rho, &jacobian);
  const double chi2 = rho.squaredNorm();
  const int dof = values - parameters;
  const double reduced_chi2 = dof > 0 ? chi2 / dof : kInf;
  const double variance_factor = dof > 0 ? std::max(1.0, reduced_chi2) : 1.0;

  // Covariance by the pseudo-inverse of the column-scaled Jacobian: directions with a
  // singular value below 1e-10 of the largest are not determined (+inf half-widths).
  Eigen::VectorXd column_scale(parameters);
  for (int j = 0; j < parameters; ++j) {
    const double norm = jacobian.col(j).norm();
    column_scale(j) = norm > 0.0 ? 1.0 / norm : 1.0;
  }
  const Eigen::MatrixXd scaled = jacobian * column_scale.asDiagonal();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(scaled, Eigen::ComputeThinV);
  const Eigen::VectorXd singular = svd.singularValues();
  const double condition =
      singular(singular.size() - 1) > 0.0 ? singular(0) / singular(singular.size() - 1) : kInf;
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(parameters, parameters);
  std::vector<bool> undetermined(static_cast<size_t>(parameters), false);
  for (int i = 0; i < singular.size(); ++i) {
    const Eigen::VectorXd v = svd.matrixV().col(i);
    if (singular(i) > 1e-10 * singular(0)) {
      covariance += v * v.transpose() / (singular(i) * singular(i));
    } else {
      for (int j = 0; j < parameters; ++j)
        if (std::abs(v(j)) > 1e-3) undetermined[static_cast<size_t>(j)] = true;
    }
  }
  covariance = column_scale.asDiagonal() * covariance * column_scale.asDiagonal();
  covariance *= variance_factor;

  // Unscaled coefficients: multiplying B and A by omega_ref^n makes A monic in s, so the
  // coefficient of s^i (both polynomials) is the scaled one times omega_ref^{n - i}.
  FrequencyFit result;
  result.points = points;
  result.tf.num.resize(static_cast<size_t>(m + 1));
  result.tf.den.resize(static_cast<size_t>(n + 1));
  auto factor = [&](int power) { return std::pow(d.omega_ref, n - power); };
  auto half_width = [&](int j, double scale) {
    if (undetermined[static_cast<size_t>(j)]) return kInf;
    return kZ975 * std::sqrt(std::max(0.0, covariance(j, j))) * std::abs(scale);
  };
  for (int j = 0; j <= m; ++j) {  // b_j multiplies s^{m-j}
    const int power = m - j;
    const double value = final_rational.b(power) * factor(power);
    result.tf.num[static_cast<size_t>(j)] = value;
    result.coefficients.push_back(
        {"b" + std::to_string(j), value, half_width(power, factor(power))});
  }
  result.tf.den[0] = 1.0;
  for (int j = 1; j <= n; ++j) {  // a_j multiplies s^{n-j}
    const int power = n - j;
    const double value = final_rational.a(power) * factor(power);
    result.tf.den[static_cast<size_t>(j)] = value;
    result.coefficients.push_back(
        {"a" + std::to_string(j), value, half_width(m + 1 + power, factor(power))});
  }
  result.tf.delay_s = delay_s;

  // Delay: the profile interval {T : chi^2(T) <= chi^2 + 3.84 max(1, chi^2 / dof)}, its
  // ends interpolated linearly between grid points. The profile rather than the Jacobian:
  // chi^2(T) is far from quadratic where the delay trades off against a fast mode.
  double profile_lo = delay_s, profile_hi = delay_s;
  std::vector<std::pair<double, double>> competing;  // (Delta chi^2, T)
  if (with_delay) {
    const double threshold = chi2 + kChi2One95 * variance_factor;
    // The optimum joins the grid as a profile point; from it the profile is taken as
    // quadratic (the crossing at sqrt of the chi^2 fraction), elsewhere as linear.
    std::vector<std::pair<double, double>> profile;  // (T, chi^2), T ascending
    for (size_t i = 0; i < grid_s.size(); ++i) profile.emplace_back(grid_s[i], profile_chi2[i]);
    const auto optimum_at = profile.insert(
        std::lower_bound(profile.begin(), profile.end(), std::make_pair(delay_s, chi2)),
        {delay_s, chi2});
    const auto optimum_index = static_cast<size_t>(optimum_at - profile.begin());
    auto crossing = [&](size_t inside, size_t outside) {
      const double c_in = profile[inside].second, c_out = profile[outside].second;
      double f = c_out > c_in ? (threshold - c_in) / (c_out - c_in) : 0.0;
      if (inside == optimum_index) f = std::sqrt(std::max(0.0, f));
      return profile[inside].first +
             std::clamp(f, 0.0, 1.0) * (profile[outside].first - profile[inside].first);
    };
    for (size_t i = 0; i < profile.size(); ++i) {
      if (profile[i].second > threshold) continue;
      profile_lo = std::min(profile_lo, i > 0 ? crossing(i, i - 1) : profile[i].first);
      profile_hi =
          std::max(profile_hi, i + 1 < profile.size() ? crossing(i, i + 1) : profile[i].first);
    }
    result.coefficients.push_back(
        {"delay_s", delay_s, std::max(profile_hi - delay_s, delay_s - profile_lo)});
    // Competing valleys: local minima of the profile outside the interval, within
    // Delta chi^2 <= 25 max(1, chi^2 / dof) (5 sigma) of the optimum.
    for (size_t i = 0; i < grid_s.size(); ++i) {
      const bool local_minimum = (i == 0 || profile_chi2[i] <= profile_chi2[i - 1]) &&
                                 (i + 1 == grid_s.size() || profile_chi2[i] <= profile_chi2[i + 1]);
      if (local_minimum && (grid_s[i] < profile_lo || grid_s[i] > profile_hi) &&
          profile_chi2[i] <= chi2 + kCompetingChi2 * variance_factor)
        competing.push_back({profile_chi2[i] - chi2, grid_s[i]});
    }
    std::sort(competing.begin(), competing.end());
  }

  // DC gain b'_0 / a'_0 (the omega_ref factors cancel), delta method.
  const double b0 = final_rational.b(0), a0 = final_rational.a(0);
  result.dc_gain.name = "dc_gain";
  result.dc_gain.value = b0 / a0;
  if (undetermined[0] || undetermined[static_cast<size_t>(m + 1)]) {
    result.dc_gain.half_width_95 = kInf;
  } else {
    const double db = 1.0 / a0, da = -b0 / (a0 * a0);
    const double var = db * db * covariance(0, 0) + 2.0 * db * da * covariance(0, m + 1) +
                       da * da * covariance(m + 1, m + 1);
    result.dc_gain.half_width_95 = kZ975 * std::sqrt(std::max(0.0, var));
  }
  // Poles: p moves by dp = -sum_i p^{n-i} da_i / A'(p) (differentiate A(p) = 0).
  {
    std::vector<int> index(static_cast<size_t>(n + 1));  // theta index of a_i
    std::vector<double> scale(static_cast<size_t>(n + 1));
    bool determined = true;
    for (int i = 1; i <= n; ++i) {
      index[static_cast<size_t>(i)] = m + 1 + (n - i);
      scale[static_cast<size_t>(i)] = factor(n - i);
      determined = determined && !undetermined[static_cast<size_t>(m + 1 + (n - i))];
    }
    std::vector<double> derivative;  // A'(s), descending
    for (int i = 0; i < n; ++i)
      derivative.push_back(result.tf.den[static_cast<size_t>(i)] * (n - i));
    for (const Complex& pole : Poles(result.tf)) {
      PoleEstimate estimate{pole.real(), pole.imag(), kInf, kInf};
      const Complex slope = EvaluatePolynomial(derivative, pole);
      if (determined && std::abs(slope) > 0.0) {
        Eigen::VectorXd g_re(parameters), g_im(parameters);
        g_re.setZero();
        g_im.setZero();
        for (int i = 1; i <= n; ++i) {
          const Complex dp = -std::pow(pole, n - i) / slope * scale[static_cast<size_t>(i)];
          g_re(index[static_cast<size_t>(i)]) = dp.real();
          g_im(index[static_cast<size_t>(i)]) = dp.imag();
        }
        estimate.re_half_width_95 = kZ975 * std::sqrt(std::max(0.0, g_re.dot(covariance * g_re)));
        estimate.im_half_width_95 = kZ975 * std::sqrt(std::max(0.0, g_im.dot(covariance * g_im)));
      }
      result.poles.push_back(estimate);
    }
  }
  result.weighted_rms_error = std::sqrt(chi2 / values);

  // Report.
  std::string report = "Frequency fit (Levy + Sanathanan-Koerner, Golubev-style): " + structure +
                       "; " + std::to_string(points.size()) + " points (" + std::to_string(values) +
                       " real values) over " + Format(omega_min) + " .. " + Format(omega_max) +
                       " rad/s; " + std::to_string(parameters) + " parameters, " +
                       std::to_string(dof) + " degrees of freedom.";
  report += " omega_ref " + Format(d.omega_ref) + " rad/s.";
  if (with_delay)
    report += " Delay grid 0 .. " + Format(options.max_delay_s) + " s step " +
              Format(options.delay_step_s) + " s: best chi2 " + Format(grid_chi2) +
              "; T = " + Format(delay_s) + " s, profile 95 % range " + Format(profile_lo) + " .. " +
              Format(profile_hi) + " s.";
  report += " SK iterations <= " + std::to_string(sk_max_iterations) + ", LM iterations " +
            std::to_string(lm_iterations) + "; chi2 " + Format(chi2) + ", weighted rms error " +
            Format(result.weighted_rms_error) + ".";
  if (!competing.empty()) {
    report += " WARNING delay ambiguous: chi2(T) has competing minima at";
    for (size_t i = 0; i < std::min<size_t>(competing.size(), 5); ++i)
      report += std::string(i ? "," : "") + " T = " + Format(competing[i].second) + " s (chi2 +" +
                Format(competing[i].first, 3) + ")";
    report += "; the delay interval is that of the best valley.";
  }
  if (reflected > 0)
    report += " " + std::to_string(reflected) +
              " unstable pole(s) reflected into the left half-plane during the SK iterations.";
  report += notes;
  if (dof == 0)
    report +=
        " WARNING exactly determined: as many parameters as real data values, the fit "
        "interpolates and cannot show a misfit.";
  else if (dof < parameters)
    report += " WARNING barely determined: " + std::to_string(dof) + " degrees of freedom for " +
              std::to_string(parameters) + " parameters.";
  std::vector<std::string> undetermined_names;
  for (int j = 0; j < parameters; ++j)
    if (undetermined[static_cast<size_t>(j)]) {
      if (j <= m)
        undetermined_names.push_back("b" + std::to_string(m - j));
      else if (j < m + 1 + n)
        undetermined_names.push_back("a" + std::to_string(n - (j - m - 1)));
      else
        undetermined_names.push_back("delay_s");
    }
  if (!undetermined_names.empty()) {
    report += " WARNING underdetermined: the points do not determine";
    for (const std::string& name : undetermined_names) report += " " + name;
    report += ".";
  } else if (condition > 1e8) {
    report += " WARNING ill-conditioned: Jacobian condition number " + Format(condition, 3) +
              " (column-scaled); coefficient intervals are wide.";
  } else {
    report += " Jacobian condition number " + Format(condition, 3) + ".";
  }
  if (dof > 0 && reduced_chi2 > 4.0)
    report += " WARNING misfit: chi2 / dof = " + Format(reduced_chi2, 3) +
              ", the model order or the point uncertainties are wrong.";
  for (const Mode& mode : Modes(result.tf)) {
    const double w = mode.natural_frequency_rad_s;
    if (w > omega_max || w < omega_min)
      report += " Pole " + Describe(mode.pole) + " (|p| " + Format(w) +
                " rad/s) lies outside the measured band: extrapolated.";
    if (mode.oscillatory && mode.damping_ratio < 0.3)
      report += " Lightly damped pair at " + Format(w) + " rad/s (damping " +
                Format(mode.damping_ratio, 3) + "); the seed's physics predicts real poles.";
  }
  result.method_report = report;
  return result;
}

FrequencyFit IdentifyFromSquareWaves(const std::vector<DataSegment>& recordings,
                                     const FrequencyFitOptions& options,
                                     const SquareWaveOptions& square_wave) {
  std::string error;
  if (!options.IsValid(&error)) throw std::invalid_argument("FrequencyFitOptions: " + error);
  if (!square_wave.IsValid(&error)) throw std::invalid_argument("SquareWaveOptions: " + error);
  if (recordings.empty()) throw InputError("no recordings");
  std::vector<FrequencyPoint> points;
  for (size_t r = 0; r < recordings.size(); ++r) {
    try {
      const double f0_Hz = DetectFundamental_Hz(recordings[r]);
      const int discard =
          std::max(square_wave.discard_periods,
                   static_cast<int>(std::ceil(square_wave.min_discard_s * f0_Hz - 1e-9)));
      const std::vector<FrequencyPoint> found =
          EstimateFrequencyResponse(recordings[r], f0_Hz, square_wave.max_harmonic, discard);
      points.insert(points.end(), found.begin(), found.end());
    } catch (const InputError& e) {
      throw InputError("recording " + std::to_string(r) + ": " + e.what());
    }
  }
  return FitFrequencyResponse(points, options);
}

}  // namespace flexid::model
