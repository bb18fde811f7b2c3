// flexid trials export ID [--out FILE.csv]: a stored trial as a recording CSV, with the
// comment lines `trials import` reads back (trial_import.h). The file appears only when it is
// complete: it is written under FILE.csv.tmp and renamed.
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <memory>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "clients/cli/trial_import.h"
#include "clients/cli/trials_common.h"

namespace flexid::cli::trials {
namespace {

struct ExportArgs {
  int64_t trial = 0;
  std::string out;  // empty: stdout
};

// A FILE* that is closed (and, for a file, removed unless committed) when it goes away.
class CsvOutput {
 public:
  explicit CsvOutput(const std::string& path) : path_(path) {
    if (path_.empty()) {
      file_ = stdout;
      return;
    }
    temporary_ = path_ + ".tmp";
    file_ = std::fopen(temporary_.c_str(), "wb");
    if (!file_) throw OperationError(path_ + ": cannot write (" + std::strerror(errno) + ")");
  }
  ~CsvOutput() {
    if (file_ && file_ != stdout) {
      std::fclose(file_);
      std::remove(temporary_.c_str());
    }
  }
  CsvOutput(const CsvOutput&) = delete;
  CsvOutput& operator=(const CsvOutput&) = delete;

  void Write(const std::string& text) {
    if (std::fwrite(text.data(), 1, text.size(), file_) != text.size())
      throw OperationError((path_.empty() ? "stdout" : path_) + ": cannot write (" +
                           std::strerror(errno) + ")");
  }
  void Commit() {
    if (std::fflush(file_) != 0)
      throw OperationError((path_.empty() ? "stdout" : path_) + ": cannot write (" +
                           std::strerror(errno) + ")");
    if (file_ == stdout) return;
    const bool closed = std::fclose(file_) == 0;
    file_ = nullptr;
    if (!closed || std::rename(temporary_.c_str(), path_.c_str()) != 0) {
      std::remove(temporary_.c_str());
      throw OperationError(path_ + ": cannot write (" + std::strerror(errno) + ")");
    }
  }

 private:
  std::string path_, temporary_;
  FILE* file_ = nullptr;
};

void RunExport(const ExportArgs& args) {
  CheckTrialId(args.trial);
  CsvOutput output(args.out);  // before loading: a bad --out fails at once
  Progress progress("export trial " + std::to_string(args.trial));
  const StoredTrial stored =
      LoadTrial(args.trial, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  progress.Finish();
  const size_t n = stored.utime.size();
  const int64_t first = n > 0 ? stored.utime.front() : TrialFromJson(stored.trial).start_utime;
  std::string chunk = ExportCommentLines(TrialFromJson(stored.trial), first);
  chunk += "t_s,voltage_V,deflection_mm\n";
  constexpr size_t kChunkBytes = 1 << 20;
  chunk.reserve(kChunkBytes + 128);
  for (size_t k = 0; k < n; ++k) {
    // Division is correctly rounded: 100000 us reads back as 0.1, not 0.09999999999999999.
    const double t_s = static_cast<double>(stored.utime[k] - first) / 1e6;
    AppendCsvRow(&chunk, t_s, stored.voltage_V[k], stored.deflection_mm[k]);
    if (chunk.size() >= kChunkBytes) {
      output.Write(chunk);
      chunk.clear();
    }
  }
  output.Write(chunk);
  output.Commit();
  if (!args.out.empty())
    std::cout << "exported trial " << args.trial << ": " << n << " samples to " << args.out << "\n";
}

}  // namespace

void AddExportCommand(CLI::App& trials) {
  auto exp = std::make_shared<ExportArgs>();
  CLI::App* export_cmd = trials.add_subcommand(
      "export", "Write a trial as a recording CSV (t_s,voltage_V,deflection_mm)");
  export_cmd->add_option("ID", exp->trial, "Trial id")->required();
  export_cmd->add_option("--out", exp->out, "Write this file (default: standard output)");
  export_cmd->footer(
      "t_s counts from the first sample; '#' lines first give the trial id, actuator, protocol\n"
      "and start_utime, which `trials import` reads back.\n"
      "Examples:\n  flexid trials export 3 --out trial3.csv\n"
      "  flexid --db var/flexid.db trials export 3 > trial3.csv");
  export_cmd->callback([exp] { RunExport(*exp); });
}

}  // namespace flexid::cli::trials
