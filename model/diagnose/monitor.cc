#include "model/diagnose/monitor.h"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <numbers>
#include <stdexcept>
#include <utility>

namespace flexid::model {
namespace {

constexpr double kBlockMax_s = 60.0;               // noise-statistics block length (header)
constexpr size_t kBlockMaxSamples = 10000;         // ... and sample count (bounded memory)
constexpr size_t kMinBlockSamples = 20;            // shorter blocks are dropped
constexpr size_t kMinWindowSamples = 10;           // the line test needs at least this many
constexpr size_t kMaxWarmUpSamples = 200000;       // sigma from at most this many values
constexpr double kMaxRho = 0.98;                   // kappa <= 99
constexpr double kResidualClear_s = 5.0;           // detector 3 latch release time
constexpr double kCriticalRatio = 5.0;             // critical when |magnitude| > 5 threshold
constexpr double kMadToSigma = 1.482602218505602;  // 1 / Phi^-1(3/4)
constexpr double kOrnsteinUhlenbeckRate = 1.5;     // lambda of exp(-lambda |d tau|)
constexpr double kRhoRecompute = 0.01;             // detector 3 cache tolerances
constexpr double kRateRecompute = 0.05;
// 1 / (2 x 0.3675): the MAD's asymptotic efficiency at the normal is 36.75 %, so
// Var(ln sigma_hat) = 1.3605 / n for n independent values.
constexpr double kMadLogVariance = 1.3605;
// The warm-up goes on until sd(ln sigma_hat) <= kMaxLogSd (the correction for it converges
// there), but no longer than kMaxWarmUpFactor * noise_estimation_s.
constexpr double kMaxLogSd = 0.08;
constexpr double kMaxWarmUpFactor = 10.0;
// ... or until sigma_hat is below the floor by this many sd(ln sigma_hat).
constexpr double kFloorMargin = 3.0;

double Seconds(int64_t microseconds) { return static_cast<double>(microseconds) * 1e-6; }
int64_t Microseconds(double seconds) { return std::llround(seconds * 1e6); }

double NormalDensity(double x) {
  return std::exp(-0.5 * x * x) / std::sqrt(2.0 * std::numbers::pi);
}
double NormalCdf(double x) { return 0.5 * std::erfc(-x / std::numbers::sqrt2); }
double NormalTail(double x) { return 0.5 * std::erfc(x / std::numbers::sqrt2); }  // Psi

__attribute__((format(printf, 1, 2))) std::string Printf(const char* format, ...) {
  char buffer[512];
  va_list args;
  va_start(args, format);
  const int size = std::vsnprintf(buffer, sizeof buffer, format, args);
  va_end(args);
  if (size < 0) return {};
  return std::string(buffer, std::min(static_cast<size_t>(size), sizeof buffer - 1));
}

// R(z) of the header: worst-case false alarms per hour of the line test over hold lengths.
double LineTestRate(double z, double min_window_s, double settle_s, int sides) {
  const double start = NormalTail(z);
  const double crossings = kOrnsteinUhlenbeckRate * z * NormalDensity(z);
  double worst = 0.0;
  // Windows w = w0 e^{l}, l = ln(w / w0) from 0 to 20 in steps of 0.005: p(w)/(w + settle)
  // has one maximum (its derivative changes sign once), which this grid resolves to 0.5 %.
  constexpr double kStep = 0.005;
  const double growth = std::exp(kStep);
  double w = min_window_s;
  for (int j = 0; j <= 4000; ++j, w *= growth)
    worst = std::max(worst, sides * (start + crossings * kStep * j) / (w + settle_s));
  return 3600.0 * worst;
}

// Multiplier x for a detector whose false-alarm rate falls as x^{-beta} near x, when the
// scale it multiplies is estimated with ln(sigma_hat / sigma) ~ N(0, s^2): the rate averaged
// over the estimate is rate(x) exp(beta^2 s^2 / 2), so x solves rate(x) = target
// exp(-beta^2 s^2 / 2). beta depends on x: three fixed-point steps, which converge for
// s <= kMaxLogSd and end within 0.2 % of the fixed point there (beyond s ~ 0.12 the steps
// diverge: the expected rate is then ruled by the estimate's lower tail).
template <typename SolveFn, typename BetaFn>
double PredictiveMultiplier(double target, double log_sd, SolveFn solve, BetaFn beta) {
  double x = solve(target);
  if (log_sd <= 0.0) return x;
  for (int i = 0; i < 3; ++i) {
    const double b = beta(x);
    x = solve(target * std::exp(-0.5 * b * b * log_sd * log_sd));
  }
  return x;
}

double Median(std::vector<double>* values) {
  const size_t middle = values->size() / 2;
  std::nth_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(middle),
                   values->end());
  double median = (*values)[middle];
  if (values->size() % 2 == 0) {
    const double below =
        *std::max_element(values->begin(), values->begin() + static_cast<std::ptrdiff_t>(middle));
    median = 0.5 * (median + below);
  }
  return median;
}

// 1.4826 median |x - median(x)|.
double RobustScale(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const double median = Median(&values);
  for (double& v : values) v = std::abs(v - median);
  return kMadToSigma * Median(&values);
}

}  // namespace

