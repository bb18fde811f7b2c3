#include "model/identify/identify.h"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <limits>
#include <stdexcept>

#include "model/core/discretise.h"
#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/polynomial.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;
constexpr double kInf = std::numeric_limits<double>::infinity();

// -----------------------------------------------------------------------------------------
// Data checks
// -----------------------------------------------------------------------------------------

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

// Deviation signals from the initial steady state, so that linear estimates need no
// initial conditions: du = u - u(0), dy = y - mean of the first samples.
struct Deviations {
  std::vector<double> u, y;
  size_t fit_begin = 0;
};

std::vector<Deviations> MakeDeviations(const std::vector<DataSegment>& segments) {
  std::vector<Deviations> out;
  for (const DataSegment& seg : segments) {
    Deviations d;
    const double u0 = seg.initial_voltage_V;
    // The output before the response to the first change: the first few samples (a
    // model of relative degree >= 1 has barely moved in them).
    const size_t head = std::min<size_t>(3, seg.voltage_V.size());
    double y0 = 0.0;
    for (size_t k = 0; k < head; ++k) y0 += seg.deflection_mm[k];
    y0 /= static_cast<double>(head);
    for (size_t k = 0; k < seg.voltage_V.size(); ++k) {
      d.u.push_back(seg.voltage_V[k] - u0);
      d.y.push_back(seg.deflection_mm[k] - y0);
    }
    d.fit_begin = seg.fit_begin;
    out.push_back(std::move(d));
  }
  return out;
}

// -----------------------------------------------------------------------------------------
// Stage 1-2: discrete-time linear estimates
// A(q) y[k] = B(q) u[k - d - 1],  A = 1 + a1 q^-1 + ... + a_na q^-na,  B = b1 + ... + b_nb
// q^-(nb-1)
// -----------------------------------------------------------------------------------------

struct ArxModel {
  std::vector<double> a;  // 1, a1..a_na
  std::vector<double> b;  // b1..b_nb (lags d+1..d+nb)
  int d = 0;
};

// Least squares of y[k] on [-y[k-1..k-na], u[k-d-1..k-d-nb]] for every d in [0, d_max]
// over one common sample range, from lagged-product tables built once; returns the d
// with the smallest residual sum of squares.
int CoarseDelay(const std::vector<Deviations>& data, int na, int nb, int d_max) {
  const int lags_u = d_max + nb;                                   // u lags 1..lags_u
  Eigen::MatrixXd yy = Eigen::MatrixXd::Zero(na + 1, na + 1);      // sum y[k-i] y[k-j]
  Eigen::MatrixXd yu = Eigen::MatrixXd::Zero(na + 1, lags_u + 1);  // sum y[k-i] u[k-l]
  Eigen::MatrixXd uu = Eigen::MatrixXd::Zero(lags_u + 1, nb);      // sum u[k-l] u[k-l-j]
  for (const Deviations& seg : data) {
    const long first = std::max<long>(std::max(na, lags_u), static_cast<long>(seg.fit_begin));
    const long count = static_cast<long>(seg.y.size());
    const double* y = seg.y.data();
    const double* u = seg.u.data();
    for (long k = first; k < count; ++k) {
      for (int i = 0; i <= na; ++i)
        for (int j = i; j <= na; ++j) yy(i, j) += y[k - i] * y[k - j];
      for (int i = 0; i <= na; ++i) {
        const double yi = y[k - i];
        for (int l = 1; l <= lags_u; ++l) yu(i, l) += yi * u[k - l];
      }
      for (int l = 1; l <= lags_u; ++l)
        for (int j = 0; j < nb && l + j <= lags_u; ++j) uu(l, j) += u[k - l] * u[k - l - j];
    }
  }
  yy = yy.selfadjointView<Eigen::Upper>();
  int best_d = 0;
  double best_ssr = kInf;
  const int p = na + nb;
  for (int d = 0; d <= d_max; ++d) {
    Eigen::MatrixXd gram(p, p);
    Eigen::VectorXd rhs(p);
    for (int i = 0; i < na; ++i) {
      rhs(i) = -yy(0, i + 1);
      for (int j = 0; j < na; ++j) gram(i, j) = yy(i + 1, j + 1);
      for (int j = 0; j < nb; ++j) gram(i, na + j) = gram(na + j, i) = -yu(i + 1, d + 1 + j);
    }
    for (int i = 0; i < nb; ++i) {
      rhs(na + i) = yu(0, d + 1 + i);
      for (int j = 0; j < nb; ++j) {
        const int l1 = d + 1 + std::min(i, j), gap = std::abs(i - j);
        gram(na + i, na + j) = uu(l1, gap);
      }
    }
    // Jacobi scaling keeps the nearly collinear lags of a slow output solvable.
    Eigen::VectorXd scale = gram.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
    const Eigen::MatrixXd scaled = scale.asDiagonal() * gram * scale.asDiagonal();
    const Eigen::VectorXd theta =
        scale.asDiagonal() * scaled.ldlt().solve(scale.asDiagonal() * rhs);
    const double ssr = yy(0, 0) - theta.dot(rhs);
    if (std::isfinite(ssr) && ssr < best_ssr) {
      best_ssr = ssr;
      best_d = d;
    }
  }
  return best_d;
}

