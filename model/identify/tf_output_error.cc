// The transfer-function fit's output-error refinement (identify.h, stage 4): the
// denominator as a product of positive factors and its bounds, the exact simulation with
// its sensitivities (the analytic Jacobian), the Ceres residual block and solve, and the
// choice between the fits from the linear estimate and from a neighbouring model.
#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <string>
#include <vector>

#include "model/core/discretise.h"
#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/polynomial.h"
#include "model/core/residual_tests.h"
#include "model/identify/tf_fit.h"

namespace flexid::model::tf_fit {
namespace {

// -----------------------------------------------------------------------------------------
// Continuous-time model pieces
// -----------------------------------------------------------------------------------------

// Denominator as a product of quadratics s^2 + c1 s + c0 (and s + c for odd n) with
// c = exp(p): every parameter vector gives a Hurwitz polynomial.
struct FactorBasis {
  std::vector<std::vector<double>> factors;  // each monic, degree 1 or 2
};

FactorBasis FactorsFromParameters(const double* p, int n) {
  FactorBasis basis;
  int i = 0;
  for (; i + 1 < n; i += 2) basis.factors.push_back({1.0, std::exp(p[i]), std::exp(p[i + 1])});
  if (n % 2 == 1) basis.factors.push_back({1.0, std::exp(p[n - 1])});
  return basis;
}

std::vector<double> ProductOf(const std::vector<std::vector<double>>& factors, size_t skip) {
  std::vector<double> product = {1.0};
  for (size_t f = 0; f < factors.size(); ++f)
    if (f != skip) product = MultiplyPolynomials(product, factors[f]);
  return product;
}

}  // namespace

void DenominatorAndDerivative(const double* p, int n, std::vector<double>* a,
                              Eigen::MatrixXd* da_dp) {
  const FactorBasis basis = FactorsFromParameters(p, n);
  const std::vector<double> den = ProductOf(basis.factors, basis.factors.size());
  a->assign(den.begin() + 1, den.end());
  if (!da_dp) return;
  da_dp->setZero(n, n);
  int l = 0;
  for (size_t f = 0; f < basis.factors.size(); ++f) {
    const std::vector<double> others = ProductOf(basis.factors, f);  // degree n - deg(f)
    const auto& factor = basis.factors[f];
    // d den / d c_j = s^{deg f - j} * others (c_j = factor[j], j >= 1); d c_j / d p = c_j.
    for (size_t j = 1; j < factor.size(); ++j, ++l) {
      std::vector<double> derivative = others;
      derivative.resize(others.size() + (factor.size() - 1 - j), 0.0);  // times s^{deg f - j}
      // derivative has degree <= n - 1; align its constant term with a_n.
      const int offset = n - static_cast<int>(derivative.size());
      for (size_t c = 0; c < derivative.size(); ++c)
        (*da_dp)(offset + static_cast<int>(c), l) = derivative[c] * factor[j];
    }
  }
}

namespace {

// The band of modes the data can tell apart from a drift or a static gain: no slower
// than a tenth of the inverse record length, no faster than twice the Nyquist frequency.
// Bounds on the factor parameters (log c) keep every pole inside it; a pole far outside
// would also make the output-derivative realisation stiff (Markov parameters growing like
// |p|^k) and its simulation inaccurate.
struct FactorBounds {
  std::vector<double> lower, upper;  // per factor parameter (log c)
};

FactorBounds BoundsFor(int n, double dt_s, size_t longest_samples) {
  const double fastest_rad_s = 2.0 * M_PI / dt_s;
  const double slowest_rad_s =
      0.1 / (dt_s * static_cast<double>(std::max<size_t>(longest_samples, 1)));
  FactorBounds bounds;
  for (int i = 0; i + 1 < n; i += 2) {
    // s^2 + c1 s + c0: c0 = |p|^2 between slowest^2 and fastest^2; c1 = 2 zeta |p| up to
    // 2 fastest (a real pair can reach c1 ~ fastest + slowest), with no useful lower bound
    // beyond keeping it positive.
    bounds.lower.insert(bounds.lower.end(), {std::log(1e-12), 2.0 * std::log(slowest_rad_s)});
    bounds.upper.insert(bounds.upper.end(),
                        {std::log(2.0 * fastest_rad_s), 2.0 * std::log(fastest_rad_s)});
  }
  if (n % 2 == 1) {
    bounds.lower.push_back(std::log(slowest_rad_s));
    bounds.upper.push_back(std::log(fastest_rad_s));
  }
  return bounds;
}

void ClampToBounds(const FactorBounds& bounds, std::vector<double>* params) {
  for (size_t i = 0; i < params->size(); ++i)
    (*params)[i] = std::clamp((*params)[i], bounds.lower[i], bounds.upper[i]);
}

}  // namespace

std::vector<double> ParametersFromPoles(std::vector<Complex> poles, int n) {
  // Clamp to the open left half-plane, then pair: complex conjugates together, real
  // poles by magnitude.
  for (Complex& p : poles) {
    if (p.real() >= 0.0) p = Complex(-std::max(std::abs(p.real()), 1e-6), p.imag());
    if (std::abs(p) < 1e-9) p = Complex(-1e-9, 0.0);
  }
  std::vector<double> real;
  std::vector<Complex> upper;
  for (const Complex& p : poles) {
    if (std::abs(p.imag()) <= 1e-12 * std::max(1.0, std::abs(p)))
      real.push_back(p.real());
    else if (p.imag() > 0)
      upper.push_back(p);
  }
  std::sort(real.begin(), real.end(), [](double x, double y) { return std::abs(x) > std::abs(y); });
  std::vector<double> params;
  for (const Complex& p : upper) {
    params.push_back(std::log(-2.0 * p.real()));
    params.push_back(std::log(std::norm(p)));
  }
  size_t r = 0;
  for (; r + 1 < real.size() && static_cast<int>(params.size()) + 1 < n; r += 2) {
    params.push_back(std::log(-(real[r] + real[r + 1])));
    params.push_back(std::log(real[r] * real[r + 1]));
  }
  if (r < real.size()) params.push_back(std::log(-real[r]));
  params.resize(static_cast<size_t>(n), 0.0);
  return params;
}

namespace {

// The per-sample loop, on fixed-size matrices for the usual orders (2n = 2..8 states).
template <int N2>
void RunSensitivities(const DiscreteModel& dm, const DataSegment& seg, const std::vector<double>& a,
                      const Eigen::RowVectorXd& cb, int m, bool with_jacobian, Drive drive,
                      double u_before, Sensitivity* out) {
  using Mat = Eigen::Matrix<double, N2, N2>;
  using Vec = Eigen::Matrix<double, N2, 1>;
  const int n = static_cast<int>(a.size());
  const Mat phi = dm.Phi;
  const Vec gamma0 = dm.Gamma0, gamma1 = dm.Gamma1;
  const size_t count = seg.voltage_V.size();
  const double u0 = drive == Drive::kRecorded ? u_before : 1.0;
  const bool recorded = drive == Drive::kRecorded;
  const long d = dm.delay_samples;
  const bool fractional = dm.delay_fraction > 0.0;
  auto u_at = [&](long j) {
    return j < 0 ? u0 : (recorded ? seg.voltage_V[static_cast<size_t>(j)] : 0.0);
  };

  // Steady state under u0: w = u0 / a_n, yhat = b_m w, v = yhat / a_n.
  Vec state = Vec::Zero(2 * n);
  state(0) = u0 / a.back();
  state(n) = cb(0) * state(0) / a.back();

  out->yhat.resize(count);
  if (with_jacobian) out->jac.resize(static_cast<Eigen::Index>(count), m + n + 2);
  for (size_t k = 0; k < count; ++k) {
    const long kk = static_cast<long>(k);
    const double u_now = u_at(kk - d), u_prev = u_at(kk - d - 1);
    double yhat = 0.0;
    for (int i = 0; i <= m; ++i) yhat += cb(i) * state(i);
    out->yhat[k] = yhat;
    if (with_jacobian) {
      double* row = out->jac.data() + k * static_cast<size_t>(m + n + 2);
      for (int j = 0; j <= m; ++j) row[j] = state(m - j);
      for (int i = 1; i <= n; ++i) row[m + i] = -state(n + n - i);
      // d yhat/dt = cb x', x'_i = x_{i+1}, x'_{n-1} = u(t - T) - sum a_i x_{n-i}.
      double last = fractional ? u_prev : u_now;
      for (int i = 1; i <= n; ++i) last -= a[static_cast<size_t>(i - 1)] * state(n - i);
      double rate = 0.0;
      for (int i = 0; i <= m; ++i) rate += cb(i) * (i + 1 < n ? state(i + 1) : last);
      row[m + n + 1] = -rate;
    }
    state = phi * state + gamma0 * u_now + gamma1 * u_prev;
  }
}

}  // namespace

void SimulateSensitivities(const DataSegment& seg, const std::vector<double>& b,
                           const std::vector<double>& a, double delay_s, bool with_jacobian,
                           Sensitivity* out, Drive drive, double u_before) {
  if (std::isnan(u_before)) u_before = seg.initial_voltage_V;
  const int n = static_cast<int>(a.size()), m = static_cast<int>(b.size()) - 1;
  // Controllable canonical form of 1/A(s): x = [w, w', ..., w^{(n-1)}].
  Eigen::MatrixXd ac = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i + 1 < n; ++i) ac(i, i + 1) = 1.0;
  for (int i = 1; i <= n; ++i) ac(n - 1, n - i) = -a[static_cast<size_t>(i - 1)];
  Eigen::RowVectorXd cb = Eigen::RowVectorXd::Zero(n);  // yhat = cb x
  for (int i = 0; i <= m; ++i) cb(i) = b[static_cast<size_t>(m - i)];
  StateSpace aug;
  aug.A = Eigen::MatrixXd::Zero(2 * n, 2 * n);
  aug.A.topLeftCorner(n, n) = ac;
  aug.A.bottomRightCorner(n, n) = ac;
  aug.A.block(2 * n - 1, 0, 1, n) = cb;  // z driven by yhat
  aug.B = Eigen::VectorXd::Zero(2 * n);
  aug.B(n - 1) = 1.0;
  aug.C = Eigen::RowVectorXd::Zero(2 * n);
  aug.delay_s = delay_s;
  const DiscreteModel dm = DiscretiseZoh(aug, seg.dt_s);
  switch (2 * n) {
    case 2:
      return RunSensitivities<2>(dm, seg, a, cb, m, with_jacobian, drive, u_before, out);
    case 4:
      return RunSensitivities<4>(dm, seg, a, cb, m, with_jacobian, drive, u_before, out);
    case 6:
      return RunSensitivities<6>(dm, seg, a, cb, m, with_jacobian, drive, u_before, out);
    case 8:
      return RunSensitivities<8>(dm, seg, a, cb, m, with_jacobian, drive, u_before, out);
    default:
      return RunSensitivities<Eigen::Dynamic>(dm, seg, a, cb, m, with_jacobian, drive, u_before,
                                              out);
  }
}