bool MonitorOptions::IsValid(std::string* error) const {
  auto fail = [error](const std::string& message) {
    if (error) *error = message;
    return false;
  };
  auto finite = [](double x) { return std::isfinite(x); };
  if (!finite(false_alarms_per_hour) || false_alarms_per_hour <= 0.0 ||
      false_alarms_per_hour > 10.0)
    return fail("false_alarms_per_hour must be in (0, 10]");
  if (!finite(noise_mm) || noise_mm < 0.0) return fail("noise_mm must be finite and >= 0");
  if (!finite(min_hold_s) || min_hold_s <= 0.0) return fail("min_hold_s must be finite and > 0");
  if (!finite(settle_s) || settle_s < 0.0) return fail("settle_s must be finite and >= 0");
  if (!finite(min_effect_mm) || min_effect_mm < 0.0)
    return fail("min_effect_mm must be finite and >= 0");
  if (!finite(dropout_s) || dropout_s <= 0.0) return fail("dropout_s must be finite and > 0");
  if (!finite(rest_band_V) || rest_band_V < 0.0) return fail("rest_band_V must be finite and >= 0");
  if (!finite(noise_estimation_s) || noise_estimation_s <= 0.0)
    return fail("noise_estimation_s must be finite and > 0");
  if (!finite(sigma_floor_mm) || sigma_floor_mm <= 0.0)
    return fail("sigma_floor_mm must be finite and > 0");
  return true;
}

double LineTestMultiplier(double false_alarms_per_hour, double min_window_s, double settle_s,
                          int sides) {
  if (!(false_alarms_per_hour > 0.0) || !(min_window_s > 0.0) || !(settle_s >= 0.0) ||
      (sides != 1 && sides != 2))
    throw std::invalid_argument(
        "LineTestMultiplier: need rate > 0, min_window_s > 0, settle_s >= 0, sides 1 or 2");
  // R(z) decreases for z >= 1 (z phi(z) and Psi(z) both do); bisection on [1, 40] to 1e-10.
  double low = 1.0, high = 40.0;
  if (LineTestRate(low, min_window_s, settle_s, sides) <= false_alarms_per_hour) return low;
  for (int i = 0; i < 40; ++i) {
    const double mid = 0.5 * (low + high);
    if (LineTestRate(mid, min_window_s, settle_s, sides) > false_alarms_per_hour)
      low = mid;
    else
      high = mid;
  }
  return 0.5 * (low + high);
}