// x filtered by 1/A(q), from rest.
std::vector<double> FilterByInverseA(const std::vector<double>& a, const std::vector<double>& x) {
  std::vector<double> out(x.size());
  const int na = static_cast<int>(a.size()) - 1;
  for (long k = 0; k < static_cast<long>(x.size()); ++k) {
    double v = x[static_cast<size_t>(k)];
    for (int i = 1; i <= na && k - i >= 0; ++i)
      v -= a[static_cast<size_t>(i)] * out[static_cast<size_t>(k - i)];
    out[static_cast<size_t>(k)] = v;
  }
  return out;
}

// Reflects roots outside the unit circle inside, so a prefilter or init is stable.
std::vector<double> StabiliseDiscrete(const std::vector<double>& a) {
  auto roots = PolynomialRoots(a);
  bool changed = false;
  for (Complex& r : roots)
    if (std::abs(r) >= 0.999999) {
      r = 0.999 * r / std::abs(r) / std::max(1.0, std::abs(r));
      changed = true;
    }
  return changed ? PolynomialFromRoots(roots) : a;
}

// Least squares of y_f[k] on [-y_f[k-1..k-na], u_f[k-d-1..k-d-nb]] by QR on the
// column-scaled regressors, where _f is filtering by 1/A_f(q) (ARX when no prefilter,
// one Steiglitz-McBride step with the previous iterate's denominator otherwise).
ArxModel SolvePrefilteredLs(const std::vector<Deviations>& data, int na, int nb, int d,
                            const std::vector<double>* prefilter_a) {
  const int p = na + nb;
  size_t rows = 0;
  const long first_lag = std::max(na, d + nb);
  for (const Deviations& seg : data) {
    const long first = std::max<long>(first_lag, static_cast<long>(seg.fit_begin));
    rows += static_cast<size_t>(std::max<long>(0, static_cast<long>(seg.y.size()) - first));
  }
  Eigen::MatrixXd phi(static_cast<Eigen::Index>(rows), p);
  Eigen::VectorXd target(static_cast<Eigen::Index>(rows));
  Eigen::Index row = 0;
  for (const Deviations& seg : data) {
    const std::vector<double> yf = prefilter_a ? FilterByInverseA(*prefilter_a, seg.y) : seg.y;
    const std::vector<double> uf = prefilter_a ? FilterByInverseA(*prefilter_a, seg.u) : seg.u;
    const long first = std::max<long>(first_lag, static_cast<long>(seg.fit_begin));
    for (long k = first; k < static_cast<long>(yf.size()); ++k, ++row) {
      for (int i = 0; i < na; ++i) phi(row, i) = -yf[static_cast<size_t>(k - 1 - i)];
      for (int j = 0; j < nb; ++j) phi(row, na + j) = uf[static_cast<size_t>(k - d - 1 - j)];
      target(row) = yf[static_cast<size_t>(k)];
    }
  }
  const Eigen::VectorXd scale = phi.colwise().norm().transpose().cwiseMax(1e-300).cwiseInverse();
  const Eigen::VectorXd theta =
      scale.asDiagonal() * (phi * scale.asDiagonal()).colPivHouseholderQr().solve(target);
  ArxModel model;
  model.d = d;
  model.a.push_back(1.0);
  for (int i = 0; i < na; ++i) model.a.push_back(theta(i));
  for (int j = 0; j < nb; ++j) model.b.push_back(theta(na + j));
  return model;
}

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

// den = s^n + a1 s^{n-1} + ... ; returns a1..a_n and d a_i / d p_l (n x n).
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

// Exact simulation of the 2n-state sensitivity system for one segment (see identify.h).
// Fills yhat and, if jac is not null, dyhat/d[b0..b_m, a1..a_n, T] for every sample.
struct Sensitivity {
  std::vector<double> yhat;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> jac;  // samples x (m+n+2)
};

