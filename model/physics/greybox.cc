#include "model/physics/greybox.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/residual_tests.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Unknowns x in the solver's coordinates (header): x = (ln D, ln[alpha (1 + H)],
// ln[R_s (1 + H)], ln delta, T), H = h/delta. Ceres sees three parameter blocks: the
// first three (well determined), ln delta (weakly determined) and T.
constexpr int kUnknowns = 5;
enum Unknown { kLnD = 0, kLnAlphaTotal = 1, kLnResistanceTotal = 2, kLnDelta = 3, kDelay = 4 };
using Unknowns = std::array<double, kUnknowns>;
using Vector5 = Eigen::Matrix<double, kUnknowns, 1>;
using Matrix5 = Eigen::Matrix<double, kUnknowns, kUnknowns>;
using Jacobian = Eigen::Matrix<double, Eigen::Dynamic, kUnknowns>;

// Central-difference steps: in the logarithms a relative step of 1e-4 keeps the
// truncation error (~1e-9 relative) and the rounding error of the simulation (~1e-13 /
// 1e-4) both far below any measurement noise; in T a hundredth of a sample period.
constexpr double kLogStep = 1e-4;
constexpr double kDelayStepPerSample = 1e-2;
// Coarse delay grid step, at least one sample period (header).
constexpr double kDelayGridStep_s = 0.25;
// delta is kept within this factor of its start value (header: it is weakly determined,
// and as delta -> 0 its own derivative vanishes, so an unbounded step could strand it).
constexpr double kDeltaRange = 1e3;

// -----------------------------------------------------------------------------------------
// Data checks: everything Ceres would abort on, or that makes the fit meaningless, becomes
// an InputError here, before a Problem is built.
// -----------------------------------------------------------------------------------------

void CheckSegments(const std::vector<DataSegment>& segments, const GreyBoxOptions& options) {
  ValidateSegments(segments, kUnknowns, options.max_delay_s);  // as identify (identify.h)
}

// -----------------------------------------------------------------------------------------
// Model
// -----------------------------------------------------------------------------------------

PhysicalParameters FromUnknowns(PhysicalParameters p, const Unknowns& x) {
  p.D_m2_per_s = std::exp(x[kLnD]);
  p.delta_m = std::exp(x[kLnDelta]);
  const double one_plus_h_over_delta = 1.0 + p.h_m / p.delta_m;
  p.alpha_m3_per_C = std::exp(x[kLnAlphaTotal]) / one_plus_h_over_delta;
  p.R_s_ohm = std::exp(x[kLnResistanceTotal]) / one_plus_h_over_delta;
  return p;
}

Unknowns ToUnknowns(const PhysicalParameters& p, double delay_s) {
  const double ln_one_plus_h_over_delta = std::log1p(p.h_m / p.delta_m);
  Unknowns x;
  x[kLnD] = std::log(p.D_m2_per_s);
  x[kLnAlphaTotal] = std::log(p.alpha_m3_per_C) + ln_one_plus_h_over_delta;
  x[kLnResistanceTotal] = std::log(p.R_s_ohm) + ln_one_plus_h_over_delta;
  x[kLnDelta] = std::log(p.delta_m);
  x[kDelay] = delay_s;
  return x;
}

// Prediction without the argument checks (the callers have checked).
std::vector<double> Predict(const PhysicalParameters& p, double delay_s, int terms,
                            const DataSegment& seg) {
  const TransferFunction tf =
      CurvatureTransferFunction(p, terms, delay_s, SeriesRemainder::kStaticCorrection);
  std::vector<double> y =
      SimulateUniform(tf, seg.dt_s, seg.voltage_V, {.initial_voltage_V = seg.initial_voltage_V});
  for (double& value : y) value = 1e3 * TipDeflectionFromCurvature_m(value, p.L_m);
  return y;
}

