#include "model/core/secant_lm.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>

namespace flexid::model {
namespace {

// Secant updates after which a failed step differences the whole Jacobian again rather
// than only raising the damping.
constexpr int kStaleAfter = 3;
// Secant updates after which the whole Jacobian is differenced again in any case.
constexpr int kRefreshAfter = 5;

// One solve's state: the point, its residuals, the Jacobian estimate and the normal
// equations, the damping.
class SecantSolver {
 public:
  SecantSolver(const std::function<bool(const double*, double*)>& residuals, size_t num_residuals,
               std::vector<double> x, const std::vector<double>& lower,
               const std::vector<double>& upper, std::vector<size_t> free,
               const SecantLmOptions& options)
      : residuals_(residuals),
        lower_(lower),
        upper_(upper),
        free_(std::move(free)),
        options_(options),
        m_(static_cast<Eigen::Index>(num_residuals)),
        p_(static_cast<Eigen::Index>(free_.size())),
        x_(std::move(x)),
        f_(m_),
        jacobian_(m_, p_),
        normal_(p_, p_),
        gradient_(p_),
        shifted_(m_),
        differenced_(m_, p_),
        fresh_(free_.size(), 0),
        trial_f_(m_) {
    if (!Evaluate(x_, &f_)) throw std::invalid_argument("secant L-M: the start is not admissible");
    cost_ = f_.squaredNorm();
  }

  SecantLmResult Run() {
    if (p_ > 0) DifferenceAll();
    for (int iteration = 0; iteration < options_.max_iterations && p_ > 0; ++iteration) {
      result_.iterations = iteration + 1;
      if (!Step()) break;
    }
    result_.x = std::move(x_);
    result_.sum_of_squares = cost_;
    return std::move(result_);
  }

 private:
  bool Evaluate(const std::vector<double>& at, Eigen::VectorXd* r) {
    ++result_.evaluations;
    return residuals_(at.data(), r->data()) && r->allFinite();
  }

  // Column c of the Jacobian by a forward difference (backward at the upper bound, or
  // where the forward point is not admissible; zero if neither is). `follow`: keep the
  // normal equations up to date.
  void DifferenceColumn(Eigen::Index c, bool follow) {
    const auto column = static_cast<size_t>(c);
    if (!fresh_[column]) {
      const size_t j = free_[column];
      double h = options_.difference_step * std::max(1.0, std::abs(x_[j]));
      bool found = false;
      for (int side = 0; side < 2 && !found; ++side, h = -h) {
        std::vector<double> at = x_;
        at[j] = x_[j] + h;
        if (at[j] > upper_[j] || at[j] < lower_[j]) continue;
        if (!Evaluate(at, &shifted_)) continue;
        differenced_.col(c) = (shifted_ - f_) / h;
        found = true;
      }
      if (!found) differenced_.col(c).setZero();
      fresh_[column] = 1;
    }
    jacobian_.col(c) = differenced_.col(c);
    if (!follow) return;
    const Eigen::VectorXd row = jacobian_.transpose() * jacobian_.col(c);
    normal_.col(c) = row;
    normal_.row(c) = row.transpose();
    gradient_(c) = jacobian_.col(c).dot(f_);
  }

  void DifferenceAll() {
    for (Eigen::Index c = 0; c < p_; ++c) DifferenceColumn(c, false);
    updates_ = 0;
    normal_.setZero();
    normal_.selfadjointView<Eigen::Lower>().rankUpdate(jacobian_.transpose());
    normal_.triangularView<Eigen::StrictlyUpper>() = normal_.transpose();
    gradient_ = jacobian_.transpose() * f_;
  }

  // Broyden's rank-one update J += a s^T along the step s, with J^T J and J^T f.
  void SecantUpdate(const Eigen::VectorXd& a, const Eigen::VectorXd& s) {
    const Eigen::VectorXd g = jacobian_.transpose() * a;
    normal_ += g * s.transpose() + s * g.transpose() + a.squaredNorm() * (s * s.transpose());
    gradient_ += a.dot(f_) * s;
    jacobian_ += a * s.transpose();
  }

  // Convergence is declared only on a Jacobian differenced afresh at x: a small step or
  // a small decrease on a secant estimate may be the estimate's fault.
  bool Converged() {
    if (updates_ == 0) return true;
    DifferenceAll();
    return false;
  }

