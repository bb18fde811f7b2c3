// flexid physics --table1 (physics_table1.h): the chain's scaling exponents of Table 1,
// steady and over hold times, against the measured ones; as JSON or as text.
#include "clients/cli/physics_table1.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "clients/cli/format.h"
#include "model/physics/physics.h"

namespace flexid::cli::physics {
namespace {

// Hold times at which the chain's step response is evaluated (log-spaced, s), to see what a
// voltage held for less than the steady state would do to the predicted exponents.
std::vector<double> HoldGrid_s() {
  std::vector<double> holds;
  for (int i = 0; i <= 24; ++i) holds.push_back(std::pow(10.0, -2.0 + 0.25 * i));  // 0.01..1e4
  return holds;
}

const model::Table1Scaling* Find(const std::vector<model::Table1Scaling>& list,
                                 model::BeamDimension dimension) {
  for (const auto& scaling : list)
    if (scaling.dimension == dimension) return &scaling;
  return nullptr;
}

// 4 h^2/(pi^2 D) of a row's beam, in s.
double DiffusionTime_s(const Table1Report& r, const model::Table1Row& row) {
  return model::SlowestDiffusionTimeConstant_s(
      model::WithGeometry(r.parameters, 1e-3 * row.L_mm, 1e-3 * row.W_mm, 1e-3 * row.h_mm));
}

}  // namespace

Table1Report ComputeTable1() {
  Table1Report r;
  r.parameters = model::SeedS1Parameters();
  r.rows = model::PredictTable1(r.parameters);
  const std::vector<model::Table1Scaling> steady = model::AnalyseTable1Scaling(r.rows);
  const std::vector<model::Table1Scaling> small_bending =
      model::AnalyseTable1Scaling(model::PredictTable1(r.parameters, 1e-3));
  const model::Table1Scaling* small_length = Find(small_bending, model::BeamDimension::kLength);
  r.small_bending_length_exponent = small_length ? small_length->predicted_exponent : 0.0;

  const std::vector<double> holds = HoldGrid_s();
  std::vector<std::vector<model::Table1Scaling>> at_hold;
  for (double hold : holds)
    at_hold.push_back(
        model::AnalyseTable1Scaling(model::PredictTable1AfterHold(r.parameters, hold)));

  for (const model::Table1Scaling& scaling : steady) {
    DimensionFinding d;
    d.scaling = scaling;
    d.chain_min_exponent = d.chain_max_exponent = scaling.predicted_exponent;
    std::vector<double> exponents;
    for (const auto& list : at_hold) {
      const double e = Find(list, scaling.dimension)->predicted_exponent;
      exponents.push_back(e);
      d.chain_min_exponent = std::min(d.chain_min_exponent, e);
      d.chain_max_exponent = std::max(d.chain_max_exponent, e);
    }
    const double m = scaling.measured_exponent;
    for (size_t i = 0; i + 1 < holds.size() && !d.has_matching_hold; ++i) {
      if ((exponents[i] - m) * (exponents[i + 1] - m) > 0.0 || exponents[i] == exponents[i + 1])
        continue;
      const double f = (m - exponents[i]) / (exponents[i + 1] - exponents[i]);
      d.has_matching_hold = true;
      d.matching_hold_s = holds[i] * std::pow(holds[i + 1] / holds[i], f);
      d.at_matching_hold = model::AnalyseTable1Scaling(
          model::PredictTable1AfterHold(r.parameters, d.matching_hold_s));
    }
    r.dimensions.push_back(d);
  }

  for (size_t i = 0; i < r.dimensions.size(); ++i)
    if (r.dimensions[i].scaling.departs) r.departing.push_back(i);
  std::sort(r.departing.begin(), r.departing.end(), [&](size_t a, size_t b) {
    return std::abs(r.dimensions[a].scaling.departure) >
           std::abs(r.dimensions[b].scaling.departure);
  });
  ExplainTable1(&r);
  return r;
}

nlohmann::json Table1Json(const Table1Report& r) {
  nlohmann::json dimensions = nlohmann::json::array();
  for (const auto& d : r.dimensions) {
    const model::Table1Scaling& s = d.scaling;
    nlohmann::json entry = {
        {"dimension", std::string(model::Name(s.dimension))},
        {"beams", {s.reference_name, s.varied_name}},
        {"reference_mm", s.reference_mm},
        {"varied_mm", s.varied_mm},
        {"predicted_ratio", s.predicted_ratio},
        {"measured_ratio", s.measured_ratio},
        {"predicted_exponent", s.predicted_exponent},
        {"measured_exponent", s.measured_exponent},
        {"measured_exponent_range",
         {s.measured_exponent_range.low, s.measured_exponent_range.high}},
        {"exponent_uncertainty", s.exponent_uncertainty},
        {"departure", s.departure},
        {"departs", s.departs},
        {"chain_exponent_range_over_hold_times", {d.chain_min_exponent, d.chain_max_exponent}},
        {"chain_matching_hold_s",
         d.has_matching_hold ? nlohmann::json(d.matching_hold_s) : nlohmann::json(nullptr)},
        {"explanation", d.explanation},
    };
    dimensions.push_back(entry);
  }
  nlohmann::json departing = nlohmann::json::array();
  for (size_t i : r.departing)
    departing.push_back(std::string(model::Name(r.dimensions[i].scaling.dimension)));
  nlohmann::json beams = nlohmann::json::array();
  for (const auto& row : r.rows)
    beams.push_back({{"name", row.name},
                     {"L_mm", row.L_mm},
                     {"W_mm", row.W_mm},
                     {"h_mm", row.h_mm},
                     {"predicted_deflection_mm", row.predicted_deflection_mm},
                     {"measured_deflection_mm", row.measured_deflection_mm},
                     {"slowest_diffusion_time_constant_s", DiffusionTime_s(r, row)}});
  return {{"voltage_V", model::kSeedTable1Voltage_V},
          {"deflection_reading_uncertainty_mm", model::kSeedTable1DeflectionHalfUnit_mm},
          {"seed_hold_s", nullptr},
          {"seed_hold_note",
           Format("not stated for Table 1; other 5 V tests in the seed hold %g s and %g s",
                  kSeedSquareWaveHold_s, kSeedLowestFrequencyHold_s)},
          {"beams", beams},
          {"dimensions", dimensions},
          {"departing", departing},
          {"findings", r.findings},
          {"notes", r.notes}};
}

void PrintTable1Human(const Table1Report& r) {
  std::printf(
      "Table 1 (seed section 3.4, 5 V, 0.12 M NaOH): how the maximum deflection scales with "
      "L, W, h,\nthe physics chain (illustrative S1 parameters, alpha calibrated on S1) vs "
      "measured\n");
  Table dimensions({"dimension", "beams", "mm", "ratio chain", "measured", "exponent chain",
                    "measured", "+-reading", "departs", "chain over holds"});
  for (const auto& d : r.dimensions) {
    const model::Table1Scaling& s = d.scaling;
    dimensions.AddRow(
        {std::string(model::Name(s.dimension)), s.varied_name + "/" + s.reference_name,
         Format("%g/%g", s.varied_mm, s.reference_mm), Format("%.3f", s.predicted_ratio),
         Format("%.3f", s.measured_ratio), Format("%+.2f", Clean(s.predicted_exponent, 0.01)),
         Format("%+.2f", Clean(s.measured_exponent, 0.01)), Format("%.3f", s.exponent_uncertainty),
         s.departs ? Format("yes %+.2f", s.departure) : std::string("no"),
         Format("%+.2f..%+.2f", Clean(d.chain_min_exponent, 0.01),
                Clean(d.chain_max_exponent, 0.01))});
  }
  dimensions.Print(std::cout);
  std::cout << "  exponent = d ln(deflection)/d ln(dimension); +-reading: deflections read to +-"
            << FormatNumber(model::kSeedTable1DeflectionHalfUnit_mm)
            << " mm;\n  chain over holds: its exponent if 5 V is held 0.01 s .. until steady\n";
  Table beams({"beam", "L x W x h mm", "chain mm", "measured mm", "4h^2/(pi^2 D) s"});
  for (const auto& row : r.rows)
    beams.AddRow({row.name, Format("%g x %g x %g", row.L_mm, row.W_mm, row.h_mm),
                  Format("%.2f", row.predicted_deflection_mm),
                  Format("%.2f", row.measured_deflection_mm),
                  Format("%.0f", DiffusionTime_s(r, row))});
  std::cout << "\n";
  beams.Print(std::cout);
  std::printf(
      "  hold time for Table 1: not stated in the seed (its other 5 V tests hold %g s and %g "
      "s)\n",
      kSeedSquareWaveHold_s, kSeedLowestFrequencyHold_s);
  std::printf("\nFindings (hypotheses and signatures: --table1 --json, \"explanation\"):\n");
  for (size_t i = 0; i < r.findings.size(); ++i)
    std::printf("  %zu. %s\n", i + 1, r.findings[i].c_str());
}

}  // namespace flexid::cli::physics