// The per-sample loop, on fixed-size matrices for the usual orders (2n = 2..8 states).
// What drives the simulation: the recorded voltage after a held u_before, or nothing
// but a unit voltage held before the first sample (by linearity the response to the
// voltage before the segment is u_before times the latter).
enum class Drive { kRecorded, kUnitBeforeStart };

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

// Exact simulation of the 2n-state sensitivity system for one segment (see identify.h).
// Fills yhat and, if with_jacobian, dyhat/d[b0..b_m, a1..a_n, T] for every sample.
void SimulateSensitivities(const DataSegment& seg, const std::vector<double>& b,
                           const std::vector<double>& a, double delay_s, bool with_jacobian,
                           Sensitivity* out, Drive drive = Drive::kRecorded,
                           double u_before = NAN) {
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

TransferFunction MakeTf(const std::vector<double>& b, const std::vector<double>& a,
                        double delay_s) {
  TransferFunction tf{b, {1.0}, delay_s};
  tf.den.insert(tf.den.end(), a.begin(), a.end());
  return tf;
}

// States x = [w, w', ..., w^{(n-1)}] of 1/A(s) driven by u(t - delay) on the segment's
// grid (exact ZOH), from steady state under the initial voltage; rows are samples.
Eigen::MatrixXd InverseAStates(const DataSegment& seg, const std::vector<double>& a,
                               double delay_s) {
  const int n = static_cast<int>(a.size());
  StateSpace ss;
  ss.A = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i + 1 < n; ++i) ss.A(i, i + 1) = 1.0;
  for (int i = 1; i <= n; ++i) ss.A(n - 1, n - i) = -a[static_cast<size_t>(i - 1)];
  ss.B = Eigen::VectorXd::Zero(n);
  ss.B(n - 1) = 1.0;
  ss.C = Eigen::RowVectorXd::Zero(n);
  ss.delay_s = delay_s;
  const DiscreteModel dm = DiscretiseZoh(ss, seg.dt_s);
  const double u0 = seg.initial_voltage_V;
  auto u_at = [&](long j) { return j < 0 ? u0 : seg.voltage_V[static_cast<size_t>(j)]; };
  Eigen::MatrixXd states(static_cast<Eigen::Index>(seg.voltage_V.size()), n);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n), next(n);
  x(0) = u0 / a.back();
  for (long k = 0; k < static_cast<long>(seg.voltage_V.size()); ++k) {
    states.row(k) = x.transpose();
    next.noalias() = dm.Phi * x;
    next += dm.Gamma0 * u_at(k - dm.delay_samples) + dm.Gamma1 * u_at(k - dm.delay_samples - 1);
    x.swap(next);
  }
  return states;
}

// Stage 3: numerator by least squares for fixed poles and delay; returns the SSR.
double FitNumerator(const std::vector<DataSegment>& segments, const std::vector<double>& a,
                    double delay_s, int m, std::vector<double>* b) {
  Eigen::MatrixXd lhs = Eigen::MatrixXd::Zero(m + 1, m + 1);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(m + 1);
  double yy = 0.0;
  for (const DataSegment& seg : segments) {
    const Eigen::MatrixXd states = InverseAStates(seg, a, delay_s);
    const Eigen::Index rows = static_cast<Eigen::Index>(seg.voltage_V.size() - seg.fit_begin);
    Eigen::MatrixXd phi(rows, m + 1);
    for (int j = 0; j <= m; ++j) phi.col(j) = states.col(m - j).tail(rows);
    const Eigen::Map<const Eigen::VectorXd> y(seg.deflection_mm.data() + seg.fit_begin, rows);
    lhs.noalias() += phi.transpose() * phi;
    rhs.noalias() += phi.transpose() * y;
    yy += y.squaredNorm();
  }
  const Eigen::VectorXd scale = lhs.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
  const Eigen::VectorXd theta =
      scale.asDiagonal() *
      (scale.asDiagonal() * lhs * scale.asDiagonal()).ldlt().solve(scale.asDiagonal() * rhs);
  b->assign(theta.data(), theta.data() + theta.size());
  return yy - theta.dot(rhs);
}

