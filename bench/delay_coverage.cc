// Coverage of the dead time's 95 % interval over fresh noise draws (issue 12: "intervals
// that mean something"). Each draw: the seed's 8 V model under its protocol (a 5 V square
// wave, 220 s period, 11,000 samples at 10 Hz) with white sensor noise of 1 % of the peak
// deflection, identified by the global fit (identify_global.h, what `flexid identify`
// runs) with its structure chosen on held-out data. Prints, per draw, the dead time with
// its interval and whether it covers the true 3.67 s, then the coverage, the mean error
// and the DC gain's coverage for comparison.
//
//   build/bench/delay_coverage [DRAWS]        (default 20)
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <random>
#include <string>

#include "model/core/presets.h"
#include "model/core/simulate.h"
#include "model/identify/identify_global.h"

int main(int argc, char** argv) {
  using namespace flexid::model;
  const int draws = argc > 1 ? std::atoi(argv[1]) : 20;
  if (draws < 1) {
    std::fprintf(stderr, "delay_coverage: DRAWS must be a positive integer\n");
    return 2;
  }
  const TransferFunction plant = SeedModel8V();
  const double true_delay_s = plant.delay_s, true_gain = DcGain(plant);
  Recording rec;
  rec.source = "coverage.csv";
  for (int k = 0; k < 11'000; ++k) {
    rec.t_s.push_back(0.1 * k);
    rec.voltage_V.push_back(std::fmod(0.1 * k, 220.0) < 110.0 ? 5.0 : 0.0);
  }
  const std::vector<double> clean = SimulateUniform(SingleRule(plant), 0.1, rec.voltage_V);
  const double sigma_mm = 0.01 * 5.0 * true_gain;
  int delay_covered = 0, gain_covered = 0;
  double error_sum_s = 0.0;
  std::printf(
      "draw  structure                 dead time s     +- 95 %%  covers %.2f s  DC gain  covers\n",
      true_delay_s);
  for (int d = 0; d < draws; ++d) {
    std::mt19937 rng(static_cast<unsigned>(1000 + d));
    std::normal_distribution<double> noise(0.0, sigma_mm);
    rec.deflection_mm = clean;
    for (double& y : rec.deflection_mm) y += noise(rng);
    const GlobalEstimate e = IdentifyGlobalTs({rec});
    const bool delay_in = std::abs(e.delay_s.value - true_delay_s) <= e.delay_s.half_width_95;
    const ParameterEstimate& gain = e.rules.front().dc_gain;
    const bool gain_in = std::abs(gain.value - true_gain) <= gain.half_width_95;
    delay_covered += delay_in;
    gain_covered += gain_in;
    error_sum_s += e.delay_s.value - true_delay_s;
    std::printf("%4d  %-24s %11.3f  %10.3f  %-13s %7.4f  %s\n", d,
                (std::to_string(e.structure.num_poles) + " poles, " +
                 std::to_string(e.structure.num_zeros) + " zeros")
                    .c_str(),
                e.delay_s.value, e.delay_s.half_width_95, delay_in ? "yes" : "no", gain.value,
                gain_in ? "yes" : "no");
  }
  std::printf("dead time: interval covers the truth in %d of %d draws; mean error %+.3f s\n",
              delay_covered, draws, error_sum_s / draws);
  std::printf("DC gain:   interval covers the truth in %d of %d draws\n", gain_covered, draws);
  return 0;
}
