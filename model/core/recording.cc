#include "model/core/recording.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/simulate.h"
#include "model/core/text_file.h"

namespace flexid::model {
namespace {

constexpr std::string_view kTimeColumn = "t_s";
constexpr std::string_view kVoltageColumn = "voltage_V";
constexpr std::string_view kDeflectionColumn = "deflection_mm";
constexpr std::string_view kPredictionColumn = "predicted_mm";
constexpr std::string_view kByteOrderMark = "\xEF\xBB\xBF";
constexpr std::size_t kNumberBufferSize = 32;  // shortest round-trip double needs <= 24
constexpr std::size_t kWriteChunkBytes = 1 << 16;

// ---------------------------------------------------------------------------------------
// Error messages

std::string FormatNumber(double value) {
  std::array<char, kNumberBufferSize> buffer{};
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  return std::string(buffer.data(), result.ptr);
}

void AppendNumber(std::string* out, double value) {
  std::array<char, kNumberBufferSize> buffer{};
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value);
  out->append(buffer.data(), result.ptr);
}

[[noreturn]] void Fail(const std::string& source, std::size_t line, std::size_t column,
                       const std::string& problem) {
  throw InputError(source + ":" + std::to_string(line) + ":" + std::to_string(column) + ": " +
                   problem);
}

// ---------------------------------------------------------------------------------------
// Lexing

bool IsBlank(char c) { return c == ' ' || c == '\t'; }

std::string_view TrimBlanks(std::string_view text) {
  std::size_t begin = 0;
  std::size_t end = text.size();
  while (begin < end && IsBlank(text[begin])) ++begin;
  while (end > begin && IsBlank(text[end - 1])) --end;
  return text.substr(begin, end - begin);
}

// Blank lines and '#' comments carry no data.
bool IsIgnorable(std::string_view line) {
  const std::string_view trimmed = TrimBlanks(line);
  return trimmed.empty() || trimmed.front() == '#';
}

// Splits text into lines at '\n', dropping one '\r' before it; counts lines from 1.
class LineReader {
 public:
  explicit LineReader(std::string_view text) : text_(text) {}

  bool Next(std::string_view* line) {
    if (done_) return false;
    ++line_number_;
    const std::size_t end = text_.find('\n', position_);
    if (end == std::string_view::npos) {
      *line = text_.substr(position_);
      position_ = text_.size();
      done_ = true;
    } else {
      *line = text_.substr(position_, end - position_);
      position_ = end + 1;
    }
    if (!line->empty() && line->back() == '\r') line->remove_suffix(1);
    return true;
  }

  std::size_t line_number() const { return line_number_; }

