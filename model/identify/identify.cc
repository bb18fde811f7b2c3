// One transfer function with dead time by output error (identify.h): the options, the
// checks of the segments, the fit figures, IdentifyTransferFunction stage by stage, and its
// stage 5 (the uncertainty). Stages 1-3 are in tf_linear.cc, stage 4 in tf_output_error.cc.
#include "model/identify/identify.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/polynomial.h"
#include "model/core/simulate.h"
#include "model/identify/tf_fit.h"

namespace flexid::model {

using namespace tf_fit;  // NOLINT(google-build-using-namespace): the fit's own parts

namespace {

// The sample period shared by all segments (identification needs one grid).
double CommonSamplePeriod(const std::vector<DataSegment>& segments) {
  const double dt_s = segments.front().dt_s;
  for (size_t s = 0; s < segments.size(); ++s)
    if (std::abs(segments[s].dt_s - dt_s) > 1e-9 * dt_s)
      throw InputError("segment " + std::to_string(s) + ": sample period " +
                       std::to_string(segments[s].dt_s) + " s differs from the first segment's " +
                       std::to_string(dt_s) + " s");
  return dt_s;
}

TransferFunction MakeTf(const std::vector<double>& b, const std::vector<double>& a,
                        double delay_s) {
  TransferFunction tf{b, {1.0}, delay_s};
  tf.den.insert(tf.den.end(), a.begin(), a.end());
  return tf;
}

std::string CoefficientName(int index, int m, int n) {
  if (index <= m) return "b" + std::to_string(index);
  if (index <= m + n) return "a" + std::to_string(index - m);
  return "delay_s";
}

// Stage 5: uncertainty in the coefficients (b, a, T); fitted initial voltages are held
// at their estimates (nuisance parameters), which makes the intervals slightly narrow.
void Uncertainty(const std::vector<DataSegment>& fitted, const IdentifyOptions& options,
                 const std::vector<double>& b, const std::vector<double>& a, double delay_s,
                 TfEstimate* out) {
  const int n = options.num_poles, m = options.num_zeros;
  TfEstimate& estimate = *out;
  const int p = m + n + 2;
  Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(p, p);
  double ssr = 0.0;
  size_t samples = 0;
  for (const DataSegment& seg : fitted) {
    Sensitivity s;
    SimulateSensitivities(seg, b, a, delay_s, true, &s);
    const Eigen::Index rows = static_cast<Eigen::Index>(seg.voltage_V.size() - seg.fit_begin);
    const auto block = s.jac.bottomRows(rows);
    jtj.noalias() += block.transpose() * block;
    for (size_t k = seg.fit_begin; k < seg.voltage_V.size(); ++k) {
      const double r = seg.deflection_mm[k] - s.yhat[k];
      ssr += r * r;
    }
    samples += static_cast<size_t>(rows);
  }
  const int free_parameters = options.estimate_delay ? p : p - 1;
  const double sigma2 =
      ssr / static_cast<double>(std::max<long>(1, static_cast<long>(samples) - free_parameters));
  estimate.noise_std_mm = std::sqrt(sigma2);
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Constant(p, p, kInf);
  {
    const int q = free_parameters;  // the delay is last; drop it when fixed
    Eigen::MatrixXd free_covariance;
    if (CovarianceFromNormalMatrix(jtj, q, sigma2, &free_covariance)) {
      covariance.topLeftCorner(q, q) = free_covariance;
      if (q < p) {
        covariance.row(p - 1).setZero();
        covariance.col(p - 1).setZero();
      }
    }
  }
  const Eigen::VectorXd theta = [&] {
    Eigen::VectorXd t(p);
    for (int j = 0; j <= m; ++j) t(j) = b[static_cast<size_t>(j)];
    for (int i = 0; i < n; ++i) t(m + 1 + i) = a[static_cast<size_t>(i)];
    t(p - 1) = delay_s;
    return t;
  }();
  auto half_width = [](double variance) {
    return std::isfinite(variance) ? 1.96 * std::sqrt(std::max(0.0, variance)) : kInf;
  };
  for (int i = 0; i < p; ++i) {
    estimate.coefficients.push_back(
        {CoefficientName(i, m, n), theta(i), half_width(covariance(i, i))});
  }
  // DC gain b_m / a_n.
  Eigen::VectorXd grad = Eigen::VectorXd::Zero(p);
  grad(m) = 1.0 / a.back();
  grad(m + n) = -b.back() / (a.back() * a.back());
  estimate.dc_gain = {"dc_gain", b.back() / a.back(), half_width(grad.dot(covariance * grad))};
  // Poles: dp/da_i = -p^{n-i} / A'(p).
  std::vector<double> den = estimate.tf.den, den_derivative;
  for (size_t i = 0; i + 1 < den.size(); ++i)
    den_derivative.push_back(den[i] * static_cast<double>(den.size() - 1 - i));
  for (const Complex& pole : Poles(estimate.tf)) {
    const Complex slope = EvaluatePolynomial(den_derivative, pole);
    Eigen::VectorXd g_re = Eigen::VectorXd::Zero(p), g_im = Eigen::VectorXd::Zero(p);
    for (int i = 1; i <= n; ++i) {
      const Complex g = -std::pow(pole, n - i) / slope;
      g_re(m + i) = g.real();
      g_im(m + i) = g.imag();
    }
    estimate.poles.push_back({pole.real(), pole.imag(), half_width(g_re.dot(covariance * g_re)),
                              half_width(g_im.dot(covariance * g_im))});
  }
}

}  // namespace

bool IdentifyOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  if (num_poles < 1 || num_poles > 8) return fail("num_poles must be between 1 and 8");
  if (num_zeros < 0 || num_zeros >= num_poles)
    return fail("num_zeros must be >= 0 and < num_poles");
  if (!std::isfinite(max_delay_s) || max_delay_s < 0.0)
    return fail("max_delay_s must be finite and >= 0");
  if (!estimate_delay && (!std::isfinite(fixed_delay_s) || fixed_delay_s < 0.0))
    return fail("fixed_delay_s must be finite and >= 0");
  if (max_iterations < 1) return fail("max_iterations must be >= 1");
  if (correlation_lags < 1) return fail("correlation_lags must be >= 1");
  return true;
}