double RunStartProbability(double c, double rho, int k) {
  if (!(rho >= 0.0 && rho <= 0.99) || k < 1 || !std::isfinite(c))
    throw std::invalid_argument("RunStartProbability: need 0 <= rho <= 0.99, k >= 1, finite c");
  if (rho < 1e-9) return NormalCdf(c) * std::pow(NormalTail(c), k);
  const double s = std::sqrt(1.0 - rho * rho);
  // Grid x_i = c + i h on [c, c + 8]: the densities below are bounded by phi(x), so the
  // truncated mass is below phi(c + 8) / phi(c) < 1e-14 relative. h <= s / 6 resolves the
  // transition kernel. Simpson's rule: the integrands do not vanish at x = c, where the
  // trapezoid rule's O(h^2 c^2) end error would reach 1e-3 relative per integration.
  const int intervals = 2 * static_cast<int>(std::ceil(4.0 / std::min(0.1, s / 6.0)));
  const double h = 8.0 / intervals;
  const int n = intervals + 1;
  std::vector<double> weight(static_cast<size_t>(n)), f(static_cast<size_t>(n));
  for (int i = 0; i < n; ++i)
    weight[static_cast<size_t>(i)] = h / 3.0 * (i == 0 || i == n - 1 ? 1.0 : (i % 2 ? 4.0 : 2.0));
  for (int i = 0; i < n; ++i) {
    const double x = c + h * i;
    f[static_cast<size_t>(i)] = NormalDensity(x) * NormalCdf((c - rho * x) / s);
  }
  std::vector<double> next(static_cast<size_t>(n));
  const double band = 8.0 * s;  // the kernel is negligible beyond 8 standard deviations
  for (int step = 1; step < k; ++step) {
    std::fill(next.begin(), next.end(), 0.0);
    for (int i = 0; i < n; ++i) {
      const double mass = weight[static_cast<size_t>(i)] * f[static_cast<size_t>(i)];
      if (mass == 0.0) continue;
      const double centre = rho * (c + h * i);
      const int first = std::max(0, static_cast<int>(std::floor((centre - band - c) / h)));
      const int last = std::min(n - 1, static_cast<int>(std::ceil((centre + band - c) / h)));
      for (int j = first; j <= last; ++j)
        next[static_cast<size_t>(j)] += mass * NormalDensity((c + h * j - centre) / s) / s;
    }
    std::swap(f, next);
  }
  double q = 0.0;
  for (int i = 0; i < n; ++i) q += weight[static_cast<size_t>(i)] * f[static_cast<size_t>(i)];
  return q;
}

double RunTestMultiplier(double false_alarms_per_hour, double samples_per_hour, double rho, int k) {
  if (!(false_alarms_per_hour > 0.0) || !(samples_per_hour > 0.0))
    throw std::invalid_argument("RunTestMultiplier: need positive rates");
  // g(c) = ln(rate / target) decreases in c for c >= 0 (fewer and shorter excursions) and
  // is smooth (close to -c^2/2 plus a slowly varying term): bracket the root between
  // neighbouring integers from c = 3, then regula falsi with the Illinois modification,
  // to 1e-6 in c or 1e-9 in g; about 8 evaluations of q in all.
  auto g = [&](double c) {
    const double q = std::max(RunStartProbability(c, rho, k), 1e-300);
    return std::log(2.0 * samples_per_hour * q / false_alarms_per_hour);
  };
  double a = 3.0, ga = g(a);
  double b = ga > 0.0 ? 4.0 : 2.0, gb = g(b);
  while ((ga > 0.0) == (gb > 0.0)) {
    if (b <= 0.0) return 0.0;
    if (b >= 12.0) return 12.0;
    a = b;
    ga = gb;
    b += ga > 0.0 ? 1.0 : -1.0;
    gb = g(b);
  }
  if (a > b) {
    std::swap(a, b);
    std::swap(ga, gb);
  }
  int side = 0;
  for (int i = 0; i < 60 && b - a > 1e-6; ++i) {
    const double c = (a * gb - b * ga) / (gb - ga);
    const double gc = g(c);
    if (std::abs(gc) < 1e-9) return c;
    if (gc > 0.0) {
      a = c;
      ga = gc;
      if (side == 1) gb *= 0.5;
      side = 1;
    } else {
      b = c;
      gb = gc;
      if (side == -1) ga *= 0.5;
      side = -1;
    }
  }
  return 0.5 * (a + b);
}

void ResidualMonitor::LineFit::Add(int64_t utime, double e_mm) {
  if (n == 0) first_utime = utime;
  last_utime = utime;
  ++n;
  const double t = Seconds(utime - first_utime);
  const double dt = t - mean_t_s;
  mean_t_s += dt / static_cast<double>(n);
  mean_e_mm += (e_mm - mean_e_mm) / static_cast<double>(n);
  s_tt += dt * (t - mean_t_s);
  s_te += dt * (e_mm - mean_e_mm);
}

