// The frequency-response route (model/identify/frequency_response.h) against known truths: the
// analytic response of a first-order lag (data integrated by RK4, test_util.h), square-wave
// recordings simulated from known models, and the seed's 8 V model (presets.h).
#include "model/identify/frequency_response.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <complex>
#include <functional>
#include <iostream>
#include <numbers>
#include <random>
#include <stdexcept>
#include <string>

#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/core/simulate.h"
#include "tests/test_util.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;
constexpr double kPi = std::numbers::pi;

// The seed's frequency experiment (section 3.4, Figure 6): 5 V square waves.
const std::vector<double> kSeedFrequencies_Hz = {0.0025, 0.02, 0.031, 0.054, 0.11, 0.15, 1.1};

// The low-order truth: G = 2 e^{-1.5 s} (s + 0.5) / ((s + 0.2)(s + 1)); DC gain 5 mm/V.
TransferFunction LowOrderTruth() { return {{2.0, 1.0}, {1.0, 1.2, 0.2}, 1.5}; }

// 0 <-> level_V square wave, 50 % duty, high first, sampled and held (ZOH):
// u_k = level if frac(f t_k) < 1/2. The period need not be a whole number of samples.
std::vector<double> SquareWave(double frequency_Hz, double dt_s, double duration_s,
                               double level_V = 5.0) {
  const auto count = static_cast<size_t>(std::lround(duration_s / dt_s));
  std::vector<double> u(count);
  for (size_t k = 0; k < count; ++k) {
    const double phase = frequency_Hz * static_cast<double>(k) * dt_s;
    u[k] = phase - std::floor(phase) < 0.5 ? level_V : 0.0;
  }
  return u;
}

// `periods` periods of a square wave through `truth` (exact ZOH simulation), with white
// output noise of standard deviation noise_fraction * max |y|.
DataSegment Record(const TransferFunction& truth, double frequency_Hz, double dt_s, double periods,
                   double noise_fraction = 0.0, unsigned seed = 1) {
  DataSegment seg;
  seg.dt_s = dt_s;
  seg.voltage_V = SquareWave(frequency_Hz, dt_s, periods / frequency_Hz);
  seg.deflection_mm = SimulateUniform(truth, dt_s, seg.voltage_V);
  if (noise_fraction > 0.0) {
    double peak = 0.0;
    for (double y : seg.deflection_mm) peak = std::max(peak, std::abs(y));
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_fraction * peak);
    for (double& y : seg.deflection_mm) y += noise(rng);
  }
  return seg;
}

// The seed's seven square waves, sampled at 10 Hz except 1.1 Hz at 100 Hz (at 10 Hz,
// 1.1 Hz has 9 samples per period and its 3rd harmonic, 3.3 Hz, would be above 0.8
// Nyquist = 4 Hz). Each records ceil(settle_s f) periods (at least 1) to be discarded,
// then `periods` more.
std::vector<DataSegment> SevenSquareWaves(const TransferFunction& truth, double periods,
                                          double settle_s, double noise_fraction = 0.0,
                                          unsigned seed = 1) {
  std::vector<DataSegment> recordings;
  for (double f_Hz : kSeedFrequencies_Hz) {
    const double discard = std::max(1.0, std::ceil(settle_s * f_Hz - 1e-9));
    recordings.push_back(
        Record(truth, f_Hz, f_Hz > 0.5 ? 0.01 : 0.1, discard + periods, noise_fraction, seed++));
  }
  return recordings;
}

double RelativeError(Complex estimate, Complex truth) {
  return std::abs(estimate - truth) / std::abs(truth);
}

void ExpectInputError(const std::function<void()>& call, const std::string& fragment) {
  try {
    call();
    ADD_FAILURE() << "no InputError (expected one mentioning \"" << fragment << "\")";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find(fragment), std::string::npos) << e.what();
  }
}

void Print(const FrequencyFit& fit) {
  std::cout << fit.method_report << "\n";
  for (const auto& c : fit.coefficients)
    std::cout << "  " << c.name << " = " << c.value << " +- " << c.half_width_95 << "\n";
  std::cout << "  dc_gain = " << fit.dc_gain.value << " +- " << fit.dc_gain.half_width_95 << "\n";
  for (const auto& p : fit.poles)
    std::cout << "  pole " << p.re << " +- " << p.re_half_width_95 << ", " << p.im << " +- "
              << p.im_half_width_95 << "j\n";
}

