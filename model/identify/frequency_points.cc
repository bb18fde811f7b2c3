// The frequency-response route's points (frequency_response.h, step 1): the fundamental of
// a periodic input, and the response at it and its harmonics, stage by stage: the window of
// whole periods, the trend from sub-period means, the harmonics by least squares, the
// estimate's noise operator, and each point with its uncertainty.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/core/errors.h"
#include "model/identify/frequency_fit.h"
#include "model/identify/frequency_response.h"

namespace flexid::model {
namespace frequency_fit {
namespace {

constexpr int kTrendDegree = 4;              // trend: Legendre polynomials up to degree 4 ...
constexpr int kTrendPartsPerPeriod = 4;      // ... fitted to the means of quarter periods
constexpr double kMinHarmonicRatio = 0.01;   // |U_h| / |U_1| below this: not excited
constexpr double kMaxNyquistFraction = 0.8;  // omega_h <= 0.8 pi / dt
constexpr int kMaxNoiseBinOffset = 12;       // noise bins at most 12 bins from the line

// Student-t 97.5 % quantile for nu degrees of freedom (Cornish-Fisher expansion about the
// normal quantile; better than 1e-3 for nu >= 4, which every caller has).
double StudentT975(double nu) {
  const double z = kZ975, z3 = z * z * z, z5 = z3 * z * z, z7 = z5 * z * z;
  return z + (z3 + z) / (4.0 * nu) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * nu * nu) +
         (3.0 * z7 + 19.0 * z5 + 17.0 * z3 - 15.0 * z) / (384.0 * nu * nu * nu);
}

// F_{2,nu} 95 % quantile, closed form: P(F <= x) = 1 - (1 + 2 x / nu)^{-nu / 2}.
double F2Quantile95(double nu) { return 0.5 * nu * (std::pow(0.05, -2.0 / nu) - 1.0); }

void CheckSegment(const DataSegment& segment) {
  if (!(segment.dt_s > 0.0) || !std::isfinite(segment.dt_s))
    throw InputError("sample period must be finite and > 0, got " + Format(segment.dt_s));
  if (segment.voltage_V.size() != segment.deflection_mm.size())
    throw InputError("voltage and deflection differ in length (" +
                     std::to_string(segment.voltage_V.size()) + " vs " +
                     std::to_string(segment.deflection_mm.size()) + ")");
  if (segment.voltage_V.size() < 10)
    throw InputError("recording too short: " + std::to_string(segment.voltage_V.size()) +
                     " samples");
  for (size_t k = 0; k < segment.voltage_V.size(); ++k)
    if (!std::isfinite(segment.voltage_V[k]) || !std::isfinite(segment.deflection_mm[k]))
      throw InputError("non-finite value at sample " + std::to_string(k));
}

// Legendre polynomials P_0..P_degree at x in [-1, 1] (Bonnet's recursion), written to
// out[0], out[stride], ... (a row of a column-major matrix).
void Legendre(double x, int degree, double* out, Eigen::Index stride) {
  auto at = [out, stride](int d) -> double& { return out[d * stride]; };
  at(0) = 1.0;
  if (degree >= 1) at(1) = x;
  for (int d = 2; d <= degree; ++d)
    at(d) = ((2.0 * d - 1.0) * x * at(d - 1) - (d - 1.0) * at(d - 2)) / d;
}

// sum_i r_i e^{-j omega dt i} for both columns of r at once. The phasor is advanced by
// multiplication and reset exactly every 256 samples, so rounding cannot accumulate.
std::pair<Complex, Complex> Dtft(const Eigen::MatrixXd& r, double omega_dt) {
  const Complex step = std::polar(1.0, -omega_dt);
  Complex phasor = 1.0, sum0 = 0.0, sum1 = 0.0;
  for (Eigen::Index i = 0; i < r.rows(); ++i) {
    if (i % 256 == 0) phasor = std::polar(1.0, -omega_dt * static_cast<double>(i));
    sum0 += r(i, 0) * phasor;
    sum1 += r(i, 1) * phasor;
    phasor *= step;
  }
  return {sum0, sum1};
}

// EstimateFrequencyResponse in stages (header, step 1), in order.
struct PointEstimator {
  PointEstimator(const DataSegment& data, double fundamental, int harmonics_asked, int discarded)
      : segment(data),
        fundamental_Hz(fundamental),
        max_harmonic(harmonics_asked),
        discard_periods(discarded) {}

