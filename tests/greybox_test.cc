// Grey-box identification against known physical parameters. The recordings are made
// without the simulator under test: the curvature transfer function (physics.h, checked
// in physics_test) is integrated with the RK4 reference of test_util.h, the dead time is a
// shift of the input function, and the arc map is written out here.
#include "model/physics/greybox.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "test_util.h"

namespace flexid::model {
namespace {

constexpr double kDt_s = 0.1;        // 10 Hz, the seed's sampling
constexpr double kPeriod_s = 220.0;  // square wave of the seed's repeatability test
constexpr double kLevel_V = 5.0;
// 2 s = 20 samples: the delayed switches fall on RK4 step boundaries, so the reference is
// exact to ~1e-12 mm (a switch inside an RK4 step would cost ~1e-4 mm).
constexpr double kTrueDelay_s = 2.0;
// RK4 step of the reference: the fastest poles of the truths here are below 3 rad/s (the
// cell pole of the 3-term model; 1.4 rad/s for S1), so the local error per step,
// ~(h w)^5 / 120, is below 1e-12 at h = 2.5 ms.
constexpr double kRk4Step_s = 0.0025;

// The "true" gel: seed S1 parameters with a faster diffusion and a thinner double layer,
// so that the fit has to move from its start (SeedS1Parameters()).
PhysicalParameters TrueS1() {
  PhysicalParameters p = SeedS1Parameters();
  p.D_m2_per_s *= 1.7;
  p.delta_m *= 0.6;
  return p;
}

// Tip deflection of an arc of length L and curvature K, in mm (written out, not
// TipDeflectionFromCurvature_m).
double ArcDeflection_mm(double curvature_per_m, double L_m) {
  if (std::abs(curvature_per_m * L_m) < 1e-6) return 1e3 * 0.5 * curvature_per_m * L_m * L_m;
  return 1e3 * (1.0 - std::cos(curvature_per_m * L_m)) / curvature_per_m;
}

struct Protocol {
  double period_s = kPeriod_s;  // 5 V square wave, 50 % duty, starting high at t = 0
  int periods = 3;
  double delay_s = kTrueDelay_s;
};

struct Recording {
  DataSegment segment;           // deflection with noise
  std::vector<double> clean_mm;  // the truth's deflection
  double peak_mm = 0.0;
};

// The protocol applied from rest to a beam with the truth's parameters, sampled at 10 Hz;
// white noise of noise_fraction times the peak deflection (fixed seed).
Recording Record(const PhysicalParameters& truth, const Protocol& protocol, double noise_fraction,
                 unsigned seed) {
  const TransferFunction tf =
      CurvatureTransferFunction(truth, 3, 0.0, SeriesRemainder::kStaticCorrection);
  auto square = [&](double t_s) {
    if (t_s < 0.0) return 0.0;
    return std::fmod(t_s, protocol.period_s) < 0.5 * protocol.period_s ? kLevel_V : 0.0;
  };
  const size_t count =
      static_cast<size_t>(std::lround(protocol.periods * protocol.period_s / kDt_s));
  std::vector<double> t_s(count);
  for (size_t k = 0; k < count; ++k) t_s[k] = static_cast<double>(k) * kDt_s;
  Recording r;
  r.segment.dt_s = kDt_s;
  // The square wave switches on the sample grid, so its zero-order hold is itself.
  for (double t : t_s) r.segment.voltage_V.push_back(square(t));
  const std::vector<double> curvature = testing::IntegrateRk4(
      tf, t_s, [&](double t) { return square(t - protocol.delay_s); }, kRk4Step_s);
  for (double k : curvature) {
    r.clean_mm.push_back(ArcDeflection_mm(k, truth.L_m));
    r.peak_mm = std::max(r.peak_mm, std::abs(r.clean_mm.back()));
  }
  r.segment.deflection_mm = r.clean_mm;
  if (noise_fraction > 0.0) {
    std::mt19937 rng(seed);
    std::normal_distribution<double> noise(0.0, noise_fraction * r.peak_mm);
    for (double& y : r.segment.deflection_mm) y += noise(rng);
  }
  return r;
}

const ParameterEstimate& Find(const std::vector<ParameterEstimate>& list, const std::string& name) {
  for (const ParameterEstimate& e : list)
    if (e.name == name) return e;
  throw std::logic_error("no estimate named " + name);
}

// The estimates with their relative half-widths, for the test log.
void Report(const GreyBoxEstimate& e) {
  for (const auto* list : {&e.estimates, &e.combinations})
    for (const ParameterEstimate& p : *list)
      std::printf("  %-26s %.6g +- %.3g (%.3g %%)\n", p.name.c_str(), p.value, p.half_width_95,
                  100.0 * p.half_width_95 / std::abs(p.value));
  std::printf("  fit %.3f %%, rmse %.3g mm; %s\n", e.fit.fit_percent, e.fit.rmse_mm,
              e.solver_report.c_str());
}

void ExpectRelativelyNear(double actual, double expected, double relative, const char* what) {
  EXPECT_NEAR(actual, expected, relative * std::abs(expected)) << what;
}

// Noise-free: the 3-term model is locally identifiable in (D, delta, alpha C_dl, R_s C_dl,
// T), so with C_dl fixed at its true value every parameter is recovered. The tolerance is
// the brief's 1 %; the fit gets ~1e-8 % (the reference is exact to ~1e-12 mm). delta,
// alpha and R_s individually hang on a ~3e-6-relative effect (header), so this shows the
// solver's convergence, not that they are determined by real data (see the noisy test).
TEST(GreyBox, NoiseFreeRecoversMaterialAndDelay) {
  const PhysicalParameters truth = TrueS1();
  const Recording r = Record(truth, {}, 0.0, 0);
  const GreyBoxEstimate e = IdentifyPhysics({r.segment}, SeedS1Parameters());
  Report(e);
  ExpectRelativelyNear(e.parameters.D_m2_per_s, truth.D_m2_per_s, 0.01, "D");
  ExpectRelativelyNear(e.parameters.delta_m, truth.delta_m, 0.01, "delta");
  ExpectRelativelyNear(e.parameters.alpha_m3_per_C, truth.alpha_m3_per_C, 0.01, "alpha");
  ExpectRelativelyNear(e.parameters.R_s_ohm, truth.R_s_ohm, 0.01, "R_s");
  ExpectRelativelyNear(e.delay_s, kTrueDelay_s, 0.01, "delay");
  // Fixed ones as given.
  EXPECT_EQ(e.parameters.C_dl_F, SeedS1Parameters().C_dl_F);
  EXPECT_EQ(e.parameters.L_m, truth.L_m);
  EXPECT_EQ(e.parameters.h_m, truth.h_m);
  EXPECT_LT(e.fit.rmse_mm, 1e-6 * r.peak_mm);
  // The reported transfer function is the fitted chain.
  const TransferFunction expected =
      CurvatureTransferFunction(e.parameters, 3, e.delay_s, SeriesRemainder::kStaticCorrection);
  EXPECT_EQ(e.curvature_tf.num, expected.num);
  EXPECT_EQ(e.curvature_tf.den, expected.den);
  EXPECT_EQ(e.curvature_tf.delay_s, e.delay_s);
  ASSERT_EQ(e.estimates.size(), 5u);
  EXPECT_EQ(e.estimates[0].name, "D_m2_per_s");
  EXPECT_EQ(e.estimates[4].name, "delay_s");
}

// 1 % white noise (0.09 mm on a 9 mm peak). What the data determine: D (slowest diffusion
// time constant), the DC curvature per volt (alpha C_dl (1 + h/delta)), the cell time
// constant R_s C_dl (1 + h/delta) and T. What they do not: delta, and so alpha and R_s
// separately (they are known only times 1 + h/delta). The intervals must say so.
TEST(GreyBox, NoisyIntervalsAreHonestAndValidationMatchesTruth) {
  const PhysicalParameters truth = TrueS1();
  const Recording r = Record(truth, {}, 0.01, 7);
  const GreyBoxEstimate e = IdentifyPhysics({r.segment}, SeedS1Parameters());
  Report(e);

  // The residual is the added white noise: it passes the whiteness test (5 % level).
  EXPECT_TRUE(e.fit.whiteness.passed) << e.fit.whiteness.ljung_box_q;
  EXPECT_NEAR(e.noise_std_mm, 0.01 * r.peak_mm, 0.05 * 0.01 * r.peak_mm);

  // Coverage: truth within 2 half-widths (a fixed seed; 2 rather than 1 so that the test
  // does not depend on this one draw landing inside the nominal 95 %).
  for (const auto& [name, value] : {std::pair<std::string, double>{"D_m2_per_s", truth.D_m2_per_s},
                                    {"alpha_m3_per_C", truth.alpha_m3_per_C},
                                    {"delta_m", truth.delta_m},
                                    {"R_s_ohm", truth.R_s_ohm},
                                    {"delay_s", kTrueDelay_s}}) {
    const ParameterEstimate& p = Find(e.estimates, name);
    EXPECT_LE(std::abs(p.value - value), 2.0 * p.half_width_95) << name;
  }
  const double dc_truth = DcCurvaturePerVolt(truth);
  const double cell_truth = truth.R_s_ohm * truth.C_dl_F * (1.0 + truth.h_m / truth.delta_m);
  const ParameterEstimate& dc = Find(e.combinations, "dc_curvature_per_m_V");
  const ParameterEstimate& cell = Find(e.combinations, "cell_time_constant_s");
  const ParameterEstimate& diffusion = Find(e.combinations, "diffusion_time_constant_s");
  EXPECT_LE(std::abs(dc.value - dc_truth), 2.0 * dc.half_width_95);
  EXPECT_LE(std::abs(cell.value - cell_truth), 2.0 * cell.half_width_95);
  EXPECT_LE(std::abs(diffusion.value - SlowestDiffusionTimeConstant_s(truth)),
            2.0 * diffusion.half_width_95);

  // Determined: narrow intervals (this run: D 3.8 %, DC curvature 0.05 %, T 0.065 s).
  EXPECT_LT(Find(e.estimates, "D_m2_per_s").half_width_95, 0.10 * e.parameters.D_m2_per_s);
  EXPECT_LT(dc.half_width_95, 0.01 * dc.value);
  EXPECT_LT(Find(e.estimates, "delay_s").half_width_95, 0.25);
  // Not determined: half-width larger than the value (this run: ~400 % each).
  for (const char* name : {"delta_m", "alpha_m3_per_C", "R_s_ohm"})
    EXPECT_GT(Find(e.estimates, name).half_width_95, Find(e.estimates, name).value) << name;

  // Fresh validation recording (other period, other noise): the fitted model's fit is
  // within 0.5 points of the truth's own fit on it.
  const Recording validation = Record(truth, {.period_s = 150.0, .periods = 3}, 0.01, 11);
  const std::vector<double> predicted =
      PredictDeflection_mm(e.parameters, e.delay_s, 3, validation.segment);
  const double fit_model = FitPercent(validation.segment.deflection_mm, predicted);
  const double fit_truth = FitPercent(validation.segment.deflection_mm, validation.clean_mm);
  std::printf("  validation fit: model %.3f %%, truth %.3f %%\n", fit_model, fit_truth);
  EXPECT_GT(fit_model, fit_truth - 0.5);
}

// Fit on S1 (noisy), predict S4 (20 x 8 x 2 mm) of the same material with WithGeometry.
TEST(GreyBox, PredictsAnotherGeometry) {
  const PhysicalParameters truth = TrueS1();
  const Recording s1 = Record(truth, {}, 0.01, 3);
  const GreyBoxEstimate e = IdentifyPhysics({s1.segment}, SeedS1Parameters());
  const Table1Measurement& s4 = kSeedTable1[3];
  auto s4_geometry = [&](const PhysicalParameters& p) {
    return WithGeometry(p, 1e-3 * s4.L_mm, 1e-3 * s4.W_mm, 1e-3 * s4.h_mm);
  };
  const Recording s4_truth = Record(s4_geometry(truth), {}, 0.0, 0);
  const std::vector<double> predicted =
      PredictDeflection_mm(s4_geometry(e.parameters), e.delay_s, 3, s4_truth.segment);
  const double rmse = Rmse(s4_truth.clean_mm, predicted);
  std::printf("  S4 peak %.3f mm, prediction RMSE %.4f mm (%.2f %% of peak)\n", s4_truth.peak_mm,
              rmse, 100.0 * rmse / s4_truth.peak_mm);
  EXPECT_LT(rmse, 0.02 * s4_truth.peak_mm);
}

// C_dl is not identifiable (header): start with C_dl twice the truth's. The fit then
// reports alpha and R_s halved (so that alpha C_dl and R_s C_dl are the truth's), D, delta
// and T unchanged, and the prediction for another geometry equals the truth's. Noise-free,
// so the products are checked to 1e-6.
TEST(GreyBox, DoubleLayerCapacitanceScalesOutOfPredictions) {
  const PhysicalParameters truth = TrueS1();
  const Recording r = Record(truth, {}, 0.0, 0);
  PhysicalParameters start = SeedS1Parameters();
  start.C_dl_F *= 2.0;
  const GreyBoxEstimate e = IdentifyPhysics({r.segment}, start);
  const PhysicalParameters& p = e.parameters;
  EXPECT_EQ(p.C_dl_F, start.C_dl_F);
  ExpectRelativelyNear(p.alpha_m3_per_C * p.C_dl_F, truth.alpha_m3_per_C * truth.C_dl_F, 1e-6,
                       "alpha C_dl");
  ExpectRelativelyNear(p.R_s_ohm * p.C_dl_F, truth.R_s_ohm * truth.C_dl_F, 1e-6, "R_s C_dl");
  ExpectRelativelyNear(p.D_m2_per_s, truth.D_m2_per_s, 1e-6, "D");
  ExpectRelativelyNear(p.delta_m, truth.delta_m, 1e-6, "delta");
  ExpectRelativelyNear(e.delay_s, kTrueDelay_s, 1e-6, "delay");
  const Recording s2 = Record(WithGeometry(truth, 0.04, 0.008, 0.001), {}, 0.0, 0);
  const std::vector<double> predicted =
      PredictDeflection_mm(WithGeometry(p, 0.04, 0.008, 0.001), e.delay_s, 3, s2.segment);
  EXPECT_LT(Rmse(s2.clean_mm, predicted), 1e-6 * s2.peak_mm);
}

// max_delay_s = 0 fixes the dead time at 0 (and reports it exactly, half-width 0).
TEST(GreyBox, ZeroMaxDelayFixesTheDeadTime) {
  const PhysicalParameters truth = TrueS1();
  const Recording r = Record(truth, {.delay_s = 0.0}, 0.0, 0);
  const GreyBoxEstimate e = IdentifyPhysics({r.segment}, SeedS1Parameters(), {.max_delay_s = 0.0});
  EXPECT_EQ(e.delay_s, 0.0);
  EXPECT_EQ(Find(e.estimates, "delay_s").half_width_95, 0.0);
  ExpectRelativelyNear(e.parameters.D_m2_per_s, truth.D_m2_per_s, 1e-6, "D");
}

// A segment that starts in steady state under its initial voltage and stays there: the
// prediction is the steady deflection (exact DC of physics.h; the static correction makes
// the 3-term DC exact) at every sample.
TEST(GreyBox, PredictionStartsInSteadyStateUnderTheInitialVoltage) {
  const PhysicalParameters p = SeedS1Parameters();
  DataSegment seg;
  seg.dt_s = kDt_s;
  seg.voltage_V.assign(50, kLevel_V);
  seg.deflection_mm.assign(50, 0.0);
  seg.initial_voltage_V = kLevel_V;
  const double steady_mm = SteadyTipDeflection_mm(p, kLevel_V);
  EXPECT_NEAR(steady_mm, 5.92, 1e-9);  // Table 1, S1 (alpha is calibrated to it)
  for (double y : PredictDeflection_mm(p, 1.0, 3, seg)) EXPECT_NEAR(y, steady_mm, 1e-9);
}

TEST(GreyBox, RejectsBadDataOptionsAndStart) {
  const PhysicalParameters start = SeedS1Parameters();
  DataSegment good;
  good.dt_s = kDt_s;
  for (int k = 0; k < 400; ++k) {
    good.voltage_V.push_back(k < 200 ? kLevel_V : 0.0);
    good.deflection_mm.push_back(0.01 * k);
  }
  auto with = [&](auto change) {
    DataSegment seg = good;
    change(seg);
    return std::vector<DataSegment>{seg};
  };
  EXPECT_THROW(IdentifyPhysics({}, start), InputError);
  // Constant input held before the segment too: no step anywhere.
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) {
                                 s.voltage_V.assign(400, 5.0);
                                 s.initial_voltage_V = 5.0;
                               }),
                               start),
               InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) {
                                 s.deflection_mm[17] = std::numeric_limits<double>::quiet_NaN();
                               }),
                               start),
               InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) {
                                 s.voltage_V[3] = std::numeric_limits<double>::infinity();
                               }),
                               start),
               InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) { s.deflection_mm.pop_back(); }), start),
               InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) { s.dt_s = 0.0; }), start), InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) { s.fit_begin = 400; }), start), InputError);
  EXPECT_THROW(IdentifyPhysics(with([](DataSegment& s) {
                                 s.voltage_V.resize(60);
                                 s.deflection_mm.resize(60);
                               }),
                               start),
               InputError);  // too short
  try {
    IdentifyPhysics(with([](DataSegment& s) {
                      s.voltage_V.assign(400, 5.0);
                      s.initial_voltage_V = 5.0;
                    }),
                    start);
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()).find('\n'), std::string::npos);  // one line
  }

  for (const GreyBoxOptions& bad :
       {GreyBoxOptions{.terms = 0}, GreyBoxOptions{.terms = kMaxTransferFunctionTerms + 1},
        GreyBoxOptions{.max_delay_s = -1.0},
        GreyBoxOptions{.max_delay_s = std::numeric_limits<double>::quiet_NaN()},
        GreyBoxOptions{.max_iterations = 0}, GreyBoxOptions{.correlation_lags = 0}}) {
    std::string why;
    EXPECT_FALSE(bad.IsValid(&why));
    EXPECT_FALSE(why.empty());
    EXPECT_THROW(IdentifyPhysics({good}, start, bad), std::invalid_argument);
  }
  EXPECT_TRUE(GreyBoxOptions{}.IsValid(nullptr));
  PhysicalParameters bad_start = start;
  bad_start.delta_m = 0.0;
  EXPECT_THROW(IdentifyPhysics({good}, bad_start), std::invalid_argument);

  EXPECT_THROW(PredictDeflection_mm(start, -1.0, 3, good), std::invalid_argument);
  EXPECT_THROW(PredictDeflection_mm(start, 0.0, 0, good), std::invalid_argument);
  EXPECT_THROW(PredictDeflection_mm(bad_start, 0.0, 3, good), std::invalid_argument);
  DataSegment no_period = good;
  no_period.dt_s = -0.1;
  EXPECT_THROW(PredictDeflection_mm(start, 0.0, 3, no_period), std::invalid_argument);
}

}  // namespace
}  // namespace flexid::model
