#include "clients/cli/format.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

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

}  // namespace flexid::cli
