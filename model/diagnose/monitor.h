// Residual monitor: watches residual = measured - predicted deflection of one actuator and
// raises alerts for back-relaxation, slow drift, large residuals and sensor dropouts.
// Pure logic: no LCM, no SQLite, no logging, no wall clock. Every time is message time
// (`utime`, microseconds); an accelerated rig or a replayed log behaves like a real run.
//
// Notation. e_k is the residual (mm) of deflection sample k at message time t_k (s).
// When the model fits, e is modelled as a stationary Gaussian AR(1) process with marginal
// standard deviation sigma (noise_mm) and lag-1 autocorrelation rho. phi and Phi are the
// standard normal density and CDF, Psi = 1 - Phi. A "hold" is a stretch of constant
// voltage: it starts when the voltage (from either stream) moves by more than rest_band_V
// from the hold's voltage; a hold with |V| <= rest_band_V is "rest" (no input). Samples
// within settle_s of a hold's start (or of Reset) are not "usable": every statistical
// detector and estimator ignores them (dead time and fast transients).
//
// Calibration (warm-up). The statistical detectors (1-3) run once noise_estimation_s of
// usable residual has been seen since construction or Reset (when sigma is estimated and the
// residual is strongly autocorrelated, longer: until s below is <= 0.08, e.g. 200 s at
// rho = 0.9, 10 Hz, or until sigma_hat exp(3 s) is below sigma_floor_mm (the floor is then
// used whatever the estimate's error), but at most 10 noise_estimation_s). Usable samples
// are grouped in blocks (contiguous, one hold, at most 60 s); at the end of a block a
// least-squares line is removed, leaving u_k. Then
//   rho:    r = sum u_k u_{k-1} / sum u_k^2 pooled over all blocks since Reset (updated
//           online; u winsorised at 5 robust sd of its block). Removing a line from a block
//           of n samples biases r by about -(2 + 3 rho)/n (measured by simulation for
//           n = 100..600, rho = 0..0.95), so with B blocks and N samples
//           rho = (r + 2 B/N) / (1 - 3 B/N), clamped to [0, 0.98].
//   sigma = noise_mm if given, else from the warm-up's N values in B blocks
//           sigma = 1.4826 median|u - median(u)| / sqrt(1 - 2 kappa B/N)
//           (a robust scale that an offset, a slow trend or a few spikes do not inflate;
//           a line removed from n AR(1) samples takes about 2 kappa sigma^2 of their sum of
//           squares, kappa below), and the monitor says so with an info alert of kind
//           "noise_estimate". Its error, ln(sigma_hat/sigma) ~ N(0, s^2) with
//           s^2 = 1.3605 (1 + rho^2) / ((1 - rho^2) N) (the MAD's 36.75 % efficiency; the
//           AR(1) effective size of a scale estimate), would raise the false-alarm rate
//           averaged over the estimate (the rate is convex in the threshold): if the rate
//           falls as x^{-beta} in the threshold multiplier x, the average is
//           rate(x) exp(beta^2 s^2 / 2). So with an estimated sigma every multiplier below
//           solves rate(x) = target exp(-beta^2 s^2 / 2) instead (beta = z^2 - 1 for the line
//           tests, -d ln q / d ln c for the run test; three fixed-point steps, which converge
//           for s <= 0.08; s is capped there if the warm-up ran out of time). Measured over
//           400 warm-ups: no bias in ln sigma_hat (|mean| < 0.002 at rho = 0, 0.8, 0.95),
//           sd 0.035 (rho 0) and 0.057 (rho 0.8) against s = 0.034 and 0.072.
//   Floor: sigma (given or estimated) is never below sigma_floor_mm (default 0.005 mm;
//           flexidd's alerts.sigma_floor_mm), best set to the sensor's resolution. A
//           quantised signal (most residuals round to the same value: MAD 0) or a
//           noise-free one (a model identified from simulated data: RMSE 0) has sigma 0,
//           and every threshold below is a multiple of sigma: at 0 they alert on rounding
//           differences of 1e-12 mm. The floor only raises thresholds, so the false-alarm
//           rates stay within their target; it hides effects smaller than a few floors.
//           An estimate below the floor has no say in the thresholds, so its error s does
//           not raise the multipliers (s is taken as 0).
//
// 1. back_relaxation and 2. drift: the line test. Over the usable samples of the current
//    hold (window W = hold start + settle_s .. now, n samples) fit e = a + b t by least
//    squares: b = S_te / S_tt with S_tt = sum (t_k - tbar)^2, S_te = sum (t_k - tbar) e_k.
//    The change over the window is D = b T, T = t_n - t_1 (mm). For white residuals
//      Var(D) = sigma^2 T^2 / S_tt   (exact, any sampling; uniform sampling gives
//               12 sigma^2 (n - 1) / (n (n + 1)), about 12 sigma^2 / n),
//    and for AR(1) residuals the variance of a least-squares slope is inflated by the
//    long-run factor kappa = (1 + rho)/(1 - rho) (effective sample size n / kappa), so
//      sd_D = sigma sqrt(kappa T^2 / S_tt),   threshold h = max(z sd_D, min_effect_mm).
//    back_relaxation (hold with |V| > rest_band_V): alert when D opposes the command,
//    sign(D) = -sign(V), and |D| > h with one-sided z_1. drift (rest): |D| > h with
//    two-sided z_2, unless it is the recovery of a back-relaxation: a gel that relaxed back
//    under the previous hold's voltage V_p overshoots past rest when the voltage is removed
//    and returns to 0 (clients/rig/effects.h), so a rest right after a hold whose fitted
//    line starts on the far side, sign(a + b t_1) = -sign(V_p), and moves back, sign(D) =
//    sign(V_p) with |D| < 2 |a + b t_1|, is back-relaxation: silent when that hold already
//    raised its alert, else a back_relaxation alert. One line-test alert per hold (latched).
//    Multiplicity. The test is repeated at every usable sample from the moment the window
//    spans min_hold_s (w0) until the hold ends. For nested windows [0, s] and [0, w] the
//    least-squares slopes of white noise have correlation (s/w)^{3/2}, so Z = D / sd_D is,
//    in log-window tau = ln w, a stationary Ornstein-Uhlenbeck process with correlation
//    exp(-3/2 |d tau|). Pickands' theorem (Pickands 1969; Leadbetter, Lindgren and
//    Rootzen 1983, ch. 12) gives for one hold whose window grows from w0 to w
//      p(w) = m [Psi(z) + (3/2) z phi(z) ln(w / w0)],   m = 1 (one-sided), 2 (two-sided),
//    an upper bound in practice (the looks are discrete). Effectively independent tests
//    per hour: one per examined hold, and a hold with window w occupies w + settle_s of
//    message time, so at most 3600 / (w + settle_s) of them fit in an hour. The rate is
//    bounded over every hold length,
//      R(z) = 3600 max_{w >= w0} p(w) / (w + settle_s)   per hour,
//    and z solves R(z) = false_alarms_per_hour (LineTestMultiplier). With the defaults
//    (0.1/h, min_hold_s 20, settle_s 10): z_1 = 3.79, z_2 = 3.98; the worst window is
//    w = 61 s, and back-to-back 110 s holds would use 92 % of the budget. Simulated (1000 h
//    of white residual with sigma given, 110 s holds alternating 0 and 5 V, so each test
//    runs half the time) the line tests raised 0.075/h in all (0.046/h back_relaxation,
//    including rest windows taken for a recovery, 0.029/h drift) against the 0.092/h this
//    bound gives for both; at rho = 0.8, 0.039/h. The discrete looks make it conservative.
//    A recovery alert comes from a rest, a hold alert from a hold, and each test's rate is
//    bounded per hour of the time it runs, so back_relaxation stays within the target.
// 3. residual: a run of k = 3 consecutive usable samples on one side beyond c sigma. The
//    probability that such a run starts at a given sample of a unit AR(1),
//      q(c, rho, k) = P(x_{j-1} <= c, x_j > c, ..., x_{j+k-1} > c),
//    follows from the Markov recursion (s_r = sqrt(1 - rho^2))
//      f_1(x) = phi(x) Phi((c - rho x)/s_r),   f_{i+1}(y) = int_c^inf f_i(x) phi((y - rho
//      x)/s_r)/s_r dx, q = int_c^inf f_k(x) dx   (RunStartProbability; Simpson's rule on a grid).
//    Rate = 2 q N_h, N_h = usable samples per hour (measured in the warm-up blocks); c solves
//    Rate = false_alarms_per_hour (RunTestMultiplier, recomputed when rho or the sample rate
//    moves). Threshold h = max(c sigma, min_effect_mm); magnitude = mean of the run. Latched:
//    one alert per excursion, cleared when |e| stays within min(2 sigma, h) for 5 s, which
//    only removes alerts, so the rate stays within the target. Simulated as above: 0.071/h
//    (white), 0.098/h (rho = 0.8).
// 4. sensor_dropout: voltage messages keep arriving (no gap longer than dropout_s) but no
//    deflection sample for more than dropout_s. One alert per dropout; cleared by the next
//    deflection sample. When both streams stop (the rig stopped), the quiet time restarts
//    with the first voltage message after the gap, so no alert. magnitude_mm and
//    threshold_mm are 0 (the size is the duration, end - start, given in the text).
// Severity: warning; critical when |magnitude| > 5 threshold.
// Cost: O(1) per sample, plus O(block) when a block closes (once a minute or per hold);
// in a warm-up that goes on past noise_estimation_s, O(warm-up values) per block closed
// (sigma_hat against the floor).
// The multipliers are solved at the end of the warm-up (the slowest call: 5 ms at rho = 0,
// 15 ms at rho = 0.98, 500 Hz, including sigma from 60,000 values) and again only when rho
// moves by > 0.01 or the sample rate by > 5 % (RunTestMultiplier: 0.4-3 ms).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace flexid::model {

