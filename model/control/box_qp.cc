#include "model/control/box_qp.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace flexid::model::control {

BoxQpResult SolveBoxQp(const Eigen::MatrixXd& M, const Eigen::VectorXd& c,
                       const Eigen::VectorXd& lo, const Eigen::VectorXd& hi,
                       const Eigen::VectorXd& x0, int max_iterations) {
  const Eigen::Index n = c.size();
  BoxQpResult result;
  result.x = x0.cwiseMax(lo).cwiseMin(hi);
  Eigen::VectorXd& x = result.x;
  const double scale = std::max(1.0, M.diagonal().cwiseAbs().maxCoeff());
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    result.iterations = iteration + 1;
    const Eigen::VectorXd g = M * x - c;
    std::vector<Eigen::Index> free;
    for (Eigen::Index i = 0; i < n; ++i) {
      const bool held = (x(i) <= lo(i) && g(i) > 0.0) || (x(i) >= hi(i) && g(i) < 0.0);
      if (!held) free.push_back(i);
    }
    if (free.empty()) {
      result.converged = true;
      return result;
    }
    const auto m = static_cast<Eigen::Index>(free.size());
    Eigen::MatrixXd M_ff(m, m);
    Eigen::VectorXd g_f(m);
    for (Eigen::Index a = 0; a < m; ++a) {
      g_f(a) = g(free[a]);
      for (Eigen::Index b = 0; b < m; ++b) M_ff(a, b) = M(free[a], free[b]);
    }
    const Eigen::VectorXd d = M_ff.ldlt().solve(-g_f);
    if (g_f.cwiseAbs().maxCoeff() <= 1e-12 * scale * std::max(1.0, x.cwiseAbs().maxCoeff())) {
      result.converged = true;
      return result;
    }
    // The longest step in (0, 1] along d that stays in the box.
    double alpha = 1.0;
    Eigen::Index blocking = -1;
    for (Eigen::Index a = 0; a < m; ++a) {
      const Eigen::Index i = free[a];
      double reach = INFINITY;
      if (d(a) > 0.0) reach = (hi(i) - x(i)) / d(a);
      if (d(a) < 0.0) reach = (lo(i) - x(i)) / d(a);
      if (reach < alpha) {
        alpha = std::max(reach, 0.0);
        blocking = i;
      }
    }
    for (Eigen::Index a = 0; a < m; ++a) x(free[a]) += alpha * d(a);
    x = x.cwiseMax(lo).cwiseMin(hi);
    if (blocking >= 0)
      x(blocking) = d(std::find(free.begin(), free.end(), blocking) - free.begin()) > 0.0
                        ? hi(blocking)
                        : lo(blocking);
  }
  return result;
}

}  // namespace flexid::model::control
