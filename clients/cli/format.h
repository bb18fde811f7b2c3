// Human-readable output helpers shared by the flexid commands.
#pragma once

#include <complex>
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

}  // namespace flexid::cli
