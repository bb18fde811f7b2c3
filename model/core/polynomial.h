// Polynomials with real coefficients stored highest power first, as in the seed's
// Eq. (18): {a1, a2, a3, a4} means a1 s^3 + a2 s^2 + a3 s + a4.
#pragma once

#include <complex>
#include <vector>

namespace flexid::model {

// Value of the polynomial at a complex point (Horner's scheme).
std::complex<double> EvaluatePolynomial(const std::vector<double>& coefficients,
                                        std::complex<double> s);

// Roots as eigenvalues of the companion matrix. Leading zeros are ignored; a constant
// polynomial has no roots.
std::vector<std::complex<double>> PolynomialRoots(const std::vector<double>& coefficients);

// Monic polynomial with the given roots; complex roots must come in conjugate pairs (the
// imaginary parts of the result are dropped).
std::vector<double> PolynomialFromRoots(const std::vector<std::complex<double>>& roots);

std::vector<double> MultiplyPolynomials(const std::vector<double>& a, const std::vector<double>& b);

// Sum aligned at the constant term.
std::vector<double> AddPolynomials(const std::vector<double>& a, const std::vector<double>& b);

// Monic real factors of a polynomial of degree n: one quadratic s^2 + c1 s + c0 per
// complex-conjugate pair, real roots paired by magnitude into quadratics, and one linear
// factor s + c when n is odd. Every polynomial of degree n gets the same structure
// (n / 2 quadratics, then n % 2 linear), so factors of different polynomials can be put
// side by side; quadratics are ordered by c0 ascending (slowest first). A polynomial with
// all roots in the open left half-plane has all factor coefficients > 0, and then so has
// any convex combination of corresponding factors.
std::vector<std::vector<double>> RealFactors(const std::vector<double>& coefficients);

// Drops leading coefficients that are exactly zero (keeps at least one coefficient).
std::vector<double> TrimLeadingZeros(const std::vector<double>& coefficients);

}  // namespace flexid::model
