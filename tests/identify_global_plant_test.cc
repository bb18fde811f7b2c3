// Global T-S identification (model/identify/identify_global.h) on plants of the independent
// T-S plant (ts_plant.h): fits on a staircase, scored on a fresh multilevel recording
// against the noise-free deflection.
//
// Known gap (issue 12): on most draws of this plant family (each rule driven by its share
// of the input, an S-shaped onset from two slow modes of 15-110 s, 80 s holds of 1 V
// steps) the staircase is fitted to the noise by models that differ on larger jumps, and
// the dead time trades against the slow onset: seed 101 predicts at 13 sigma with a dead
// time of 10 s (true 4.6 s), seed 202 at 22 sigma with 0 s (true 5.9 s). Seed 101 passed
// (0.29 sigma) before the fits moved to secant Jacobians and structures to a signed-rank
// test; over seeds 7100-7109 that change took 3 of 10 passes to 2 of 10. Both tests are
// registered WILL_FAIL (tests/CMakeLists.txt) so that they run in every build and show
// when the identifier reaches the bar: then they "fail" and WILL_FAIL goes. Since stage 6
// tries few smooth rules in both realisations, seed 101 predicts at 2.9 sigma with 10 s,
// seed 202 at 1.1 sigma with 10 s +- 0.25 s (its dead time check still fails).
// bench/own_plant prints the figures over fresh draws.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <iostream>
#include <string>
#include <vector>

#include "effect_battery.h"
#include "model/core/simulate.h"
#include "model/core/transfer_function.h"
#include "model/identify/identify_global.h"
#include "ts_plant.h"