double ResidualMonitor::LineFit::Span_s() const {
  return n == 0 ? 0.0 : Seconds(last_utime - first_utime);
}

double ResidualMonitor::LineFit::Change_mm() const {
  return s_tt > 0.0 ? s_te / s_tt * Span_s() : 0.0;
}

double ResidualMonitor::LineFit::FittedAtStart_mm() const {
  return s_tt > 0.0 ? mean_e_mm - s_te / s_tt * mean_t_s : mean_e_mm;
}

double ResidualMonitor::LineFit::VarianceFactor() const {
  const double span = Span_s();
  return s_tt > 0.0 ? span * span / s_tt : INFINITY;
}

ResidualMonitor::ResidualMonitor(std::string actuator_id, MonitorOptions options)
    : actuator_id_(std::move(actuator_id)), options_(options) {
  std::string why;
  if (!options_.IsValid(&why)) throw std::invalid_argument("residual monitor options: " + why);
  z_back_relaxation_ =
      LineTestMultiplier(options_.false_alarms_per_hour, options_.min_hold_s, options_.settle_s, 1);
  z_drift_ =
      LineTestMultiplier(options_.false_alarms_per_hour, options_.min_hold_s, options_.settle_s, 2);
}

double ResidualMonitor::noise_mm() const {
  if (options_.noise_mm > 0.0) return Floored(options_.noise_mm);
  return calibrated_ ? sigma_mm_ : 0.0;
}

double ResidualMonitor::Floored(double sigma_mm) const {
  // The floor first: std::max returns its first argument when the other is NaN.
  return std::max(options_.sigma_floor_mm, sigma_mm);
}

double ResidualMonitor::lag1_autocorrelation() const { return calibrated_ ? rho_ : 0.0; }

Alert ResidualMonitor::Make(std::string kind, int64_t start_utime, int64_t end_utime,
                            double magnitude_mm, double threshold_mm, std::string text) const {
  Alert alert;
  alert.kind = std::move(kind);
  alert.severity =
      threshold_mm > 0.0 && std::abs(magnitude_mm) > kCriticalRatio * threshold_mm ? 2 : 1;
  alert.start_utime = start_utime;
  alert.end_utime = end_utime;
  alert.magnitude_mm = magnitude_mm;
  alert.threshold_mm = threshold_mm;
  alert.text = actuator_id_ + ": " + std::move(text);
  return alert;
}

void ResidualMonitor::RestartStatistics() {
  block_.clear();
  warmup_detrended_mm_.clear();
  warmup_started_ = false;
  warmup_first_utime_ = 0;
  warmup_duration_s_ = 0;
  warmup_samples_ = warmup_blocks_ = 0;
  sigma_log_sd_ = 0;
  warmup_below_floor_ = false;
  sum_uu_ = sum_uu1_ = samples_ = blocks_ = pairs_span_s_ = pairs_ = 0;
  calibrated_ = false;
  sigma_mm_ = rho_ = 0;
  run_c_ = 0;
  run_c_rho_ = -1;
  run_c_rate_ = 0;
  line_ = {};
  line_latched_ = false;
  hold_back_relaxation_ = previous_hold_back_relaxation_ = false;
  run_sign_ = run_count_ = 0;
  run_sum_mm_ = 0;
  residual_latched_ = within_ = false;
}

void ResidualMonitor::Reset() {
  RestartStatistics();
  if (have_message_)
    settle_until_utime_ =
        std::max(settle_until_utime_, last_utime_ + Microseconds(options_.settle_s));
}

void ResidualMonitor::TrackVoltage(int64_t utime, double voltage_V) {
  if (have_hold_ && std::abs(voltage_V - hold_voltage_V_) <= options_.rest_band_V) return;
  previous_hold_voltage_V_ = have_hold_ ? hold_voltage_V_ : 0.0;
  previous_hold_back_relaxation_ = hold_back_relaxation_;
  hold_back_relaxation_ = false;
  have_hold_ = true;
  hold_start_utime_ = utime;
  hold_voltage_V_ = voltage_V;
  settle_until_utime_ = std::max(settle_until_utime_, utime + Microseconds(options_.settle_s));
  CloseBlock();
  line_ = {};
  line_latched_ = false;
  run_sign_ = run_count_ = 0;
}

