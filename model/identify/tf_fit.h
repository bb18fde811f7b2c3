// The transfer-function fit's parts (internal to identify.cc, tf_linear.cc and
// tf_output_error.cc): the linear estimate the output-error fit starts from (stages 1-3 of
// identify.h: tf_linear.cc); the denominator as a product of positive factors, the exact
// simulation with its sensitivities, and the output-error refinement (stage 4:
// tf_output_error.cc, the only one of them that uses Ceres). The maths is in identify.h.
#pragma once

#include <Eigen/Dense>
#include <cmath>
#include <complex>
#include <limits>
#include <string>
#include <vector>

#include "model/identify/identify.h"

namespace flexid::model::tf_fit {

using Complex = std::complex<double>;
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---------------------------------------------------------------------------------------
// Stages 1-3 (tf_linear.cc)
// ---------------------------------------------------------------------------------------

// The start of the output-error fit.
struct LinearEstimate {
  std::vector<double> b;              // b0..b_m
  std::vector<double> factor_params;  // the denominator's factors (FactorsFromParameters)
  double delay_s = 0.0;
};

// Stages 1-3 (identify.h) on the segments' leading part: at most 30,000 fitted samples.
LinearEstimate EstimateLinear(const std::vector<DataSegment>& segments,
                              const IdentifyOptions& options, double dt_s);

// ---------------------------------------------------------------------------------------
// The output-error model and its fit (tf_output_error.cc)
// ---------------------------------------------------------------------------------------

// The denominator of factor parameters p (FactorBasis in tf_output_error.cc):
// den = s^n + a1 s^{n-1} + ... ; returns a1..a_n and d a_i / d p_l (n x n).
void DenominatorAndDerivative(const double* p, int n, std::vector<double>* a,
                              Eigen::MatrixXd* da_dp);

// The factor parameters of given poles (clamped to the open left half-plane; complex
// conjugates paired, real poles paired by magnitude).
std::vector<double> ParametersFromPoles(std::vector<Complex> poles, int n);

// SimulateSensitivities' output.
struct Sensitivity {
  std::vector<double> yhat;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> jac;  // samples x (m+n+2)
};

// What drives the simulation: the recorded voltage after a held u_before, or nothing
// but a unit voltage held before the first sample (by linearity the response to the
// voltage before the segment is u_before times the latter).
enum class Drive { kRecorded, kUnitBeforeStart };

// Exact simulation of the 2n-state sensitivity system for one segment (see identify.h).
// Fills yhat and, if with_jacobian, dyhat/d[b0..b_m, a1..a_n, T] for every sample.
void SimulateSensitivities(const DataSegment& seg, const std::vector<double>& b,
                           const std::vector<double>& a, double delay_s, bool with_jacobian,
                           Sensitivity* out, Drive drive = Drive::kRecorded, double u_before = NAN);

// What the solver says of stage 4's fit.
struct OutputErrorSummary {
  bool usable = false;
  std::string message;  // why it is not usable
  int iterations = 0;
  std::string report;  // one line
};

// Stage 4 (identify.h): output-error refinement of b, the denominator factors, the dead
// time (unless fixed) and the initial voltages to be estimated, from the linear estimate
// and, when given, from a neighbouring model (options.start); each argument holds a start
// and receives the fit kept.
OutputErrorSummary RefineOutputError(const std::vector<DataSegment>& segments,
                                     const IdentifyOptions& options, std::vector<double>* b,
                                     std::vector<double>* factor_params, double* delay_s,
                                     std::vector<double>* initial_voltages_V);

}  // namespace flexid::model::tf_fit