// The poles of `fit` sorted by |p|, ascending.
std::vector<PoleEstimate> PolesByMagnitude(const FrequencyFit& fit) {
  std::vector<PoleEstimate> poles = fit.poles;
  std::sort(poles.begin(), poles.end(), [](const auto& a, const auto& b) {
    return std::hypot(a.re, a.im) < std::hypot(b.re, b.im);
  });
  return poles;
}

// -----------------------------------------------------------------------------------------
// Points
// -----------------------------------------------------------------------------------------

// K / (tau s + 1) under a 0.05 Hz square wave (200 samples per period, 5 periods, the
// first discarded). Data by RK4 at 0.01 s steps (test_util.h), not by model/simulate.
TEST(FrequencyResponse, FirstOrderSquareWaveMatchesAnalyticAfterZohCorrection) {
  const double gain = 2.0, tau_s = 3.0, dt_s = 0.1, f_Hz = 0.05;
  const TransferFunction lag{{gain}, {tau_s, 1.0}, 0.0};
  DataSegment seg;
  seg.dt_s = dt_s;
  seg.voltage_V = SquareWave(f_Hz, dt_s, 5.0 / f_Hz);
  std::vector<double> t_s(seg.voltage_V.size());
  for (size_t k = 0; k < t_s.size(); ++k) t_s[k] = static_cast<double>(k) * dt_s;
  seg.deflection_mm = testing::IntegrateRk4(
      lag, t_s,
      [&](double t) {  // the held sample
        const auto k = static_cast<size_t>(std::floor(t / dt_s + 1e-9));
        return seg.voltage_V[std::min(k, seg.voltage_V.size() - 1)];
      },
      0.01);

  const auto points = EstimateFrequencyResponse(seg, f_Hz);
  ASSERT_EQ(points.size(), 3u);  // h = 1, 3, 5: the even harmonics of a 50 % square are absent
  const double a = std::exp(-dt_s / tau_s);
  const double omega_s = 2.0 * kPi / dt_s;
  for (const auto& p : points) {
    EXPECT_EQ(p.periods, 4);
    const double w = p.omega_rad_s;
    EXPECT_NEAR(w, 2.0 * kPi * f_Hz * p.harmonic, 1e-12);
    auto continuous = [&](double omega) { return gain / Complex(1.0, omega * tau_s); };
    // The sampled system exactly: ZOH discretisation K (1 - a) / (z - a), a = e^{-dt/tau}.
    const Complex sampled = gain * (1.0 - a) / (std::polar(1.0, w * dt_s) - a);
    const Complex zoh = Complex(0.0, w * dt_s) / (1.0 - std::polar(1.0, -w * dt_s));
    // Aliasing left after the ZOH correction (header): sum_{k != 0} |G(j w_k) / G(j w)|
    // w / |w_k|, w_k = w + k omega_s (first order: the terms fall as 1/k^2).
    double aliasing = 0.0;
    for (int k = -100000; k <= 100000; ++k) {
      if (k == 0) continue;
      const double wk = w + k * omega_s;
      aliasing += std::abs(continuous(wk) / continuous(w)) * w / std::abs(wk);
    }
    std::cout << "h " << p.harmonic << ": vs sampled system "
              << RelativeError(p.response, sampled * zoh) << ", vs G(jw) "
              << RelativeError(p.response, continuous(w)) << " (aliasing bound " << aliasing
              << "), uncorrected " << RelativeError(sampled, continuous(w)) << "\n";
    // The estimator returns the sampled system's response times the ZOH factor: 1e-4
    // covers the RK4 error (~1e-10) and what the trend leaves of the start-up transient
    // (e^{-20/3} of it at the window start).
    EXPECT_LT(RelativeError(p.response, sampled * zoh), 1e-4) << "harmonic " << p.harmonic;
    // Against the continuous truth the only further error is aliasing, within its bound.
    EXPECT_LT(RelativeError(p.response, continuous(w)), 1.05 * aliasing + 1e-4);
    // Without the correction the error is ~w dt / 2 (the half-sample lag): 10x larger.
    EXPECT_GT(RelativeError(sampled, continuous(w)), 10.0 * (aliasing + 1e-4));
    EXPECT_GT(p.std_dev, 0.0);
    EXPECT_LT(p.gain_half_width_95, 1e-3 * std::abs(p.response));
  }
}

