// Exact zero-order-hold discretisation with a dead time that need not be a whole number
// of samples (modified z-transform). With T = d dt + theta, 0 <= theta < dt, and the
// input held constant between samples:
//
//   x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1]
//   y[k]   = C x[k] + D u(t_k - T)
//
//   Phi    = e^{A dt}
//   Gamma0 = int_0^{dt-theta} e^{A s} ds B
//   Gamma1 = e^{A (dt-theta)} int_0^{theta} e^{A s} ds B = int_{dt-theta}^{dt} e^{A s} ds B
//
// Both integrals come from one matrix exponential of the augmented matrix
// [[A, B], [0, 0]] (Van Loan), so no inverse of A is needed and integrators are allowed.
#pragma once

#include <Eigen/Dense>

#include "model/core/state_space.h"

namespace flexid::model {

// Propagator over an interval h with constant input: x(h) = E x(0) + F u.
struct ZohStep {
  Eigen::MatrixXd E;  // e^{A h}
  Eigen::MatrixXd F;  // int_0^h e^{A s} ds [B_1 ... B_m] (one column per input)
};

// Columns of `inputs` are the input vectors B_1..B_m. h >= 0.
ZohStep ExactZohStep(const Eigen::MatrixXd& A, const Eigen::MatrixXd& inputs, double h);

struct DiscreteModel {
  double dt_s = 0.0;
  int delay_samples = 0;        // d
  double delay_fraction = 0.0;  // theta / dt in [0, 1)
  Eigen::MatrixXd Phi;
  Eigen::VectorXd Gamma0;
  Eigen::VectorXd Gamma1;
  Eigen::RowVectorXd C;
  double D = 0.0;
};

// Splits a delay into whole samples and a fraction; fractions within 1e-9 of a whole
// sample are rounded to it, so that a delay of exactly k samples stays integral.
void SplitDelay(double delay_s, double dt_s, int* delay_samples, double* delay_fraction);

// Precondition: dt_s > 0.
DiscreteModel DiscretiseZoh(const StateSpace& ss, double dt_s);

}  // namespace flexid::model