// Fitted samples of one segment; false if the model cannot be evaluated there (a Ceres
// cost function must not throw).
bool PredictFitted(const PhysicalParameters& fixed, const Unknowns& x, int terms,
                   const DataSegment& seg, double* out) {
  if (!(x[kDelay] >= 0.0)) return false;
  try {
    const std::vector<double> y = Predict(FromUnknowns(fixed, x), x[kDelay], terms, seg);
    for (size_t k = seg.fit_begin; k < y.size(); ++k) {
      if (!std::isfinite(y[k])) return false;
      out[k - seg.fit_begin] = y[k];
    }
    return true;
  } catch (const std::exception&) {
    return false;
  }
}

// d yhat / dx on the fitted samples (rows), for the columns with wanted[j], by central
// differences (one-sided forward in T where T - step < 0); yhat is the prediction at x.
bool PredictionJacobian(const PhysicalParameters& fixed, const Unknowns& x, int terms,
                        const DataSegment& seg, const std::vector<double>& yhat,
                        const std::array<bool, kUnknowns>& wanted, Jacobian* jacobian) {
  const size_t rows = seg.voltage_V.size() - seg.fit_begin;
  jacobian->setZero(static_cast<Eigen::Index>(rows), kUnknowns);
  std::vector<double> plus(rows), minus(rows);
  for (int j = 0; j < kUnknowns; ++j) {
    if (!wanted[static_cast<size_t>(j)]) continue;
    const double step = j == kDelay ? kDelayStepPerSample * seg.dt_s : kLogStep;
    const bool central = j != kDelay || x[kDelay] - step >= 0.0;
    Unknowns shifted = x;
    shifted[static_cast<size_t>(j)] = x[static_cast<size_t>(j)] + step;
    if (!PredictFitted(fixed, shifted, terms, seg, plus.data())) return false;
    if (central) {
      shifted[static_cast<size_t>(j)] = x[static_cast<size_t>(j)] - step;
      if (!PredictFitted(fixed, shifted, terms, seg, minus.data())) return false;
    }
    for (size_t r = 0; r < rows; ++r)
      (*jacobian)(static_cast<Eigen::Index>(r), j) =
          central ? (plus[r] - minus[r]) / (2.0 * step) : (plus[r] - yhat[r]) / step;
  }
  return true;
}

// Ceres residual block for one segment: r = y - yhat over the fitted samples; parameter
// blocks (ln D, ln[alpha (1 + H)], ln[R_s (1 + H)]), (ln delta) and (T). The Jacobian is
// computed by central differences here rather than by ceres::NumericDiffCostFunction so
// that the step in T stays inside T >= 0 (the simulation rejects a negative dead time)
// and no column of a constant block is computed.
class SegmentCost final : public ceres::CostFunction {
 public:
  SegmentCost(const DataSegment& segment, const PhysicalParameters& fixed, int terms)
      : seg_(segment), fixed_(fixed), terms_(terms) {
    set_num_residuals(static_cast<int>(segment.voltage_V.size() - segment.fit_begin));
    mutable_parameter_block_sizes()->assign({3, 1, 1});
  }

  bool Evaluate(double const* const* parameters, double* residuals,
                double** jacobians) const override {
    const Unknowns x = {parameters[0][0], parameters[0][1], parameters[0][2], parameters[1][0],
                        parameters[2][0]};
    const size_t rows = static_cast<size_t>(num_residuals());
    std::vector<double> yhat(rows);
    if (!PredictFitted(fixed_, x, terms_, seg_, yhat.data())) return false;
    for (size_t r = 0; r < rows; ++r)
      residuals[r] = seg_.deflection_mm[seg_.fit_begin + r] - yhat[r];
    if (!jacobians) return true;
    const bool strong = jacobians[0] != nullptr;
    const std::array<bool, kUnknowns> wanted = {strong, strong, strong, jacobians[1] != nullptr,
                                                jacobians[2] != nullptr};
    Jacobian jacobian;
    if (!PredictionJacobian(fixed_, x, terms_, seg_, yhat, wanted, &jacobian)) return false;
    for (size_t r = 0; r < rows; ++r) {
      const Eigen::Index row = static_cast<Eigen::Index>(r);
      if (jacobians[0])
        for (int j = 0; j < 3; ++j)
          jacobians[0][r * 3 + static_cast<size_t>(j)] = -jacobian(row, j);
      if (jacobians[1]) jacobians[1][r] = -jacobian(row, kLnDelta);
      if (jacobians[2]) jacobians[2][r] = -jacobian(row, kDelay);
    }
    return true;
  }