struct MonitorOptions {
  double false_alarms_per_hour = 0.1;  // target rate when the model fits (per actuator, per kind)
  double noise_mm = 0.0;       // residual noise scale (marginal sd) of the model when it fits;
                               // 0: estimate from the first noise_estimation_s (robustly), say so
  double min_hold_s = 20.0;    // a hold is examined once its window after settle_s spans this
  double settle_s = 10.0;      // ignore this long after a voltage change (dead time, transients)
  double min_effect_mm = 0.0;  // never alert on effects smaller than this (0: off)
  double dropout_s = 2.0;      // no deflection sample this long while voltage messages continue
  double rest_band_V = 0.05;   // |voltage| <= this is "no input"; also the hold tolerance
  double noise_estimation_s = 120.0;  // warm-up: usable residual needed for sigma and rho
  double sigma_floor_mm = 0.005;      // sigma in use is never below this (header, "Floor"), > 0
  bool IsValid(std::string* error) const;
};

struct Alert {
  std::string kind;  // "back_relaxation", "drift", "residual", "sensor_dropout", "noise_estimate"
  int severity = 1;  // 0 info, 1 warning, 2 critical
  int64_t start_utime = 0, end_utime = 0;  // span the finding covers, microseconds
  double magnitude_mm = 0.0;               // signed where it has a sign
  double threshold_mm = 0.0;               // the threshold it crossed
  std::string text;                        // one plain sentence: what, where, how large
};

