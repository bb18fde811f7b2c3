// Simulation throughput (samples/s, one core). DESIGN.md targets: a 4th-order model with
// dead time > 20 M samples/s, a 2-rule T-S model > 5 M samples/s.
//
//   build/bench/simulate_bench --benchmark_min_time=1
//
// Inputs are at 10 Hz, with the seed's 3.67 s dead time (36.7 samples: a fractional
// delay). T-S runs are reported for three kinds of input, because the exact blend is
// discretised once per distinct voltage: a staircase (few levels), a chirp quantised by
// a 16-bit DAQ over +-10 V (what a real rig records), and a worst case in which every
// sample has a new voltage (one matrix exponential per sample).
#include <benchmark/benchmark.h>

#include <cmath>
#include <numbers>
#include <random>

#include "model/core/presets.h"
#include "model/core/simulate.h"

namespace {

using namespace flexid::model;

constexpr double kDt_s = 0.1;

std::vector<double> Staircase(size_t count) {
  std::vector<double> u(count);
  const double levels_V[] = {0, 2, 4, 6, 8, 5, 3, 0};
  for (size_t k = 0; k < count; ++k) u[k] = levels_V[(k / 1500) % 8];
  return u;
}

std::vector<double> Chirp(size_t count, double quantum_V) {
  std::vector<double> u(count);
  for (size_t k = 0; k < count; ++k) {
    const double t = kDt_s * static_cast<double>(k);
    const double v = 5.0 + 3.0 * std::sin(2 * std::numbers::pi * (0.001 + 1e-6 * t) * t);
    u[k] = quantum_V > 0 ? quantum_V * std::round(v / quantum_V) : v;
  }
  return u;
}

void Report(benchmark::State& state, size_t samples) {
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()) * static_cast<int64_t>(samples));
  state.counters["samples"] = static_cast<double>(samples);
}

void BM_Lti4thOrderWithDelay(benchmark::State& state) {
  const auto u = Staircase(static_cast<size_t>(state.range(0)));
  const TransferFunction tf = SeedModel8V();
  for (auto _ : state) benchmark::DoNotOptimize(SimulateUniform(tf, kDt_s, u));
  Report(state, u.size());
}
BENCHMARK(BM_Lti4thOrderWithDelay)->Arg(11'000)->Arg(1'000'000)->Unit(benchmark::kMillisecond);

void BM_Ts2RuleStaircase(benchmark::State& state) {
  const auto u = Staircase(static_cast<size_t>(state.range(0)));
  const TsModel ts = SeedTsModel();
  for (auto _ : state) benchmark::DoNotOptimize(SimulateUniform(ts, kDt_s, u));
  Report(state, u.size());
}
BENCHMARK(BM_Ts2RuleStaircase)->Arg(11'000)->Arg(1'000'000)->Unit(benchmark::kMillisecond);

void BM_Ts2RuleChirp16BitDaq(benchmark::State& state) {
  const auto u = Chirp(static_cast<size_t>(state.range(0)), 20.0 / 65536.0);
  const TsModel ts = SeedTsModel();
  for (auto _ : state) benchmark::DoNotOptimize(SimulateUniform(ts, kDt_s, u));
  Report(state, u.size());
}
BENCHMARK(BM_Ts2RuleChirp16BitDaq)->Arg(1'000'000)->Unit(benchmark::kMillisecond);

void BM_Ts2RuleEverySampleNewVoltage(benchmark::State& state) {
  const auto u = Chirp(static_cast<size_t>(state.range(0)), 0.0);
  const TsModel ts = SeedTsModel();
  for (auto _ : state) benchmark::DoNotOptimize(SimulateUniform(ts, kDt_s, u));
  Report(state, u.size());
}
BENCHMARK(BM_Ts2RuleEverySampleNewVoltage)->Arg(11'000)->Unit(benchmark::kMillisecond);

void BM_StreamingTs2RulePerSample(benchmark::State& state) {
  // The live-prediction path: one Step per deflection sample, 500 Hz, square wave.
  const TsModel ts = SeedTsModel();
  StreamingSimulator simulator(ts);
  double t_s = 0.0;
  size_t k = 0;
  for (auto _ : state) {
    t_s += 0.002;
    benchmark::DoNotOptimize(simulator.Step(t_s, (k++ / 5000) % 2 ? 6.0 : 2.0));
  }
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()));
}
BENCHMARK(BM_StreamingTs2RulePerSample);

}  // namespace

BENCHMARK_MAIN();
