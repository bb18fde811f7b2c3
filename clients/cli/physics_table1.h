// flexid physics --table1 (internal to clients/cli/physics_*.cc): how Table 1's deflection
// scales with L, W and h in the seed's physics chain and in the measurements, which
// dimension departs beyond the table's reading precision, and what physics could explain it.
//   physics_table1.cc           the analysis (ComputeTable1) and its JSON and text forms
//   physics_table1_findings.cc  the explanations, findings and notes, in words
#pragma once

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "model/physics/physics.h"

namespace flexid::cli::physics {

// Tests of the seed at 5 V whose hold times are stated (section 3.4): the 220 s square wave
// at 50 % duty of the repeatability test, and half a period at the lowest test frequency.
inline constexpr double kSeedSquareWaveHold_s = 110.0;
inline constexpr double kSeedLowestFrequencyHold_s = 200.0;

struct DimensionFinding {
  model::Table1Scaling scaling;
  // The chain's exponent for this dimension over every hold time of HoldGrid_s() and the
  // steady state.
  double chain_min_exponent = 0.0;
  double chain_max_exponent = 0.0;
  // A hold time at which the chain reproduces the measured exponent, if any (log-linear
  // interpolation on the grid), and the chain's exponents of every dimension there.
  bool has_matching_hold = false;
  double matching_hold_s = 0.0;
  std::vector<model::Table1Scaling> at_matching_hold;
  std::string explanation;
};

struct Table1Report {
  model::PhysicalParameters parameters;
  std::vector<model::Table1Row> rows;
  std::vector<DimensionFinding> dimensions;  // Table 1 row order: thickness, width, length
  std::vector<size_t> departing;             // indices into dimensions, largest departure first
  // Length exponent of the chain without the arc geometry's large-deflection effect
  // (PredictTable1 at 1 mV, where K L ~ 6e-5): the small-bending law.
  double small_bending_length_exponent = 0.0;
  std::vector<std::string> findings;
  std::vector<std::string> notes;
};

// The analysis with the illustrative S1 parameters, explained (ExplainTable1). Throws
// std::invalid_argument from model/physics/physics.h.
Table1Report ComputeTable1();

// Writes each dimension's explanation and the report's findings and notes, from its rows
// and dimensions (physics_table1_findings.cc).
void ExplainTable1(Table1Report* report);

// The --table1 --json document.
nlohmann::json Table1Json(const Table1Report& r);

// The --table1 text, on standard output.
void PrintTable1Human(const Table1Report& r);

// printf-style formatting into a string of any length.
template <typename... Args>
std::string Format(const char* format, Args... args) {
  const int size = std::snprintf(nullptr, 0, format, args...);
  if (size <= 0) return {};
  std::string text(static_cast<size_t>(size) + 1, '\0');
  std::snprintf(text.data(), text.size(), format, args...);
  text.resize(static_cast<size_t>(size));
  return text;
}

// -0.000 would read as a sign; values that round to zero print as 0.
inline double Clean(double value, double resolution) {
  return std::abs(value) < 0.5 * resolution ? 0.0 : value;
}

}  // namespace flexid::cli::physics
