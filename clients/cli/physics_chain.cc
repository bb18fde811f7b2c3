// flexid physics without --table1 (physics_chain.h): the chain's parameters, the truncation
// study of the N-term model against the exact Eq. (11), its N = 3 poles and zeros, and
// Table 1 predicted vs measured; as JSON or as text.
#include "clients/cli/physics_chain.h"

#include <cmath>
#include <complex>
#include <cstdio>
#include <iterator>
#include <nlohmann/json.hpp>
#include <optional>
#include <vector>

#include "model/core/transfer_function.h"
#include "model/physics/physics.h"

namespace flexid::cli::physics {
namespace {

using model::PhysicalParameters;
using model::SeriesRemainder;
using model::TransferFunction;

constexpr int kStudyTerms[] = {1, 2, 3, 5, 10, 30, 100};
constexpr int kPoleZeroTerms = 3;  // the seed's Eq. (13): 3 zeros, 4 poles

nlohmann::json ComplexJson(std::complex<double> value) {
  return {{"re", value.real()}, {"im", value.imag()}};
}

nlohmann::json RootsJson(const std::vector<std::complex<double>>& roots) {
  nlohmann::json out = nlohmann::json::array();
  for (const auto& root : roots) out.push_back(ComplexJson(root));
  return out;
}

nlohmann::json ModelJson(const TransferFunction& tf) {
  return {{"num", tf.num},
          {"den", tf.den},
          {"delay_s", tf.delay_s},
          {"dc_gain_per_m_V", model::DcGain(tf)}};
}

void PrintRoots(const char* label, const std::vector<std::complex<double>>& roots) {
  std::printf("  %s:", label);
  for (size_t i = 0; i < roots.size(); ++i) {
    const auto& root = roots[i];
    if (root.imag() != 0.0)
      std::printf("%s %.4g%+.4gj", i ? "," : "", root.real(), root.imag());
    else
      std::printf("%s %.4g (%.4g s)", i ? "," : "", root.real(), -1.0 / root.real());
  }
  std::printf("\n");
}

void PrintCoefficients(const char* label, const std::vector<double>& coefficients) {
  std::printf("    %s:", label);
  for (double c : coefficients) std::printf(" %.10g", c);
  std::printf("\n");
}

}  // namespace

ChainReport ComputeChainReport(double voltage_V, std::optional<int> terms) {
  ChainReport report;
  report.parameters = model::SeedS1Parameters();
  report.voltage_V = voltage_V;
  report.grid_rad_s = model::DefaultTruncationGrid_rad_s();
  report.truncation = model::TruncationErrors(
      report.parameters, std::vector<int>(std::begin(kStudyTerms), std::end(kStudyTerms)),
      report.grid_rad_s);
  const TransferFunction n3 = model::CurvatureTransferFunction(report.parameters, kPoleZeroTerms);
  report.n3_poles = model::Poles(n3);
  report.n3_zeros = model::Zeros(n3);
  for (const auto* roots : {&report.n3_poles, &report.n3_zeros})
    for (const auto& root : *roots)
      if (!(root.real() < 0.0) || std::abs(root.imag()) > 1e-9 * std::abs(root.real()))
        report.n3_real_negative = false;
  // RC network (Foster): sorted by decreasing real part, pole, zero, pole, ... alternate.
  for (size_t i = 0; i < report.n3_zeros.size() && i + 1 < report.n3_poles.size(); ++i)
    if (!(report.n3_poles[i].real() > report.n3_zeros[i].real() &&
          report.n3_zeros[i].real() > report.n3_poles[i + 1].real()))
      report.n3_interlaced = false;
  if (terms) {
    report.has_terms_model = true;
    report.terms_model = model::CurvatureTransferFunction(report.parameters, *terms);
    report.terms_model_corrected = model::CurvatureTransferFunction(
        report.parameters, *terms, 0.0, SeriesRemainder::kStaticCorrection);
  }
  report.table1 = model::PredictTable1(report.parameters, voltage_V);
  // Rows are S1 (40/8/2), S2 (h = 1), S3 (W = 4), S4 (L = 20): kSeedTable1 order.
  const auto& t = report.table1;
  report.predicted_length_exponent =
      std::log2(t[0].predicted_deflection_mm / t[3].predicted_deflection_mm);
  report.measured_length_exponent =
      std::log2(t[0].measured_deflection_mm / t[3].measured_deflection_mm);
  report.predicted_thickness_exponent =
      std::log2(t[1].predicted_deflection_mm / t[0].predicted_deflection_mm);
  report.measured_thickness_exponent =
      std::log2(t[1].measured_deflection_mm / t[0].measured_deflection_mm);
  return report;
}

nlohmann::json ChainReportJson(const ChainReport& r, int terms) {
  const PhysicalParameters& p = r.parameters;
  nlohmann::json parameters = {
      {"source",
       "illustrative S1 parameters (model/physics/physics.h); alpha calibrated to Table 1 S1, 5.92 "
       "mm "
       "at 5 V"},
      {"D_m2_per_s", p.D_m2_per_s},
      {"delta_m", p.delta_m},
      {"C_dl_F", p.C_dl_F},
      {"R_s_ohm", p.R_s_ohm},
      {"alpha_m3_per_C", p.alpha_m3_per_C},
      {"E_Pa", p.E_Pa},
      {"L_m", p.L_m},
      {"W_m", p.W_m},
      {"h_m", p.h_m},
      {"derived",
       {{"slowest_diffusion_time_constant_s", model::SlowestDiffusionTimeConstant_s(p)},
        {"R_s_C_dl_s", p.R_s_ohm * p.C_dl_F},
        {"h_over_delta", p.h_m / p.delta_m},
        {"dc_curvature_per_m_V", model::DcCurvaturePerVolt(p)},
        {"voltage_V", r.voltage_V},
        {"steady_tip_deflection_mm", model::SteadyTipDeflection_mm(p, r.voltage_V)}}},
  };

  nlohmann::json rows = nlohmann::json::array();
  for (const auto& row : r.truncation) {
    rows.push_back(
        {{"terms", row.terms},
         {"max_relative_error", row.max_relative_error},
         {"omega_at_max_rad_s", row.omega_at_max_rad_s},
         {"dc_truncated_per_m_V", row.dc_truncated_per_m_V},
         {"dc_exact_per_m_V", row.dc_exact_per_m_V},
         {"dc_relative_error", row.dc_relative_error},
         {"max_relative_error_static_correction", row.max_relative_error_static_correction},
         {"omega_at_max_static_correction_rad_s", row.omega_at_max_static_correction_rad_s}});
  }
  nlohmann::json truncation = {
      {"omega_grid_rad_s",
       {{"min", r.grid_rad_s.front()},
        {"max", r.grid_rad_s.back()},
        {"points", r.grid_rad_s.size()},
        {"spacing", "log"}}},
      {"rows", rows},
      {"n3",
       {{"terms", kPoleZeroTerms},
        {"poles_rad_s", RootsJson(r.n3_poles)},
        {"zeros_rad_s", RootsJson(r.n3_zeros)},
        {"all_real_negative", r.n3_real_negative},
        {"interlaced", r.n3_interlaced}}},
  };
  if (r.has_terms_model) {
    truncation["model"] = {{"terms", terms},
                           {"output", "curvature in 1/m per volt"},
                           {"series_dropped", ModelJson(r.terms_model)},
                           {"static_correction", ModelJson(r.terms_model_corrected)}};
  }

  nlohmann::json table_rows = nlohmann::json::array();
  for (const auto& row : r.table1) {
    table_rows.push_back({{"name", row.name},
                          {"L_mm", row.L_mm},
                          {"W_mm", row.W_mm},
                          {"h_mm", row.h_mm},
                          {"predicted_curvature_per_m", row.predicted_curvature_per_m},
                          {"predicted_deflection_mm", row.predicted_deflection_mm},
                          {"measured_deflection_mm", row.measured_deflection_mm},
                          {"predicted_ratio_to_s1", row.predicted_ratio_to_s1},
                          {"measured_ratio_to_s1", row.measured_ratio_to_s1}});
  }
  nlohmann::json table1 = {
      {"voltage_V", r.voltage_V},
      {"measured_voltage_V", model::kSeedTable1Voltage_V},
      {"scaling",
       "C_dl proportional to W L; R_s, D, delta, alpha, E fixed; alpha calibrated on S1"},
      {"rows", table_rows},
      {"exponents",
       {{"length_predicted", r.predicted_length_exponent},
        {"length_measured", r.measured_length_exponent},
        {"thickness_predicted", r.predicted_thickness_exponent},
        {"thickness_measured", r.measured_thickness_exponent}}},
  };
  return {{"parameters", parameters}, {"truncation", truncation}, {"table1", table1}};
}

void PrintChainReport(const ChainReport& r, int terms) {
  const PhysicalParameters& p = r.parameters;
  std::printf(
      "Physical parameters: illustrative S1 (40 x 8 x 2 mm, 0.12 M NaOH); the paper gives\n"
      "no values, the choices are explained in model/physics/physics.h\n");
  std::printf("  %-6s %-12.4g %-8s %s\n", "D", p.D_m2_per_s, "m^2/s",
              "ion diffusion coefficient (effective)");
  std::printf("  %-6s %-12.4g %-8s %s\n", "delta", p.delta_m, "m",
              "double-layer thickness (effective)");
  std::printf("  %-6s %-12.4g %-8s %s\n", "C_dl", p.C_dl_F, "F",
              "double-layer capacitance, 0.2 F/m^2 x W L");
  std::printf("  %-6s %-12.4g %-8s %s\n", "R_s", p.R_s_ohm, "ohm", "solution resistance");
  std::printf("  %-6s %-12.4g %-8s %s\n", "alpha", p.alpha_m3_per_C, "m^3/C",
              "strain-to-charge ratio, calibrated: 5.92 mm at 5 V (Table 1, S1)");
  std::printf("  %-6s %-12.4g %-8s %s\n", "E", p.E_Pa, "Pa",
              "Young's modulus (cancels from free-bending curvature)");
  std::printf("  %-6s %g x %g x %g mm\n", "L W h", 1e3 * p.L_m, 1e3 * p.W_m, 1e3 * p.h_m);
  std::printf(
      "  derived: slowest diffusion time constant 4 h^2/(pi^2 D) = %.4g s, R_s C_dl = "
      "%.4g s,\n           h/delta = %.4g, DC curvature (Eq. 11, s = 0) = %.4g 1/(m V),\n"
      "           steady tip deflection at %g V = %.4g mm\n",
      model::SlowestDiffusionTimeConstant_s(p), p.R_s_ohm * p.C_dl_F, p.h_m / p.delta_m,
      model::DcCurvaturePerVolt(p), r.voltage_V, model::SteadyTipDeflection_mm(p, r.voltage_V));

  std::printf(
      "\nExact Eq. (11) vs the N-term rational model (Eqs. 12-13): max over %zu "
      "log-spaced w in\n[%g, %g] rad/s of |G_N(jw) - G(jw)| / |G(jw)|\n",
      r.grid_rad_s.size(), r.grid_rad_s.front(), r.grid_rad_s.back());
  std::printf("  %5s  %13s  %10s  %13s  %12s  %20s\n", "N", "max rel error", "at w rad/s",
              "DC_N 1/(m V)", "DC rel error", "DC-corrected max err");
  for (const auto& row : r.truncation) {
    std::printf("  %5d  %13.4g  %10.4g  %13.6g  %12.4g  %20.4g\n", row.terms,
                row.max_relative_error, row.omega_at_max_rad_s, row.dc_truncated_per_m_V,
                row.dc_relative_error, row.max_relative_error_static_correction);
  }
  std::printf(
      "  exact DC: %.6g 1/(m V). The N-term DC gain is low by the dropped static part, "
      "about\n  2/(pi^2 N); \"DC-corrected\" adds that part back as a constant "
      "capacitance (DC exact).\n",
      r.truncation.front().dc_exact_per_m_V);
  std::printf("\nN = %d model (the structure of Eq. 13), roots in rad/s (time constant):\n",
              kPoleZeroTerms);
  PrintRoots("poles", r.n3_poles);
  PrintRoots("zeros", r.n3_zeros);
  if (r.n3_real_negative && r.n3_interlaced)
    std::printf("  all real and negative, poles and zeros interlaced: an RC diffusion network\n");
  else
    std::printf(
        "  WARNING: roots not real, negative and interlaced (unexpected for this physics)\n");

  if (r.has_terms_model) {
    std::printf("\nN = %d model, curvature in 1/m per volt, coefficients highest power first:\n",
                terms);
    std::printf("  series dropped (Eq. 13), DC gain %.6g 1/(m V):\n", model::DcGain(r.terms_model));
    PrintCoefficients("num", r.terms_model.num);
    PrintCoefficients("den", r.terms_model.den);
    std::printf("  static remainder added (DC exact), DC gain %.6g 1/(m V):\n",
                model::DcGain(r.terms_model_corrected));
    PrintCoefficients("num", r.terms_model_corrected.num);
    PrintCoefficients("den", r.terms_model_corrected.den);
  }

  std::printf(
      "\nTable 1 (seed section 3.4): predicted steady tip deflection at %g V vs measured "
      "maximum\ndeflection at %g V\n",
      r.voltage_V, model::kSeedTable1Voltage_V);
  std::printf("scaling: C_dl ~ W L; R_s, D, delta, alpha, E fixed; alpha calibrated on S1\n");
  std::printf("  %-8s %5s %5s %5s %9s %13s %12s %13s %12s\n", "actuator", "L mm", "W mm", "h mm",
              "K 1/m", "predicted mm", "measured mm", "predicted/S1", "measured/S1");
  for (const auto& row : r.table1) {
    std::printf("  %-8s %5g %5g %5g %9.4g %13.3f %12.2f %13.3f %12.3f\n", row.name.c_str(),
                row.L_mm, row.W_mm, row.h_mm, row.predicted_curvature_per_m,
                row.predicted_deflection_mm, row.measured_deflection_mm, row.predicted_ratio_to_s1,
                row.measured_ratio_to_s1);
  }
  std::printf("  deflection ~ L^a: predicted a = %.2f, measured a = %.2f (S4 -> S1)\n",
              r.predicted_length_exponent, r.measured_length_exponent);
  std::printf("  deflection ~ h^-b: predicted b = %.2f, measured b = %.2f (S2 -> S1)\n",
              r.predicted_thickness_exponent, r.measured_thickness_exponent);
  std::printf("  width: the chain predicts no effect; measured S3/S1 = %.3f\n",
              r.table1[2].measured_ratio_to_s1);
}

}  // namespace flexid::cli::physics