  const DataSegment& segment;
  const double fundamental_Hz;
  const int max_harmonic, discard_periods;
  double dt_s = 0.0, nyquist_Hz = 0.0;
  // The window: whole periods after the discarded ones.
  double period_samples = 0.0;
  int periods = 0;
  Eigen::Index begin = 0, length = 0;
  Eigen::MatrixXd signals;  // u, y on the window
  // The trend.
  int parts = 0, degree = 0, cells = 0;
  double cell_samples = 0.0;
  Eigen::MatrixXd legendre, design, detrended;
  Eigen::VectorXd cell_weight;
  // The harmonics.
  static constexpr int trend = 1;
  int harmonics = 0;
  double omega0_rad_s = 0.0;
  Eigen::MatrixXd regressors, coefficients, residuals, covariance;
  Eigen::MatrixXd operator_rows;  // W (I - T A)

  void Window();
  void Detrend();
  void Harmonics();
  void NoiseOperator();
  Complex Amplitude(int column, int h) const;
  std::vector<FrequencyPoint> Points() const;
};

void PointEstimator::Window() {
  if (!std::isfinite(fundamental_Hz) || !(fundamental_Hz > 0.0))
    throw std::invalid_argument("fundamental_Hz must be finite and > 0");
  if (max_harmonic < 1) throw std::invalid_argument("max_harmonic must be >= 1");
  if (discard_periods < 0) throw std::invalid_argument("discard_periods must be >= 0");
  CheckSegment(segment);
  dt_s = segment.dt_s;
  nyquist_Hz = 0.5 / dt_s;
  if (fundamental_Hz > kMaxNyquistFraction * nyquist_Hz)
    throw InputError("fundamental " + Format(fundamental_Hz) + " Hz is above 0.8 Nyquist (" +
                     Format(kMaxNyquistFraction * nyquist_Hz) + " Hz at dt = " + Format(dt_s) +
                     " s)");

  // Window: whole periods after the discarded ones.
  period_samples = 1.0 / (fundamental_Hz * dt_s);
  const auto total = static_cast<double>(segment.voltage_V.size());
  double start = std::round(discard_periods * period_samples);
  // A recording that ends less than one sample short of a whole period still counts it
  // (the fundamental is only known to about a sample per recording): the window then
  // starts up to a sample earlier, so that it always holds whole periods.
  periods =
      start < total ? static_cast<int>(std::floor((total - start + 1.0) / period_samples)) : 0;
  if (periods < 2)
    throw InputError("recording holds " + Format(total / period_samples, 3) + " periods of " +
                     Format(fundamental_Hz) + " Hz; need discard_periods + 2 = " +
                     std::to_string(discard_periods + 2) + " whole ones");
  const double window = std::min(std::round(periods * period_samples), total);
  start = std::max(0.0, std::min(start, total - window));
  begin = static_cast<Eigen::Index>(start);
  length = static_cast<Eigen::Index>(window);

  signals.resize(length, 2);
  for (Eigen::Index i = 0; i < length; ++i) {
    signals(i, 0) = segment.voltage_V[static_cast<size_t>(begin + i)];
    signals(i, 1) = segment.deflection_mm[static_cast<size_t>(begin + i)];
  }
  const double y_range_mm = signals.col(1).maxCoeff() - signals.col(1).minCoeff();
  if (!(y_range_mm > 0.0))
    throw InputError("output is constant over the analysis window (from t = " +
                     Format(static_cast<double>(begin) * dt_s) +
                     " s): is the dead time longer than the recording?");
}

// Trend from sub-period means (header): each period is cut into `parts` cells of at
// least 4 samples; the cell means are a periodic pattern (one value per part: whatever
// the periodic signal is, measured harmonics or not) plus the trend's Legendre terms
// 1..degree, fitted by least squares (parts * periods equations, parts + degree
// unknowns). Sample i stands for [i, i + 1) in sample units from the window start;
// samples on a cell boundary are shared by overlap.
void PointEstimator::Detrend() {
  parts = std::clamp(static_cast<int>(std::floor(period_samples / 4.0)), 1, kTrendPartsPerPeriod);
  degree = std::min(kTrendDegree, parts * (periods - 1));
  cells = parts * periods;
  cell_samples = period_samples / parts;
  legendre.resize(length, degree + 1);
  for (Eigen::Index i = 0; i < length; ++i) {
    const double x = 2.0 * (static_cast<double>(i) + 0.5) / static_cast<double>(length) - 1.0;
    Legendre(x, degree, legendre.row(i).data(), length);
  }
  // Columns: Legendre 1..degree, then the signals u, y; rows: the cells' means.
  Eigen::MatrixXd cell_means = Eigen::MatrixXd::Zero(cells, degree + 2);
  cell_weight = Eigen::VectorXd::Zero(cells);
  for (Eigen::Index i = 0; i < length; ++i) {
    const double cell_begin = static_cast<double>(i);
    const int j = std::min(cells - 1, static_cast<int>(std::floor(cell_begin / cell_samples)));
    const double boundary = (j + 1) * cell_samples;
    const double w_first = std::clamp(boundary - cell_begin, 0.0, 1.0);
    for (int cell = j; cell <= std::min(j + 1, cells - 1); ++cell) {
      const double w = cell == j ? w_first : 1.0 - w_first;
      if (w <= 0.0) continue;
      cell_means.row(cell).head(degree) += w * legendre.row(i).tail(degree);
      cell_means.row(cell).tail(2) += w * signals.row(i);
      cell_weight(cell) += w;
    }
  }
  for (int j = 0; j < cells; ++j) cell_means.row(j) /= cell_weight(j);
  design = Eigen::MatrixXd::Zero(cells, degree + parts);
  design.leftCols(degree) = cell_means.leftCols(degree);
  for (int j = 0; j < cells; ++j) design(j, degree + j % parts) = 1.0;
  const Eigen::MatrixXd solution = design.colPivHouseholderQr().solve(cell_means.rightCols(2));
  detrended = signals - legendre.rightCols(degree) * solution.topRows(degree);
}

// Harmonics: least squares on the detrended signals with a constant and cos / sin of
// every harmonic up to max_harmonic below 0.8 Nyquist (on whole periods these columns
// are orthogonal, so this is the DFT at the lines; the constant takes the mean).
void PointEstimator::Harmonics() {
  harmonics = std::min(
      max_harmonic,
      static_cast<int>(std::floor(kMaxNyquistFraction * nyquist_Hz / fundamental_Hz + 1e-9)));
  const int columns = trend + 2 * harmonics;
  omega0_rad_s = 2.0 * kPi * fundamental_Hz;
  regressors.resize(length, columns);
  for (Eigen::Index i = 0; i < length; ++i) {
    // Window time: G = Y / U does not depend on the time origin.
    const double t_s = static_cast<double>(i) * dt_s;
    regressors(i, 0) = 1.0;
    for (int h = 1; h <= harmonics; ++h) {
      regressors(i, trend + 2 * (h - 1)) = std::cos(h * omega0_rad_s * t_s);
      regressors(i, trend + 2 * (h - 1) + 1) = std::sin(h * omega0_rad_s * t_s);
    }
  }
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(regressors);
  coefficients = qr.solve(detrended);
  residuals = detrended - regressors * coefficients;
  // C = (M^T M)^{-1} = R^{-1} R^{-T}.
  const Eigen::MatrixXd r_upper = qr.matrixQR().topRows(columns).triangularView<Eigen::Upper>();
  const Eigen::MatrixXd r_inverse =
      r_upper.triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(columns, columns));
  covariance = r_inverse * r_inverse.transpose();
}

// The whole estimate is linear in the signal: coefficients = W (I - T A) x, with
// W = C M^T the least-squares operator, A (cells x L) the cell averaging and T (L x
// cells) the trend fitted to cell means. Its rows r give the variance under white noise
// exactly, trend noise included: var = sigma^2 |r|^2 (with C alone it would be missed;
// for a long period and degree-4 trend it is comparable to the harmonic's own).
void PointEstimator::NoiseOperator() {
  const Eigen::MatrixXd design_inverse =
      design.colPivHouseholderQr().solve(Eigen::MatrixXd::Identity(cells, cells));
  const Eigen::MatrixXd least_squares = covariance * regressors.transpose();  // W, p x L
  const Eigen::MatrixXd w_trend =
      (least_squares * legendre.rightCols(degree)) * design_inverse.topRows(degree);  // p x cells
  operator_rows = least_squares;                                                      // W (I - T A)
  for (Eigen::Index i = 0; i < length; ++i) {
    const double cell_begin = static_cast<double>(i);
    const int j = std::min(cells - 1, static_cast<int>(std::floor(cell_begin / cell_samples)));
    const double w_first = std::clamp((j + 1) * cell_samples - cell_begin, 0.0, 1.0);
    for (int cell = j; cell <= std::min(j + 1, cells - 1); ++cell) {
      const double w = cell == j ? w_first : 1.0 - w_first;
      if (w > 0.0) operator_rows.col(i) -= w_trend.col(cell) * (w / cell_weight(cell));
    }
  }
}

Complex PointEstimator::Amplitude(int column, int h) const {
  const Eigen::Index c = trend + 2 * (h - 1);
  return Complex(coefficients(c, column), -coefficients(c + 1, column));
}

// The points at the harmonics the input excites, each with its uncertainty (header).
std::vector<FrequencyPoint> PointEstimator::Points() const {
  const double u_max_V = signals.col(0).maxCoeff(), u_min_V = signals.col(0).minCoeff();
  const double u_range_V = u_max_V - u_min_V;
  if (!(u_range_V > 1e-12 * std::max({1.0, std::abs(u_max_V), std::abs(u_min_V)})))
    throw InputError("input is constant over the analysis window: no component at " +
                     Format(fundamental_Hz) + " Hz");
  const double u1 = std::abs(Amplitude(0, 1));
  if (!(u1 > kMinHarmonicRatio * u_range_V))
    throw InputError("input has no component at " + Format(fundamental_Hz) + " Hz (amplitude " +
                     Format(u1) + " V of a " + Format(u_range_V) + " V range)");

  const double bin_rad = 2.0 * kPi / static_cast<double>(length);  // delta * dt
  std::vector<FrequencyPoint> points;
  for (int h = 1; h <= harmonics; ++h) {
    const Complex u_h = Amplitude(0, h), y_h = Amplitude(1, h);
    if (std::abs(u_h) < kMinHarmonicRatio * u1) continue;
    const Complex g_sampled = y_h / u_h;
    const double omega_rad_s = h * omega0_rad_s;
    const double omega_dt = omega_rad_s * dt_s;

    // Noise near the line from the bins between the harmonic lines (header).
    double noise_power = 0.0;
    int bins = 0;
    const int max_offset = std::min(2 * periods - 1, kMaxNoiseBinOffset);
    for (int offset = -max_offset; offset <= max_offset; ++offset) {
      if (offset % periods == 0) continue;
      const int bin = h * periods + offset;
      // Bins 0..degree hold the trend's degrees of freedom; past Nyquist is nothing.
      if (bin <= degree || bin >= length / 2) continue;
      const auto [r_u, r_y] = Dtft(residuals, bin * bin_rad);
      noise_power += std::norm(r_y - g_sampled * r_u);
      ++bins;
    }

    const double sigma2 = bins > 0 ? noise_power / bins / static_cast<double>(length) : 0.0;
    const Eigen::Index c = trend + 2 * (h - 1);
    const double var_y =
        sigma2 * (operator_rows.row(c).squaredNorm() + operator_rows.row(c + 1).squaredNorm());

    // Zero-order-hold correction (header): G(j w) = G_d j w dt / (1 - e^{-j w dt}).
    const Complex zoh = Complex(0.0, omega_dt) / (1.0 - std::polar(1.0, -omega_dt));
    const Complex g = g_sampled * zoh;
    const double var_g = var_y / std::norm(u_h) * std::norm(zoh);

    FrequencyPoint point;
    point.frequency_Hz = h * fundamental_Hz;
    point.omega_rad_s = omega_rad_s;
    point.response = g;
    point.periods = periods;
    point.harmonic = h;
    point.std_dev = std::sqrt(0.5 * var_g);
    const double nu = std::max(2.0 * bins, 4.0);
    const double q = StudentT975(nu);
    const double disc = std::sqrt(2.0 * F2Quantile95(nu)) * point.std_dev;
    if (disc >= std::abs(g)) {  // the 95 % disc holds 0: phase not resolved
      point.gain_half_width_95 = disc;
      point.phase_half_width_95_rad = kPi;
    } else {
      point.gain_half_width_95 = q * point.std_dev;
      point.phase_half_width_95_rad = std::min(kPi, q * point.std_dev / std::abs(g));
    }
    points.push_back(point);
  }
  return points;
}

}  // namespace
}  // namespace frequency_fit

