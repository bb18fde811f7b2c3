// What `flexid physics` prints without --table1 (internal to clients/cli/physics_*.cc): the
// illustrative S1 parameters of the seed's physics chain (Eqs. 1-13, model/physics/physics.h), how
// well the N-term rational model of Eq. (13) approximates the exact Eq. (11), and Table 1
// predicted vs measured. Implemented in physics_chain.cc.
#pragma once

#include <complex>
#include <nlohmann/json.hpp>
#include <optional>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/physics/physics.h"

namespace flexid::cli::physics {

// Everything the command prints, computed once for both output forms.
struct ChainReport {
  model::PhysicalParameters parameters;
  double voltage_V = 0.0;
  std::vector<double> grid_rad_s;
  std::vector<model::TruncationErrorRow> truncation;
  std::vector<std::complex<double>> n3_poles;
  std::vector<std::complex<double>> n3_zeros;
  bool n3_real_negative = true;
  bool n3_interlaced = true;
  bool has_terms_model = false;
  model::TransferFunction terms_model;
  model::TransferFunction terms_model_corrected;
  std::vector<model::Table1Row> table1;
  // Power laws over a factor 2 in length (S4 -> S1) and thickness (S1 -> S2).
  double predicted_length_exponent = 0.0;
  double measured_length_exponent = 0.0;
  double predicted_thickness_exponent = 0.0;
  double measured_thickness_exponent = 0.0;
};

// The report for the illustrative S1 parameters, with the steady deflections at voltage_V;
// with terms, also the N = terms model printed in full. Throws std::invalid_argument from
// model/physics/physics.h.
ChainReport ComputeChainReport(double voltage_V, std::optional<int> terms);

// The --json document: {"parameters", "truncation", "table1"}; terms is N of the model
// printed in full (used when report.has_terms_model).
nlohmann::json ChainReportJson(const ChainReport& r, int terms);

// The human form, on standard output.
void PrintChainReport(const ChainReport& r, int terms);

}  // namespace flexid::cli::physics
