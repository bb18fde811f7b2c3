// A small quadratic programme with bounds, the model predictive controller's inner
// problem (mpc.h): minimise (1/2) x^T M x - c^T x subject to lo <= x <= hi, with M
// symmetric positive definite and a few dozen variables at most.
//
// Method: a primal active-set (projected Newton) iteration. From a feasible x, the
// variables at a bound whose gradient g = M x - c pushes them outwards are held there; a
// Newton step solves for the others (M_FF d_F = -g_F) and is shortened to stay within
// the bounds; a variable that reaches a bound joins the held ones. At the optimum every
// free variable has g_i = 0 and every held one g_i pushing outwards (the Karush-Kuhn-Tucker
// conditions of a convex programme).
#pragma once

#include <Eigen/Dense>

namespace flexid::model::control {

struct BoxQpResult {
  Eigen::VectorXd x;
  int iterations = 0;
  bool converged = false;  // the KKT conditions hold (to rounding)
};

// Preconditions: sizes agree, lo <= hi. x0 is a starting point (clipped into the box).
BoxQpResult SolveBoxQp(const Eigen::MatrixXd& M, const Eigen::VectorXd& c,
                       const Eigen::VectorXd& lo, const Eigen::VectorXd& hi,
                       const Eigen::VectorXd& x0, int max_iterations = 100);

}  // namespace flexid::model::control
