// Storage throughput. DESIGN.md targets: bulk import of a 1,000,000-sample recording
// < 2 s, export of it < 1 s; the daemon records 16 actuators x 500 Hz (8,000 samples/s)
// through the SampleWriter, committed every 100 ms.
//
//   build/bench/storage_bench
//
// Every run works on a fresh SQLite file in the temporary directory (WAL,
// synchronous=NORMAL, as the daemon uses it). The setup of each iteration (a new file, a
// trial) is not timed.
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "storage/database.h"
#include "storage/sample_writer.h"

namespace {

using namespace flexid::storage;
namespace fs = std::filesystem;

// A directory of its own, removed at the end.
class BenchDir {
 public:
  BenchDir()
      : path_(fs::temp_directory_path() / ("flexid-storage-bench-" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~BenchDir() {
    std::error_code ignored;
    fs::remove_all(path_, ignored);
  }
  std::string Fresh() {  // the path of a new database file
    return (path_ / ("run" + std::to_string(++runs_) + ".db")).string();
  }

 private:
  fs::path path_;
  int runs_ = 0;
};

// A recording at 500 Hz: a 5 V square wave and a smooth deflection.
std::vector<Sample> Recording(size_t count) {
  std::vector<Sample> samples(count);
  for (size_t k = 0; k < count; ++k) {
    const double t_s = 0.002 * static_cast<double>(k);
    samples[k] = {static_cast<int64_t>(k) * 2000, std::fmod(t_s, 220.0) < 110.0 ? 5.0 : 0.0,
                  1.5 * std::sin(0.05 * t_s) + 1e-3 * static_cast<double>(k % 7)};
  }
  return samples;
}

void Report(benchmark::State& state, size_t samples) {
  state.SetItemsProcessed(static_cast<int64_t>(state.iterations()) * static_cast<int64_t>(samples));
  state.counters["samples"] = static_cast<double>(samples);
}

void BM_ImportSamples(benchmark::State& state) {
  const std::vector<Sample> samples = Recording(static_cast<size_t>(state.range(0)));
  BenchDir dir;
  for (auto _ : state) {
    state.PauseTiming();
    std::optional<Database> db = Database::Open(dir.Fresh());
    const int64_t trial = db->StartTrial("S1", "square:level=5,period=220", 0);
    state.ResumeTiming();
    benchmark::DoNotOptimize(db->AppendSamples(trial, samples));
    state.PauseTiming();
    db.reset();
    state.ResumeTiming();
  }
  Report(state, samples.size());
}
BENCHMARK(BM_ImportSamples)->Arg(1'000'000)->Unit(benchmark::kMillisecond)->Iterations(5);

void BM_ExportSamples(benchmark::State& state) {
  const std::vector<Sample> samples = Recording(static_cast<size_t>(state.range(0)));
  BenchDir dir;
  const std::string path = dir.Fresh();
  int64_t trial = 0;
  {
    Database db = Database::Open(path);
    trial = db.StartTrial("S1", "square:level=5,period=220", 0);
    db.AppendSamples(trial, samples);
  }
  Database db = Database::Open(path);
  for (auto _ : state) benchmark::DoNotOptimize(db.Samples(trial));
  Report(state, samples.size());
}
BENCHMARK(BM_ExportSamples)->Arg(1'000'000)->Unit(benchmark::kMillisecond);

void BM_HashSamples(benchmark::State& state) {
  const std::vector<Sample> samples = Recording(static_cast<size_t>(state.range(0)));
  for (auto _ : state) benchmark::DoNotOptimize(HashSamples(samples));
  Report(state, samples.size());
}
BENCHMARK(BM_HashSamples)->Arg(1'000'000)->Unit(benchmark::kMillisecond);

// The daemon's load: 16 trials, samples interleaved as they arrive, through the writer
// (enqueue and commit of 10 s of recording: 80,000 samples). Real time would be 10 s.
void BM_SampleWriter16x500Hz(benchmark::State& state) {
  constexpr int kActuators = 16;
  constexpr int64_t kSamplesPerActuator = 5000;  // 10 s at 500 Hz
  BenchDir dir;
  for (auto _ : state) {
    state.PauseTiming();
    const std::string path = dir.Fresh();
    std::vector<int64_t> trials;
    {
      Database db = Database::Open(path);
      for (int a = 0; a < kActuators; ++a)
        trials.push_back(db.StartTrial("S" + std::to_string(a), "p", 0));
    }
    state.ResumeTiming();
    SampleWriter writer(path);
    for (int64_t k = 0; k < kSamplesPerActuator; ++k)
      for (int64_t trial : trials)
        writer.Enqueue(trial, {k * 2000, 5.0, 0.001 * static_cast<double>(k)});
    writer.Flush();
    if (writer.stored() != kActuators * kSamplesPerActuator) state.SkipWithError("lost samples");
  }
  Report(state, kActuators * kSamplesPerActuator);
}
BENCHMARK(BM_SampleWriter16x500Hz)->Unit(benchmark::kMillisecond)->Iterations(5)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
