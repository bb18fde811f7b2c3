// Global identification (model/identify/identify_global.h, what `flexid identify` runs) on fresh
// plants of the independent T-S test plant (tests/ts_plant.h: its own realisation, RK4
// integrator and smoothstep memberships on the delayed voltage; each rule driven by its
// share of the voltage). Per draw: fit on one recording, predict a fresh 600 s recording
// of random levels 0-8 V, score the RMSE against the noise-free deflection in units of the
// sensor noise. The fitted recording (PROTOCOL):
//   staircase    1-8-1 V in 1 V steps, 80 s per level (the default);
//   multilevel   1300 s of random levels 0-8 V, 40-120 s each, every level visited.
// Prints one line per draw (the in-sample fit's RMSE too, in the same unit: near 1 the
// fitted data are explained, and a large validation figure beside it is what the fitted
// recording did not show), then how many are within 1.5 times the noise. A second
// validation ("between") holds voltages drawn anywhere in 0-8 V rather than on whole
// volts: where the rules hand over between two fitted levels, only it shows what the model
// does there.
// OWN_PLANT_REASON=1 also prints why each structure was chosen. The seeds are fresh on
// every run (printed; pass FIRST_SEED to repeat a run).
//
//   build/bench/own_plant [DRAWS [FIRST_SEED [PROTOCOL]]]      (default 8 draws)
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>
#include <vector>

#include "model/core/metrics.h"
#include "model/core/simulate.h"
#include "model/identify/identify_global.h"
#include "ts_plant.h"

namespace {

// 10 s at 0 V, then voltages drawn uniformly in [0, 8] V, each held U(40, 120) s.
flexid::testing::TsProtocol BetweenLevels(uint64_t seed, double duration_s = 600.0) {
  flexid::testing::TsPlantRandom draw(seed);
  flexid::testing::TsProtocol protocol;
  protocol.samples = flexid::testing::TsSamplesIn(duration_s) + 1;
  for (size_t at = flexid::testing::TsSamplesIn(10.0); at < protocol.samples;
       at += flexid::testing::TsSamplesIn(draw.Uniform(40.0, 120.0)))
    protocol.holds.push_back({at, draw.Uniform(0.0, 8.0)});
  return protocol;
}

// RMSE of a model's prediction of a recording against its noise-free deflection.
double RmseMm(const flexid::model::TsModel& model, const flexid::testing::TsRecording& check) {
  return flexid::model::Rmse(check.clean_mm, flexid::model::Simulate(model, check.recording.t_s,
                                                                     check.recording.voltage_V));
}

}  // namespace

int main(int argc, char** argv) {
  using namespace flexid;
  const int draws = argc > 1 ? std::atoi(argv[1]) : 8;
  const uint64_t first =
      argc > 2 ? std::strtoull(argv[2], nullptr, 10) : std::random_device{}() % 1000000;
  const std::string protocol = argc > 3 ? argv[3] : "staircase";
  if (draws < 1) {
    std::fprintf(stderr, "own_plant: DRAWS must be a positive integer\n");
    return 2;
  }
  if (protocol != "staircase" && protocol != "multilevel") {
    std::fprintf(stderr, "own_plant: PROTOCOL must be staircase or multilevel, not '%s'\n",
                 protocol.c_str());
    return 2;
  }
  std::printf("own_plant: %d draws from seed %llu, fitted on a %s\n", draws,
              static_cast<unsigned long long>(first), protocol.c_str());
  std::printf(
      "seed     rules  fit RMSE/noise  val RMSE/noise  between/noise  dead time s (true)  fit s  "
      "structure\n");
  int within = 0, between_within = 0;
  std::vector<double> ratios, between_ratios;
  for (int d = 0; d < draws; ++d) {
    const uint64_t seed = first + static_cast<uint64_t>(d);
    const testing::TsPlant plant = testing::DrawTsPlant(seed);
    const testing::TsRecording fit =
        protocol == "staircase"
            ? testing::RecordTsPlant(plant, testing::TsStaircase(80.0), seed * 10 + 1,
                                     "own-plant-staircase.csv")
            : testing::RecordTsPlant(plant, testing::TsRandomLevels(seed * 10 + 4, 1300.0),
                                     seed * 10 + 1, "own-plant-multilevel.csv");
    const testing::TsRecording check = testing::RecordTsPlant(
        plant, testing::TsRandomLevels(seed * 10 + 2), seed * 10 + 3, "own-plant-levels.csv");
    const testing::TsRecording between = testing::RecordTsPlant(
        plant, BetweenLevels(seed * 10 + 5), seed * 10 + 6, "own-plant-between.csv");
    const auto start = std::chrono::steady_clock::now();
    try {
      const model::GlobalEstimate e = model::IdentifyGlobalTs({fit.recording});
      const double fit_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const double ratio = RmseMm(e.model, check) / plant.noise_std_mm;
      const double between_ratio = RmseMm(e.model, between) / plant.noise_std_mm;
      ratios.push_back(ratio);
      between_ratios.push_back(between_ratio);
      within += ratio <= 1.5;
      between_within += between_ratio <= 1.5;
      std::printf("%-8llu %5zu  %14.2f  %14.2f  %13.2f  %8.2f (%5.2f)  %7.1f  %s\n",
                  static_cast<unsigned long long>(seed), plant.rules.size(),
                  e.fit.rmse_mm / plant.noise_std_mm, ratio, between_ratio, e.delay_s.value,
                  plant.delay_s, fit_s, e.structure.Describe().c_str());
      if (std::getenv("OWN_PLANT_REASON")) std::printf("  %s\n", e.reason.c_str());
    } catch (const std::exception& error) {
      std::printf("%-8llu %5zu  failed: %s\n", static_cast<unsigned long long>(seed),
                  plant.rules.size(), error.what());
    }
  }
  std::sort(ratios.begin(), ratios.end());
  std::sort(between_ratios.begin(), between_ratios.end());
  std::printf("own_plant: %d of %d draws within 1.5x the noise; median %.2fx\n", within, draws,
              ratios.empty() ? NAN : ratios[ratios.size() / 2]);
  std::printf("own_plant: between the levels, %d of %d within 1.5x the noise; median %.2fx\n",
              between_within, draws,
              between_ratios.empty() ? NAN : between_ratios[between_ratios.size() / 2]);
  return 0;
}
