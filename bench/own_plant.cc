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
// recording did not show), then how many are within 1.5 times the noise.
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

#include "model/core/simulate.h"
#include "model/identify/identify_global.h"
#include "ts_plant.h"

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
      "seed     rules  fit RMSE/noise  val RMSE/noise  dead time s (true)  fit s  structure\n");
  int within = 0;
  std::vector<double> ratios;
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
    const auto start = std::chrono::steady_clock::now();
    try {
      const model::GlobalEstimate e = model::IdentifyGlobalTs({fit.recording});
      const double fit_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      const std::vector<double> predicted =
          model::Simulate(e.model, check.recording.t_s, check.recording.voltage_V);
      double squares = 0.0;
      for (size_t k = 0; k < predicted.size(); ++k)
        squares += (predicted[k] - check.clean_mm[k]) * (predicted[k] - check.clean_mm[k]);
      const double ratio =
          std::sqrt(squares / static_cast<double>(predicted.size())) / plant.noise_std_mm;
      ratios.push_back(ratio);
      within += ratio <= 1.5;
      std::printf("%-8llu %5zu  %14.2f  %14.2f  %8.2f (%5.2f)  %7.1f  %s\n",
                  static_cast<unsigned long long>(seed), plant.rules.size(),
                  e.fit.rmse_mm / plant.noise_std_mm, ratio, e.delay_s.value, plant.delay_s, fit_s,
                  e.structure.Describe().c_str());
      if (std::getenv("OWN_PLANT_REASON")) std::printf("  %s\n", e.reason.c_str());
    } catch (const std::exception& error) {
      std::printf("%-8llu %5zu  failed: %s\n", static_cast<unsigned long long>(seed),
                  plant.rules.size(), error.what());
    }
  }
  std::sort(ratios.begin(), ratios.end());
  std::printf("own_plant: %d of %d draws within 1.5x the noise; median %.2fx\n", within, draws,
              ratios.empty() ? NAN : ratios[ratios.size() / 2]);
  return 0;
}