  // One iteration: a step tried, taken if it lowers the cost. False once converged.
  bool Step() {
    if (updates_ >= kRefreshAfter) DifferenceAll();
    if (gradient_.cwiseAbs().maxCoeff() <= 1e-14 * std::max(cost_, 1e-300) && Converged())
      return false;
    // Marquardt's scaling: damping proportional to the diagonal of J^T J.
    const Eigen::VectorXd scale =
        normal_.diagonal().cwiseMax(1e-12 * normal_.diagonal().maxCoeff());
    Eigen::MatrixXd damped = normal_;
    damped.diagonal() += mu_ * scale;
    const Eigen::VectorXd proposed = damped.ldlt().solve(-gradient_);
    if (!proposed.allFinite()) {
      RaiseDamping();
      return true;
    }
    std::vector<double> trial = x_;
    Eigen::VectorXd step(p_);
    double x_norm = 0.0;
    for (Eigen::Index c = 0; c < p_; ++c) {
      const size_t j = free_[static_cast<size_t>(c)];
      trial[j] = std::clamp(x_[j] + proposed(c), lower_[j], upper_[j]);
      step(c) = trial[j] - x_[j];
      x_norm += x_[j] * x_[j];
    }
    x_norm = std::sqrt(x_norm);
    if (step.norm() <= options_.parameter_tolerance * (x_norm + options_.parameter_tolerance))
      return !Converged();
    // The decrease the linear model predicts for the step taken, before any update.
    const double predicted = -(2.0 * gradient_.dot(step) + step.dot(normal_ * step));
    // One coordinate direction per iteration, cycling, differenced afresh when the step
    // hardly explores it (Algorithm 3.34): keeps every column from going stale.
    cycle_ = (cycle_ + 1) % p_;
    if (std::abs(step(cycle_)) < 0.8 * step.norm()) DifferenceColumn(cycle_, true);
    const bool admissible = Evaluate(trial, &trial_f_);
    if (admissible) {
      // Broyden's rank-one update along the step taken.
      SecantUpdate((trial_f_ - f_ - jacobian_ * step) / step.squaredNorm(), step);
      ++updates_;
    }
    const double trial_cost =
        admissible ? trial_f_.squaredNorm() : std::numeric_limits<double>::infinity();
    if (trial_cost < cost_) {
      Take(std::move(trial), trial_cost, predicted);
      return true;
    }
    if (updates_ >= kStaleAfter) {
      // The step may have failed on a stale estimate: difference it all again here.
      DifferenceAll();
    } else {
      RaiseDamping();
    }
    return true;
  }

  // The trial point becomes x (its residuals are in trial_f_).
  void Take(std::vector<double> trial, double trial_cost, double predicted) {
    const double decrease = cost_ - trial_cost;
    const double rho = predicted > 0.0 ? decrease / predicted : 0.0;
    x_ = std::move(trial);
    std::fill(fresh_.begin(), fresh_.end(), uint8_t{0});
    f_ = trial_f_;
    cost_ = trial_cost;
    mu_ *= std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3));
    nu_ = 2.0;
    gradient_ = jacobian_.transpose() * f_;
    // A small decrease refreshes the whole Jacobian but does not end the fit: the fit
    // runs until the step or the gradient vanishes on a fresh Jacobian, or for
    // max_iterations. Measured: ending it here, once a step from a fresh Jacobian lowers
    // the cost by less than 1e-7 (or 1e-9, 1e-11), made identification 10-25 % faster
    // but moved its choice of structure on held-out data, and the independent plants'
    // fresh recordings were predicted worse: the worst of the six fits that visit every
    // level went from 0.48 to 2.31 times the noise (0.66 at 1e-9, 0.82 at 1e-11).
    if (decrease <= options_.small_decrease * (cost_ + decrease)) DifferenceAll();
  }

  void RaiseDamping() {
    mu_ *= nu_;
    nu_ *= 2.0;
  }

  const std::function<bool(const double*, double*)>& residuals_;
  const std::vector<double>& lower_;
  const std::vector<double>& upper_;
  const std::vector<size_t> free_;  // parameters that may move
  const SecantLmOptions& options_;
  const Eigen::Index m_, p_;
  SecantLmResult result_;
  std::vector<double> x_;
  Eigen::VectorXd f_;  // residuals at x
  double cost_ = 0.0;  // |f|^2
  // The Jacobian J and the normal equations' J^T J and J^T f. After the first, every
  // change of J is a column or a rank-one update, and J^T J follows it in O(m p) rather
  // than O(m p^2) (the product was a fifth of a fit's time); it is formed afresh whenever
  // the whole Jacobian is differenced again, so rounding does not accumulate.
  Eigen::MatrixXd jacobian_;
  Eigen::MatrixXd normal_;    // J^T J
  Eigen::VectorXd gradient_;  // J^T f
  Eigen::VectorXd shifted_;   // residuals at a differenced point
  // The columns differenced at the current x, kept apart from the Jacobian (which secant
  // updates change): differencing a column again before x moves would evaluate the same
  // points again. Measured on the 77,000-sample HASEL mixed recording's diagnosis: a
  // fifth of all evaluations were such repeats (a column differenced by the cycle,
  // then the whole Jacobian after a failed step at the same x).
  Eigen::MatrixXd differenced_;
  std::vector<uint8_t> fresh_;  // differenced_.col(c) is at x
  Eigen::VectorXd trial_f_;     // residuals at the trial point
  int updates_ = 0;             // secant updates since the whole Jacobian was last differenced
  double mu_ = 1e-4, nu_ = 2.0;
  Eigen::Index cycle_ = -1;
};

}  // namespace

SecantLmResult SolveSecantLm(const std::function<bool(const double*, double*)>& residuals,
                             size_t num_residuals, std::vector<double> x,
                             const std::vector<double>& lower, const std::vector<double>& upper,
                             const SecantLmOptions& options) {
  const size_t n = x.size();
  if (lower.size() != n || upper.size() != n)
    throw std::invalid_argument("secant L-M: bounds and parameters differ in length");
  if (num_residuals == 0) throw std::invalid_argument("secant L-M: no residuals");
  if (options.max_iterations < 0 || !(options.difference_step > 0.0))
    throw std::invalid_argument("secant L-M: invalid options");
  std::vector<size_t> free;
  for (size_t j = 0; j < n; ++j) {
    if (!(lower[j] <= upper[j]) || std::isnan(x[j]))
      throw std::invalid_argument("secant L-M: parameter " + std::to_string(j) +
                                  " has empty bounds or is NaN");
    x[j] = std::clamp(x[j], lower[j], upper[j]);
    if (lower[j] < upper[j]) free.push_back(j);
  }
  return SecantSolver(residuals, num_residuals, std::move(x), lower, upper, std::move(free),
                      options)
      .Run();
}

}  // namespace flexid::model
