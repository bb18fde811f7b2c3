#include "clients/cli/format.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <iostream>

namespace flexid::cli {

std::string FormatNumber(double value, int significant) {
  if (std::isnan(value)) return "nan";
  if (std::isinf(value)) return value > 0 ? "inf" : "-inf";
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, "%.*g", significant, value);
  return buffer;
}

std::string FormatComplex(std::complex<double> value, int significant) {
  std::string text = FormatNumber(value.real(), significant);
  if (value.imag() == 0.0) return text;
  text.append(value.imag() < 0 ? " - " : " + ");
  text.append(FormatNumber(std::abs(value.imag()), significant));
  text.push_back('j');
  return text;
}

std::string FormatPolynomial(const std::vector<double>& coefficients) {
  std::string text;
  const size_t degree = coefficients.size() - 1;
  for (size_t i = 0; i < coefficients.size(); ++i) {
    const double c = coefficients[i];
    const size_t power = degree - i;
    if (c == 0.0 && coefficients.size() > 1) continue;
    if (!text.empty()) {
      text.append(c < 0 ? " - " : " + ");
    } else if (c < 0) {
      text.push_back('-');
    }
    const double magnitude = std::abs(c);
    const bool unit = magnitude == 1.0 && power > 0;
    if (!unit) text.append(FormatNumber(magnitude));
    if (power > 0) {
      if (!unit) text.push_back(' ');
      text.push_back('s');
    }
    if (power > 1) {
      text.push_back('^');
      text.append(std::to_string(power));
    }
  }
  return text.empty() ? "0" : text;
}

std::string FormatUtcTime(int64_t utime) {
  constexpr int64_t kPerSecond = 1'000'000;
  int64_t seconds = utime / kPerSecond;
  int64_t micros = utime % kPerSecond;
  if (micros < 0) {  // floor, for times before 1970
    micros += kPerSecond;
    --seconds;
  }
  const auto time = static_cast<std::time_t>(seconds);
  std::tm parts{};
  if (gmtime_r(&time, &parts) == nullptr) return std::to_string(utime) + " us";
  char text[64];
  size_t length = std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%S", &parts);
  if (micros != 0) {
    length += static_cast<size_t>(std::snprintf(text + length, sizeof text - length, ".%06lld",
                                                static_cast<long long>(micros)));
    while (text[length - 1] == '0') --length;
  }
  return std::string(text, length) + "Z";
}

void Table::Print(std::ostream& out, const std::string& indent) const {
  std::vector<size_t> width(header_.size(), 0);
  auto measure = [&](const std::vector<std::string>& row) {
    for (size_t c = 0; c < row.size() && c < width.size(); ++c)
      width[c] = std::max(width[c], row[c].size());
  };
  measure(header_);
  for (const auto& row : rows_) measure(row);
  auto numeric = [](const std::string& cell) {
    return !cell.empty() && (std::isdigit(static_cast<unsigned char>(cell[0])) || cell[0] == '-' ||
                             cell[0] == '+' || cell == "inf" || cell == "nan");
  };
  auto print_row = [&](const std::vector<std::string>& row) {
    std::string line = indent;
    for (size_t c = 0; c < row.size() && c < width.size(); ++c) {
      const std::string padding(width[c] - row[c].size(), ' ');
      line += numeric(row[c]) ? padding + row[c] : row[c] + padding;
      if (c + 1 < row.size()) line += "  ";
    }
    while (!line.empty() && line.back() == ' ') line.pop_back();
    out << line << '\n';
  };
  print_row(header_);
  for (const auto& row : rows_) print_row(row);
}

Progress::Progress(std::string what, std::string unit)
    : what_(std::move(what)), unit_(std::move(unit)) {
  terminal_ = isatty(STDERR_FILENO) == 1;
  const char* forced = std::getenv("FLEXID_PROGRESS");
  enabled_ = terminal_ || (forced != nullptr && std::string(forced) == "1");
}

Progress::~Progress() { Finish(); }

void Progress::Update(int64_t done, int64_t total) {
  if (!enabled_) return;
  const int percent = total > 0 ? static_cast<int>(100 * std::min(done, total) / total) : 100;
  const std::string line = what_ + ": " + std::to_string(done) + " of " + std::to_string(total) +
                           " " + unit_ + " (" + std::to_string(percent) + " %)";
  if (terminal_) {
    std::cerr << '\r' << line << "\x1b[K" << std::flush;
    open_line_ = true;
  } else if (percent / 10 != last_decile_) {
    last_decile_ = percent / 10;
    std::cerr << line << '\n';
  }
}

void Progress::Note(const std::string& text) {
  if (!enabled_) return;
  if (terminal_) {
    std::cerr << '\r' << what_ << ": " << text << "\x1b[K" << std::flush;
    open_line_ = true;
  } else {
    std::cerr << what_ << ": " << text << '\n';
  }
}

void Progress::Finish() {
  if (open_line_) std::cerr << '\n';
  open_line_ = false;
}

}  // namespace flexid::cli