// -----------------------------------------------------------------------------------------
// The Ceres fit
// -----------------------------------------------------------------------------------------

namespace {

// Ceres residual block for one segment: r = y - yhat over the fitted samples. Parameter
// blocks: b, the denominator factors, the dead time and, when the segment's initial
// voltage is estimated, that voltage u0 (yhat = yhat_recorded + u0 yhat_unit, both from
// the exact simulation: the output is linear in the voltage held before the segment).
class SegmentCost final : public ceres::CostFunction {
 public:
  SegmentCost(const DataSegment& segment, int m, int n) : seg_(segment), m_(m), n_(n) {
    set_num_residuals(static_cast<int>(segment.voltage_V.size() - segment.fit_begin));
    mutable_parameter_block_sizes()->assign({m + 1, n, 1});
    if (segment.estimate_initial_voltage) mutable_parameter_block_sizes()->push_back(1);
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const std::vector<double> b(parameters[0], parameters[0] + m_ + 1);
    std::vector<double> a;
    Eigen::MatrixXd da_dp;
    DenominatorAndDerivative(parameters[1], n_, &a, jacobians ? &da_dp : nullptr);
    for (double c : a)
      if (!std::isfinite(c) || c <= 0.0) return false;
    const double delay_s = parameters[2][0];
    if (!(delay_s >= 0.0)) return false;
    const bool with_jacobian = jacobians != nullptr;
    Sensitivity s, unit;
    double u0 = 0.0;
    if (seg_.estimate_initial_voltage) {
      u0 = parameters[3][0];
      SimulateSensitivities(seg_, b, a, delay_s, with_jacobian, &s, Drive::kRecorded, 0.0);
      SimulateSensitivities(seg_, b, a, delay_s, with_jacobian, &unit, Drive::kUnitBeforeStart);
      for (size_t k = 0; k < s.yhat.size(); ++k) s.yhat[k] += u0 * unit.yhat[k];
      if (with_jacobian) s.jac += u0 * unit.jac;
    } else {
      SimulateSensitivities(seg_, b, a, delay_s, with_jacobian, &s);
    }
    const size_t first = seg_.fit_begin;
    const size_t rows = seg_.voltage_V.size() - first;
    for (size_t r = 0; r < rows; ++r) {
      residuals[r] = seg_.deflection_mm[first + r] - s.yhat[first + r];
      if (!std::isfinite(residuals[r])) return false;
    }
    if (!with_jacobian) return true;
    for (size_t r = 0; r < rows; ++r) {
      const auto row = s.jac.row(static_cast<Eigen::Index>(first + r));
      if (jacobians[0])
        for (int j = 0; j <= m_; ++j)
          jacobians[0][r * static_cast<size_t>(m_ + 1) + static_cast<size_t>(j)] = -row(j);
      if (jacobians[1])
        for (int l = 0; l < n_; ++l) {
          double v = 0.0;
          for (int i = 0; i < n_; ++i) v += row(m_ + 1 + i) * da_dp(i, l);
          jacobians[1][r * static_cast<size_t>(n_) + static_cast<size_t>(l)] = -v;
        }
      if (jacobians[2]) jacobians[2][r] = -row(m_ + n_ + 1);
      if (seg_.estimate_initial_voltage && jacobians[3]) jacobians[3][r] = -unit.yhat[first + r];
    }
    return true;
  }