// A sine whose period is not a whole number of samples (0.031 Hz at 10 Hz: 322.58).
TEST(FrequencyResponse, FirstOrderSineWithNonIntegerPeriod) {
  const double gain = 2.0, tau_s = 3.0, dt_s = 0.1, f_Hz = 0.031;
  const TransferFunction lag{{gain}, {tau_s, 1.0}, 0.0};
  DataSegment seg;
  seg.dt_s = dt_s;
  const auto count = static_cast<size_t>(std::lround(4.0 / f_Hz / dt_s));
  std::vector<double> t_s;
  for (size_t k = 0; k < count; ++k) {
    t_s.push_back(static_cast<double>(k) * dt_s);
    seg.voltage_V.push_back(2.5 + 2.5 * std::sin(2.0 * kPi * f_Hz * t_s.back()));
  }
  seg.deflection_mm = testing::IntegrateRk4(
      lag, t_s,
      [&](double t) {
        const auto k = static_cast<size_t>(std::floor(t / dt_s + 1e-9));
        return seg.voltage_V[std::min(k, seg.voltage_V.size() - 1)];
      },
      0.01);
  const double detected_Hz = DetectFundamental_Hz(seg);
  EXPECT_NEAR(detected_Hz, f_Hz, 1e-3 * f_Hz);
  const auto points = EstimateFrequencyResponse(seg, f_Hz);
  ASSERT_EQ(points.size(), 1u);  // a sine has no harmonics
  const Complex truth = gain / Complex(1.0, points[0].omega_rad_s * tau_s);
  // Tolerance: aliasing at 0.19 rad/s is 7e-5 (the bound of the previous test); three
  // periods are 967.7 samples, rounded to 968, an edge term of order 1 / L at most.
  // Observed 6e-5.
  EXPECT_LT(RelativeError(points[0].response, truth), 3e-4);
}

TEST(FrequencyResponse, DetectsTheSeedFrequencies) {
  for (double f_Hz : kSeedFrequencies_Hz) {
    const double dt_s = f_Hz > 0.5 ? 0.01 : 0.1;
    const DataSegment seg = Record(LowOrderTruth(), f_Hz, dt_s, 4.0);
    // Edges are on the sample grid: each crossing is off by up to dt, and the least-
    // squares period over ~8 edges spread over 4 periods is off by ~dt / (4 P).
    EXPECT_NEAR(DetectFundamental_Hz(seg), f_Hz, 0.5 * dt_s * f_Hz * f_Hz) << f_Hz << " Hz";
  }
}

// -----------------------------------------------------------------------------------------
// Fit on exact points (no estimation error): the fit alone against the truth
// -----------------------------------------------------------------------------------------

std::vector<FrequencyPoint> ExactPoints(const TransferFunction& truth,
                                        const std::vector<double>& frequencies_Hz,
                                        double relative_sd) {
  std::vector<FrequencyPoint> points;
  for (double f_Hz : frequencies_Hz) {
    FrequencyPoint p;
    p.frequency_Hz = f_Hz;
    p.omega_rad_s = 2.0 * kPi * f_Hz;
    p.response = FrequencyResponse(truth, p.omega_rad_s);
    p.std_dev = relative_sd * std::abs(p.response);
    p.gain_half_width_95 = 1.96 * p.std_dev;
    p.phase_half_width_95_rad = 1.96 * relative_sd;
    points.push_back(p);
  }
  return points;
}