 private:
  const DataSegment& seg_;
  PhysicalParameters fixed_;
  int terms_;
};

// Stage 2 (header): start delay on a grid, with the deflection scale solved in closed form
// at each delay. Returns the delay; multiplies start->alpha by the best scale.
double StartDelay(const std::vector<DataSegment>& segments, const GreyBoxOptions& options,
                  PhysicalParameters* start) {
  double dt_max_s = 0.0;
  for (const DataSegment& seg : segments) dt_max_s = std::max(dt_max_s, seg.dt_s);
  const double step_s = std::max(dt_max_s, kDelayGridStep_s);
  const int steps = static_cast<int>(std::floor(options.max_delay_s / step_s + 1e-9));
  double best_delay_s = 0.0, best_scale = 1.0, best_ssr = kInf;
  for (int i = 0; i <= steps; ++i) {
    const double delay_s = i * step_s;
    double yy = 0.0, ym = 0.0, mm = 0.0;  // sums of yhat^2, yhat y, y^2
    for (const DataSegment& seg : segments) {
      const std::vector<double> yhat = Predict(*start, delay_s, options.terms, seg);
      for (size_t k = seg.fit_begin; k < yhat.size(); ++k) {
        yy += yhat[k] * yhat[k];
        ym += yhat[k] * seg.deflection_mm[k];
        mm += seg.deflection_mm[k] * seg.deflection_mm[k];
      }
    }
    const double scale = yy > 0.0 ? ym / yy : 0.0;
    const double ssr = mm - scale * ym;
    if (std::isfinite(ssr) && ssr < best_ssr) {
      best_ssr = ssr;
      best_delay_s = delay_s;
      best_scale = scale;
    }
  }
  // A non-positive scale means the start predicts the wrong sign: keep alpha, let the
  // solver sort it out (the log-parameterisation cannot flip it).
  if (best_scale > 0.0 && std::isfinite(best_scale)) start->alpha_m3_per_C *= best_scale;
  return best_delay_s;
}

ceres::Solver::Summary Solve(ceres::Problem* problem, int max_iterations) {
  ceres::Solver::Options solver_options;
  solver_options.minimizer_type = ceres::TRUST_REGION;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  // Five unknowns, thousands of residuals: QR of J is cheap and keeps the digits of the
  // weak ln delta direction that the normal equations would square away.
  solver_options.linear_solver_type = ceres::DENSE_QR;
  solver_options.max_num_iterations = max_iterations;
  // A relative cost change of 1e-12 is far below any noise; on noise-free data the weak
  // direction (header) only shows once the cost is ~1e-6 of its start.
  solver_options.function_tolerance = 1e-12;
  solver_options.gradient_tolerance = 1e-14;
  solver_options.parameter_tolerance = 1e-10;
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, problem, &summary);
  return summary;
}

FitFigures FitOf(const PhysicalParameters& p, double delay_s, int terms,
                 const std::vector<DataSegment>& segments, int correlation_lags) {
  return FitOnSegments(
      segments, [&](const DataSegment& seg) { return Predict(p, delay_s, terms, seg); },
      correlation_lags);
}

double HalfWidth95(double variance) {
  return std::isfinite(variance) ? 1.96 * std::sqrt(std::max(0.0, variance)) : kInf;
}

}  // namespace

