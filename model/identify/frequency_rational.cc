// The frequency-response route's rational fit at the points (frequency_response.h, step
// 2): Levy's least squares and the Sanathanan-Koerner iterations at a fixed dead time, with
// unstable poles reflected and the numerator refitted, and Levenberg-Marquardt on the
// normalised complex errors with the dead time fixed or free.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

#include "model/core/polynomial.h"
#include "model/identify/frequency_fit.h"

namespace flexid::model::frequency_fit {
namespace {

Complex Horner(const Eigen::VectorXd& ascending, Complex s) {
  Complex value = 0.0;
  for (Eigen::Index i = ascending.size() - 1; i >= 0; --i) value = value * s + ascending(i);
  return value;
}

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

}  // namespace

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

Rational Unpack(const FitData& d, const Eigen::VectorXd& theta) {
  Rational r;
  r.b = theta.head(d.m + 1);
  r.a.resize(d.n + 1);
  r.a.head(d.n) = theta.segment(d.m + 1, d.n);
  r.a(d.n) = 1.0;
  return r;
}

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

}  // namespace flexid::model::frequency_fit