void ResidualMonitor::CloseBlock() {
  const size_t n = block_.size();
  if (n >= kMinBlockSamples) {
    // Least-squares line through the block; u = e - line.
    const int64_t origin = block_.front().utime;
    double mean_t = 0, mean_e = 0;
    for (const Sample& s : block_) {
      mean_t += Seconds(s.utime - origin);
      mean_e += s.e_mm;
    }
    mean_t /= static_cast<double>(n);
    mean_e /= static_cast<double>(n);
    double s_tt = 0, s_te = 0;
    for (const Sample& s : block_) {
      const double dt = Seconds(s.utime - origin) - mean_t;
      s_tt += dt * dt;
      s_te += dt * (s.e_mm - mean_e);
    }
    const double slope = s_te / s_tt;
    std::vector<double> u(n);
    for (size_t i = 0; i < n; ++i)
      u[i] = block_[i].e_mm - mean_e - slope * (Seconds(block_[i].utime - origin) - mean_t);
    // Winsorise at 5 robust standard deviations of the block: a spike must not pull rho
    // towards 0 (which would shrink kappa); Gaussian values are untouched (P = 6e-7).
    const double clip = 5.0 * RobustScale(u);
    if (clip > 0.0)
      for (double& v : u) v = std::clamp(v, -clip, clip);
    double uu = 0, uu1 = 0;
    for (size_t i = 0; i < n; ++i) {
      uu += u[i] * u[i];
      if (i > 0) uu1 += u[i] * u[i - 1];
    }
    const double span = Seconds(block_.back().utime - origin);
    sum_uu_ += uu;
    sum_uu1_ += uu1;
    samples_ += static_cast<double>(n);
    blocks_ += 1;
    pairs_ += static_cast<double>(n - 1);
    pairs_span_s_ += span;
    if (!calibrated_) {
      if (!warmup_started_) {
        warmup_started_ = true;
        warmup_first_utime_ = origin;
      }
      warmup_duration_s_ += span;
      warmup_samples_ += static_cast<double>(n);
      warmup_blocks_ += 1;
      for (double v : u)
        if (warmup_detrended_mm_.size() < kMaxWarmUpSamples) warmup_detrended_mm_.push_back(v);
      if (options_.noise_mm <= 0.0 && warmup_duration_s_ >= options_.noise_estimation_s) {
        // A warm-up that goes on for sigma_hat's sake may stop once the floor will be used
        // anyway (a noise-free model's smooth residual would otherwise keep the detectors
        // off for 10 noise_estimation_s).
        UpdateRho();
        warmup_below_floor_ =
            SigmaEstimate() * std::exp(kFloorMargin * SigmaLogSd()) < options_.sigma_floor_mm;
      }
    } else {
      UpdateRho();
      UpdateRunThreshold();
    }
  }
  block_.clear();
}

void ResidualMonitor::UpdateRho() {
  if (!(sum_uu_ > 0.0) || samples_ <= 0.0) {
    rho_ = 0.0;
    return;
  }
  const double r = sum_uu1_ / sum_uu_;
  const double f = blocks_ / samples_;  // <= 1 / kMinBlockSamples
  rho_ = std::clamp((r + 2.0 * f) / (1.0 - 3.0 * f), 0.0, kMaxRho);
}

void ResidualMonitor::UpdateRunThreshold() {
  if (!(pairs_span_s_ > 0.0)) return;
  const double rate = 3600.0 * pairs_ / pairs_span_s_;
  if (run_c_rho_ >= 0.0 && std::abs(rho_ - run_c_rho_) <= kRhoRecompute &&
      std::abs(std::log(rate / run_c_rate_)) <= kRateRecompute)
    return;
  const double rho = rho_;
  run_c_ = PredictiveMultiplier(
      options_.false_alarms_per_hour, sigma_log_sd_,
      [&](double target) { return RunTestMultiplier(target, rate, rho, kResidualRunSamples); },
      [&](double c) {  // -d ln q / d ln c, by a 1 % step
        return -std::log(RunStartProbability(1.01 * c, rho, kResidualRunSamples) /
                         RunStartProbability(c, rho, kResidualRunSamples)) /
               std::log(1.01);
      });
  run_c_rho_ = rho_;
  run_c_rate_ = rate;
}

