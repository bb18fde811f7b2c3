// A small quadratic programme with bounds, the model predictive controller's inner
// problem (mpc.h): minimise (1/2) x^T M x - c^T x subject to lo <= x <= hi, with M
// symmetric positive definite and a few dozen variables at most.
//
// Method: the primal active-set method. A working set of variables is held at their
// bounds (where x0, clipped into the box, puts them). Each iteration takes the Newton step
// to the minimiser over the other variables (M_FF d_F = -g_F, g = M x - c), shortened to
// stay within the box; a variable that reaches a bound first joins the working set. At the
// working set's minimiser, the held variable whose gradient pulls it into the box most
// leaves it; when none does, every free variable has g_i = 0 and every held one g_i
// pushing outwards: the Karush-Kuhn-Tucker conditions of a convex programme. Only there
// does a variable leave the set, so the cost falls at every step and no set comes back:
// the method ends within finitely many iterations. (Releasing every variable whose
// gradient points inwards at each iteration, as an earlier version did, can cycle without
// progress when M is ill-conditioned: the controller's plans then stayed where they
// started, see tests/control_test.cc.)
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
                       const Eigen::VectorXd& x0, int max_iterations = 1000);

}  // namespace flexid::model::control
