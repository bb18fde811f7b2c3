#include "model/core/state_space.h"

namespace flexid::model {

Eigen::VectorXd MarkovParameters(const TransferFunction& tf) {
  const TransferFunction g = Normalised(tf);
  const int n = static_cast<int>(g.den.size()) - 1;
  // Numerator padded to n + 1 coefficients: b0 s^n + ... + b_n.
  Eigen::VectorXd b = Eigen::VectorXd::Zero(n + 1);
  const int pad = n + 1 - static_cast<int>(g.num.size());
  for (size_t i = 0; i < g.num.size(); ++i) b(pad + static_cast<int>(i)) = g.num[i];
  Eigen::VectorXd h(n + 1);
  for (int k = 0; k <= n; ++k) {
    double hk = b(k);
    for (int i = 1; i <= k; ++i) hk -= g.den[i] * h(k - i);
    h(k) = hk;
  }
  return h;
}

StateSpace RealiseOutputDerivativeForm(const TransferFunction& tf) {
  const TransferFunction g = Normalised(tf);
  const int n = static_cast<int>(g.den.size()) - 1;
  const Eigen::VectorXd h = MarkovParameters(g);
  StateSpace ss;
  ss.A = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i + 1 < n; ++i) ss.A(i, i + 1) = 1.0;
  for (int j = 0; j < n; ++j) ss.A(n - 1, j) = -g.den[n - j];
  ss.B = h.tail(n);
  ss.C = Eigen::RowVectorXd::Zero(n);
  if (n > 0) ss.C(0) = 1.0;
  ss.D = h(0);
  ss.delay_s = g.delay_s;
  return ss;
}

}  // namespace flexid::model
