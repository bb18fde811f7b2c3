// T-S identification from recordings of a voltage-dependent truth.
#include "model/identify/identify_ts.h"

#include <gtest/gtest.h>

#include <random>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/presets.h"
#include "model/core/simulate.h"

namespace flexid::model {
namespace {

constexpr double kDt_s = 0.1;

// A voltage-dependent actuator that is not a T-S model: the 2 V seed dynamics after a
// static gain that grows with voltage, y = G(s) f(u), f(u) = u (4 + 0.6 |u|) / K_G, so
// that the steady deflection per volt rises from 5.2 at 2 V to 8.8 at 8 V (the seed's
// 2 V and 8 V gains are 5.3 and 8.7).
std::vector<double> HammersteinTruth(const std::vector<double>& voltage_V) {
  const TransferFunction g = SeedModel2V();
  std::vector<double> drive(voltage_V.size());
  for (size_t k = 0; k < drive.size(); ++k)
    drive[k] = voltage_V[k] * (4.0 + 0.6 * std::abs(voltage_V[k])) / DcGain(g);
  return SimulateUniform(g, kDt_s, drive);
}

// Voltage held at each level for dwell_s, sampled at 10 Hz, simulated through the
// Hammerstein truth from rest, with white noise of noise_fraction of the peak deflection.
Recording Staircase(const std::vector<double>& levels_V, double dwell_s, double noise_fraction,
                    unsigned seed, const std::string& name) {
  Recording rec;
  rec.source = name;
  const size_t per_level = static_cast<size_t>(std::lround(dwell_s / kDt_s));
  for (double level : levels_V)
    for (size_t k = 0; k < per_level; ++k) {
      rec.t_s.push_back(kDt_s * static_cast<double>(rec.t_s.size()));
      rec.voltage_V.push_back(level);
    }
  rec.deflection_mm = HammersteinTruth(rec.voltage_V);
  double peak = 0.0;
  for (double y : rec.deflection_mm) peak = std::max(peak, std::abs(y));
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_fraction * peak);
  for (double& y : rec.deflection_mm) y += noise(rng);
  return rec;
}

double Rmse(const TsModel& model, const Recording& rec) {
  return model::Rmse(rec.deflection_mm, Simulate(model, rec.t_s, rec.voltage_V));
}

TEST(IdentifyTs, StaircaseBlendBeatsEverySingleLevelModelOnValidation) {
  // Fit on 0-2-4-6-8-0 V, validate on 0-7-3-5-1-0 V, both from the Hammerstein truth.
  const Recording fit_data = Staircase({0, 2, 4, 6, 8, 0}, 400.0, 0.005, 1, "staircase.csv");
  const Recording validation = Staircase({0, 7, 3, 5, 1, 0}, 400.0, 0.005, 2, "validation.csv");
  const TsEstimate estimate = IdentifyTsModel({fit_data});
  ASSERT_EQ(estimate.local.size(), 4u);
  for (size_t i = 0; i < 4; ++i)
    EXPECT_NEAR(estimate.local[i].level_V, 2.0 * static_cast<double>(i + 1), 0.01);
  const double blend_rmse = Rmse(estimate.model, validation);
  double best_single = INFINITY;
  for (const LocalModelReport& local : estimate.local)
    best_single = std::min(best_single, Rmse(SingleRule(local.estimate.tf), validation));
  EXPECT_LT(blend_rmse, 0.7 * best_single)
      << "T-S validation RMSE " << blend_rmse << " mm, best single-level model " << best_single
      << " mm";
  // Leave one level out: every level reported; the end levels are extrapolations from one
  // neighbour and must come out worse than with their own local model.
  ASSERT_EQ(estimate.leave_one_level_out.size(), 4u);
  for (const LevelOutReport& report : estimate.leave_one_level_out)
    EXPECT_TRUE(std::isfinite(report.left_out_rmse_mm)) << report.level_V << " V";
  EXPECT_GT(estimate.leave_one_level_out.front().left_out_rmse_mm,
            estimate.leave_one_level_out.front().in_sample_rmse_mm);
}

TEST(IdentifyTs, BlendBetweenIdentifiedLevelsStaysPhysical) {
  // Between identified levels every frozen model is stable and its DC gain lies between
  // the neighbouring local gains; a step from one level to the next moves the output
  // monotonically towards the new steady state, without a spike.
  const Recording data = Staircase({0, 2, 4, 6, 8, 0}, 400.0, 0.005, 3, "staircase.csv");
  const TsEstimate estimate = IdentifyTsModel({data});
  ASSERT_EQ(estimate.local.size(), 4u);
  for (size_t i = 0; i + 1 < estimate.local.size(); ++i) {
    const double low = DcGain(estimate.local[i].estimate.tf),
                 high = DcGain(estimate.local[i + 1].estimate.tf);
    for (double w = 0.05; w < 1.0; w += 0.05) {
      const double z = (1 - w) * estimate.local[i].level_V + w * estimate.local[i + 1].level_V;
      const TransferFunction frozen = FrozenModelAt(estimate.model, z);
      EXPECT_TRUE(IsStable(frozen)) << z << " V";
      EXPECT_GE(DcGain(frozen), std::min(low, high) - 1e-9) << z << " V";
      EXPECT_LE(DcGain(frozen), std::max(low, high) + 1e-9) << z << " V";
    }
  }
  // 3 V held until steady, then 5 V (both between levels).
  std::vector<double> u(30000, 3.0);
  std::fill(u.begin() + 15000, u.end(), 5.0);
  const std::vector<double> y = SimulateUniform(estimate.model, kDt_s, u);
  const double before = y[14999], after = y.back();
  for (size_t k = 15000; k < y.size(); ++k) {
    ASSERT_GT(y[k], before - 0.02 * (after - before)) << k;
    ASSERT_LT(y[k], after + 0.02 * (after - before)) << k;
  }
}

TEST(IdentifyTs, TwoSquareWaveRecordingsGiveTwoLevels) {
  // With the held scheduling, a 0 <-> 8 V square wave of the blend is the 8 V model alone.
  TsModel truth = SeedTsModel();
  truth.scheduling = SchedulingVariable::kAbsVoltageHeld;
  truth.rest_band_V = 0.1;
  Recording low, high;
  for (auto [rec, level, name] :
       {std::tuple{&low, 2.0, "low.csv"}, std::tuple{&high, 8.0, "high.csv"}}) {
    rec->source = name;
    for (size_t k = 0; k < 6600; ++k) {
      rec->t_s.push_back(kDt_s * static_cast<double>(k));
      rec->voltage_V.push_back(std::fmod(kDt_s * static_cast<double>(k), 220.0) < 110.0 ? level
                                                                                        : 0.0);
    }
    rec->deflection_mm = SimulateUniform(truth, kDt_s, rec->voltage_V);
  }
  const TsEstimate estimate = IdentifyTsModel({low, high});
  ASSERT_EQ(estimate.local.size(), 2u);
  // Each level's local model is the truth's frozen model there (noise-free data).
  EXPECT_NEAR(DcGain(estimate.local[0].estimate.tf), DcGain(SeedModel2V()),
              0.01 * DcGain(SeedModel2V()));
  EXPECT_NEAR(DcGain(estimate.local[1].estimate.tf), DcGain(SeedModel8V()),
              0.01 * DcGain(SeedModel8V()));
  EXPECT_GT(estimate.fit.fit_percent, 99.9);
  EXPECT_EQ(estimate.leave_one_level_out.size(), 2u);
}

TEST(IdentifyTs, NonUniformTimeIsResampledAndSaid) {
  const TsModel truth = SingleRule(SeedModel2V());
  Recording rec;
  rec.source = "jittered.csv";
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> jitter(-0.02, 0.02);
  for (size_t k = 0; k < 6600; ++k) {
    rec.t_s.push_back(kDt_s * static_cast<double>(k) + (k > 0 ? jitter(rng) : 0.0));
    rec.voltage_V.push_back(std::fmod(kDt_s * static_cast<double>(k), 220.0) < 110.0 ? 2.0 : 0.0);
  }
  rec.deflection_mm = Simulate(truth, rec.t_s, rec.voltage_V);
  const TsEstimate estimate = IdentifyTsModel({rec});
  ASSERT_EQ(estimate.notes.size(), 1u);
  EXPECT_NE(estimate.notes[0].find("resampled"), std::string::npos);
  EXPECT_NEAR(DcGain(estimate.local[0].estimate.tf), DcGain(SeedModel2V()),
              0.02 * DcGain(SeedModel2V()));
}

TEST(IdentifyTs, BadRecordingsNameTheFile) {
  Recording flat;
  flat.source = "flat.csv";
  for (size_t k = 0; k < 1000; ++k) {
    flat.t_s.push_back(0.1 * static_cast<double>(k));
    flat.voltage_V.push_back(5.0);
    flat.deflection_mm.push_back(0.0);
  }
  try {
    IdentifyTsModel({flat});
    FAIL() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("flat.csv"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("constant"), std::string::npos) << e.what();
  }
  EXPECT_THROW(IdentifyTsModel({}), InputError);
}

}  // namespace
}  // namespace flexid::model