// Output-error delay scan with the poles fixed: for every whole-sample delay d in
// [0, d_max] the numerator is the least-squares solution on the states of 1/A(s) delayed
// by d samples (shifted copies of one simulation); returns the d with the least residual
// sum of squares. Gram matrices come from prefix sums, so each d costs O(N (m + 1)).
int ScanDelay(const std::vector<DataSegment>& segments, const std::vector<double>& a, int m,
              int d_max) {
  const int p = m + 1;
  std::vector<Eigen::MatrixXd> gram(static_cast<size_t>(d_max) + 1, Eigen::MatrixXd::Zero(p, p));
  std::vector<Eigen::VectorXd> rhs(static_cast<size_t>(d_max) + 1, Eigen::VectorXd::Zero(p));
  double yy = 0.0;
  for (const DataSegment& seg : segments) {
    // Regressor phi_j(i) = x_{m-j}(i) for sample i of the undelayed simulation; before the
    // first sample the state is the initial steady state.
    const Eigen::MatrixXd states = InverseAStates(seg, a, 0.0);
    const long count = static_cast<long>(seg.voltage_V.size());
    const long first = static_cast<long>(seg.fit_begin);
    Eigen::MatrixXd phi(count, p);
    for (int j = 0; j < p; ++j) phi.col(j) = states.col(m - j);
    const Eigen::RowVectorXd steady = phi.row(0);
    // prefix[i] = sum_{r < i} phi(r)^T phi(r)
    std::vector<Eigen::MatrixXd> prefix(static_cast<size_t>(count) + 1,
                                        Eigen::MatrixXd::Zero(p, p));
    for (long r = 0; r < count; ++r)
      prefix[static_cast<size_t>(r + 1)] =
          prefix[static_cast<size_t>(r)] + phi.row(r).transpose() * phi.row(r);
    const Eigen::MatrixXd steady_outer = steady.transpose() * steady;
    for (long k = first; k < count; ++k)
      yy += seg.deflection_mm[static_cast<size_t>(k)] * seg.deflection_mm[static_cast<size_t>(k)];
    for (int d = 0; d <= d_max; ++d) {
      // Samples k in [first, count) use phi(k - d); those with k - d < 0 use the steady row.
      const long lo = std::max<long>(first - d, 0), hi = count - d;
      const long before = std::max<long>(0, std::min<long>(d, count) - first);
      if (hi > lo)
        gram[static_cast<size_t>(d)] +=
            prefix[static_cast<size_t>(hi)] - prefix[static_cast<size_t>(lo)];
      gram[static_cast<size_t>(d)] += static_cast<double>(before) * steady_outer;
      Eigen::VectorXd& b = rhs[static_cast<size_t>(d)];
      for (int j = 0; j < p; ++j) {
        const double* column = phi.col(j).data();
        double sum = 0.0;
        for (long k = first; k < count; ++k) {
          const long r = k - d;
          sum += (r >= 0 ? column[r] : steady(j)) * seg.deflection_mm[static_cast<size_t>(k)];
        }
        b(j) += sum;
      }
    }
  }
  int best_d = 0;
  double best_ssr = kInf;
  for (int d = 0; d <= d_max; ++d) {
    const Eigen::MatrixXd& g = gram[static_cast<size_t>(d)];
    const Eigen::VectorXd scale = g.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
    const Eigen::VectorXd theta =
        scale.asDiagonal() * (scale.asDiagonal() * g * scale.asDiagonal())
                                 .ldlt()
                                 .solve(scale.asDiagonal() * rhs[static_cast<size_t>(d)]);
    const double ssr = yy - theta.dot(rhs[static_cast<size_t>(d)]);
    if (std::isfinite(ssr) && ssr < best_ssr) {
      best_ssr = ssr;
      best_d = d;
    }
  }
  return best_d;
}

// Steiglitz-McBride estimate at whole-sample delay d, as continuous-time poles.
std::vector<Complex> LinearPoles(const std::vector<Deviations>& deviations, int na, int nb, int d,
                                 double dt_s) {
  ArxModel arx = SolvePrefilteredLs(deviations, na, nb, d, nullptr);
  for (int iteration = 0; iteration < 4; ++iteration) {
    const std::vector<double> prefilter = StabiliseDiscrete(arx.a);
    arx = SolvePrefilteredLs(deviations, na, nb, d, &prefilter);
  }
  std::vector<Complex> poles;
  for (const Complex& z : PolynomialRoots(StabiliseDiscrete(arx.a))) {
    // s = ln(z) / dt; a negative real z has no real-coefficient preimage: keep |z|.
    const bool negative_real = std::abs(z.imag()) < 1e-12 && z.real() < 0.0;
    poles.push_back(negative_real ? Complex(std::log(std::abs(z)) / dt_s, 0.0)
                                  : std::log(z) / dt_s);
  }
  return poles;
}

