// The transfer-function fit's start (identify.h, stages 1-3): deviations from the initial
// steady state, the coarse dead time and the poles by ARX and Steiglitz-McBride least
// squares, the output-error delay scan with the poles fixed, and the numerator with the
// fraction of a sample.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <complex>
#include <vector>

#include "model/core/discretise.h"
#include "model/core/polynomial.h"
#include "model/identify/tf_fit.h"

namespace flexid::model::tf_fit {
namespace {

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
// Stage 3 and the delay scan: the states of 1/A(s) for fixed poles
// -----------------------------------------------------------------------------------------

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

}  // namespace

LinearEstimate EstimateLinear(const std::vector<DataSegment>& segments,
                              const IdentifyOptions& options, double dt_s) {
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
  return {b, factor_params, delay_s};
}

}  // namespace flexid::model::tf_fit
