#include "model/core/polynomial.h"

#include <gtest/gtest.h>

namespace flexid::model {
namespace {

TEST(Polynomial, EvaluatesWithHorner) {
  // 2 s^2 - 3 s + 1 at s = 2 is 3; at s = j it is -1 - 3j.
  EXPECT_DOUBLE_EQ(EvaluatePolynomial({2, -3, 1}, 2.0).real(), 3.0);
  const auto v = EvaluatePolynomial({2, -3, 1}, {0.0, 1.0});
  EXPECT_DOUBLE_EQ(v.real(), -1.0);
  EXPECT_DOUBLE_EQ(v.imag(), -3.0);
}

TEST(Polynomial, RootsOfKnownFactors) {
  // (s + 1)(s + 2)(s^2 + 2 s + 5) has roots -1, -2, -1 +- 2j.
  const auto roots = PolynomialRoots({1, 5, 13, 19, 10});
  ASSERT_EQ(roots.size(), 4u);
  EXPECT_NEAR(roots[0].real(), -1.0, 1e-12);
  EXPECT_NEAR(roots[0].imag(), 2.0, 1e-12);
  EXPECT_NEAR(roots[1].real(), -1.0, 1e-12);
  EXPECT_NEAR(roots[1].imag(), -2.0, 1e-12);
  EXPECT_NEAR(roots[2].real(), -1.0, 1e-12);
  EXPECT_NEAR(roots[3].real(), -2.0, 1e-12);
}

TEST(Polynomial, LeadingZerosAndConstants) {
  EXPECT_EQ(PolynomialRoots({0, 0, 1, 3}).size(), 1u);
  EXPECT_TRUE(PolynomialRoots({4}).empty());
  EXPECT_EQ(TrimLeadingZeros({0, 0}), std::vector<double>{0.0});
}

TEST(Polynomial, FromRootsInvertsRoots) {
  const std::vector<double> p = {1, 0.5898, 367.2, 29.41, 0.2275};
  const auto back = PolynomialFromRoots(PolynomialRoots(p));
  ASSERT_EQ(back.size(), p.size());
  for (size_t i = 0; i < p.size(); ++i) EXPECT_NEAR(back[i], p[i], 1e-9 * (1 + std::abs(p[i])));
}

TEST(Polynomial, MultiplyAndAdd) {
  EXPECT_EQ(MultiplyPolynomials({1, 1}, {1, -1}), (std::vector<double>{1, 0, -1}));
  EXPECT_EQ(AddPolynomials({1, 0, 0}, {2, 3}), (std::vector<double>{1, 2, 3}));
}

}  // namespace
}  // namespace flexid::model
