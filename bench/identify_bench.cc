// Identification time, one core.
// - One 3-zero / 4-pole model with dead time (identify.h). DESIGN.md targets: < 50 ms for
//   11,000 samples (1100 s at 10 Hz), < 500 ms for 110,000.
// - The global T-S fit with its structure chosen on held-out data (identify_global.h,
//   what `flexid identify` runs). Issue 12's goals: two trials of 6,600 samples < 1 s, a
//   20,000-sample staircase < 2 s.
//
//   build/bench/identify_bench
//
// Data: the seed's 8 V model under a 5 V square wave (220 s period), with white sensor
// noise of 1 % of the peak deflection, so the solver does real work. The global fit: the
// seed's T-S model (presets.h) under its protocol (2 V and 8 V square waves, 660 s each)
// and under a 1-8 V staircase (120 s per level, up and down), noise 0.02 mm.
#include <benchmark/benchmark.h>

#include <random>

#include "model/core/presets.h"
#include "model/core/simulate.h"
#include "model/identify/identify.h"
#include "model/identify/identify_global.h"

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

flexid::model::Recording TsRecording(std::vector<double> voltage_V, unsigned seed) {
  flexid::model::Recording rec;
  rec.source = "bench.csv";
  for (size_t k = 0; k < voltage_V.size(); ++k) rec.t_s.push_back(0.1 * static_cast<double>(k));
  rec.deflection_mm = SimulateUniform(SeedTsModel(), 0.1, voltage_V);
  rec.voltage_V = std::move(voltage_V);
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.02);
  for (double& y : rec.deflection_mm) y += noise(rng);
  return rec;
}

void BM_IdentifyGlobalTwoSquareWaves(benchmark::State& state) {
  std::vector<flexid::model::Recording> data;
  for (double level_V : {2.0, 8.0}) {
    std::vector<double> u;
    for (size_t k = 0; k < 6'600; ++k)
      u.push_back(std::fmod(0.1 * static_cast<double>(k), 220.0) < 110.0 ? level_V : 0.0);
    data.push_back(TsRecording(std::move(u), static_cast<unsigned>(level_V)));
  }
  for (auto _ : state) benchmark::DoNotOptimize(IdentifyGlobalTs(data));
  state.counters["samples"] = 2 * 6'600;
}
BENCHMARK(BM_IdentifyGlobalTwoSquareWaves)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->Repetitions(3)
    ->ReportAggregatesOnly(true);

void BM_IdentifyGlobalStaircase(benchmark::State& state) {
  std::vector<double> u;
  for (int step = 0; step < 16; ++step)  // 1..8 V up, 8..1 V down, 120 s each
    u.insert(u.end(), 1'200, step < 8 ? step + 1.0 : 16.0 - step);
  u.resize(20'000, 0.0);  // rest at the end
  const std::vector<flexid::model::Recording> data = {TsRecording(std::move(u), 3)};
  for (auto _ : state) benchmark::DoNotOptimize(IdentifyGlobalTs(data));
  state.counters["samples"] = 20'000;
}
BENCHMARK(BM_IdentifyGlobalStaircase)
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1)
    ->Repetitions(3)
    ->ReportAggregatesOnly(true);

}  // namespace

BENCHMARK_MAIN();