// Multiplier z of the line test: solves R(z) = false_alarms_per_hour (header, detectors 1-2)
// for windows first examined at min_window_s after settle_s; sides 1 or 2. Throws
// std::invalid_argument for non-positive rate or window, negative settle or other sides.
double LineTestMultiplier(double false_alarms_per_hour, double min_window_s, double settle_s,
                          int sides);

// q(c, rho, k) of the header (detector 3): probability that a run of at least k samples above
// c starts at a given sample of a stationary Gaussian AR(1) with unit variance. Accurate to
// ~1e-4 relative (against an 8 times finer grid, rho 0.3-0.99, c 2-4). Throws
// std::invalid_argument unless 0 <= rho <= 0.99 and k >= 1.
double RunStartProbability(double c, double rho, int k);

// c of detector 3: solves 2 q(c, rho, k) samples_per_hour = false_alarms_per_hour.
double RunTestMultiplier(double false_alarms_per_hour, double samples_per_hour, double rho, int k);

class ResidualMonitor {
 public:
  static constexpr int kResidualRunSamples = 3;  // k of detector 3

  // Throws std::invalid_argument if !options.IsValid().
  ResidualMonitor(std::string actuator_id, MonitorOptions options);

  // Each accepted deflection sample with the voltage in force and the residual (mm; NaN when
  // there is no model: ignored except for dropout and hold bookkeeping). A sample not later
  // than the previous one is ignored.
  std::vector<Alert> OnDeflection(int64_t utime, double voltage_V, double residual_mm);

  // Each voltage message (dropout detection and hold tracking). Non-finite voltages and
  // messages older than the previous voltage message are ignored.
  std::vector<Alert> OnVoltage(int64_t utime, double voltage_V);

