// Recordings: what the lab measured (time, applied voltage, tip deflection), and the
// Recording CSV contract of DESIGN.md ("Contracts other tools rely on").
//
// Format read:
//   - one header row, comma separated, with at least the columns t_s, voltage_V and
//     deflection_mm in any order (names are case-sensitive); other columns are ignored;
//   - lines whose first non-blank character is '#' are comments, anywhere in the file
//     (also before the header); blank lines are ignored; CRLF line ends and a UTF-8 byte
//     order mark are accepted; spaces and tabs around fields are ignored;
//   - every data row has as many fields as the header; the three columns hold finite
//     decimal numbers (std::from_chars syntax, plus an optional leading '+'); time is
//     strictly increasing but need not be uniform; at least 2 data rows.
// Errors are model::InputError with one line "FILE:LINE:COLUMN: problem" (1-based; the
// column counts characters, not bytes, and points at the offending field).
//
// Format written: header "t_s,voltage_V,deflection_mm", LF line ends, numbers in the
// shortest form that reads back to the same double.
#pragma once

#include <ostream>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace flexid::model {

struct Recording {
  std::vector<double> t_s;            // strictly increasing, finite, not necessarily uniform
  std::vector<double> voltage_V;      // applied voltage, same length as t_s, or empty if the
                                      // file had no voltage column (only when not required)
  std::vector<double> deflection_mm;  // same length as t_s, or empty if the file had no
                                      // deflection column (only when not required)
  std::string source;                 // file name used in error messages
};

struct CsvReadOptions {
  // false: a file without a deflection_mm column is accepted (deflection_mm stays empty),
  // e.g. a voltage protocol to simulate. A deflection_mm column, if present, is read.
  bool require_deflection = true;
  // false: a file without a voltage_V column is accepted (voltage_V stays empty), e.g. a
  // reference deflection t_s,deflection_mm for a controller. A voltage_V column, if
  // present, is read.
  bool require_voltage = true;
};

// Reads and validates a recording file. Throws InputError ("FILE: cannot open: ..." when
// the file cannot be read, otherwise as ParseRecordingCsv with the path as the name).
Recording ReadRecordingCsv(const std::string& path, const CsvReadOptions& options = {});

// Parses a recording from memory; source_name names it in error messages and becomes
// Recording::source. Throws InputError on any malformed input, never crashes.
Recording ParseRecordingCsv(std::string_view text, const std::string& source_name,
                            const CsvReadOptions& options = {});

// Writes t_s,voltage_V,deflection_mm (or t_s,voltage_V when deflection_mm is empty) to
// PATH.tmp and renames it over PATH. Throws std::invalid_argument if the column lengths
// differ, InputError if the file cannot be written.
void WriteRecordingCsv(const std::string& path, const Recording& recording);

// Writes the prediction CSV of `flexid simulate`: header t_s,voltage_V,predicted_mm, one
// row per sample. Throws std::invalid_argument if the lengths differ.
void WritePredictionCsv(std::ostream& out, std::span<const double> t_s,
                        std::span<const double> voltage_V, std::span<const double> predicted_mm);

// A recording on a uniform grid: as given when it already is one, otherwise resampled to
// its median sample period (voltage held, deflection interpolated linearly).
struct UniformRecording {
  double dt_s = 0.0;
  std::vector<double> voltage_V, deflection_mm, t_s;
  bool resampled = false;
};

// Throws InputError (named by source) with fewer than 2 rows or without deflection.
UniformRecording OnUniformGrid(const Recording& rec);

// Every recording on a uniform grid, all with the first one's sample period (InputError
// naming the recording otherwise); a note per resampled recording is appended to *notes.
std::vector<UniformRecording> OnCommonUniformGrid(const std::vector<Recording>& recordings,
                                                  std::vector<std::string>* notes);

}  // namespace flexid::model