 private:
  std::string_view text_;
  std::size_t position_ = 0;
  std::size_t line_number_ = 0;
  bool done_ = false;
};

// Fields of a line, untrimmed (they keep their place in the line for column numbers).
void SplitFields(std::string_view line, std::vector<std::string_view>* fields) {
  fields->clear();
  std::size_t begin = 0;
  while (true) {
    const std::size_t comma = line.find(',', begin);
    if (comma == std::string_view::npos) {
      fields->push_back(line.substr(begin));
      return;
    }
    fields->push_back(line.substr(begin, comma - begin));
    begin = comma + 1;
  }
}

// Byte offset of the (trimmed) field within its line.
std::size_t OffsetInLine(std::string_view line, std::string_view field) {
  return static_cast<std::size_t>(field.data() - line.data());
}

// ---------------------------------------------------------------------------------------
// Numbers

// For a decimal literal that std::from_chars reported out of range: true if its magnitude
// is below 1 (so it underflowed towards zero) rather than above the largest double.
bool MagnitudeBelowOne(std::string_view literal) {
  std::size_t i = 0;
  if (i < literal.size() && (literal[i] == '+' || literal[i] == '-')) ++i;
  long long integer_digits = 0;      // digits before the decimal point
  long long first_significant = -1;  // index among all mantissa digits
  long long digit_index = 0;
  bool after_point = false;
  for (; i < literal.size(); ++i) {
    const char c = literal[i];
    if (c == '.') {
      after_point = true;
      continue;
    }
    if (c < '0' || c > '9') break;
    if (c != '0' && first_significant < 0) first_significant = digit_index;
    ++digit_index;
    if (!after_point) ++integer_digits;
  }
  long long exponent = 0;
  if (i < literal.size() && (literal[i] == 'e' || literal[i] == 'E')) {
    ++i;
    bool negative = false;
    if (i < literal.size() && (literal[i] == '+' || literal[i] == '-')) {
      negative = literal[i] == '-';
      ++i;
    }
    constexpr long long kSaturation = 1'000'000'000;
    for (; i < literal.size() && literal[i] >= '0' && literal[i] <= '9'; ++i) {
      exponent = std::min(kSaturation, exponent * 10 + (literal[i] - '0'));
    }
    if (negative) exponent = -exponent;
  }
  if (first_significant < 0) return true;
  // value = 0.d... * 10^(integer_digits - first_significant + exponent)
  return integer_digits - first_significant + exponent <= 0;
}

enum class NumberStatus { kOk, kNotANumber, kNotFinite, kOutOfRange };

NumberStatus ParseNumber(std::string_view field, double* value) {
  std::string_view literal = field;
  // std::from_chars takes no '+'; accept one in front of a digit or a point.
  if (literal.size() >= 2 && literal[0] == '+' && literal[1] != '+' && literal[1] != '-') {
    literal.remove_prefix(1);
  }
  if (literal.empty()) return NumberStatus::kNotANumber;
  const char* const end = literal.data() + literal.size();
  const auto result = std::from_chars(literal.data(), end, *value);
  if (result.ptr != end) return NumberStatus::kNotANumber;
  if (result.ec == std::errc::result_out_of_range) {
    if (!MagnitudeBelowOne(literal)) return NumberStatus::kOutOfRange;
    *value = literal.front() == '-' ? -0.0 : 0.0;
    return NumberStatus::kOk;
  }
  if (result.ec != std::errc()) return NumberStatus::kNotANumber;
  if (!std::isfinite(*value)) return NumberStatus::kNotFinite;
  return NumberStatus::kOk;
}

// ---------------------------------------------------------------------------------------
// Header

struct ColumnLayout {
  std::size_t field_count = 0;
  std::size_t time_index = 0;
  std::size_t voltage_index = 0;
  std::size_t deflection_index = 0;
  bool has_voltage = false;
  bool has_deflection = false;
  std::size_t max_index = 0;  // highest index read
};

// The required columns, e.g. "t_s,voltage_V,deflection_mm".
std::string ExpectedColumns(const CsvReadOptions& options) {
  return std::string(kTimeColumn) + (options.require_voltage ? ",voltage_V" : "") +
         (options.require_deflection ? ",deflection_mm" : "");
}

std::string DescribeHeader(const std::vector<std::string_view>& fields) {
  constexpr std::size_t kMaxNamesShown = 8;
  std::string out;
  for (std::size_t i = 0; i < fields.size() && i < kMaxNamesShown; ++i) {
    if (i > 0) out += ", ";
    out += Quoted(TrimBlanks(fields[i]));
  }
  if (fields.size() > kMaxNamesShown) {
    out += ", ... (" + std::to_string(fields.size()) + " columns)";
  }
  return out;
}

ColumnLayout ParseHeader(std::string_view line, std::size_t line_number, const std::string& source,
                         const CsvReadOptions& options) {
  std::vector<std::string_view> fields;
  SplitFields(line, &fields);

  struct Wanted {
    std::string_view name;
    bool required;
    bool found = false;
    std::size_t index = 0;
  };
  std::array<Wanted, 3> wanted = {Wanted{kTimeColumn, true},
                                  Wanted{kVoltageColumn, options.require_voltage},
                                  Wanted{kDeflectionColumn, options.require_deflection}};
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const std::string_view name = TrimBlanks(fields[i]);
    for (Wanted& column : wanted) {
      if (name != column.name) continue;
      if (column.found) {
        Fail(source, line_number, CharacterColumn(line, OffsetInLine(line, name)),
             "duplicate column " + Quoted(name) + " (first in column " +
                 std::to_string(column.index + 1) + " of the header)");
      }
      column.found = true;
      column.index = i;
    }
  }

  std::vector<std::string_view> missing;
  for (const Wanted& column : wanted) {
    if (column.required && !column.found) missing.push_back(column.name);
  }
  if (!missing.empty()) {
    std::string problem =
        missing.size() == 1 ? "missing required column " : "missing required columns ";
    for (std::size_t i = 0; i < missing.size(); ++i) {
      if (i > 0) problem += ", ";
      problem += Quoted(missing[i]);
    }
    problem += " (header has: " + DescribeHeader(fields) + "; expected at least " +
               ExpectedColumns(options) + ")";
    Fail(source, line_number, 1, problem);
  }

  ColumnLayout layout;
  layout.field_count = fields.size();
  layout.time_index = wanted[0].index;
  layout.voltage_index = wanted[1].index;
  layout.has_voltage = wanted[1].found;
  layout.has_deflection = wanted[2].found;
  layout.deflection_index = wanted[2].index;
  layout.max_index = std::max({layout.time_index, layout.has_voltage ? layout.voltage_index : 0,
                               layout.has_deflection ? layout.deflection_index : 0});
  return layout;
}

// ---------------------------------------------------------------------------------------
// Rows