 private:
  const DataSegment& seg_;
  int m_, n_;
};

// Sensor noise of the deflection, estimated from the data alone: the robust spread of
// second differences, sigma = 1.4826 MAD(d2 y) / sqrt(6) (white noise of variance sigma^2
// gives d2 y of variance 6 sigma^2; the slow, smooth response contributes little and the
// few steps are outliers to the median).
double NoiseFromData(const std::vector<DataSegment>& segments) {
  std::vector<double> second;
  for (const DataSegment& seg : segments)
    for (size_t k = seg.fit_begin + 2; k < seg.deflection_mm.size(); ++k)
      second.push_back(seg.deflection_mm[k] - 2.0 * seg.deflection_mm[k - 1] +
                       seg.deflection_mm[k - 2]);
  return RobustSpread(std::move(second)) / std::sqrt(6.0);
}

// Ends the fit when a successful step lowers the cost by less than `threshold`.
class NoiseAwareStop final : public ceres::IterationCallback {
 public:
  explicit NoiseAwareStop(double threshold) : threshold_(threshold) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override {
    if (summary.iteration > 0 && summary.step_is_successful && summary.cost_change < threshold_)
      return ceres::SOLVER_TERMINATE_SUCCESSFULLY;
    return ceres::SOLVER_CONTINUE;
  }