TEST(FrequencyResponse, FitRecoversLowOrderTruthFromExactPoints) {
  std::vector<double> frequencies_Hz;
  for (int i = 0; i < 15; ++i) frequencies_Hz.push_back(0.002 * std::pow(10.0, i / 6.0));
  FrequencyFitOptions options;
  options.num_zeros = 1;
  options.num_poles = 2;
  const FrequencyFit fit =
      FitFrequencyResponse(ExactPoints(LowOrderTruth(), frequencies_Hz, 1e-3), options);
  ASSERT_EQ(fit.tf.num.size(), 2u);
  ASSERT_EQ(fit.tf.den.size(), 3u);
  EXPECT_NEAR(fit.tf.num[0], 2.0, 1e-6);
  EXPECT_NEAR(fit.tf.num[1], 1.0, 1e-6);
  EXPECT_NEAR(fit.tf.den[1], 1.2, 1e-6);
  EXPECT_NEAR(fit.tf.den[2], 0.2, 1e-6);
  EXPECT_NEAR(fit.tf.delay_s, 1.5, 1e-6);
  EXPECT_NEAR(fit.dc_gain.value, 5.0, 1e-6);
  EXPECT_LT(fit.weighted_rms_error, 1e-3);
  ASSERT_EQ(fit.coefficients.size(), 5u);  // b0, b1, a1, a2, delay_s
  EXPECT_EQ(fit.coefficients.back().name, "delay_s");
}

TEST(FrequencyResponse, FitWithoutDelay) {
  const TransferFunction lag{{2.0}, {3.0, 1.0}, 0.0};
  FrequencyFitOptions options;
  options.num_zeros = 0;
  options.num_poles = 1;
  options.max_delay_s = 0.0;
  const FrequencyFit fit =
      FitFrequencyResponse(ExactPoints(lag, {0.01, 0.05, 0.1, 0.5}, 1e-3), options);
  EXPECT_NEAR(fit.dc_gain.value, 2.0, 1e-8);
  EXPECT_NEAR(fit.tf.den[1], 1.0 / 3.0, 1e-8);
  EXPECT_EQ(fit.tf.delay_s, 0.0);
  EXPECT_EQ(fit.coefficients.size(), 2u);  // b0, a1: no delay
  // Points without any uncertainty: an unweighted fit, said so.
  auto bare = ExactPoints(lag, {0.01, 0.05, 0.1, 0.5}, 0.0);
  const FrequencyFit unweighted = FitFrequencyResponse(bare, options);
  EXPECT_NEAR(unweighted.dc_gain.value, 2.0, 1e-8);
  EXPECT_NE(unweighted.method_report.find("unweighted"), std::string::npos);
}

// -----------------------------------------------------------------------------------------
// Square waves at the seed's frequencies
// -----------------------------------------------------------------------------------------

// 3 analysed periods after at least one discarded (10 s of settling: 2 periods at 0.11
// and 0.15 Hz, 11 at 1.1 Hz, where the 1.5 s dead time alone is 1.7 periods).
TEST(FrequencyResponse, LowOrderTruthFromSevenSquareWaves) {
  const TransferFunction truth = LowOrderTruth();
  FrequencyFitOptions options;
  options.num_zeros = 1;
  options.num_poles = 2;
  SquareWaveOptions square;
  square.min_discard_s = 9.5;  // a little under the 10 s recorded: f0 is detected, not given
  const FrequencyFit fit =
      IdentifyFromSquareWaves(SevenSquareWaves(truth, 3.0, 10.0), options, square);
  Print(fit);
  // Points: 3 odd harmonics per recording; at 0.11 and 1.1 Hz the sampled square wave's
  // duty cycle is 46 / 91 samples, so its even harmonics exceed 1 % and are used too.
  EXPECT_GE(fit.points.size(), 21u);
  for (const auto& p : fit.points) EXPECT_GE(p.periods, 3);
  EXPECT_NEAR(fit.dc_gain.value, 5.0, 0.02 * 5.0);
  const auto poles = PolesByMagnitude(fit);
  ASSERT_EQ(poles.size(), 2u);
  EXPECT_NEAR(poles[0].re, -0.2, 0.02 * 0.2);
  EXPECT_NEAR(poles[1].re, -1.0, 0.02 * 1.0);
  EXPECT_EQ(poles[0].im, 0.0);
  EXPECT_EQ(poles[1].im, 0.0);
  EXPECT_NEAR(fit.tf.delay_s, 1.5, 0.02 * 1.5);
  EXPECT_EQ(fit.method_report.find("underdetermined"), std::string::npos);
}

