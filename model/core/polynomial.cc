#include "model/core/polynomial.h"

#include <Eigen/Eigenvalues>
#include <algorithm>

namespace flexid::model {

std::complex<double> EvaluatePolynomial(const std::vector<double>& coefficients,
                                        std::complex<double> s) {
  std::complex<double> value = 0.0;
  for (double c : coefficients) value = value * s + c;
  return value;
}

std::vector<double> TrimLeadingZeros(const std::vector<double>& coefficients) {
  auto first =
      std::find_if(coefficients.begin(), coefficients.end(), [](double c) { return c != 0.0; });
  if (first == coefficients.end()) return {0.0};
  return {first, coefficients.end()};
}

std::vector<std::complex<double>> PolynomialRoots(const std::vector<double>& coefficients) {
  const std::vector<double> p = TrimLeadingZeros(coefficients);
  const int degree = static_cast<int>(p.size()) - 1;
  if (degree < 1) return {};
  // Companion matrix of the monic polynomial; its eigenvalues are the roots.
  Eigen::MatrixXd companion = Eigen::MatrixXd::Zero(degree, degree);
  for (int j = 0; j < degree; ++j) companion(0, j) = -p[j + 1] / p[0];
  for (int i = 1; i < degree; ++i) companion(i, i - 1) = 1.0;
  Eigen::EigenSolver<Eigen::MatrixXd> solver(companion, /*computeEigenvectors=*/false);
  std::vector<std::complex<double>> roots(solver.eigenvalues().begin(), solver.eigenvalues().end());
  // Stable order: by real part, then imaginary part, so printed output is deterministic.
  std::sort(roots.begin(), roots.end(), [](auto a, auto b) {
    return a.real() != b.real() ? a.real() > b.real() : a.imag() > b.imag();
  });
  return roots;
}

std::vector<double> PolynomialFromRoots(const std::vector<std::complex<double>>& roots) {
  std::vector<std::complex<double>> p = {1.0};
  for (const auto& r : roots) {
    std::vector<std::complex<double>> next(p.size() + 1, 0.0);
    for (size_t i = 0; i < p.size(); ++i) {
      next[i] += p[i];
      next[i + 1] -= r * p[i];
    }
    p = std::move(next);
  }
  std::vector<double> real(p.size());
  std::transform(p.begin(), p.end(), real.begin(), [](auto c) { return c.real(); });
  return real;
}

std::vector<std::vector<double>> RealFactors(const std::vector<double>& coefficients) {
  const std::vector<std::complex<double>> roots = PolynomialRoots(coefficients);
  std::vector<double> real;
  std::vector<std::vector<double>> quadratics;
  for (const auto& r : roots) {
    if (std::abs(r.imag()) <= 1e-12 * std::max(1.0, std::abs(r))) {
      real.push_back(r.real());
    } else if (r.imag() > 0.0) {
      quadratics.push_back({1.0, -2.0 * r.real(), std::norm(r)});
    }
  }
  std::sort(real.begin(), real.end(), [](double a, double b) { return std::abs(a) < std::abs(b); });
  size_t i = 0;
  for (; i + 1 < real.size(); i += 2)
    quadratics.push_back({1.0, -(real[i] + real[i + 1]), real[i] * real[i + 1]});
  std::sort(quadratics.begin(), quadratics.end(),
            [](const auto& a, const auto& b) { return a[2] < b[2]; });
  if (i < real.size()) quadratics.push_back({1.0, -real[i]});
  return quadratics;
}

std::vector<double> MultiplyPolynomials(const std::vector<double>& a,
                                        const std::vector<double>& b) {
  if (a.empty() || b.empty()) return {};
  std::vector<double> product(a.size() + b.size() - 1, 0.0);
  for (size_t i = 0; i < a.size(); ++i)
    for (size_t j = 0; j < b.size(); ++j) product[i + j] += a[i] * b[j];
  return product;
}

std::vector<double> AddPolynomials(const std::vector<double>& a, const std::vector<double>& b) {
  const std::vector<double>& longer = a.size() >= b.size() ? a : b;
  const std::vector<double>& shorter = a.size() >= b.size() ? b : a;
  std::vector<double> sum = longer;
  const size_t offset = longer.size() - shorter.size();
  for (size_t i = 0; i < shorter.size(); ++i) sum[offset + i] += shorter[i];
  return sum;
}

}  // namespace flexid::model