 private:
  double threshold_;
};

// Output-error fit of b, the denominator factors and (unless fixed) the dead time, from
// the given start; see identify.h, stage 4.
void SolveOutputError(const std::vector<DataSegment>& segments, int m, int n, bool estimate_delay,
                      double max_delay_s, int max_iterations, std::vector<double>* b,
                      std::vector<double>* factor_params, double* delay_s,
                      std::vector<double>* initial_voltages_V, ceres::Solver::Summary* summary) {
  ceres::Problem problem;
  size_t fitted_samples = 0;
  for (size_t i = 0; i < segments.size(); ++i) {
    const DataSegment& seg = segments[i];
    std::vector<double*> blocks = {b->data(), factor_params->data(), delay_s};
    if (seg.estimate_initial_voltage) blocks.push_back(&(*initial_voltages_V)[i]);
    problem.AddResidualBlock(new SegmentCost(seg, m, n), nullptr, blocks);
    fitted_samples += seg.voltage_V.size() - seg.fit_begin;
  }
  size_t longest = 0;
  for (const DataSegment& seg : segments) longest = std::max(longest, seg.voltage_V.size());
  const FactorBounds bounds = BoundsFor(n, segments.front().dt_s, longest);
  ClampToBounds(bounds, factor_params);
  for (int i = 0; i < n; ++i) {
    problem.SetParameterLowerBound(factor_params->data(), i, bounds.lower[static_cast<size_t>(i)]);
    problem.SetParameterUpperBound(factor_params->data(), i, bounds.upper[static_cast<size_t>(i)]);
  }
  if (estimate_delay) {
    problem.SetParameterLowerBound(delay_s, 0, 0.0);
    problem.SetParameterUpperBound(delay_s, 0, std::max(max_delay_s, segments.front().dt_s));
  } else {
    problem.SetParameterBlockConstant(delay_s);
  }
  ceres::Solver::Options solver_options;
  solver_options.minimizer_type = ceres::TRUST_REGION;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  // Few parameters, many residuals: J^T J (with Ceres' Jacobi scaling) is much cheaper
  // than QR of J, and the log-parameterised factors keep it well conditioned.
  solver_options.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;
  solver_options.max_num_iterations = max_iterations;
  // Stop when a step gains less than 0.05 sigma^2 in the sum of squares, with sigma the
  // sensor noise estimated from the data (NoiseFromData): a twentieth of the noise
  // variance, far below what a likelihood-ratio test could detect (3.84 sigma^2 at 95 %).
  // On noisy data this ends the slow crawl along the ridge where the dead time and a
  // weakly excited fast mode trade off; on clean data sigma is ~0 and the fit runs to
  // machine precision.
  (void)fitted_samples;
  NoiseAwareStop stop(0.5 * 0.05 * NoiseFromData(segments) * NoiseFromData(segments));
  solver_options.callbacks.push_back(&stop);
  solver_options.function_tolerance = 1e-12;
  solver_options.gradient_tolerance = 1e-12;
  solver_options.parameter_tolerance = 1e-10;
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solve(solver_options, &problem, summary);
}

}  // namespace