double ResidualMonitor::SigmaLogSd() const {
  // The MAD's variance with the effective size of a scale estimate under AR(1),
  // N (1 - rho^2) / (1 + rho^2). Conservative for large rho: measured 0.056 against 0.072
  // from this at rho = 0.8, N = 1200 (400 runs), since detrending removes the slow wander
  // that makes a scale estimate vary.
  const double n = static_cast<double>(warmup_detrended_mm_.size());
  if (n <= 0.0) return INFINITY;
  return std::sqrt(kMadLogVariance * (1 + rho_ * rho_) / ((1 - rho_ * rho_) * n));
}

double ResidualMonitor::SigmaEstimate() const {
  if (warmup_detrended_mm_.empty()) return NAN;
  // Removing a line from a block of n AR(1) samples removes about 2 kappa sigma^2 of
  // their sum of squares (the mean and slope each take the variance of n / kappa
  // independent samples), so the detrended scale is low by sqrt(1 - 2 kappa B / N).
  const double kappa = (1.0 + rho_) / (1.0 - rho_);
  const double kept = std::max(0.5, 1.0 - 2.0 * kappa * warmup_blocks_ / warmup_samples_);
  const double sigma_mm = RobustScale(warmup_detrended_mm_) / std::sqrt(kept);
  if (sigma_mm > 0.0) return sigma_mm;
  // A quantised residual (most values the same: MAD 0): the RMS, then the floor.
  double sum = 0;
  for (double v : warmup_detrended_mm_) sum += v * v;
  return std::sqrt(sum / static_cast<double>(warmup_detrended_mm_.size()));
}

bool ResidualMonitor::WarmUpSufficient() {
  if (options_.noise_mm > 0.0 || warmup_below_floor_) return true;
  UpdateRho();
  return SigmaLogSd() <= kMaxLogSd ||
         warmup_duration_s_ >= kMaxWarmUpFactor * options_.noise_estimation_s;
}

void ResidualMonitor::FinishWarmUp(int64_t utime, std::vector<Alert>* alerts) {
  const bool estimate = options_.noise_mm <= 0.0;
  double estimate_mm = 0.0;  // the residual's own scale, before the floor
  bool floored = false;      // ... below it: sigma is the floor
  UpdateRho();
  if (estimate) {
    estimate_mm = SigmaEstimate();
    floored = !(estimate_mm >= options_.sigma_floor_mm);
    sigma_mm_ = Floored(estimate_mm);
    // Its uncertainty, capped where the correction stops converging (only when the warm-up
    // ran out of time; the info alert says so); none when the floor is used instead.
    sigma_log_sd_ = floored ? 0.0 : std::min(SigmaLogSd(), kMaxLogSd);
    auto line = [&](int sides) {
      return PredictiveMultiplier(
          options_.false_alarms_per_hour, sigma_log_sd_,
          [&](double target) {
            return LineTestMultiplier(target, options_.min_hold_s, options_.settle_s, sides);
          },
          [](double z) { return z * z - 1.0; });  // R ~ z phi(z): -d ln R / d ln z
    };
    z_back_relaxation_ = line(1);
    z_drift_ = line(2);
  } else {
    sigma_mm_ = Floored(options_.noise_mm);
  }
  calibrated_ = true;
  UpdateRunThreshold();
  if (estimate) {
    const double log_sd = SigmaLogSd();
    const std::string scale =
        floored ? Printf(
                      "the floor sigma_floor_mm: the detrended residual's own scale, %.2g mm, "
                      "is below it",
                      estimate_mm)
                : Printf("robust scale of the detrended residual, +-%.0f %%", 100 * log_sd);
    Alert alert = Make(
        "noise_estimate", warmup_first_utime_, utime, sigma_mm_, 0.0,
        Printf(
            "residual noise estimated from the first %.0f s of residual: sigma %.4f mm "
            "(%s), lag-1 autocorrelation %.2f; detectors active (false-alarm target %.3g "
            "per hour per kind%s)",
            warmup_duration_s_, sigma_mm_, scale.c_str(), rho_, options_.false_alarms_per_hour,
            !floored && log_sd > kMaxLogSd ? "; sigma too uncertain: the rate may exceed it" : ""));
    alert.severity = 0;
    alerts->push_back(std::move(alert));
  }
  warmup_detrended_mm_.clear();
  warmup_detrended_mm_.shrink_to_fit();
}

