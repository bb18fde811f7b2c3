#include "model/core/discretise.h"

#include <cmath>
#include <unsupported/Eigen/MatrixFunctions>

namespace flexid::model {

namespace {

// The augmented exponential [[A h, B h], [0, 0]] -> [[E, F], [0, I]] in matrices of S
// rows (Eigen::Dynamic: any size). Fixed sizes keep a simulation's hundreds of
// discretisations off the heap (a chirp's operating points cost a third of its time).
template <int S>
ZohStep AugmentedExponential(const Eigen::MatrixXd& A, const Eigen::MatrixXd& inputs, double h) {
  const Eigen::Index n = A.rows();
  const Eigen::Index m = inputs.cols();
  using Matrix = Eigen::Matrix<double, S, S>;
  Matrix augmented = Matrix::Zero(n + m, n + m);
  augmented.topLeftCorner(n, n) = A * h;
  augmented.topRightCorner(n, m) = inputs * h;
  const Matrix exp_augmented = augmented.exp();
  return {exp_augmented.topLeftCorner(n, n), exp_augmented.topRightCorner(n, m)};
}

}  // namespace

ZohStep ExactZohStep(const Eigen::MatrixXd& A, const Eigen::MatrixXd& inputs, double h) {
  switch (A.rows() + inputs.cols()) {
    case 2:
      return AugmentedExponential<2>(A, inputs, h);
    case 3:
      return AugmentedExponential<3>(A, inputs, h);
    case 4:
      return AugmentedExponential<4>(A, inputs, h);
    case 5:
      return AugmentedExponential<5>(A, inputs, h);
    case 6:
      return AugmentedExponential<6>(A, inputs, h);
    case 7:
      return AugmentedExponential<7>(A, inputs, h);
    default:
      return AugmentedExponential<Eigen::Dynamic>(A, inputs, h);
  }
}

void SplitDelay(double delay_s, double dt_s, int* delay_samples, double* delay_fraction) {
  const double samples = delay_s / dt_s;
  double whole = std::floor(samples);
  double fraction = samples - whole;
  if (fraction > 1.0 - 1e-9) {
    whole += 1.0;
    fraction = 0.0;
  } else if (fraction < 1e-9) {
    fraction = 0.0;
  }
  *delay_samples = static_cast<int>(whole);
  *delay_fraction = fraction;
}

DiscreteModel DiscretiseZoh(const StateSpace& ss, double dt_s) {
  DiscreteModel dm;
  dm.dt_s = dt_s;
  SplitDelay(ss.delay_s, dt_s, &dm.delay_samples, &dm.delay_fraction);
  const double theta_s = dm.delay_fraction * dt_s;
  const ZohStep full = ExactZohStep(ss.A, ss.B, dt_s);
  dm.Phi = full.E;
  if (theta_s == 0.0) {
    dm.Gamma0 = full.F.col(0);
    dm.Gamma1 = Eigen::VectorXd::Zero(ss.A.rows());
  } else {
    // Gamma1 = int_{dt-theta}^{dt} e^{A s} ds B = F(dt) - F(dt - theta): one more
    // exponential instead of two.
    const ZohStep late = ExactZohStep(ss.A, ss.B, dt_s - theta_s);
    dm.Gamma0 = late.F.col(0);
    dm.Gamma1 = full.F.col(0) - late.F.col(0);
  }
  dm.C = ss.C;
  dm.D = ss.D;
  return dm;
}

}  // namespace flexid::model
