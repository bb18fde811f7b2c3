// Independent references for tests: a fixed-step RK4 integrator of the controllable
// canonical form, built straight from the transfer-function coefficients (no code from
// model/ except the coefficient struct), and vector comparison helpers.
#pragma once

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <random>
#include <vector>

#include "model/core/transfer_function.h"

namespace flexid::testing {

// Piecewise-constant voltage: a new level uniform in [low_V, high_V] every `hold` samples.
inline std::vector<double> RandomStaircase(size_t count, size_t hold, unsigned seed, double low_V,
                                           double high_V) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> level(low_V, high_V);
  std::vector<double> u(count);
  double value = 0.0;
  for (size_t k = 0; k < count; ++k) {
    if (k % hold == 0) value = level(rng);
    u[k] = value;
  }
  return u;
}

// Controllable canonical form of num/den (den monic after division): x' = A x + B u,
// y = C x + D u. Written out here so that tests do not depend on model/state_space.
struct CanonicalForm {
  Eigen::MatrixXd A;
  Eigen::VectorXd B;
  Eigen::RowVectorXd C;
  double D;
};

inline CanonicalForm ControllableForm(const model::TransferFunction& tf) {
  const double lead = tf.den.front();
  const int n = static_cast<int>(tf.den.size()) - 1;
  std::vector<double> a(tf.den.size()), b(tf.den.size(), 0.0);
  for (size_t i = 0; i < a.size(); ++i) a[i] = tf.den[i] / lead;
  const size_t pad = b.size() - tf.num.size();
  for (size_t i = 0; i < tf.num.size(); ++i) b[pad + i] = tf.num[i] / lead;
  CanonicalForm f{Eigen::MatrixXd::Zero(n, n), Eigen::VectorXd::Zero(n),
                  Eigen::RowVectorXd::Zero(n), b[0]};
  for (int i = 0; i + 1 < n; ++i) f.A(i, i + 1) = 1.0;
  for (int j = 0; j < n; ++j) f.A(n - 1, j) = -a[static_cast<size_t>(n - j)];
  f.B(n - 1) = 1.0;
  // y = sum_j (b_{n-j} - b0 a_{n-j}) x_{j+1} + b0 u
  for (int j = 0; j < n; ++j)
    f.C(j) = b[static_cast<size_t>(n - j)] - b[0] * a[static_cast<size_t>(n - j)];
  return f;
}

// Output of the delay-free model at each t_s[k] for input u(t) given as a function,
// integrated with RK4 at a fixed step no larger than max_step_s.
template <typename InputFn>
std::vector<double> IntegrateRk4(const model::TransferFunction& tf, const std::vector<double>& t_s,
                                 InputFn input, double max_step_s) {
  const CanonicalForm f = ControllableForm(tf);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(f.A.rows());
  std::vector<double> y;
  double t = t_s.front();
  for (double target : t_s) {
    const int steps = static_cast<int>(std::ceil((target - t) / max_step_s));
    const double h = steps > 0 ? (target - t) / steps : 0.0;
    for (int i = 0; i < steps; ++i) {
      // The input is evaluated on the open interval so that a zero-order-hold input
      // switching exactly at a step boundary is sampled consistently.
      const double u = input(t + 0.5 * h);
      auto rate = [&](const Eigen::VectorXd& state) {
        return Eigen::VectorXd(f.A * state + f.B * u);
      };
      const Eigen::VectorXd k1 = rate(x), k2 = rate(x + 0.5 * h * k1), k3 = rate(x + 0.5 * h * k2),
                            k4 = rate(x + h * k3);
      x += h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
      t += h;
    }
    t = target;
    y.push_back((f.C * x)(0) + f.D * input(target));
  }
  return y;
}

inline void ExpectVectorsNear(const std::vector<double>& actual,
                              const std::vector<double>& expected, double tolerance) {
  ASSERT_EQ(actual.size(), expected.size());
  for (size_t k = 0; k < actual.size(); ++k)
    ASSERT_NEAR(actual[k], expected[k], tolerance) << "at index " << k;
}

inline double MaxAbsDifference(const std::vector<double>& a, const std::vector<double>& b) {
  double worst = 0.0;
  for (size_t k = 0; k < a.size() && k < b.size(); ++k)
    worst = std::max(worst, std::abs(a[k] - b[k]));
  return worst;
}

}  // namespace flexid::testing
