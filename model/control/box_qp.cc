#include "model/control/box_qp.h"

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
  // The working set: the variables held at a bound (where x0 puts them, to begin with).
  std::vector<bool> held(static_cast<size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i)
    held[static_cast<size_t>(i)] = x(i) <= lo(i) || x(i) >= hi(i);
  const double scale = std::max(1.0, M.diagonal().cwiseAbs().maxCoeff());
  Eigen::VectorXd g = M * x - c;  // the gradient at x, kept with x
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    result.iterations = iteration + 1;
    std::vector<Eigen::Index> free;
    for (Eigen::Index i = 0; i < n; ++i)
      if (!held[static_cast<size_t>(i)]) free.push_back(i);
    const auto m = static_cast<Eigen::Index>(free.size());
    // The Newton step to the minimiser over the free variables, the held ones fixed.
    Eigen::VectorXd step = Eigen::VectorXd::Zero(m);
    if (m > 0) {
      Eigen::MatrixXd M_ff(m, m);
      Eigen::VectorXd g_f(m);
      for (Eigen::Index a = 0; a < m; ++a) {
        g_f(a) = g(free[a]);
        for (Eigen::Index b = 0; b < m; ++b) M_ff(a, b) = M(free[a], free[b]);
      }
      step = M_ff.ldlt().solve(-g_f);
    }
    // The longest part of it, up to all, that stays in the box.
    double alpha = 1.0;
    Eigen::Index blocking = -1;
    for (Eigen::Index a = 0; a < m; ++a) {
      const Eigen::Index i = free[a];
      double reach = INFINITY;
      if (step(a) > 0.0) reach = (hi(i) - x(i)) / step(a);
      if (step(a) < 0.0) reach = (lo(i) - x(i)) / step(a);
      if (reach < alpha) {
        alpha = std::max(reach, 0.0);
        blocking = a;
      }
    }
    for (Eigen::Index a = 0; a < m; ++a) x(free[a]) += alpha * step(a);
    x = x.cwiseMax(lo).cwiseMin(hi);
    if (blocking >= 0) {  // a bound reached first: held there
      const Eigen::Index i = free[blocking];
      x(i) = step(blocking) > 0.0 ? hi(i) : lo(i);
      held[static_cast<size_t>(i)] = true;
    }
    g = M * x - c;
    if (blocking >= 0) continue;
    // At the working set's minimiser: release the held variable whose gradient pulls it
    // inwards most (its multiplier has the wrong sign). None: the KKT conditions hold.
    const double tolerance = 1e-12 * scale * std::max(1.0, x.cwiseAbs().maxCoeff());
    Eigen::Index release = -1;
    double pull = tolerance;
    for (Eigen::Index i = 0; i < n; ++i) {
      if (!held[static_cast<size_t>(i)] || !(lo(i) < hi(i))) continue;
      const double inwards = x(i) <= lo(i) ? -g(i) : g(i);
      if (inwards > pull) {
        pull = inwards;
        release = i;
      }
    }
    if (release < 0) {
      result.converged = true;
      return result;
    }
    held[static_cast<size_t>(release)] = false;
  }
  return result;
}

}  // namespace flexid::model::control