void ResidualMonitor::CheckLine(int64_t utime, std::vector<Alert>* alerts) {
  if (line_latched_ || line_.n < kMinWindowSamples || line_.Span_s() < options_.min_hold_s) return;
  const double kappa = (1.0 + rho_) / (1.0 - rho_);
  const double sd_mm = sigma_mm_ * std::sqrt(kappa * line_.VarianceFactor());
  const bool rest = std::abs(hold_voltage_V_) <= options_.rest_band_V;
  const double z = rest ? z_drift_ : z_back_relaxation_;
  const double threshold_mm = std::max(z * sd_mm, options_.min_effect_mm);
  const double change_mm = line_.Change_mm();
  if (!(std::abs(change_mm) > threshold_mm)) return;
  const double window_s = line_.Span_s();
  // Recovery after a hold: the gel overshot past rest (residual opposite to the previous
  // voltage at the window's start) and returns towards 0 (change with the previous
  // voltage's sign, smaller than twice the starting offset): back-relaxation, not drift.
  const double start_mm = line_.FittedAtStart_mm();
  const double previous_V = previous_hold_voltage_V_;
  const bool recovering = rest && std::abs(previous_V) > options_.rest_band_V &&
                          change_mm * previous_V > 0.0 && start_mm * previous_V < 0.0 &&
                          std::abs(start_mm) > 0.5 * std::abs(change_mm);
  if (recovering) {
    line_latched_ = true;
    if (previous_hold_back_relaxation_) return;  // that hold's alert covers it
    alerts->push_back(
        Make("back_relaxation", line_.first_utime, utime, change_mm, threshold_mm,
             Printf("after the hold at %+.2f V the measured deflection overshot past rest "
                    "(residual %+.3f mm after settling) and returned %.3f mm towards 0 over %.1f s "
                    "with no voltage applied (threshold %.3f mm): back-relaxation",
                    previous_V, start_mm, std::abs(change_mm), window_s, threshold_mm)));
  } else if (rest) {
    line_latched_ = true;
    alerts->push_back(Make("drift", line_.first_utime, utime, change_mm, threshold_mm,
                           Printf("slow drift of %+.3f mm over %.1f s with no voltage applied "
                                  "(threshold %.3f mm): sensor or baseline drift",
                                  change_mm, window_s, threshold_mm)));
  } else if (change_mm * hold_voltage_V_ < 0.0) {
    line_latched_ = hold_back_relaxation_ = true;
    alerts->push_back(Make(
        "back_relaxation", line_.first_utime, utime, change_mm, threshold_mm,
        Printf("during the hold at %+.2f V (%.1f s so far), over the %.1f s after settling the "
               "measured deflection fell back %.3f mm towards 0 relative to the model "
               "(threshold %.3f mm): back-relaxation",
               hold_voltage_V_, Seconds(utime - hold_start_utime_), window_s, std::abs(change_mm),
               threshold_mm)));
  }
}

void ResidualMonitor::CheckResidual(int64_t utime, double e_mm, std::vector<Alert>* alerts) {
  const double threshold_mm = std::max(run_c_ * sigma_mm_, options_.min_effect_mm);
  if (residual_latched_) {
    if (std::abs(e_mm) <= std::min(2.0 * sigma_mm_, threshold_mm)) {
      if (!within_) {
        within_ = true;
        within_since_utime_ = utime;
      } else if (Seconds(utime - within_since_utime_) >= kResidualClear_s) {
        residual_latched_ = within_ = false;
        run_sign_ = run_count_ = 0;
      }
    } else {
      within_ = false;
    }
    return;
  }
  const int sign = e_mm > threshold_mm ? 1 : (e_mm < -threshold_mm ? -1 : 0);
  if (sign == 0) {
    run_sign_ = run_count_ = 0;
    return;
  }
  if (sign != run_sign_ || run_count_ == 0) {
    run_sign_ = sign;
    run_count_ = 0;
    run_sum_mm_ = 0;
    run_start_utime_ = utime;
  }
  ++run_count_;
  run_sum_mm_ += e_mm;
  if (run_count_ < kResidualRunSamples) return;
  residual_latched_ = true;
  within_ = false;
  const double mean_mm = run_sum_mm_ / run_count_;
  alerts->push_back(
      Make("residual", run_start_utime_, utime, mean_mm, threshold_mm,
           Printf("residual %+.3f mm (mean of %d consecutive samples over %.2f s) beyond %.3f mm "
                  "(%.2f sigma, sigma %.4f mm): the model does not explain the measurement",
                  mean_mm, run_count_, Seconds(utime - run_start_utime_), threshold_mm,
                  threshold_mm / sigma_mm_, sigma_mm_)));
}