  // After a model change: statistics (warm-up, sigma if estimated, rho, windows, latches)
  // restart, with a settle period from the last message time. Hold and dropout tracking go on.
  void Reset();

  double noise_mm() const;              // given or estimated, floored; 0 before the estimate
  double lag1_autocorrelation() const;  // rho in use (0 before the warm-up ends)
  bool calibrated() const { return calibrated_; }  // warm-up over: detectors 1-3 running

 private:
  // Least-squares line e = a + b t over a growing window, Welford-style updates.
  struct LineFit {
    int64_t first_utime = 0, last_utime = 0;
    size_t n = 0;
    double mean_t_s = 0, mean_e_mm = 0, s_tt = 0, s_te = 0;
    void Add(int64_t utime, double e_mm);
    double Span_s() const;            // T = t_n - t_1
    double Change_mm() const;         // D = b T
    double FittedAtStart_mm() const;  // a + b t_1
    double VarianceFactor() const;    // T^2 / S_tt, so Var(D) = sigma^2 kappa T^2 / S_tt
  };
  struct Sample {
    int64_t utime;
    double e_mm;
  };

  void TrackVoltage(int64_t utime, double voltage_V);
  void CloseBlock();
  bool WarmUpSufficient();       // noise_mm given, or sigma_hat certain enough, or time is up
  double SigmaLogSd() const;     // s of the header for the warm-up values so far
  double SigmaEstimate() const;  // sigma_hat of the header from the warm-up values so far
  void FinishWarmUp(int64_t utime, std::vector<Alert>* alerts);
  void UpdateRho();
  void UpdateRunThreshold();
  void CheckLine(int64_t utime, std::vector<Alert>* alerts);
  void CheckResidual(int64_t utime, double e_mm, std::vector<Alert>* alerts);
  void RestartStatistics();
  double Floored(double sigma_mm) const;  // max(sigma_floor_mm, sigma_mm), NaN: the floor
  Alert Make(std::string kind, int64_t start_utime, int64_t end_utime, double magnitude_mm,
             double threshold_mm, std::string text) const;

  std::string actuator_id_;
  MonitorOptions options_;
  double z_back_relaxation_ = 0, z_drift_ = 0;

  // Hold tracking.
  bool have_hold_ = false;
  int64_t hold_start_utime_ = 0;
  double hold_voltage_V_ = 0;
  int64_t settle_until_utime_ = 0;
  int64_t last_utime_ = 0;  // latest message time seen on either stream
  bool have_message_ = false;

  // Dropout tracking.
  bool have_voltage_ = false, have_deflection_ = false;
  int64_t last_voltage_utime_ = 0, last_deflection_utime_ = 0;
  int64_t quiet_since_utime_ = 0;  // no deflection sample since (voltage stream running)
  bool in_dropout_ = false;

  // Warm-up and noise statistics.
  std::vector<Sample> block_;
  std::vector<double> warmup_detrended_mm_;
  int64_t warmup_first_utime_ = 0;
  bool warmup_started_ = false;
  double warmup_duration_s_ = 0;
  double warmup_samples_ = 0, warmup_blocks_ = 0;
  double sigma_log_sd_ = 0;          // sd of ln(sigma_hat / sigma); 0 when noise_mm is given
  bool warmup_below_floor_ = false;  // sigma_hat exp(3 s) < sigma_floor_mm (at the last block)
  double sum_uu_ = 0, sum_uu1_ = 0;  // pooled sum u_k^2 and sum u_k u_{k-1}
  double samples_ = 0, blocks_ = 0, pairs_span_s_ = 0, pairs_ = 0;
  bool calibrated_ = false;
  double sigma_mm_ = 0, rho_ = 0;

  // Detector 3 threshold cache.
  double run_c_ = 0, run_c_rho_ = -1, run_c_rate_ = 0;

  // Line test (detectors 1-2) of the current hold.
  LineFit line_;
  bool line_latched_ = false;           // this hold has raised its line-test alert
  bool hold_back_relaxation_ = false;   // ... and it was back_relaxation
  double previous_hold_voltage_V_ = 0;  // the hold before this one (0: none)
  bool previous_hold_back_relaxation_ = false;

  // Residual run (detector 3).
  int run_sign_ = 0, run_count_ = 0;
  double run_sum_mm_ = 0;
  int64_t run_start_utime_ = 0;
  bool residual_latched_ = false;
  bool within_ = false;
  int64_t within_since_utime_ = 0;
};

}  // namespace flexid::model
