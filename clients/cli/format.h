// Human-readable output helpers shared by the flexid commands.
#pragma once

#include <complex>
#include <cstdint>
#include <ostream>
#include <string>
#include <vector>

namespace flexid::cli {

// Number with `significant` significant digits, no trailing zeros ("0.2275", "367.2",
// "1.2e-05").
std::string FormatNumber(double value, int significant = 6);

std::string FormatComplex(std::complex<double> value, int significant = 6);

// Polynomial in s, highest power first: "0.0085 s^3 + 0.842 s^2 + 1.924 s + 1.97".
std::string FormatPolynomial(const std::vector<double>& coefficients);

// A utime (microseconds since 1970-01-01 UTC) as ISO-8601 UTC: "2023-11-14T22:13:20Z", with
// the fraction of a second when there is one ("2023-11-14T22:13:20.25Z").
std::string FormatUtcTime(int64_t utime);

// Columns aligned to their widest cell; numbers are right-aligned, text left-aligned.
class Table {
 public:
  explicit Table(std::vector<std::string> header) : header_(std::move(header)) {}
  void AddRow(std::vector<std::string> row) { rows_.push_back(std::move(row)); }
  void Print(std::ostream& out, const std::string& indent = "  ") const;

 private:
  std::vector<std::string> header_;
  std::vector<std::vector<std::string>> rows_;
};

// Progress of a long operation (identification, import, export) on stderr, e.g.
// "export trial 3: 450000 of 1000000 samples (45 %)". Shown only when stderr is a terminal
// (redrawn in place) or FLEXID_PROGRESS=1 is set (one line per step of 10 %), so scripts
// that read stderr still see only the one error line.
class Progress {
 public:
  explicit Progress(std::string what, std::string unit = "samples");
  ~Progress();
  Progress(const Progress&) = delete;
  Progress& operator=(const Progress&) = delete;
  void Update(int64_t done, int64_t total);
  // A phase without a count, e.g. "identifying S1 on trials 3, 4".
  void Note(const std::string& text);
  void Finish();

 private:
  std::string what_, unit_;
  bool enabled_ = false, terminal_ = false, open_line_ = false;
  int last_decile_ = -1;
};

}  // namespace flexid::cli
