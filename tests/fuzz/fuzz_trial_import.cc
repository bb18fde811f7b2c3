// Fuzz target: `flexid trials import FILE --actuator S1` up to the database
// (clients/cli/trial_import.h): an lcm-logger log (lcm::LogFile, then wire::WellFormed and
// decode() of each event) or a trial CSV (comment lines, then the recording), chosen as
// the command chooses, by the log's magic number; then PairSamples of every trial.
//
// Two inputs in three are imported with --start-utime near INT64_MAX or INT64_MIN (by
// length). The importer reads a path, so each input is written to one file in a private temporary
// directory (removed at exit).
//
// Invariants (abort otherwise): only model::InputError is thrown; every planned trial has
// deflections, as many as PairSamples gives samples, in increasing time.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <string>

#include "clients/cli/trial_import.h"
#include "model/core/errors.h"

namespace {

namespace fs = std::filesystem;

[[noreturn]] void Fail(const char* what) {
  std::fprintf(stderr, "fuzz_trial_import: %s\n", what);
  std::abort();
}

// A private directory for the input file, removed when the fuzzer exits normally.
class ScratchFile {
 public:
  ScratchFile() {
    std::string pattern = (fs::temp_directory_path() / "flexid-fuzz-XXXXXX").string();
    if (!mkdtemp(pattern.data())) Fail("cannot create a temporary directory");
    dir_ = pattern;
    path_ = (dir_ / "input").string();
  }
  ~ScratchFile() {
    std::error_code ignored;
    fs::remove_all(dir_, ignored);
  }
  const std::string& Write(const uint8_t* data, size_t size) {
    FILE* f = std::fopen(path_.c_str(), "wb");
    if (!f) Fail("cannot write the input file");
    if (size > 0 && std::fwrite(data, 1, size, f) != size) Fail("cannot write the input file");
    std::fclose(f);
    return path_;
  }

 private:
  fs::path dir_;
  std::string path_;
};

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static ScratchFile scratch;
  const std::string& path = scratch.Write(data, size);
  flexid::cli::PlanOptions options;
  options.actuator = "S1";
  options.now_utime = 1700000000000000;
  // --start-utime near either end of int64, through the importer's overflow checks.
  if (size % 3 == 1) options.start_utime = std::numeric_limits<int64_t>::max() - 1000;
  if (size % 3 == 2) options.start_utime = std::numeric_limits<int64_t>::min() + 1000;
  flexid::cli::ImportPlan plan;
  try {
    plan = flexid::cli::IsLcmLog(path) ? flexid::cli::PlanFromLcmLog(path, options)
                                       : flexid::cli::PlanFromCsv(path, options);
  } catch (const flexid::model::InputError&) {
    return 0;
  }
  for (const flexid::cli::ImportTrial& trial : plan.trials) {
    if (trial.deflections <= 0) Fail("a planned trial without deflections");
    const auto samples = flexid::cli::PairSamples(trial);
    if (static_cast<int64_t>(samples.size()) != trial.deflections)
      Fail("PairSamples gives another number of samples than the plan counts");
    for (size_t k = 1; k < samples.size(); ++k)
      if (samples[k].utime <= samples[k - 1].utime) Fail("paired samples not in time order");
  }
  return 0;
}