// The seed's 8 V model (3 zeros / 4 poles, 3.67 s): slow real poles at -0.00868 and
// -0.0714 rad/s (time constants 115 s and 14 s), a lightly damped pair at -0.255 +- 19.16j
// (3.05 Hz, damping 0.013) and DC gain 8.66. The pair lies between the 1.1 Hz fundamental
// (6.9 rad/s) and its 3rd harmonic (20.7 rad/s); only the 1.1 Hz recording (at 100 Hz)
// reaches it, where the gain is 0.03 % (6.9 rad/s) to 0.15 % (20.7 rad/s) of DC. The
// slowest pole is below the lowest point (0.0157 rad/s): the DC gain is an extrapolation.
// 30 s of settling is far less than the 115 s time constant: the trend takes the rest.
TEST(FrequencyResponse, Seed8VNoiseFree) {
  const TransferFunction truth = SeedModel8V();
  SquareWaveOptions square;
  square.min_discard_s = 29.0;
  const FrequencyFit fit = IdentifyFromSquareWaves(SevenSquareWaves(truth, 3.0, 30.0), {}, square);
  Print(fit);
  EXPECT_EQ(fit.tf.num.size(), 4u);
  EXPECT_EQ(fit.tf.den.size(), 5u);
  EXPECT_NEAR(fit.dc_gain.value, DcGain(truth), 0.02 * DcGain(truth));
  const auto poles = PolesByMagnitude(fit);
  ASSERT_EQ(poles.size(), 4u);
  EXPECT_NEAR(poles[0].re, -0.008675, 0.05 * 0.008675);
  EXPECT_NEAR(poles[1].re, -0.071426, 0.05 * 0.071426);
  // Noise-free, even the pair comes back (observed: frequency to 0.01 %, real part to
  // 2 %) and the report flags it; the dead time carries a 0.7 % bias (3.646 s, outside its
  // own +-0.008 s): what the ZOH correction leaves (aliasing) and the sampled square
  // waves' edge jitter at 1.1 Hz are not in the points' uncertainty.
  EXPECT_NEAR(std::hypot(poles[2].re, poles[2].im), 19.161, 0.01 * 19.161);
  EXPECT_NEAR(poles[2].re, -0.2549, 0.25 * 0.2549);
  EXPECT_NE(fit.method_report.find("Lightly damped pair"), std::string::npos);
  EXPECT_NEAR(fit.tf.delay_s, 3.67, 0.02 * 3.67);
}

// 1 % white output noise (of each recording's peak deflection): DC gain and slow poles
// stay within 2 % and 5 % and inside their 95 % intervals; the fast pair is not determined
// (over noise draws its frequency lands anywhere in 16..26 rad/s, its damping interval
// spans zero) and the dead time only to +-1..2 s, with competing valleys of chi^2(T) named
// in the report. Over 20 draws (this test's set-up, other seeds) the 95 % intervals held
// the truth for the DC gain 18 times, the slow poles 18 and 14, the delay 15 (in 4 of the
// other 5 the true delay's valley was reported as competing); worst errors DC 0.6 %, slow
// poles 0.8 % and 1.9 %. At 0.3 % noise: 18, 19, 19 and 19 of 20, the pair's frequency
// within ~1 rad/s, its damping still not determined.
TEST(FrequencyResponse, Seed8VWithOnePercentNoise) {
  const TransferFunction truth = SeedModel8V();
  SquareWaveOptions square;
  square.min_discard_s = 29.0;
  const FrequencyFit fit =
      IdentifyFromSquareWaves(SevenSquareWaves(truth, 3.0, 30.0, 0.01, 1), {}, square);
  Print(fit);
  EXPECT_NEAR(fit.dc_gain.value, DcGain(truth), 0.02 * DcGain(truth));
  EXPECT_LE(std::abs(fit.dc_gain.value - DcGain(truth)), fit.dc_gain.half_width_95);
  const auto poles = PolesByMagnitude(fit);
  ASSERT_EQ(poles.size(), 4u);
  // The two slowest by magnitude are the real slow poles here (in some draws the free
  // pair falls below them; this draw's does not).
  EXPECT_NEAR(poles[0].re, -0.008675, 0.05 * 0.008675);
  EXPECT_NEAR(poles[1].re, -0.071426, 0.05 * 0.071426);
  EXPECT_LE(std::abs(poles[0].re + 0.008675), poles[0].re_half_width_95);
  EXPECT_LE(std::abs(poles[1].re + 0.071426), poles[1].re_half_width_95);
  const ParameterEstimate& delay = fit.coefficients.back();
  ASSERT_EQ(delay.name, "delay_s");
  EXPECT_LE(std::abs(delay.value - 3.67), delay.half_width_95);
  EXPECT_GT(delay.half_width_95, 0.5);  // honestly wide
}