namespace flexid::testing {
namespace {

// Fits on a staircase (80 s per level, 12,901 samples) with default options, then
// predicts a fresh 600 s multilevel recording; seeds fixed before the first run.
// `checks`: the prediction within 1.5 times the noise, the dead time (within 1.5 s of the
// plant's, or said to be undetermined, and in its interval), or both.
enum class Checks { kPrediction, kDeadTime, kBoth };
void FitStaircaseAndPredictFreshLevels(uint64_t seed, Checks checks = Checks::kBoth) {
  const TsPlant plant = DrawTsPlant(seed);
  const std::string name = "ts-plant-" + std::to_string(seed);
  const TsRecording fit =
      RecordTsPlant(plant, TsStaircase(80.0), seed * 10 + 1, name + "-staircase.csv");
  const TsRecording check =
      RecordTsPlant(plant, TsRandomLevels(seed * 10 + 2), seed * 10 + 3, name + "-levels.csv");

  const auto start = std::chrono::steady_clock::now();
  const model::GlobalEstimate estimate = model::IdentifyGlobalTs({fit.recording});
  const double fit_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const std::vector<double> predicted =
      model::Simulate(estimate.model, check.recording.t_s, check.recording.voltage_V);
  double squares = 0.0;
  for (size_t k = 0; k < predicted.size(); ++k)
    squares += (predicted[k] - check.clean_mm[k]) * (predicted[k] - check.clean_mm[k]);
  const double rmse_mm = std::sqrt(squares / static_cast<double>(predicted.size()));
  const double ratio = rmse_mm / plant.noise_std_mm;

  const std::string summary = "seed " + std::to_string(seed) + ": validation RMSE " +
                              std::to_string(rmse_mm) + " mm = " + std::to_string(ratio) +
                              " sigma; dead time " + std::to_string(estimate.delay_s.value) +
                              " s (true " + std::to_string(plant.delay_s) +
                              " s); structure: " + estimate.structure.Describe();
  std::cout << summary << "\n  fit " << fit_s << " s, " << estimate.fits
            << " fits\n  reason: " << estimate.reason << "\n  plant: " << DescribeTsPlant(plant)
            << "\n";
  ::testing::Test::RecordProperty("rmse_over_sigma", std::to_string(ratio));
  ::testing::Test::RecordProperty("delay_found_s", std::to_string(estimate.delay_s.value));
  ::testing::Test::RecordProperty("delay_true_s", std::to_string(plant.delay_s));

  if (checks != Checks::kDeadTime) {
    EXPECT_LE(ratio, 1.5) << summary;
  }
  if (checks == Checks::kPrediction) return;
  // The dead time: within 1.5 s of the plant's, or said to be undetermined (it trades off
  // against the zeros of higher orders) with an interval that holds the plant's.
  const double delay_error_s = std::abs(estimate.delay_s.value - plant.delay_s);
  const bool said_undetermined =
      std::any_of(estimate.warnings.begin(), estimate.warnings.end(), [](const std::string& w) {
        return w.find("the dead time is not determined") != std::string::npos;
      });
  EXPECT_LE(delay_error_s, estimate.delay_s.half_width_95)
      << summary << ": +- " << estimate.delay_s.half_width_95 << " s";
  EXPECT_TRUE(delay_error_s <= 1.5 || said_undetermined)
      << summary << ": +- " << estimate.delay_s.half_width_95 << " s";
}

// One of the draws of seeds 7100-7109 that reach the bar today (bench/own_plant 10 7100
// prints all ten): a guard that what works keeps working.
TEST(IdentifyGlobalPlant, Seed7103PredictsFreshLevelsWithinTheNoise) {
  FitStaircaseAndPredictFreshLevels(7103, Checks::kPrediction);
}

// Its dead time: the chosen three smooth rules of 4 poles and 3 zeros predict at 0.11
// times the noise with T = 5.4 +- 0.5 s, against the plant's 3.83 s: the zeros take part
// of the delay, and the profile interval, conditional on the structure, excludes it.
TEST(IdentifyGlobalPlant, KnownGapSeed7103DeadTimeWithinItsInterval) {
  FitStaircaseAndPredictFreshLevels(7103, Checks::kDeadTime);
}

TEST(IdentifyGlobalPlant, KnownGapSeed101PredictsFreshLevelsWithinTheNoise) {
  FitStaircaseAndPredictFreshLevels(101);
}

TEST(IdentifyGlobalPlant, KnownGapSeed202PredictsFreshLevelsWithinTheNoise) {
  FitStaircaseAndPredictFreshLevels(202);
}

// Two recordings of different protocols (the effect battery's identification recordings:
// a 1-8-1 V staircase and 600 s of random levels of both signs). Leaving one recording out
// in turn chose these draws' structures by how a fit on one protocol extrapolated to the
// other: they predicted fresh levels at 7.3 and 5.9 times the noise (2 poles and 1 zero,
// and 1 pole). With alternate tenths of both held out, both predict within the noise.
TEST(IdentifyGlobalPlant, TwoProtocolsAreBothSeenByEveryFold) {
  for (uint64_t seed : {424244ull, 424248ull}) {
    const BatteryCase battery_case = DrawBatteryCase(seed, {.effect = BatteryEffect::kNone});
    const model::GlobalEstimate estimate =
        model::IdentifyGlobalTs(RecordBatteryIdentification(battery_case));
    const TsPlant& plant = battery_case.plant;
    const TsRecording check = RecordTsPlant(plant, TsRandomLevels(seed * 10 + 2), seed * 10 + 3,
                                            "battery-" + std::to_string(seed) + "-levels.csv");
    const std::vector<double> predicted =
        model::Simulate(estimate.model, check.recording.t_s, check.recording.voltage_V);
    double squares = 0.0;
    for (size_t k = 0; k < predicted.size(); ++k)
      squares += (predicted[k] - check.clean_mm[k]) * (predicted[k] - check.clean_mm[k]);
    const double ratio =
        std::sqrt(squares / static_cast<double>(predicted.size())) / plant.noise_std_mm;
    EXPECT_LE(ratio, 1.5) << "seed " << seed << ": " << estimate.structure.Describe() << "\n"
                          << estimate.reason;
    EXPECT_NE(estimate.reason.find("alternate tenths of every recording"), std::string::npos)
        << estimate.reason;
  }
}

}  // namespace
}  // namespace flexid::testing