bool CovarianceFromNormalMatrix(const Eigen::MatrixXd& jtj, int q, double sigma2,
                                Eigen::MatrixXd* covariance) {
  const Eigen::MatrixXd sub = jtj.topLeftCorner(q, q);
  const Eigen::VectorXd scale = sub.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
  Eigen::FullPivLU<Eigen::MatrixXd> lu(scale.asDiagonal() * sub * scale.asDiagonal());
  lu.setThreshold(1e-13);
  if (!lu.isInvertible()) return false;
  *covariance = sigma2 * scale.asDiagonal() * lu.inverse() * scale.asDiagonal();
  return true;
}

size_t MinimumSamplesToIdentify(int parameters, double max_delay_s, double dt_s) {
  return std::max<size_t>(20 * static_cast<size_t>(std::max(parameters, 0)),
                          static_cast<size_t>(max_delay_s / dt_s) + 50);
}

void ValidateSegments(const std::vector<DataSegment>& segments, int parameters,
                      double max_delay_s) {
  if (segments.empty()) throw InputError("no data to identify from");
  size_t fitted = 0;
  double u_min = kInf, u_max = -kInf, dt_max_s = 0.0;
  for (size_t s = 0; s < segments.size(); ++s) {
    const DataSegment& seg = segments[s];
    const std::string where = "segment " + std::to_string(s) + ": ";
    if (!(seg.dt_s > 0.0) || !std::isfinite(seg.dt_s))
      throw InputError(where + "sample period must be finite and > 0");
    if (seg.voltage_V.size() != seg.deflection_mm.size())
      throw InputError(where + "voltage and deflection differ in length");
    if (!std::isfinite(seg.initial_voltage_V))
      throw InputError(where + "initial voltage is not finite");
    if (seg.fit_begin >= seg.voltage_V.size())
      throw InputError(where + "nothing to fit after the lead-in");
    for (size_t k = 0; k < seg.voltage_V.size(); ++k) {
      if (!std::isfinite(seg.voltage_V[k]) || !std::isfinite(seg.deflection_mm[k]))
        throw InputError(where + "non-finite value at sample " + std::to_string(k));
      u_min = std::min(u_min, seg.voltage_V[k]);
      u_max = std::max(u_max, seg.voltage_V[k]);
    }
    // The step from the voltage held before the segment excites it too.
    u_min = std::min(u_min, seg.initial_voltage_V);
    u_max = std::max(u_max, seg.initial_voltage_V);
    fitted += seg.voltage_V.size() - seg.fit_begin;
    dt_max_s = std::max(dt_max_s, seg.dt_s);
  }
  const size_t needed = MinimumSamplesToIdentify(parameters, max_delay_s, dt_max_s);
  if (fitted < needed)
    throw InputError("recording too short: " + std::to_string(fitted) +
                     " samples to fit, need at least " + std::to_string(needed));
  if (u_max - u_min == 0.0)
    throw InputError("voltage is constant at " + std::to_string(u_max) +
                     " V: no excitation to identify from");
}

