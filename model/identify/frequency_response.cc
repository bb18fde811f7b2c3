// The frequency-response route's entry (frequency_response.h): its options, the rational
// fit with dead time to the points stage by stage (FrequencyFitter: the weighted points,
// the delay grid, the profile, the joint fit, the intervals, the report), and the route
// from square waves. The points are estimated in frequency_points.cc; the rational fit's
// pieces are in frequency_rational.cc.
#include "model/identify/frequency_response.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "model/core/errors.h"
#include "model/core/polynomial.h"
#include "model/identify/frequency_fit.h"

namespace flexid::model {
namespace frequency_fit {

std::string Format(double value, int digits) {
  char text[64];
  std::snprintf(text, sizeof text, "%.*g", digits, value);
  return text;
}

namespace {

constexpr double kChi2One95 = 3.841458820694124;  // chi^2_1 95 % quantile
constexpr double kCompetingChi2 = 9.0;  // a competing delay valley: Delta chi^2 <= 9 (3 sigma)

std::string Describe(const Complex& p) {
  if (p.imag() == 0.0) return Format(p.real());
  return Format(p.real()) + (p.imag() > 0 ? " + " : " - ") + Format(std::abs(p.imag())) + "j";
}

// FitFrequencyResponse in stages (header, step 2), in order.
struct FrequencyFitter {
  FrequencyFitter(const std::vector<FrequencyPoint>& given, const FrequencyFitOptions& asked)
      : points(given), options(asked) {}

  const std::vector<FrequencyPoint>& points;
  const FrequencyFitOptions& options;
  bool with_delay = false;
  int m = 0, n = 0;
  int parameters = 0;  // real parameters: b, a and (with_delay) the delay
  int values = 0;      // real data values: two per point
  std::string structure;
  FitData d;
  double omega_min = kInf, omega_max = 0.0;
  std::string notes;
  // The delay grid and the profile chi^2(T) over it.
  std::vector<double> grid_s;
  std::vector<DelayFit> grid_fits;
  std::vector<double> profile_chi2;
  std::vector<Eigen::VectorXd> profile_theta;
  size_t best_index = 0;
  int sk_max_iterations = 0, reflected = 0;
  double grid_chi2 = 0.0;
  int lm_iterations = 0;
  int rational_parameters = 0;
  // The fit: its parameters (Pack) and their covariance.
  Eigen::VectorXd theta;
  double start_chi2 = 0.0;
  DelaySetting free_delay;
  Rational final_rational;
  double delay_s = 0.0;
  double chi2 = 0.0;
  int dof = 0;
  double reduced_chi2 = 0.0, variance_factor = 1.0, condition = 0.0;
  Eigen::MatrixXd covariance;
  std::vector<bool> undetermined;
  FrequencyFit result;
  double profile_lo = 0.0, profile_hi = 0.0;
  std::vector<std::pair<double, double>> competing;  // (Delta chi^2, T)