// Each point's 95 % gain interval should hold the true |G(j omega)| about 95 % of the time:
// three noise draws of the seven square waves (75 points), at least 90 % required.
TEST(FrequencyResponse, GainAndPhaseIntervalsCoverTheTruthUnderNoise) {
  const TransferFunction truth = LowOrderTruth();
  int gain_inside = 0, phase_inside = 0, total = 0;
  for (unsigned seed = 1; seed <= 41; seed += 20) {
    for (const DataSegment& rec : SevenSquareWaves(truth, 3.0, 10.0, 0.01, seed)) {
      const double f0_Hz = DetectFundamental_Hz(rec);
      const int discard = std::max(1, static_cast<int>(std::ceil(10.0 * f0_Hz - 1e-9)));
      for (const FrequencyPoint& p : EstimateFrequencyResponse(rec, f0_Hz, 5, discard)) {
        const Complex g = FrequencyResponse(truth, p.omega_rad_s);
        gain_inside += std::abs(std::abs(p.response) - std::abs(g)) <= p.gain_half_width_95;
        phase_inside += std::abs(std::arg(p.response / g)) <= p.phase_half_width_95_rad;
        ++total;
      }
    }
  }
  std::cout << "gain intervals hold the truth at " << gain_inside << " of " << total
            << " points, phase intervals at " << phase_inside << "\n";
  EXPECT_GE(gain_inside, 0.9 * total);
  EXPECT_GE(phase_inside, 0.9 * total);
}

// -----------------------------------------------------------------------------------------
// Errors and options
// -----------------------------------------------------------------------------------------

TEST(FrequencyResponse, NonPeriodicInputIsAnInputError) {
  const TransferFunction truth = LowOrderTruth();
  // Random telegraph: switches after exponentially distributed holds (mean 20 s).
  DataSegment telegraph;
  telegraph.dt_s = 0.1;
  std::mt19937 rng(7);
  std::exponential_distribution<double> hold(1.0 / 20.0);
  double level = 5.0;
  while (telegraph.voltage_V.size() < 3000) {
    const auto samples = static_cast<size_t>(hold(rng) / telegraph.dt_s) + 1;
    telegraph.voltage_V.insert(telegraph.voltage_V.end(), samples, level);
    level = 5.0 - level;
  }
  telegraph.deflection_mm = SimulateUniform(truth, telegraph.dt_s, telegraph.voltage_V);
  ExpectInputError([&] { DetectFundamental_Hz(telegraph); }, "not periodic");

  DataSegment step = telegraph;
  for (size_t k = 0; k < step.voltage_V.size(); ++k) step.voltage_V[k] = k < 500 ? 0.0 : 5.0;
  ExpectInputError([&] { DetectFundamental_Hz(step); }, "upwards 1 times");

  DataSegment constant = telegraph;
  std::fill(constant.voltage_V.begin(), constant.voltage_V.end(), 5.0);
  ExpectInputError([&] { DetectFundamental_Hz(constant); }, "constant");
  ExpectInputError([&] { EstimateFrequencyResponse(constant, 0.05); }, "no component");

  // The fit names the recording.
  const std::vector<DataSegment> recordings = {Record(truth, 0.05, 0.1, 5.0), telegraph};
  ExpectInputError([&] { IdentifyFromSquareWaves(recordings); }, "recording 1: input is not");
}