using namespace frequency_fit;  // NOLINT(google-build-using-namespace): the route's own parts

bool SquareWaveOptions::IsValid(std::string* error) const {
  if (max_harmonic < 1) {
    if (error) *error = "max_harmonic must be >= 1";
    return false;
  }
  if (discard_periods < 0) {
    if (error) *error = "discard_periods must be >= 0";
    return false;
  }
  if (!std::isfinite(min_discard_s) || min_discard_s < 0.0) {
    if (error) *error = "min_discard_s must be finite and >= 0";
    return false;
  }
  return true;
}

// -----------------------------------------------------------------------------------------
// Fundamental
// -----------------------------------------------------------------------------------------

double DetectFundamental_Hz(const DataSegment& segment) {
  CheckSegment(segment);
  const std::vector<double>& u = segment.voltage_V;
  const double dt_s = segment.dt_s;
  std::vector<double> sorted = u;
  auto quantile = [&sorted](double q) {
    const size_t index = static_cast<size_t>(q * static_cast<double>(sorted.size() - 1));
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(index),
                     sorted.end());
    return sorted[index];
  };
  const double low_V = quantile(0.02), high_V = quantile(0.98);
  const double range_V = high_V - low_V;
  if (!(range_V > 1e-12 * std::max(1.0, std::abs(high_V))))
    throw InputError("input is not periodic: the voltage is constant at " + Format(high_V) + " V");
  const double mid_V = 0.5 * (low_V + high_V), hysteresis_V = 0.1 * range_V;

  // Schmitt trigger: the state flips when the voltage passes mid +- hysteresis; the
  // crossing time is where the signal last passed the mid level (linear interpolation).
  std::vector<double> rising_s, falling_s;
  int state = 0;  // 0 unknown, +1 high, -1 low
  for (size_t k = 0; k < u.size(); ++k) {
    const int next = u[k] > mid_V + hysteresis_V ? 1 : (u[k] < mid_V - hysteresis_V ? -1 : state);
    if (next != state && state != 0) {
      size_t j = k;  // first sample of the final run on the new side of mid
      while (j > 0 && (next > 0 ? u[j - 1] > mid_V : u[j - 1] < mid_V)) --j;
      double t_s = static_cast<double>(j) * dt_s;
      if (j > 0) {
        const double fraction = (mid_V - u[j - 1]) / (u[j] - u[j - 1]);
        t_s = (static_cast<double>(j - 1) + fraction) * dt_s;
      }
      (next > 0 ? rising_s : falling_s).push_back(t_s);
    }
    state = next;
  }
  if (rising_s.size() < 3)
    throw InputError("input is not periodic: it crosses its mid level " + Format(mid_V) +
                     " V upwards " + std::to_string(rising_s.size()) +
                     " times, two periods need three");
  const double rough_period_s =
      (rising_s.back() - rising_s.front()) / static_cast<double>(rising_s.size() - 1);
  const double tolerance_s = std::max(0.05 * rough_period_s, 1.5 * dt_s);
  for (const std::vector<double>* crossings : {&rising_s, &falling_s}) {
    for (size_t i = 1; i < crossings->size(); ++i) {
      const double interval_s = (*crossings)[i] - (*crossings)[i - 1];
      if (std::abs(interval_s - rough_period_s) > tolerance_s)
        throw InputError(
            "input is not periodic: " + std::string(crossings == &rising_s ? "rising" : "falling") +
            " crossings of the mid level " + Format(mid_V) + " V are " + Format(interval_s) +
            " s apart at t = " + Format((*crossings)[i]) + " s, the mean period is " +
            Format(rough_period_s) + " s");
    }
  }
  // Least squares over both edge types: t = t_edge + P c with one intercept per type and
  // a common period P (c = cycle index). Edge jitter of up to dt averages out.
  double sxy = 0.0, sxx = 0.0;
  for (const std::vector<double>* crossings : {&rising_s, &falling_s}) {
    if (crossings->size() < 2) continue;
    const double count = static_cast<double>(crossings->size());
    const double mean_c = 0.5 * (count - 1.0);
    double mean_t = 0.0;
    for (double t : *crossings) mean_t += t / count;
    for (size_t i = 0; i < crossings->size(); ++i) {
      const double c = std::round(((*crossings)[i] - crossings->front()) / rough_period_s);
      sxy += (c - mean_c) * ((*crossings)[i] - mean_t);
      sxx += (c - mean_c) * (c - mean_c);
    }
  }
  return sxx / sxy;
}

// -----------------------------------------------------------------------------------------
// Frequency response points
// -----------------------------------------------------------------------------------------

std::vector<FrequencyPoint> EstimateFrequencyResponse(const DataSegment& segment,
                                                      double fundamental_Hz, int max_harmonic,
                                                      int discard_periods) {
  PointEstimator estimator(segment, fundamental_Hz, max_harmonic, discard_periods);
  estimator.Window();
  estimator.Detrend();
  estimator.Harmonics();
  estimator.NoiseOperator();
  return estimator.Points();
}

}  // namespace flexid::model