  void Prepare();
  Eigen::VectorXd Pack(const Rational& r, double delay) const;
  void SearchGrid();
  Eigen::VectorXd ImproveProfile(size_t i, const Eigen::VectorXd& start);
  void Profile();
  void Refine();
  void Covariance();
  double Factor(int power) const;
  double HalfWidth(int j, double scale) const;
  void Coefficients();
  void DelayInterval();
  void DcGainAndPoles();
  void Report();
};

// The options and the points checked; the points' variances, in the scaled variable.
void FrequencyFitter::Prepare() {
  std::string error;
  if (!options.IsValid(&error)) throw std::invalid_argument("FrequencyFitOptions: " + error);
  if (points.empty()) throw InputError("no frequency points to fit");
  with_delay = options.max_delay_s > 0.0;
  m = options.num_zeros;
  n = options.num_poles;
  parameters = m + 1 + n + (with_delay ? 1 : 0);
  values = 2 * static_cast<int>(points.size());
  structure = std::to_string(m) + " zeros / " + std::to_string(n) + " poles" +
              (with_delay ? " + delay" : "");
  if (values < parameters)
    throw InputError("too few frequency points: " + std::to_string(points.size()) +
                     " points give " + std::to_string(values) + " real values, fewer than the " +
                     std::to_string(parameters) + " parameters of " + structure +
                     "; add frequencies or lower num_zeros / num_poles");

  d.m = m;
  d.n = n;
  double g_max = 0.0;
  bool any_uncertainty = false;
  for (size_t k = 0; k < points.size(); ++k) {
    const FrequencyPoint& p = points[k];
    if (!std::isfinite(p.omega_rad_s) || !(p.omega_rad_s > 0.0) ||
        !std::isfinite(p.response.real()) || !std::isfinite(p.response.imag()) ||
        !std::isfinite(p.std_dev) || !std::isfinite(p.gain_half_width_95))
      throw InputError("frequency point " + std::to_string(k) +
                       " is not usable (omega must be > 0, values finite)");
    omega_min = std::min(omega_min, p.omega_rad_s);
    omega_max = std::max(omega_max, p.omega_rad_s);
    g_max = std::max(g_max, std::abs(p.response));
    const double sd = p.std_dev > 0.0 ? p.std_dev : p.gain_half_width_95 / kZ975;
    if (sd > 0.0) any_uncertainty = true;
    d.omega.push_back(p.omega_rad_s);
    d.g.push_back(p.response);
    d.var.push_back(2.0 * sd * sd);
  }
  // Points without an uncertainty take the median variance of the others (all of them
  // without: unweighted, variance 1); a floor at rounding level keeps every weight finite.
  std::vector<double> given;
  for (double v : d.var)
    if (v > 0.0) given.push_back(v);
  double median_var = 1.0;
  if (!given.empty()) {
    std::nth_element(given.begin(), given.begin() + static_cast<std::ptrdiff_t>(given.size() / 2),
                     given.end());
    median_var = given[given.size() / 2];
  }
  const size_t without = d.var.size() - given.size();
  for (size_t k = 0; k < d.var.size(); ++k) {
    if (!(d.var[k] > 0.0)) d.var[k] = median_var;
    const double floor = std::pow(1e-9 * std::abs(d.g[k]), 2) + std::pow(1e-12 * g_max, 2);
    d.var[k] = std::max(d.var[k], floor > 0.0 ? floor : 1e-300);
  }
  if (!any_uncertainty)
    notes += " The points carry no uncertainty: unweighted fit.";
  else if (without > 0)
    notes += " " + std::to_string(without) +
             " point(s) without an uncertainty took the median variance of the others.";
  d.omega_ref = std::sqrt(omega_min * omega_max);
  for (double omega : d.omega) d.s.emplace_back(0.0, omega / d.omega_ref);
}

Eigen::VectorXd FrequencyFitter::Pack(const Rational& r, double delay) const {
  Eigen::VectorXd packed(parameters);
  packed.head(m + 1) = r.b;
  packed.segment(m + 1, n) = r.a.head(n);
  if (with_delay) packed(parameters - 1) = delay;
  return packed;
}

// 1. Delay grid: Levy + SK at every grid delay.
void FrequencyFitter::SearchGrid() {
  if (with_delay) {
    const auto steps =
        static_cast<long>(std::floor(options.max_delay_s / options.delay_step_s + 1e-9));
    for (long i = 0; i <= steps; ++i)
      grid_s.push_back(static_cast<double>(i) * options.delay_step_s);
    if (options.max_delay_s - grid_s.back() > 1e-9) grid_s.push_back(options.max_delay_s);
  } else {
    grid_s.push_back(0.0);
  }
  grid_fits.resize(grid_s.size());
  profile_chi2.resize(grid_s.size());
  for (size_t i = 0; i < grid_s.size(); ++i) {
    grid_fits[i] = FitAtDelay(d, grid_s[i], options.sk_iterations);
    profile_chi2[i] = grid_fits[i].chi2;
    sk_max_iterations = std::max(sk_max_iterations, grid_fits[i].iterations);
    reflected += grid_fits[i].reflected;
    if (grid_fits[i].chi2 < grid_fits[best_index].chi2) best_index = i;
  }
  grid_chi2 = grid_fits[best_index].chi2;
  theta = Pack(grid_fits[best_index].rational, grid_s[best_index]);
  start_chi2 = grid_chi2;
  rational_parameters = m + 1 + n;
  profile_theta.resize(grid_s.size());
}

// Profile point i: Levenberg-Marquardt on b, a with T = grid_s[i] fixed, from `start`;
// kept if it lowers profile_chi2[i].
// Returns the local solution (the next start of a continuation sweep).
Eigen::VectorXd FrequencyFitter::ImproveProfile(size_t i, const Eigen::VectorXd& start) {
  Eigen::VectorXd candidate = start;
  double cost = kInf;
  LevenbergMarquardt(d, {false, grid_s[i], 0.0}, 30, &candidate, &cost);
  if (cost < profile_chi2[i]) {
    profile_chi2[i] = cost;
    profile_theta[i] = candidate;
  }
  return candidate;
}

void FrequencyFitter::Profile() {
  if (with_delay && options.refine) {
    // 2. Profile: SK's fixed point is near, not at, the weighted least-squares optimum, and
    // the delay's interval needs the profile chi^2(T) = min over b, a.
    for (size_t i = 0; i < grid_s.size(); ++i) {
      profile_theta[i] = Pack(grid_fits[i].rational, 0.0).head(rational_parameters);
      ImproveProfile(i, profile_theta[i]);
      if (profile_chi2[i] < start_chi2) {
        start_chi2 = profile_chi2[i];
        theta = Pack(Unpack(d, profile_theta[i]), grid_s[i]);
      }
    }
    // 3. Golden-section search of the SK chi^2(T) between the best SK grid point's
    // neighbours; kept if it beats the best profile point.
    double lo = grid_s[best_index > 0 ? best_index - 1 : 0];
    double hi = grid_s[std::min(best_index + 1, grid_s.size() - 1)];
    const double ratio = 0.5 * (std::sqrt(5.0) - 1.0);
    double x1 = hi - ratio * (hi - lo), x2 = lo + ratio * (hi - lo);
    DelayFit f1 = FitAtDelay(d, x1, options.sk_iterations);
    DelayFit f2 = FitAtDelay(d, x2, options.sk_iterations);
    for (int i = 0; i < 40 && hi - lo > 1e-6 * (1.0 + options.max_delay_s); ++i) {
      if (f1.chi2 < f2.chi2) {
        hi = x2;
        x2 = x1;
        f2 = f1;
        x1 = hi - ratio * (hi - lo);
        f1 = FitAtDelay(d, x1, options.sk_iterations);
      } else {
        lo = x1;
        x1 = x2;
        f1 = f2;
        x2 = lo + ratio * (hi - lo);
        f2 = FitAtDelay(d, x2, options.sk_iterations);
      }
    }
    const bool first = f1.chi2 < f2.chi2;
    if ((first ? f1 : f2).chi2 < start_chi2) {
      start_chi2 = (first ? f1 : f2).chi2;
      theta = Pack((first ? f1 : f2).rational, first ? x1 : x2);
    }
  }
}

// 4. Levenberg-Marquardt on everything; then 5. the profile again by continuation from
// the optimum (each grid point starts from its neighbour's solution, sweeping outwards),
// which traces the valley the local fits from SK starts miss. If the profile finds a
// lower point than the optimum, the free fit restarts there (at most three rounds).
void FrequencyFitter::Refine() {
  free_delay = {with_delay, 0.0, options.max_delay_s};
  for (int round = 0; round < 3 && options.refine; ++round) {
    lm_iterations += LevenbergMarquardt(d, free_delay, 100, &theta, nullptr);
    if (!with_delay) break;
    Eigen::VectorXd residual;
    Residuals(d, theta, free_delay, &residual, nullptr);
    const double optimum_chi2 = residual.squaredNorm();
    const size_t centre =
        static_cast<size_t>(std::clamp(std::llround(theta(parameters - 1) / options.delay_step_s),
                                       0LL, static_cast<long long>(grid_s.size()) - 1));
    const Eigen::VectorXd optimum = theta.head(rational_parameters);
    for (int direction : {1, -1}) {
      Eigen::VectorXd start = optimum;
      for (long long i = static_cast<long long>(centre);
           i >= 0 && i < static_cast<long long>(grid_s.size()); i += direction) {
        start = ImproveProfile(static_cast<size_t>(i), start);
      }
    }
    const size_t lowest = static_cast<size_t>(
        std::min_element(profile_chi2.begin(), profile_chi2.end()) - profile_chi2.begin());
    if (!(profile_chi2[lowest] < optimum_chi2 - 1e-9 * (1.0 + optimum_chi2))) break;
    theta = Pack(Unpack(d, profile_theta[lowest]), grid_s[lowest]);
  }
  final_rational = Unpack(d, theta);
  delay_s = with_delay ? theta(parameters - 1) : 0.0;
}

void FrequencyFitter::Covariance() {
  Eigen::VectorXd rho;
  Eigen::MatrixXd jacobian;
  Residuals(d, theta, free_delay, &rho, &jacobian);
  chi2 = rho.squaredNorm();
  dof = values - parameters;
  reduced_chi2 = dof > 0 ? chi2 / dof : kInf;
  variance_factor = dof > 0 ? std::max(1.0, reduced_chi2) : 1.0;

  // Covariance by the pseudo-inverse of the column-scaled Jacobian: directions with a
  // singular value below 1e-10 of the largest are not determined (+inf half-widths).
  Eigen::VectorXd column_scale(parameters);
  for (int j = 0; j < parameters; ++j) {
    const double norm = jacobian.col(j).norm();
    column_scale(j) = norm > 0.0 ? 1.0 / norm : 1.0;
  }
  const Eigen::MatrixXd scaled = jacobian * column_scale.asDiagonal();
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(scaled, Eigen::ComputeThinV);
  const Eigen::VectorXd singular = svd.singularValues();
  condition =
      singular(singular.size() - 1) > 0.0 ? singular(0) / singular(singular.size() - 1) : kInf;
  covariance = Eigen::MatrixXd::Zero(parameters, parameters);
  undetermined.assign(static_cast<size_t>(parameters), false);
  for (int i = 0; i < singular.size(); ++i) {
    const Eigen::VectorXd v = svd.matrixV().col(i);
    if (singular(i) > 1e-10 * singular(0)) {
      covariance += v * v.transpose() / (singular(i) * singular(i));
    } else {
      for (int j = 0; j < parameters; ++j)
        if (std::abs(v(j)) > 1e-3) undetermined[static_cast<size_t>(j)] = true;
    }
  }
  covariance = column_scale.asDiagonal() * covariance * column_scale.asDiagonal();
  covariance *= variance_factor;
}

double FrequencyFitter::Factor(int power) const { return std::pow(d.omega_ref, n - power); }

double FrequencyFitter::HalfWidth(int j, double scale) const {
  if (undetermined[static_cast<size_t>(j)]) return kInf;
  return kZ975 * std::sqrt(std::max(0.0, covariance(j, j))) * std::abs(scale);
}

// Unscaled coefficients: multiplying B and A by omega_ref^n makes A monic in s, so the
// coefficient of s^i (both polynomials) is the scaled one times omega_ref^{n - i}.
void FrequencyFitter::Coefficients() {
  result.points = points;
  result.tf.num.resize(static_cast<size_t>(m + 1));
  result.tf.den.resize(static_cast<size_t>(n + 1));
  for (int j = 0; j <= m; ++j) {  // b_j multiplies s^{m-j}
    const int power = m - j;
    const double value = final_rational.b(power) * Factor(power);
    result.tf.num[static_cast<size_t>(j)] = value;
    result.coefficients.push_back(
        {"b" + std::to_string(j), value, HalfWidth(power, Factor(power))});
  }
  result.tf.den[0] = 1.0;
  for (int j = 1; j <= n; ++j) {  // a_j multiplies s^{n-j}
    const int power = n - j;
    const double value = final_rational.a(power) * Factor(power);
    result.tf.den[static_cast<size_t>(j)] = value;
    result.coefficients.push_back(
        {"a" + std::to_string(j), value, HalfWidth(m + 1 + power, Factor(power))});
  }
  result.tf.delay_s = delay_s;
}

// Delay: the profile interval {T : chi^2(T) <= chi^2 + 3.84 max(1, chi^2 / dof)}, its
// ends interpolated linearly between grid points. The profile rather than the Jacobian:
// chi^2(T) is far from quadratic where the delay trades off against a fast mode.
void FrequencyFitter::DelayInterval() {
  profile_lo = delay_s;
  profile_hi = delay_s;
  if (with_delay) {
    const double threshold = chi2 + kChi2One95 * variance_factor;
    // The optimum joins the grid as a profile point; from it the profile is taken as
    // quadratic (the crossing at sqrt of the chi^2 fraction), elsewhere as linear.
    std::vector<std::pair<double, double>> profile;  // (T, chi^2), T ascending
    for (size_t i = 0; i < grid_s.size(); ++i) profile.emplace_back(grid_s[i], profile_chi2[i]);
    const auto optimum_at = profile.insert(
        std::lower_bound(profile.begin(), profile.end(), std::make_pair(delay_s, chi2)),
        {delay_s, chi2});
    const auto optimum_index = static_cast<size_t>(optimum_at - profile.begin());
    auto crossing = [&](size_t inside, size_t outside) {
      const double c_in = profile[inside].second, c_out = profile[outside].second;
      double f = c_out > c_in ? (threshold - c_in) / (c_out - c_in) : 0.0;
      if (inside == optimum_index) f = std::sqrt(std::max(0.0, f));
      return profile[inside].first +
             std::clamp(f, 0.0, 1.0) * (profile[outside].first - profile[inside].first);
    };
    for (size_t i = 0; i < profile.size(); ++i) {
      if (profile[i].second > threshold) continue;
      profile_lo = std::min(profile_lo, i > 0 ? crossing(i, i - 1) : profile[i].first);
      profile_hi =
          std::max(profile_hi, i + 1 < profile.size() ? crossing(i, i + 1) : profile[i].first);
    }
    result.coefficients.push_back(
        {"delay_s", delay_s, std::max(profile_hi - delay_s, delay_s - profile_lo)});
    // Competing valleys: local minima of the profile outside the interval, within
    // Delta chi^2 <= 25 max(1, chi^2 / dof) (5 sigma) of the optimum.
    for (size_t i = 0; i < grid_s.size(); ++i) {
      const bool local_minimum = (i == 0 || profile_chi2[i] <= profile_chi2[i - 1]) &&
                                 (i + 1 == grid_s.size() || profile_chi2[i] <= profile_chi2[i + 1]);
      if (local_minimum && (grid_s[i] < profile_lo || grid_s[i] > profile_hi) &&
          profile_chi2[i] <= chi2 + kCompetingChi2 * variance_factor)
        competing.push_back({profile_chi2[i] - chi2, grid_s[i]});
    }
    std::sort(competing.begin(), competing.end());
  }
}

void FrequencyFitter::DcGainAndPoles() {
  // DC gain b'_0 / a'_0 (the omega_ref factors cancel), delta method.
  const double b0 = final_rational.b(0), a0 = final_rational.a(0);
  result.dc_gain.name = "dc_gain";
  result.dc_gain.value = b0 / a0;
  if (undetermined[0] || undetermined[static_cast<size_t>(m + 1)]) {
    result.dc_gain.half_width_95 = kInf;
  } else {
    const double db = 1.0 / a0, da = -b0 / (a0 * a0);
    const double var = db * db * covariance(0, 0) + 2.0 * db * da * covariance(0, m + 1) +
                       da * da * covariance(m + 1, m + 1);
    result.dc_gain.half_width_95 = kZ975 * std::sqrt(std::max(0.0, var));
  }
  // Poles: p moves by dp = -sum_i p^{n-i} da_i / A'(p) (differentiate A(p) = 0).
  {
    std::vector<int> index(static_cast<size_t>(n + 1));  // theta index of a_i
    std::vector<double> scale(static_cast<size_t>(n + 1));
    bool determined = true;
    for (int i = 1; i <= n; ++i) {
      index[static_cast<size_t>(i)] = m + 1 + (n - i);
      scale[static_cast<size_t>(i)] = Factor(n - i);
      determined = determined && !undetermined[static_cast<size_t>(m + 1 + (n - i))];
    }
    std::vector<double> derivative;  // A'(s), descending
    for (int i = 0; i < n; ++i)
      derivative.push_back(result.tf.den[static_cast<size_t>(i)] * (n - i));
    for (const Complex& pole : Poles(result.tf)) {
      PoleEstimate estimate{pole.real(), pole.imag(), kInf, kInf};
      const Complex slope = EvaluatePolynomial(derivative, pole);
      if (determined && std::abs(slope) > 0.0) {
        Eigen::VectorXd g_re(parameters), g_im(parameters);
        g_re.setZero();
        g_im.setZero();
        for (int i = 1; i <= n; ++i) {
          const Complex dp = -std::pow(pole, n - i) / slope * scale[static_cast<size_t>(i)];
          g_re(index[static_cast<size_t>(i)]) = dp.real();
          g_im(index[static_cast<size_t>(i)]) = dp.imag();
        }
        estimate.re_half_width_95 = kZ975 * std::sqrt(std::max(0.0, g_re.dot(covariance * g_re)));
        estimate.im_half_width_95 = kZ975 * std::sqrt(std::max(0.0, g_im.dot(covariance * g_im)));
      }
      result.poles.push_back(estimate);
    }
  }
}

void FrequencyFitter::Report() {
  result.weighted_rms_error = std::sqrt(chi2 / values);

  // Report.
  std::string report = "Frequency fit (Levy + Sanathanan-Koerner, Golubev-style): " + structure +
                       "; " + std::to_string(points.size()) + " points (" + std::to_string(values) +
                       " real values) over " + Format(omega_min) + " .. " + Format(omega_max) +
                       " rad/s; " + std::to_string(parameters) + " parameters, " +
                       std::to_string(dof) + " degrees of freedom.";
  report += " omega_ref " + Format(d.omega_ref) + " rad/s.";
  if (with_delay)
    report += " Delay grid 0 .. " + Format(options.max_delay_s) + " s step " +
              Format(options.delay_step_s) + " s: best chi2 " + Format(grid_chi2) +
              "; T = " + Format(delay_s) + " s, profile 95 % range " + Format(profile_lo) + " .. " +
              Format(profile_hi) + " s.";
  report += " SK iterations <= " + std::to_string(sk_max_iterations) + ", LM iterations " +
            std::to_string(lm_iterations) + "; chi2 " + Format(chi2) + ", weighted rms error " +
            Format(result.weighted_rms_error) + ".";
  if (!competing.empty()) {
    report += " WARNING delay ambiguous: chi2(T) has competing minima at";
    for (size_t i = 0; i < std::min<size_t>(competing.size(), 5); ++i)
      report += std::string(i ? "," : "") + " T = " + Format(competing[i].second) + " s (chi2 +" +
                Format(competing[i].first, 3) + ")";
    report += "; the delay interval is that of the best valley.";
  }
  if (reflected > 0)
    report += " " + std::to_string(reflected) +
              " unstable pole(s) reflected into the left half-plane during the SK iterations.";
  report += notes;
  if (dof == 0)
    report +=
        " WARNING exactly determined: as many parameters as real data values, the fit "
        "interpolates and cannot show a misfit.";
  else if (dof < parameters)
    report += " WARNING barely determined: " + std::to_string(dof) + " degrees of freedom for " +
              std::to_string(parameters) + " parameters.";
  std::vector<std::string> undetermined_names;
  for (int j = 0; j < parameters; ++j)
    if (undetermined[static_cast<size_t>(j)]) {
      if (j <= m)
        undetermined_names.push_back("b" + std::to_string(m - j));
      else if (j < m + 1 + n)
        undetermined_names.push_back("a" + std::to_string(n - (j - m - 1)));
      else
        undetermined_names.push_back("delay_s");
    }
  if (!undetermined_names.empty()) {
    report += " WARNING underdetermined: the points do not determine";
    for (const std::string& name : undetermined_names) report += " " + name;
    report += ".";
  } else if (condition > 1e8) {
    report += " WARNING ill-conditioned: Jacobian condition number " + Format(condition, 3) +
              " (column-scaled); coefficient intervals are wide.";
  } else {
    report += " Jacobian condition number " + Format(condition, 3) + ".";
  }
  if (dof > 0 && reduced_chi2 > 4.0)
    report += " WARNING misfit: chi2 / dof = " + Format(reduced_chi2, 3) +
              ", the model order or the point uncertainties are wrong.";
  for (const Mode& mode : Modes(result.tf)) {
    const double w = mode.natural_frequency_rad_s;
    if (w > omega_max || w < omega_min)
      report += " Pole " + Describe(mode.pole) + " (|p| " + Format(w) +
                " rad/s) lies outside the measured band: extrapolated.";
    if (mode.oscillatory && mode.damping_ratio < 0.3)
      report += " Lightly damped pair at " + Format(w) + " rad/s (damping " +
                Format(mode.damping_ratio, 3) + "); the seed's physics predicts real poles.";
  }
  result.method_report = report;
}

}  // namespace
}  // namespace frequency_fit

using namespace frequency_fit;  // NOLINT(google-build-using-namespace): the route's own parts

// -----------------------------------------------------------------------------------------
// Options
// -----------------------------------------------------------------------------------------

bool FrequencyFitOptions::IsValid(std::string* error) const {
  auto fail = [error](std::string message) {
    if (error) *error = std::move(message);
    return false;
  };
  if (num_poles < 1) return fail("num_poles must be >= 1");
  if (num_zeros < 0 || num_zeros > num_poles)
    return fail("num_zeros must be in [0, num_poles] (a proper model)");
  if (!std::isfinite(max_delay_s) || max_delay_s < 0.0)
    return fail("max_delay_s must be finite and >= 0");
  if (sk_iterations < 1) return fail("sk_iterations must be >= 1");
  if (!std::isfinite(delay_step_s) || !(delay_step_s > 0.0))
    return fail("delay_step_s must be finite and > 0");
  if (max_delay_s / delay_step_s > 1e6) return fail("delay grid has more than 1e6 points");
  return true;
}

// -----------------------------------------------------------------------------------------
// Rational fit with dead time
// -----------------------------------------------------------------------------------------

FrequencyFit FitFrequencyResponse(const std::vector<FrequencyPoint>& points,
                                  const FrequencyFitOptions& options) {
  FrequencyFitter fitter(points, options);
  fitter.Prepare();
  fitter.SearchGrid();
  fitter.Profile();
  fitter.Refine();
  fitter.Covariance();
  fitter.Coefficients();
  fitter.DelayInterval();
  fitter.DcGainAndPoles();
  fitter.Report();
  return std::move(fitter.result);
}

FrequencyFit IdentifyFromSquareWaves(const std::vector<DataSegment>& recordings,
                                     const FrequencyFitOptions& options,
                                     const SquareWaveOptions& square_wave) {
  std::string error;
  if (!options.IsValid(&error)) throw std::invalid_argument("FrequencyFitOptions: " + error);
  if (!square_wave.IsValid(&error)) throw std::invalid_argument("SquareWaveOptions: " + error);
  if (recordings.empty()) throw InputError("no recordings");
  std::vector<FrequencyPoint> points;
  for (size_t r = 0; r < recordings.size(); ++r) {
    try {
      const double f0_Hz = DetectFundamental_Hz(recordings[r]);
      const int discard =
          std::max(square_wave.discard_periods,
                   static_cast<int>(std::ceil(square_wave.min_discard_s * f0_Hz - 1e-9)));
      const std::vector<FrequencyPoint> found =
          EstimateFrequencyResponse(recordings[r], f0_Hz, square_wave.max_harmonic, discard);
      points.insert(points.end(), found.begin(), found.end());
    } catch (const InputError& e) {
      throw InputError("recording " + std::to_string(r) + ": " + e.what());
    }
  }
  return FitFrequencyResponse(points, options);
}

}  // namespace flexid::model