std::string CoefficientName(int index, int m, int n) {
  if (index <= m) return "b" + std::to_string(index);
  if (index <= m + n) return "a" + std::to_string(index - m);
  return "delay_s";
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
  const int n = options.num_poles, m = options.num_zeros;
  const int na = n, nb = n + 1;
  // Stages 1-3 only give the output-error fit its start: on long records they use the
  // leading part of each segment, at most kInitialSamples fitted samples in all.
  constexpr size_t kInitialSamples = 30000;
  size_t total = 0;
  for (const DataSegment& seg : segments) total += seg.voltage_V.size() - seg.fit_begin;
  std::vector<DataSegment> initial = segments;
  if (total > kInitialSamples) {
    const double keep = static_cast<double>(kInitialSamples) / static_cast<double>(total);
    for (DataSegment& seg : initial) {
      const size_t fitted = seg.voltage_V.size() - seg.fit_begin;
      const size_t size =
          seg.fit_begin + static_cast<size_t>(std::ceil(keep * static_cast<double>(fitted)));
      seg.voltage_V.resize(size);
      seg.deflection_mm.resize(size);
    }
  }
  const std::vector<Deviations> deviations = MakeDeviations(initial);

  // Stage 1-2: whole-sample delay and poles. The equation-error delay is exact on clean
  // data but biased under noise; the output-error scan with the resulting poles is not,
  // so when it disagrees the poles are re-estimated at its delay.
  const int d_max = static_cast<int>(std::floor(options.max_delay_s / dt_s));
  int d = options.estimate_delay
              ? CoarseDelay(deviations, na, nb, d_max)
              : static_cast<int>(std::floor(options.fixed_delay_s / dt_s + 1e-9));
  // A mode slower than ten record lengths cannot be told from a drift: clamp it there.
  size_t longest = 0;
  for (const DataSegment& seg : initial) longest = std::max(longest, seg.voltage_V.size());
  const double slowest_rad_s = 0.1 / (dt_s * static_cast<double>(longest));
  auto clamp_slow = [slowest_rad_s](std::vector<Complex> poles) {
    for (Complex& p : poles)
      if (std::abs(p) < slowest_rad_s) p = Complex(-slowest_rad_s, 0.0);
    return poles;
  };
  std::vector<Complex> poles = clamp_slow(LinearPoles(deviations, na, nb, d, dt_s));
  std::vector<double> factor_params = ParametersFromPoles(poles, n);
  std::vector<double> a;
  DenominatorAndDerivative(factor_params.data(), n, &a, nullptr);
  if (options.estimate_delay) {
    const int scanned = ScanDelay(initial, a, m, d_max);
    if (scanned != d) {
      d = scanned;
      factor_params = ParametersFromPoles(clamp_slow(LinearPoles(deviations, na, nb, d, dt_s)), n);
      DenominatorAndDerivative(factor_params.data(), n, &a, nullptr);
    }
  }

  // Stage 3: numerator and fraction of a sample.
  std::vector<double> b;
  double delay_s = options.estimate_delay ? d * dt_s : options.fixed_delay_s;
  if (options.estimate_delay) {
    double best = kInf;
    for (double fraction : {0.0, 0.25, 0.5, 0.75}) {
      std::vector<double> trial_b;
      const double trial_delay = (d + fraction) * dt_s;
      const double ssr = FitNumerator(initial, a, trial_delay, m, &trial_b);
      if (ssr < best) {
        best = ssr;
        b = trial_b;
        delay_s = trial_delay;
      }
    }
  } else {
    FitNumerator(initial, a, delay_s, m, &b);
  }

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
  ceres::Solver::Summary summary;
  std::vector<double> initial_voltages_V;
  for (const DataSegment& seg : segments) initial_voltages_V.push_back(seg.initial_voltage_V);
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
  // From here on each segment starts under its fitted (or given) initial voltage.
  std::vector<DataSegment> fitted = segments;
  for (size_t i = 0; i < fitted.size(); ++i) {
    fitted[i].initial_voltage_V = initial_voltages_V[i];
    fitted[i].estimate_initial_voltage = false;
  }
  if (!summary.IsSolutionUsable())
    throw std::runtime_error("identification did not converge: " + summary.message);

  DenominatorAndDerivative(factor_params.data(), n, &a, nullptr);
  TfEstimate estimate;
  estimate.tf = MakeTf(b, a, delay_s);
  estimate.iterations = static_cast<int>(summary.iterations.size());
  estimate.solver_report = summary.BriefReport();

  // Stage 5: uncertainty in the coefficients (b, a, T); fitted initial voltages are held
  // at their estimates (nuisance parameters), which makes the intervals slightly narrow.
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
  estimate.initial_voltage_V = initial_voltages_V;
  estimate.fit = EvaluateFit(estimate.tf, fitted, options.correlation_lags);
  return estimate;
}

}  // namespace flexid::model