bool GreyBoxOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (terms < 1 || terms > kMaxTransferFunctionTerms)
    return fail("terms must be between 1 and " + std::to_string(kMaxTransferFunctionTerms));
  if (!std::isfinite(max_delay_s) || max_delay_s < 0.0)
    return fail("max_delay_s must be finite and >= 0");
  if (max_iterations < 1) return fail("max_iterations must be >= 1");
  if (correlation_lags < 1) return fail("correlation_lags must be >= 1");
  return true;
}

std::vector<double> PredictDeflection_mm(const PhysicalParameters& p, double delay_s, int terms,
                                         const DataSegment& segment) {
  // CurvatureTransferFunction checks p, terms and delay_s; SimulateUniform the voltages.
  if (!(segment.dt_s > 0.0) || !std::isfinite(segment.dt_s))
    throw std::invalid_argument("sample period must be finite and > 0");
  if (!std::isfinite(segment.initial_voltage_V))
    throw std::invalid_argument("initial voltage must be finite");
  return Predict(p, delay_s, terms, segment);
}

GreyBoxEstimate IdentifyPhysics(const std::vector<DataSegment>& segments,
                                const PhysicalParameters& start, const GreyBoxOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("grey-box options: " + why);
  if (!IsValid(start, &why)) throw std::invalid_argument("grey-box start parameters: " + why);
  CheckSegments(segments, options);

  // Stage 2: start delay and gain.
  PhysicalParameters fixed = start;
  const double start_delay_s = StartDelay(segments, options, &fixed);
  Unknowns x = ToUnknowns(fixed, start_delay_s);

  // Stage 3: output-error refinement, first with delta fixed at its start (the well-
  // determined groups and T), then with delta free within kDeltaRange of its start. The
  // first stage leaves only the weak delta effect in the residual, so that the second
  // stage's steps in ln delta follow it rather than the misfit of the strong groups.
  ceres::Problem problem;
  for (const DataSegment& seg : segments)
    problem.AddResidualBlock(new SegmentCost(seg, fixed, options.terms), nullptr, &x[kLnD],
                             &x[kLnDelta], &x[kDelay]);
  const bool estimate_delay = options.max_delay_s > 0.0;
  if (estimate_delay) {
    problem.SetParameterLowerBound(&x[kDelay], 0, 0.0);
    problem.SetParameterUpperBound(&x[kDelay], 0, options.max_delay_s);
  } else {
    problem.SetParameterBlockConstant(&x[kDelay]);
  }
  const double ln_delta_start = x[kLnDelta];
  problem.SetParameterBlockConstant(&x[kLnDelta]);
  const ceres::Solver::Summary first = Solve(&problem, options.max_iterations);
  if (!first.IsSolutionUsable())
    throw std::runtime_error("grey-box identification did not converge: " + first.message);
  problem.SetParameterBlockVariable(&x[kLnDelta]);
  problem.SetParameterLowerBound(&x[kLnDelta], 0, ln_delta_start - std::log(kDeltaRange));
  problem.SetParameterUpperBound(&x[kLnDelta], 0, ln_delta_start + std::log(kDeltaRange));
  const ceres::Solver::Summary second = Solve(&problem, options.max_iterations);
  if (!second.IsSolutionUsable())
    throw std::runtime_error("grey-box identification did not converge: " + second.message);

  GreyBoxEstimate estimate;
  estimate.parameters = FromUnknowns(fixed, x);
  estimate.delay_s = x[kDelay];
  estimate.curvature_tf = CurvatureTransferFunction(estimate.parameters, options.terms, x[kDelay],
                                                    SeriesRemainder::kStaticCorrection);
  estimate.iterations = static_cast<int>(first.iterations.size() + second.iterations.size());
  estimate.solver_report =
      "delta fixed: " + first.BriefReport() + "; delta free: " + second.BriefReport();
  if (std::abs(x[kLnDelta] - ln_delta_start) > std::log(kDeltaRange) * (1.0 - 1e-9))
    estimate.solver_report += "; delta_m stopped at its bound (start times 1e+-3)";
  if (estimate_delay && x[kDelay] >= options.max_delay_s * (1.0 - 1e-9))
    estimate.solver_report += "; delay_s stopped at max_delay_s";

  // Stage 4: covariance sigma^2 (J^T J)^-1 in x.
  Matrix5 jtj = Matrix5::Zero();
  double ssr = 0.0;
  size_t samples = 0;
  for (const DataSegment& seg : segments) {
    const size_t rows = seg.voltage_V.size() - seg.fit_begin;
    std::vector<double> yhat(rows);
    Jacobian jacobian;
    if (!PredictFitted(fixed, x, options.terms, seg, yhat.data()) ||
        !PredictionJacobian(fixed, x, options.terms, seg, yhat, {true, true, true, true, true},
                            &jacobian))
      throw std::runtime_error("grey-box identification: model not computable at the estimate");
    jtj.noalias() += jacobian.transpose() * jacobian;
    for (size_t r = 0; r < rows; ++r) {
      const double e = seg.deflection_mm[seg.fit_begin + r] - yhat[r];
      ssr += e * e;
    }
    samples += rows;
  }
  const int q = estimate_delay ? kUnknowns : kUnknowns - 1;  // T is last; dropped when fixed
  const double sigma2 =
      ssr / static_cast<double>(std::max<long>(1, static_cast<long>(samples) - q));
  estimate.noise_std_mm = std::sqrt(sigma2);
  Matrix5 covariance = Matrix5::Zero();  // zero row and column for a fixed delay
  Eigen::MatrixXd free_covariance;
  const bool determined = CovarianceFromNormalMatrix(jtj, q, sigma2, &free_covariance);
  if (determined) covariance.topLeftCorner(q, q) = free_covariance;
  // Variance of c^T x; +inf when J^T J is singular.
  auto variance = [&](const Vector5& c) { return determined ? c.dot(covariance * c) : kInf; };

  // Natural parameters by the delta method: ln alpha = x_1 - ln(1 + H), ln R_s = x_2 -
  // ln(1 + H), d ln(1 + H) / d ln delta = -H/(1 + H); half-width = value * 1.96 sigma_ln.
  const PhysicalParameters& fitted = estimate.parameters;
  const double h_over_delta = fitted.h_m / fitted.delta_m;
  const double share = h_over_delta / (1.0 + h_over_delta);
  auto unit = [](int j, double extra_delta = 0.0) {
    Vector5 c = Vector5::Zero();
    c(j) = 1.0;
    c(kLnDelta) += extra_delta;
    return c;
  };
  auto add = [&](std::vector<ParameterEstimate>* list, const char* name, double value,
                 const Vector5& c) {
    list->push_back({name, value, value * HalfWidth95(variance(c))});
  };
  add(&estimate.estimates, "D_m2_per_s", fitted.D_m2_per_s, unit(kLnD));
  add(&estimate.estimates, "delta_m", fitted.delta_m, unit(kLnDelta));
  add(&estimate.estimates, "R_s_ohm", fitted.R_s_ohm, unit(kLnResistanceTotal, share));
  add(&estimate.estimates, "alpha_m3_per_C", fitted.alpha_m3_per_C, unit(kLnAlphaTotal, share));
  estimate.estimates.push_back(
      {"delay_s", x[kDelay], estimate_delay ? HalfWidth95(variance(unit(kDelay))) : 0.0});

  // Well-determined groups (header).
  add(&estimate.combinations, "dc_curvature_per_m_V", DcCurvaturePerVolt(fitted),
      unit(kLnAlphaTotal));
  add(&estimate.combinations, "cell_time_constant_s",
      fitted.R_s_ohm * fitted.C_dl_F * (1.0 + h_over_delta), unit(kLnResistanceTotal));
  add(&estimate.combinations, "diffusion_time_constant_s", SlowestDiffusionTimeConstant_s(fitted),
      -unit(kLnD));

  estimate.fit = FitOf(fitted, x[kDelay], options.terms, segments, options.correlation_lags);
  return estimate;
}

}  // namespace flexid::model