std::vector<Alert> ResidualMonitor::OnDeflection(int64_t utime, double voltage_V,
                                                 double residual_mm) {
  std::vector<Alert> alerts;
  if (have_deflection_ && utime <= last_deflection_utime_) return alerts;
  have_deflection_ = true;
  last_deflection_utime_ = utime;
  quiet_since_utime_ = std::max(quiet_since_utime_, utime);
  in_dropout_ = false;
  last_utime_ = have_message_ ? std::max(last_utime_, utime) : utime;
  have_message_ = true;
  if (std::isfinite(voltage_V)) TrackVoltage(utime, voltage_V);
  if (!std::isfinite(residual_mm)) {  // no model: a gap in the statistics
    CloseBlock();
    run_sign_ = run_count_ = 0;
    return alerts;
  }
  if (!have_hold_ || utime < settle_until_utime_) return alerts;

  if (!block_.empty() &&
      (utime - block_.back().utime > Microseconds(options_.dropout_s) ||
       Seconds(utime - block_.front().utime) > kBlockMax_s || block_.size() >= kBlockMaxSamples))
    CloseBlock();
  block_.push_back({utime, residual_mm});
  if (!calibrated_) {
    // The first noise_estimation_s are complete with this sample: close the block now.
    if (block_.size() >= kMinBlockSamples && warmup_duration_s_ < options_.noise_estimation_s &&
        warmup_duration_s_ + Seconds(utime - block_.front().utime) >= options_.noise_estimation_s)
      CloseBlock();
    if (warmup_duration_s_ >= options_.noise_estimation_s && WarmUpSufficient())
      FinishWarmUp(utime, &alerts);
  }
  line_.Add(utime, residual_mm);
  if (!calibrated_) return alerts;
  CheckResidual(utime, residual_mm, &alerts);
  CheckLine(utime, &alerts);
  return alerts;
}

std::vector<Alert> ResidualMonitor::OnVoltage(int64_t utime, double voltage_V) {
  std::vector<Alert> alerts;
  if (!std::isfinite(voltage_V)) return alerts;
  if (have_voltage_ && utime < last_voltage_utime_) return alerts;
  const int64_t dropout_us = Microseconds(options_.dropout_s);
  if (!have_voltage_ || utime - last_voltage_utime_ > dropout_us) {
    // The voltage stream (re)starts: the rig was silent, so the quiet time counts from here.
    quiet_since_utime_ = have_deflection_ ? std::max(utime, last_deflection_utime_) : utime;
    in_dropout_ = false;
  }
  have_voltage_ = true;
  last_voltage_utime_ = utime;
  last_utime_ = have_message_ ? std::max(last_utime_, utime) : utime;
  have_message_ = true;
  if (!in_dropout_ && utime - quiet_since_utime_ > dropout_us) {
    in_dropout_ = true;
    const double gap_s = Seconds(utime - quiet_since_utime_);
    const bool had_sample = have_deflection_ && last_deflection_utime_ == quiet_since_utime_;
    alerts.push_back(Make(
        "sensor_dropout", quiet_since_utime_, utime, 0.0, 0.0,
        Printf("no deflection sample %s %.1f s while voltage messages continue (limit %.1f s): "
               "sensor dropout",
               had_sample ? "for" : "in the first", gap_s, options_.dropout_s)));
  }
  TrackVoltage(utime, voltage_V);
  return alerts;
}

}  // namespace flexid::model
