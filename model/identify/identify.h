// Identification of one continuous-time transfer function with dead time from sampled
// data, the seed's Eq. (18):
//
//   G(s) = e^{-T s} (b0 s^m + ... + b_m) / (s^n + a1 s^{n-1} + ... + a_n),  m < n.
//
// Method (each stage's output is the next stage's start; stages 1-3 use at most the
// leading 30,000 fitted samples, stage 4 all of them):
//  1. Coarse dead time: discrete ARX(n, n+1) least squares for every whole-sample delay
//     d in [0, max_delay]; the d with the least residual is floor(T / dt).
//  2. Linear initial estimate at that d: ARX, then Steiglitz-McBride iterations (least
//     squares on data prefiltered by 1/A(q) of the previous iterate), which converge
//     towards the output-error estimate; every least-squares problem is solved by QR on
//     the regressors (the normal equations of a slow output at 10 Hz are too ill-
//     conditioned to keep the slow poles). Discrete poles map exactly to continuous ones
//     (s = ln z / dt under the zero-order hold); unstable ones are reflected.
//  3. Numerator and fractional delay: with the poles fixed, the output is linear in
//     b0..b_m, so b is solved by least squares at a few fractions of a sample and the best
//     fraction is kept.
//  4. Output-error refinement (Ceres, Levenberg-Marquardt) of b, the poles and T jointly,
//     through the exact ZOH simulation (discretise.h). The Jacobian is analytic: with
//     x = states of 1/A(s) driven by u(t - T) and z = states of 1/A(s) driven by yhat,
//     dyhat/db_j = s^{m-j}/A u = x_{m-j},  dyhat/da_i = -s^{n-i}/A yhat = -z_{n-i},
//     dyhat/dT = -d yhat/dt; all from ONE exact simulation of the 2n-state system [x; z].
//     The denominator is a product of quadratics s^2 + c1 s + c0 (and one s + c for odd n)
//     with c = exp(parameter) > 0, so every iterate is stable (stability enforced).
//  5. Uncertainty: covariance sigma^2 (J^T J)^{-1} in the coefficients (b, a, T), with
//     sigma^2 = SSR / (N - p); 95 % half-widths 1.96 sigma_i; DC gain and poles by the
//     delta method (dp/da_i = -p^{n-i} / A'(p)). These assume white residuals and a cost
//     that is locally quadratic: check the whiteness test before trusting the digits.
//     Known limit: with the seed's structure under output noise, the dead time trades off
//     against the weakly excited fast pole pair along a long curved ridge of the cost, and
//     its linearised interval is far too narrow (8 V model, 1 % noise: the true 3.67 s was
//     inside the dead time's interval in 1 of 20 noise draws, inside the DC gain's in 19
//     of 20). The fit and the slow dynamics are unaffected; the dead time is only
//     determined to a few seconds there (SEED-NOTES.md: "to about +-1 s").
//
// Data: one or more segments on uniform grids of one sample period. Each segment starts
// in steady state under its initial_voltage_V (0 V: at rest); samples before
// `fit_begin` are simulated but not fitted (a lead-in). Segments that share a voltage
// level are fitted jointly: one model, all residuals.
#pragma once

#include <Eigen/Dense>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "model/core/metrics.h"
#include "model/core/transfer_function.h"

namespace flexid::model {

struct IdentifyOptions {
  int num_zeros = 3;           // m
  int num_poles = 4;           // n (> m)
  bool estimate_delay = true;  // false: use fixed_delay_s
  double fixed_delay_s = 0.0;
  double max_delay_s = 10.0;  // coarse search range [0, max_delay_s]
  int max_iterations = 50;    // Levenberg-Marquardt iterations
  int correlation_lags = 25;  // residual tests
  // A model of the same structure to start the output-error fit from as well (e.g. the
  // neighbouring voltage level's); the result keeps its structure unless the fit from the
  // linear estimate is better by more than noise can explain.
  std::optional<TransferFunction> start;
  bool IsValid(std::string* error) const;
};

struct DataSegment {
  double dt_s = 0.0;
  std::vector<double> voltage_V;
  std::vector<double> deflection_mm;
  size_t fit_begin = 0;            // samples [0, fit_begin) are lead-in: simulated, not fitted
  double initial_voltage_V = 0.0;  // held before the first sample (steady state under it)
  // Fit the voltage held before the first sample instead of taking initial_voltage_V (the
  // starting value). For a segment that begins at an equilibrium left by another voltage
  // level: the model starts at the equilibrium that explains the measured deflection.
  bool estimate_initial_voltage = false;
};

struct ParameterEstimate {
  std::string name;
  double value = 0.0;
  double half_width_95 = 0.0;  // +inf when not determined by the data
};

struct PoleEstimate {
  double re = 0.0, im = 0.0;
  double re_half_width_95 = 0.0, im_half_width_95 = 0.0;
};

struct TfEstimate {
  TransferFunction tf;
  std::vector<ParameterEstimate> coefficients;  // b0..b_m, a1..a_n, delay_s
  ParameterEstimate dc_gain;
  std::vector<PoleEstimate> poles;
  FitFigures fit;
  std::vector<double> initial_voltage_V;  // per segment: as given, or fitted
  double noise_std_mm = 0.0;              // sqrt(SSR / (N - p))
  int iterations = 0;
  std::string solver_report;  // one line from Ceres
};

// Throws InputError for unusable data (too short, constant input, non-finite values,
// unequal sample periods) and std::invalid_argument for invalid options.
TfEstimate IdentifyTransferFunction(const std::vector<DataSegment>& segments,
                                    const IdentifyOptions& options = {});

// Fit figures of any model on segments (the validation figures).
FitFigures EvaluateFit(const TransferFunction& tf, const std::vector<DataSegment>& segments,
                       int correlation_lags = 25);

// The same over the fitted samples of segments, with `predict` giving each segment's
// predicted deflection (every sample, lead-in included).
FitFigures FitOnSegments(const std::vector<DataSegment>& segments,
                         const std::function<std::vector<double>(const DataSegment&)>& predict,
                         int correlation_lags = 25);

// sigma^2 (J^T J)^{-1} for the leading q parameters, inverted with Jacobi scaling (the
// columns of J differ by orders of magnitude). False, and *covariance untouched, when J^T J
// is singular to 1e-13 after scaling: those parameters are not determined by the data.
bool CovarianceFromNormalMatrix(const Eigen::MatrixXd& jtj, int q, double sigma2,
                                Eigen::MatrixXd* covariance);

// Samples a fit of `parameters` parameters needs at sample period dt_s: 20 per parameter,
// and the dead-time range (max_delay_s) plus 50. IdentifyOptions' fit has
// num_zeros + num_poles + 2 parameters (the gain and the dead time with the coefficients).
size_t MinimumSamplesToIdentify(int parameters, double max_delay_s, double dt_s);

// Checks what every fit needs of its segments, before any solver sees them: finite values,
// equal lengths, something to fit after the lead-in, at least 20 samples per parameter and
// the dead-time range plus 50, and an input that changes (counting the step from the
// voltage held before a segment). Throws InputError with one line naming the problem.
void ValidateSegments(const std::vector<DataSegment>& segments, int parameters, double max_delay_s);

}  // namespace flexid::model
