// Box-bounded Levenberg-Marquardt whose Jacobian is estimated by forward differences once
// and then kept up to date by secant (Broyden rank-one) updates: the secant version of
// the L-M method in Madsen, Nielsen and Tingleff, "Methods for non-linear least squares
// problems" (2004), Algorithm 3.34.
//
// Why: the global T-S fit (identify_global.h) has no analytic Jacobian; every residual
// evaluation is a simulation of the whole model over every recording. Forward differences
// at every iteration cost one simulation per parameter (20-35 of them), which made nearly
// all of an identification's time. Here an iteration costs two simulations: the trial
// point, and one coordinate direction whose difference refreshes one column (cycling over
// the parameters, only when the step barely moves along it, as in the reference). The
// whole Jacobian is differenced again when a step fails on a Jacobian that is no longer
// fresh, since the failure may be the estimate's and not the model's. No point is
// evaluated twice: a column differenced at the current point is kept (a second m x p
// matrix) until the point moves.
//
// Bounds: the trial point is projected onto the box, and the step taken is the projected
// one. A parameter with equal bounds is held. Scaling: the damping is mu * diag(J^T J)
// (Marquardt), so parameters of very different sizes (a dead time in seconds, gains in
// mm/V, log-frequencies) are treated alike.
#pragma once

#include <cstddef>
#include <functional>
#include <vector>

namespace flexid::model {

struct SecantLmOptions {
  int max_iterations = 60;  // steps tried, accepted or not
  // An accepted step that lowers the cost by less than this, relatively, has the whole
  // Jacobian differenced again (it does not end the fit: see secant_lm.cc).
  double small_decrease = 1e-7;
  double parameter_tolerance = 1e-10;  // stop when the step is this small, relatively
  double difference_step = 1e-6;       // relative forward-difference step (at least this)
};

struct SecantLmResult {
  std::vector<double> x;
  double sum_of_squares = 0.0;
  int iterations = 0;
  int evaluations = 0;  // calls of the residual function
};

// residuals(x, r) writes num_residuals values to r; false marks x as not admissible (the
// step is then refused and the damping raised). Throws std::invalid_argument for
// inconsistent sizes or bounds, or when the start itself is not admissible.
SecantLmResult SolveSecantLm(const std::function<bool(const double*, double*)>& residuals,
                             size_t num_residuals, std::vector<double> x,
                             const std::vector<double>& lower, const std::vector<double>& upper,
                             const SecantLmOptions& options = {});

}  // namespace flexid::model
