// Identification time for one 3-zero / 4-pole model with dead time, one core.
// DESIGN.md targets: < 50 ms for 11,000 samples (1100 s at 10 Hz), < 500 ms for 110,000.
//
//   build/bench/identify_bench
//
// Data: the seed's 8 V model under a 5 V square wave (220 s period), with white sensor
// noise of 1 % of the peak deflection, so the solver does real work.
#include <benchmark/benchmark.h>

#include <random>

#include "model/identify.h"
#include "model/presets.h"
#include "model/simulate.h"

namespace {

using namespace flexid::model;

DataSegment Recording(size_t samples) {
  DataSegment seg;
  seg.dt_s = 0.1;
  for (size_t k = 0; k < samples; ++k)
    seg.voltage_V.push_back(std::fmod(0.1 * static_cast<double>(k), 220.0) < 110.0 ? 5.0 : 0.0);
  seg.deflection_mm = SimulateUniform(SeedModel8V(), seg.dt_s, seg.voltage_V);
  std::mt19937 rng(1);
  std::normal_distribution<double> noise(0.0, 0.01 * 5.0 * DcGain(SeedModel8V()));
  for (double& y : seg.deflection_mm) y += noise(rng);
  return seg;
}

void BM_IdentifyOneModel(benchmark::State& state) {
  const std::vector<DataSegment> data = {Recording(static_cast<size_t>(state.range(0)))};
  for (auto _ : state) benchmark::DoNotOptimize(IdentifyTransferFunction(data));
  state.counters["samples"] = static_cast<double>(state.range(0));
}
BENCHMARK(BM_IdentifyOneModel)
    ->Arg(11'000)
    ->Arg(110'000)
    ->Unit(benchmark::kMillisecond)
    ->Repetitions(5)
    ->ReportAggregatesOnly(true);

}  // namespace

BENCHMARK_MAIN();