OutputErrorSummary RefineOutputError(const std::vector<DataSegment>& segments,
                                     const IdentifyOptions& options, std::vector<double>* b_io,
                                     std::vector<double>* factor_params_io, double* delay_s_io,
                                     std::vector<double>* initial_voltages_io) {
  const int n = options.num_poles, m = options.num_zeros;
  std::vector<double>& b = *b_io;
  std::vector<double>& factor_params = *factor_params_io;
  double& delay_s = *delay_s_io;
  std::vector<double>& initial_voltages_V = *initial_voltages_io;
  ceres::Solver::Summary summary;
  SolveOutputError(segments, m, n, options.estimate_delay, options.max_delay_s,
                   options.max_iterations, &b, &factor_params, &delay_s, &initial_voltages_V,
                   &summary);
  if (options.start && Order(*options.start) == n && IsStable(*options.start) &&
      static_cast<int>(TrimLeadingZeros(options.start->num).size()) <= m + 1) {
    const TransferFunction start = Normalised(*options.start);
    std::vector<double> start_b(static_cast<size_t>(m) + 1, 0.0);
    std::copy(start.num.begin(), start.num.end(),
              start_b.end() - static_cast<long>(start.num.size()));
    std::vector<double> start_factors = ParametersFromPoles(Poles(start), n);
    double start_delay = options.estimate_delay ? start.delay_s : delay_s;
    std::vector<double> start_voltages = initial_voltages_V;
    for (size_t i = 0; i < segments.size(); ++i) start_voltages[i] = segments[i].initial_voltage_V;
    ceres::Solver::Summary start_summary;
    SolveOutputError(segments, m, n, options.estimate_delay, options.max_delay_s,
                     options.max_iterations, &start_b, &start_factors, &start_delay,
                     &start_voltages, &start_summary);
    // Keep the model of the neighbour's structure unless the free fit is better both by
    // more than a likelihood-ratio test could put down to noise (chi2_1 95 %: 3.84 sigma^2
    // in the sum of squares, 1.92 sigma^2 in the cost) and by more than 1 % of the cost
    // (on nearly noise-free data the test alone would take any difference as real).
    size_t count = 0;
    for (const DataSegment& seg : segments) count += seg.voltage_V.size() - seg.fit_begin;
    const double sigma2 = 2.0 * std::min(summary.final_cost, start_summary.final_cost) /
                          static_cast<double>(std::max<size_t>(1, count));
    if (start_summary.IsSolutionUsable() &&
        !(summary.final_cost <
              start_summary.final_cost - 0.5 * ChiSquareQuantile(0.95, 1) * sigma2 &&
          summary.final_cost < 0.99 * start_summary.final_cost)) {
      b = start_b;
      factor_params = start_factors;
      delay_s = start_delay;
      initial_voltages_V = start_voltages;
      summary = start_summary;
    }
  }
  return {summary.IsSolutionUsable(), summary.message, static_cast<int>(summary.iterations.size()),
          summary.BriefReport()};
}

}  // namespace flexid::model::tf_fit