class RowParser {
 public:
  RowParser(const std::string& source, const ColumnLayout& layout)
      : source_(source), layout_(layout) {}

  // Appends one data row to recording, or throws InputError.
  void Parse(std::string_view line, std::size_t line_number, Recording* recording) {
    SplitFields(line, &fields_);
    if (fields_.size() != layout_.field_count) {
      // Point at the first extra field, or just past the end of a short row.
      const std::size_t column =
          fields_.size() > layout_.field_count
              ? CharacterColumn(line, OffsetInLine(line, fields_[layout_.field_count]))
              : CharacterColumn(line, line.size());
      Fail(source_, line_number, column,
           "wrong number of fields: expected " + std::to_string(layout_.field_count) +
               " as in the header, found " + std::to_string(fields_.size()));
    }
    const double t_s = Number(line, line_number, layout_.time_index, kTimeColumn);
    if (!recording->t_s.empty() && !(t_s > recording->t_s.back())) {
      const std::string_view field = TrimBlanks(fields_[layout_.time_index]);
      Fail(source_, line_number, CharacterColumn(line, OffsetInLine(line, field)),
           "time is not strictly increasing (" + FormatNumber(t_s) + " after " +
               FormatNumber(recording->t_s.back()) + ")");
    }
    recording->t_s.push_back(t_s);
    if (layout_.has_voltage) {
      recording->voltage_V.push_back(
          Number(line, line_number, layout_.voltage_index, kVoltageColumn));
    }
    if (layout_.has_deflection) {
      recording->deflection_mm.push_back(
          Number(line, line_number, layout_.deflection_index, kDeflectionColumn));
    }
  }

 private:
  double Number(std::string_view line, std::size_t line_number, std::size_t index,
                std::string_view column_name) const {
    const std::string_view field = TrimBlanks(fields_[index]);
    double value = 0.0;
    const NumberStatus status = ParseNumber(field, &value);
    if (status == NumberStatus::kOk) return value;
    std::string problem;
    switch (status) {
      case NumberStatus::kNotANumber:
        problem = field.empty()
                      ? "empty field in column " + Quoted(column_name)
                      : "not a number in column " + Quoted(column_name) + ": " + Quoted(field);
        break;
      case NumberStatus::kNotFinite:
        problem = "NaN or Inf in column " + Quoted(column_name) + ": " + Quoted(field) +
                  " (values must be finite)";
        break;
      case NumberStatus::kOutOfRange:
        problem = "number out of range (Inf) in column " + Quoted(column_name) + ": " +
                  Quoted(field) + " (values must be finite)";
        break;
      case NumberStatus::kOk:
        break;
    }
    Fail(source_, line_number, CharacterColumn(line, OffsetInLine(line, field)), problem);
  }

  const std::string& source_;
  const ColumnLayout& layout_;
  std::vector<std::string_view> fields_;
};

void AppendRow(std::string* out, double a, double b, double c) {
  AppendNumber(out, a);
  *out += ',';
  AppendNumber(out, b);
  *out += ',';
  AppendNumber(out, c);
  *out += '\n';
}

}  // namespace

Recording ParseRecordingCsv(std::string_view text, const std::string& source_name,
                            const CsvReadOptions& options) {
  if (text.substr(0, kByteOrderMark.size()) == kByteOrderMark) {
    text.remove_prefix(kByteOrderMark.size());
  }
  LineReader lines(text);
  std::string_view line;
  bool have_header = false;
  while (lines.Next(&line)) {
    if (!IsIgnorable(line)) {
      have_header = true;
      break;
    }
  }
  if (!have_header) {
    Fail(source_name, lines.line_number(), 1,
         "missing header row (expected at least the columns " + ExpectedColumns(options) + ")");
  }
  const std::size_t header_line_number = lines.line_number();
  const ColumnLayout layout = ParseHeader(line, header_line_number, source_name, options);

  Recording recording;
  recording.source = source_name;
  const auto expected_rows = static_cast<std::size_t>(std::count(text.begin(), text.end(), '\n'));
  recording.t_s.reserve(expected_rows + 1);
  if (layout.has_voltage) recording.voltage_V.reserve(expected_rows + 1);
  if (layout.has_deflection) recording.deflection_mm.reserve(expected_rows + 1);

  RowParser rows(source_name, layout);
  while (lines.Next(&line)) {
    if (IsIgnorable(line)) continue;
    rows.Parse(line, lines.line_number(), &recording);
  }
  if (recording.t_s.size() < 2) {
    Fail(source_name, header_line_number, 1,
         "fewer than 2 data rows after the header (found " + std::to_string(recording.t_s.size()) +
             ")");
  }
  return recording;
}