TEST(FrequencyResponse, TooFewPeriodsOrBadSegments) {
  const DataSegment seg = Record(LowOrderTruth(), 0.05, 0.1, 2.5);
  ExpectInputError([&] { EstimateFrequencyResponse(seg, 0.05); }, "need discard_periods + 2");
  EXPECT_NO_THROW(EstimateFrequencyResponse(seg, 0.05, 5, 0));
  ExpectInputError([&] { EstimateFrequencyResponse(seg, 4.5); }, "above 0.8 Nyquist");
  DataSegment bad = seg;
  bad.deflection_mm.pop_back();
  ExpectInputError([&] { EstimateFrequencyResponse(bad, 0.05); }, "differ in length");
  bad = seg;
  bad.deflection_mm[10] = std::nan("");
  ExpectInputError([&] { EstimateFrequencyResponse(bad, 0.05); }, "non-finite");
  // The dead time outlasts the recording: the output never moves.
  const DataSegment late = Record({{1.0}, {1.0, 1.0}, 50.0}, 0.1, 0.1, 4.0);
  ExpectInputError([&] { EstimateFrequencyResponse(late, 0.1); }, "output is constant");
  EXPECT_THROW(EstimateFrequencyResponse(seg, 0.0), std::invalid_argument);
  EXPECT_THROW(EstimateFrequencyResponse(seg, 0.05, 0), std::invalid_argument);
  EXPECT_THROW(EstimateFrequencyResponse(seg, 0.05, 5, -1), std::invalid_argument);
}

// 3 zeros / 4 poles + delay = 9 parameters; each point gives 2 real values.
TEST(FrequencyResponse, TooFewPointsForTheOrder) {
  const TransferFunction truth = SeedModel8V();
  const auto four = ExactPoints(truth, {0.0025, 0.02, 0.031, 0.054}, 1e-3);
  ExpectInputError([&] { FitFrequencyResponse(four); },
                   "4 points give 8 real values, fewer than the 9 parameters");
  ExpectInputError([&] { FitFrequencyResponse({}); }, "no frequency points");
  // Five points: determined on paper (10 values), reported as barely so.
  const auto five = ExactPoints(truth, {0.0025, 0.02, 0.031, 0.054, 0.11}, 1e-3);
  const FrequencyFit fit = FitFrequencyResponse(five);
  EXPECT_NE(fit.method_report.find("WARNING barely determined"), std::string::npos)
      << fit.method_report;
  // A lower order is what few points support.
  FrequencyFitOptions low;
  low.num_zeros = 1;
  low.num_poles = 2;
  EXPECT_NO_THROW(FitFrequencyResponse(four, low));
}

TEST(FrequencyResponse, OptionsValidation) {
  std::string error;
  EXPECT_TRUE(FrequencyFitOptions{}.IsValid(&error));
  FrequencyFitOptions options;
  options.num_poles = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_NE(error.find("num_poles"), std::string::npos);
  options = {};
  options.num_zeros = 5;
  EXPECT_FALSE(options.IsValid(&error));
  options = {};
  options.max_delay_s = -1.0;
  EXPECT_FALSE(options.IsValid(&error));
  options = {};
  options.delay_step_s = 0.0;
  EXPECT_FALSE(options.IsValid(&error));
  options = {};
  options.sk_iterations = 0;
  EXPECT_FALSE(options.IsValid(&error));
  EXPECT_THROW(FitFrequencyResponse(ExactPoints(LowOrderTruth(), {0.01, 0.1, 1.0}, 1e-3), options),
               std::invalid_argument);
  SquareWaveOptions square;
  EXPECT_TRUE(square.IsValid(&error));
  square.min_discard_s = -1.0;
  EXPECT_FALSE(square.IsValid(&error));
  square = {};
  square.max_harmonic = 0;
  EXPECT_FALSE(square.IsValid(&error));
  EXPECT_THROW(IdentifyFromSquareWaves({}, {}, square), std::invalid_argument);
}

}  // namespace
}  // namespace flexid::model