FitFigures FitOnSegments(const std::vector<DataSegment>& segments,
                         const std::function<std::vector<double>(const DataSegment&)>& predict,
                         int correlation_lags) {
  std::vector<double> measured, predicted, input;
  for (const DataSegment& seg : segments) {
    const std::vector<double> y = predict(seg);
    for (size_t k = seg.fit_begin; k < y.size(); ++k) {
      measured.push_back(seg.deflection_mm[k]);
      predicted.push_back(y[k]);
      input.push_back(seg.voltage_V[k]);
    }
  }
  return FitFiguresOf(measured, predicted, input, correlation_lags);
}

FitFigures EvaluateFit(const TransferFunction& tf, const std::vector<DataSegment>& segments,
                       int correlation_lags) {
  return FitOnSegments(
      segments,
      [&tf](const DataSegment& seg) {
        return SimulateUniform(tf, seg.dt_s, seg.voltage_V,
                               {.initial_voltage_V = seg.initial_voltage_V});
      },
      correlation_lags);
}

TfEstimate IdentifyTransferFunction(const std::vector<DataSegment>& segments,
                                    const IdentifyOptions& options) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("identification options: " + why);
  ValidateSegments(segments, options.num_zeros + options.num_poles + 2, options.max_delay_s);
  const double dt_s = CommonSamplePeriod(segments);
  const int n = options.num_poles;
  // Stages 1-3: the linear estimate the output-error fit starts from.
  const LinearEstimate linear = EstimateLinear(segments, options, dt_s);
  std::vector<double> b = linear.b, factor_params = linear.factor_params;
  double delay_s = linear.delay_s;

  // Ceres aborts the process on an empty or non-finite start: refuse it here instead.
  auto all_finite = [](const std::vector<double>& v) {
    return !v.empty() && std::all_of(v.begin(), v.end(), [](double x) { return std::isfinite(x); });
  };
  if (!all_finite(b) || !all_finite(factor_params) || !std::isfinite(delay_s))
    throw std::runtime_error(
        "identification failed: the linear initial estimate is not finite (is the recording "
        "long enough and the input exciting?)");

  // Stage 4: output-error refinement, from the linear estimate and, when given, from a
  // neighbouring model (options.start).
  std::vector<double> initial_voltages_V;
  for (const DataSegment& seg : segments) initial_voltages_V.push_back(seg.initial_voltage_V);
  const OutputErrorSummary summary =
      RefineOutputError(segments, options, &b, &factor_params, &delay_s, &initial_voltages_V);
  // From here on each segment starts under its fitted (or given) initial voltage.
  std::vector<DataSegment> fitted = segments;
  for (size_t i = 0; i < fitted.size(); ++i) {
    fitted[i].initial_voltage_V = initial_voltages_V[i];
    fitted[i].estimate_initial_voltage = false;
  }
  if (!summary.usable)
    throw std::runtime_error("identification did not converge: " + summary.message);

  std::vector<double> a;
  DenominatorAndDerivative(factor_params.data(), n, &a, nullptr);
  TfEstimate estimate;
  estimate.tf = MakeTf(b, a, delay_s);
  estimate.iterations = summary.iterations;
  estimate.solver_report = summary.report;
  Uncertainty(fitted, options, b, a, delay_s, &estimate);
  estimate.initial_voltage_V = initial_voltages_V;
  estimate.fit = EvaluateFit(estimate.tf, fitted, options.correlation_lags);
  return estimate;
}

}  // namespace flexid::model