Recording ReadRecordingCsv(const std::string& path, const CsvReadOptions& options) {
  return ParseRecordingCsv(ReadWholeFile(path), path, options);
}

void WriteRecordingCsv(const std::string& path, const Recording& recording) {
  const std::size_t n = recording.t_s.size();
  const bool has_deflection = !recording.deflection_mm.empty();
  if (recording.voltage_V.size() != n || (has_deflection && recording.deflection_mm.size() != n)) {
    throw std::invalid_argument(
        "WriteRecordingCsv: t_s, voltage_V and deflection_mm differ in length");
  }
  std::string out;
  // Typical row: three numbers of up to ~20 characters.
  out.reserve(64 + n * (has_deflection ? 48 : 32));
  out += kTimeColumn;
  out += ',';
  out += kVoltageColumn;
  if (has_deflection) {
    out += ',';
    out += kDeflectionColumn;
  }
  out += '\n';
  for (std::size_t k = 0; k < n; ++k) {
    if (has_deflection) {
      AppendRow(&out, recording.t_s[k], recording.voltage_V[k], recording.deflection_mm[k]);
    } else {
      AppendNumber(&out, recording.t_s[k]);
      out += ',';
      AppendNumber(&out, recording.voltage_V[k]);
      out += '\n';
    }
  }
  WriteFileAtomically(path, out);
}

void WritePredictionCsv(std::ostream& out, std::span<const double> t_s,
                        std::span<const double> voltage_V, std::span<const double> predicted_mm) {
  if (voltage_V.size() != t_s.size() || predicted_mm.size() != t_s.size()) {
    throw std::invalid_argument(
        "WritePredictionCsv: t_s, voltage_V and predicted_mm differ in length");
  }
  std::string chunk;
  chunk.reserve(kWriteChunkBytes + 128);
  chunk += kTimeColumn;
  chunk += ',';
  chunk += kVoltageColumn;
  chunk += ',';
  chunk += kPredictionColumn;
  chunk += '\n';
  for (std::size_t k = 0; k < t_s.size(); ++k) {
    AppendRow(&chunk, t_s[k], voltage_V[k], predicted_mm[k]);
    if (chunk.size() >= kWriteChunkBytes) {
      out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
      chunk.clear();
    }
  }
  out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
}

UniformRecording OnUniformGrid(const Recording& rec) {
  if (rec.t_s.size() < 2 || rec.deflection_mm.size() != rec.t_s.size())
    throw InputError(rec.source +
                     ": needs time, voltage and deflection columns with 2 or more rows");
  UniformRecording out;
  if (IsUniformGrid(rec.t_s, &out.dt_s)) {
    out.t_s = rec.t_s;
    out.voltage_V = rec.voltage_V;
    out.deflection_mm = rec.deflection_mm;
    return out;
  }
  std::vector<double> steps;
  for (size_t k = 1; k < rec.t_s.size(); ++k) steps.push_back(rec.t_s[k] - rec.t_s[k - 1]);
  std::nth_element(steps.begin(), steps.begin() + static_cast<long>(steps.size() / 2), steps.end());
  out.dt_s = steps[steps.size() / 2];
  out.resampled = true;
  size_t j = 0;
  for (double t = rec.t_s.front(); t <= rec.t_s.back() + 1e-9 * out.dt_s; t += out.dt_s) {
    while (j + 1 < rec.t_s.size() && rec.t_s[j + 1] <= t) ++j;
    out.t_s.push_back(t);
    out.voltage_V.push_back(rec.voltage_V[j]);  // zero-order hold
    if (j + 1 < rec.t_s.size()) {
      const double w = (t - rec.t_s[j]) / (rec.t_s[j + 1] - rec.t_s[j]);
      out.deflection_mm.push_back((1 - w) * rec.deflection_mm[j] + w * rec.deflection_mm[j + 1]);
    } else {
      out.deflection_mm.push_back(rec.deflection_mm[j]);
    }
  }
  return out;
}

std::vector<UniformRecording> OnCommonUniformGrid(const std::vector<Recording>& recordings,
                                                  std::vector<std::string>* notes) {
  std::vector<UniformRecording> out;
  for (const Recording& rec : recordings) {
    out.push_back(OnUniformGrid(rec));
    const UniformRecording& u = out.back();
    if (u.resampled)
      notes->push_back(rec.source + ": non-uniform time, resampled to " + std::to_string(u.dt_s) +
                       " s");
    if (std::abs(u.dt_s - out.front().dt_s) > 1e-6 * out.front().dt_s)
      throw InputError(rec.source + ": sample period " + std::to_string(u.dt_s) +
                       " s differs from " + recordings.front().source + "'s " +
                       std::to_string(out.front().dt_s) + " s");
  }
  return out;
}

}  // namespace flexid::model
