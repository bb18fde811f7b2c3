// flexid physics: what the seed's physics chain (Eqs. 1-13, model/physics/physics.h) predicts with
// the illustrative S1 parameters: the parameters, how well the N-term rational model of
// Eq. (13) approximates the exact Eq. (11), and Table 1 predicted vs measured. With
// --table1, only Table 1: how the deflection scales with L, W and h in the chain and in the
// measurements, which dimension departs beyond the table's reading precision, and what
// physics could explain it.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <complex>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "model/core/transfer_function.h"
#include "model/physics/physics.h"

namespace flexid::cli {
namespace {

using model::PhysicalParameters;
using model::SeriesRemainder;
using model::TransferFunction;

struct PhysicsOptions {
  bool json = false;
  bool table1 = false;  // only the Table 1 scaling analysis
  int terms = 0;        // model to print in full; meaningful only if terms_option->count() > 0
  double voltage_V = model::kSeedTable1Voltage_V;
  const CLI::Option* terms_option = nullptr;
  const CLI::Option* voltage_option = nullptr;
};

constexpr int kStudyTerms[] = {1, 2, 3, 5, 10, 30, 100};
constexpr int kPoleZeroTerms = 3;  // the seed's Eq. (13): 3 zeros, 4 poles

// Everything the command prints, computed once for both output forms.
struct PhysicsReport {
  PhysicalParameters parameters;
  double voltage_V = 0.0;
  std::vector<double> grid_rad_s;
  std::vector<model::TruncationErrorRow> truncation;
  std::vector<std::complex<double>> n3_poles;
  std::vector<std::complex<double>> n3_zeros;
  bool n3_real_negative = true;
  bool n3_interlaced = true;
  bool has_terms_model = false;
  TransferFunction terms_model;
  TransferFunction terms_model_corrected;
  std::vector<model::Table1Row> table1;
  // Power laws over a factor 2 in length (S4 -> S1) and thickness (S1 -> S2).
  double predicted_length_exponent = 0.0;
  double measured_length_exponent = 0.0;
  double predicted_thickness_exponent = 0.0;
  double measured_thickness_exponent = 0.0;
};

PhysicsReport Compute(const PhysicsOptions& options) {
  PhysicsReport report;
  report.parameters = model::SeedS1Parameters();
  report.voltage_V = options.voltage_V;
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
  if (options.terms_option->count() > 0) {
    report.has_terms_model = true;
    report.terms_model = model::CurvatureTransferFunction(report.parameters, options.terms);
    report.terms_model_corrected = model::CurvatureTransferFunction(
        report.parameters, options.terms, 0.0, SeriesRemainder::kStaticCorrection);
  }
  report.table1 = model::PredictTable1(report.parameters, options.voltage_V);
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

nlohmann::json ToJson(const PhysicsReport& r, int terms) {
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

void PrintHuman(const PhysicsReport& r, int terms) {
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

// ---- flexid physics --table1: how Table 1 departs from the chain's scaling ----

// Hold times at which the chain's step response is evaluated (log-spaced, s), to see what a
// voltage held for less than the steady state would do to the predicted exponents.
std::vector<double> HoldGrid_s() {
  std::vector<double> holds;
  for (int i = 0; i <= 24; ++i) holds.push_back(std::pow(10.0, -2.0 + 0.25 * i));  // 0.01..1e4
  return holds;
}

// Standard gravity, for the weight-to-stiffness number of a beam.
constexpr double kGravity_m_s2 = 9.81;

// Tests of the seed at 5 V whose hold times are stated (section 3.4): the 220 s square wave
// at 50 % duty of the repeatability test, and half a period at the lowest test frequency.
constexpr double kSeedSquareWaveHold_s = 110.0;
constexpr double kSeedLowestFrequencyHold_s = 200.0;

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
  PhysicalParameters parameters;
  std::vector<model::Table1Row> rows;
  std::vector<DimensionFinding> dimensions;  // Table 1 row order: thickness, width, length
  std::vector<size_t> departing;             // indices into dimensions, largest departure first
  // Length exponent of the chain without the arc geometry's large-deflection effect
  // (PredictTable1 at 1 mV, where K L ~ 6e-5): the small-bending law.
  double small_bending_length_exponent = 0.0;
  std::vector<std::string> findings;
  std::vector<std::string> notes;
};

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
double Clean(double value, double resolution) {
  return std::abs(value) < 0.5 * resolution ? 0.0 : value;
}

const model::Table1Scaling* Find(const std::vector<model::Table1Scaling>& list,
                                 model::BeamDimension dimension) {
  for (const auto& scaling : list)
    if (scaling.dimension == dimension) return &scaling;
  return nullptr;
}

const model::Table1Row& Row(const Table1Report& r, const std::string& name) {
  for (const auto& row : r.rows)
    if (row.name == name) return row;
  throw std::invalid_argument("no Table 1 row " + name);
}

// 4 h^2/(pi^2 D) of a row's beam, in s.
double DiffusionTime_s(const Table1Report& r, const model::Table1Row& row) {
  return model::SlowestDiffusionTimeConstant_s(
      model::WithGeometry(r.parameters, 1e-3 * row.L_mm, 1e-3 * row.W_mm, 1e-3 * row.h_mm));
}

// Density contrast (kg/m^3) at which a beam's weight in the electrolyte matches its bending
// stiffness, 12 (rho_gel - rho_liquid) g L^3/(E h^2) = 1, with the illustrative E.
double CriticalDensityContrast_kg_m3(const Table1Report& r, const model::Table1Row& row) {
  const double L = 1e-3 * row.L_mm;
  const double h = 1e-3 * row.h_mm;
  return r.parameters.E_Pa * h * h / (12.0 * kGravity_m_s2 * L * L * L);
}

std::string ShortHoldSentence(const Table1Report& r, const DimensionFinding& d) {
  if (!d.has_matching_hold)
    return Format(
        "For no hold time does the chain reach the measured value: over holds of 0.01 s to "
        "steady its exponent stays within %.2f .. %.2f.",
        Clean(d.chain_min_exponent, 0.01), Clean(d.chain_max_exponent, 0.01));
  std::string others;
  for (const auto& scaling : d.at_matching_hold) {
    if (scaling.dimension == d.scaling.dimension) continue;
    const model::Table1Scaling* measured = nullptr;
    for (const auto& other : r.dimensions)
      if (other.scaling.dimension == scaling.dimension) measured = &other.scaling;
    others += Format("%s%s %.2f (measured %.2f)", others.empty() ? "" : ", ",
                     std::string(model::Name(scaling.dimension)).c_str(),
                     Clean(scaling.predicted_exponent, 0.01),
                     measured ? Clean(measured->measured_exponent, 0.01) : 0.0);
  }
  return Format(
      "A hold of about %.2g s would give the chain this exponent, but there it also gives %s, "
      "and the seed's slow time constants (tens of seconds) make a maximum read that early "
      "implausible.",
      d.matching_hold_s, others.c_str());
}

std::string ExplainThickness(const Table1Report& r, const DimensionFinding& d,
                             bool resisting_load_fits_both) {
  const model::Table1Scaling& s = d.scaling;
  const double shortfall = 1.0 - s.measured_ratio / s.predicted_ratio;
  if (!s.departs) return "Within Table 1's reading precision of the chain; nothing to explain.";
  if (s.departure > 0.0) {
    return Format(
               "Deflection falls with thickness more slowly than the chain's ~1/h: the %g mm "
               "beam %s reaches %.2fx %s, not %.2fx (%.0f %% short). Hypotheses, best supported "
               "first. (1) A load resisting the bending, e.g. the beam's weight net of "
               "buoyancy when it hangs and bends sideways: against the stiffness E W h^3 it "
               "grows as L^3/h^2 and does not depend on W, so it holds thin beams back more%s; "
               "signature: the departure changes with the beam's orientation and with the "
               "density difference between gel and electrolyte. (2) Ions crossing a thin "
               "beam even out its two faces (back-relaxation, which the seed reports), so a thin "
               "beam keeps less differential swelling; signature: %s peaks earlier and relaxes "
               "more after the peak, and the ratio depends on when the maximum is read. (3) The "
               "printed material depends on thickness (a %g mm print has fewer layers, another "
               "crosslink gradient and porosity), so E no longer cancels and the beams are not "
               "the same gel; signature: modulus or swelling ratio of %g and %g mm prints "
               "differ. Not a short hold: holding less than h^2/D charges only a surface layer "
               "~sqrt(D t), the same for every h, which steepens the chain's exponent toward -2 "
               "instead. ",
               s.varied_mm, s.varied_name.c_str(), s.measured_ratio, s.reference_name.c_str(),
               s.predicted_ratio, 100.0 * shortfall,
               resisting_load_fits_both ? "; the only hypothesis here that also lowers the length "
                                          "exponent, as measured"
                                        : "",
               s.varied_name.c_str(), s.varied_mm, s.varied_mm, s.reference_mm) +
           ShortHoldSentence(r, d);
  }
  return std::string(
             "Deflection falls with thickness faster than the chain's ~1/h: the thick beam is "
             "held back. Hypotheses: (1) diffusion-limited charging: a hold shorter than "
             "h^2/D leaves the thick beam partly charged (the chain's exponent tends to -2 "
             "for short holds); signature: the ratio approaches the steady one for long "
             "holds. (2) Actuation confined to a surface layer independent of h. ") +
         ShortHoldSentence(r, d);
}

std::string ExplainLength(const Table1Report& r, const DimensionFinding& d,
                          bool resisting_load_fits_both) {
  const model::Table1Scaling& s = d.scaling;
  if (!s.departs) return "Within Table 1's reading precision of the chain; nothing to explain.";
  const double arc_effect = r.small_bending_length_exponent - s.predicted_exponent;
  const std::string not_arc = Format(
      "Not large-deflection geometry: the arc formula is already in the chain and lowers the "
      "exponent only by %.3f from the small-bending %.2f. ",
      arc_effect, r.small_bending_length_exponent);
  if (s.departure < 0.0) {
    const double excess = s.measured_ratio / s.predicted_ratio - 1.0;
    return Format(
               "Deflection grows with length more slowly than the chain's ~L^2: the %g mm beam "
               "%s reaches %.3f of %s instead of %.3f (%.0f %% more), i.e. the long beam falls "
               "short. Hypotheses, best supported first. (1) A load resisting the bending (the "
               "weight net of buoyancy of a hanging beam), whose share grows as L^3 against the "
               "stiffness%s; signature: the departure changes with orientation and with the "
               "density difference between gel and electrolyte. (2) "
               "Actuation weaker toward the tip of a long beam (a field between electrodes "
               "shorter than the beam, or a far end that sits in a weaker field); signature: "
               "curvature not uniform along the beam, the tip straighter than the root. ",
               s.varied_mm, s.varied_name.c_str(), s.measured_ratio, s.reference_name.c_str(),
               s.predicted_ratio, 100.0 * excess,
               resisting_load_fits_both ? "; it also explains the thickness departure" : "") +
           not_arc +
           "Clamp compliance alone does not act: free bending by swelling puts no moment on the "
           "clamp, so it matters only together with a load. " +
           ShortHoldSentence(r, d);
  }
  return std::string(
             "Deflection grows with length faster than the chain's ~L^2: the short beam falls "
             "short. Hypotheses: (1) a clamped or electrode-shielded root length that does not "
             "bend, the same for every beam, so the free length is shorter than nominal; "
             "signature: a straight segment at the root. ") +
         not_arc + ShortHoldSentence(r, d);
}

std::string ExplainWidth(const Table1Report& r, const DimensionFinding& d) {
  const model::Table1Scaling& s = d.scaling;
  if (!s.departs) return "Within Table 1's reading precision of the chain; nothing to explain.";
  const model::Table1Row& reference = Row(r, s.reference_name);
  const model::Table1Row& varied = Row(r, s.varied_name);
  // Searle's plate parameter W^2 K/h: << 1 narrow beam (free anticlastic curvature),
  // >> 1 plate (bent in plane strain).
  auto plate_parameter = [](const model::Table1Row& row) {
    return 1e-3 * row.W_mm * 1e-3 * row.W_mm * row.predicted_curvature_per_m / (1e-3 * row.h_mm);
  };
  const std::string common = Format(
      "The change is small (%s deflects %.0f %% %s than %s); Table 1 gives no trial-to-trial "
      "scatter and the seed itself reads it as almost no correlation, so it may lie within "
      "repeatability. ",
      s.varied_name.c_str(), 100.0 * std::abs(1.0 - s.measured_ratio),
      s.measured_ratio < 1.0 ? "less" : "more", s.reference_name.c_str());
  if (s.departure > 0.0) {
    return common +
           Format(
               "If real, hypotheses: (1) edge zones that bend less than the centre (the side "
               "faces exchange ions on both sides alike; their share 2h/W is %.2f in %s and "
               "%.2f in %s); signature: curvature varying across the width, narrow beams "
               "weaker in proportion to h/W. (2) The printed pattern is not the same at half "
               "the width (fewer filaments); signature: porosity or modulus differ. (3) "
               "Plate stiffening of the wider strip (bent in plane strain, swelling gives up "
               "to (1+nu) more curvature) points the right way, but the plate parameter W^2 "
               "K/h is %.2f (%s) and %.2f (%s), both in the narrow-beam range, so it should "
               "stay far below the measured change. A load resisting the bending does not "
               "depend on W, and a short hold (the larger face charges more slowly through the "
               "cell's R_s) would hold the wider beam back, the opposite direction.",
               2.0 * reference.h_mm / reference.W_mm, reference.name.c_str(),
               2.0 * varied.h_mm / varied.W_mm, varied.name.c_str(), plate_parameter(reference),
               reference.name.c_str(), plate_parameter(varied), varied.name.c_str());
  }
  return common +
         "If real, hypotheses: (1) the larger face of the wider beam charges more slowly "
         "through the cell's resistance (the chain does this for short holds); (2) the printed "
         "pattern differs with width. " +
         ShortHoldSentence(r, d);
}

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

  const DimensionFinding* thickness = nullptr;
  const DimensionFinding* length = nullptr;
  const DimensionFinding* width = nullptr;
  for (const auto& d : r.dimensions) {
    if (d.scaling.dimension == model::BeamDimension::kThickness) thickness = &d;
    if (d.scaling.dimension == model::BeamDimension::kLength) length = &d;
    if (d.scaling.dimension == model::BeamDimension::kWidth) width = &d;
  }
  // A load resisting the bending holds back long and thin beams: a negative length and a
  // positive thickness departure.
  const bool load_fits_both = thickness && length && thickness->scaling.departs &&
                              length->scaling.departs && thickness->scaling.departure > 0.0 &&
                              length->scaling.departure < 0.0;
  for (auto& d : r.dimensions) {
    switch (d.scaling.dimension) {
      case model::BeamDimension::kThickness:
        d.explanation = ExplainThickness(r, d, load_fits_both);
        break;
      case model::BeamDimension::kLength:
        d.explanation = ExplainLength(r, d, load_fits_both);
        break;
      case model::BeamDimension::kWidth:
        d.explanation = ExplainWidth(r, d);
        break;
    }
  }

  // Findings, for the human output: one line per departing dimension, largest first, then
  // what the signs of the departures say.
  for (size_t k = 0; k < r.departing.size(); ++k) {
    const model::Table1Scaling& s = r.dimensions[r.departing[k]].scaling;
    std::string name(model::Name(s.dimension));
    name[0] = static_cast<char>(std::toupper(static_cast<unsigned char>(name[0])));
    r.findings.push_back(
        Format("%s departs%s: %+.2f measured vs %+.2f chain (+-%.3f): %s/%s is %.3f, not %.3f%s.",
               name.c_str(), k == 0 ? " most" : "", Clean(s.measured_exponent, 0.01),
               Clean(s.predicted_exponent, 0.01), s.exponent_uncertainty, s.varied_name.c_str(),
               s.reference_name.c_str(), s.measured_ratio, s.predicted_ratio,
               s.dimension == model::BeamDimension::kWidth ? " (no scatter given)" : ""));
  }
  if (r.departing.empty())
    r.findings.push_back("No dimension departs beyond Table 1's reading precision.");
  if (thickness && thickness->scaling.departs && !thickness->has_matching_hold)
    r.findings.push_back(Format(
        "Not a short hold: holding < h^2/D steepens the chain's h exponent (%.2f..%.2f), never "
        "%.2f.",
        thickness->chain_min_exponent, thickness->chain_max_exponent,
        thickness->scaling.measured_exponent));
  if (load_fits_both)
    r.findings.push_back(
        "Long and thin beams both fall short: a load resisting bending (share ~L^3/h^2, not W) "
        "fits both.");
  if (thickness && thickness->scaling.departs && thickness->scaling.departure > 0.0)
    r.findings.push_back(
        std::string("h alone: ion equalisation across thin beams (back-relaxation), a "
                    "print-dependent gel") +
        (width && width->scaling.departs && width->scaling.departure > 0.0 ? "; W: edge zones."
                                                                           : "."));

  r.notes = {
      Format("Reading precision: Table 1 prints deflections with two decimals, so each is "
             "+-%g mm; the exponent uncertainty is the range of the exponent over those ends. "
             "L, W and h are taken as the nominal printed sizes (their tolerance is not given).",
             model::kSeedTable1DeflectionHalfUnit_mm),
      "Table 1 gives one value per beam and no trial-to-trial scatter, so reading precision is "
      "a lower bound on the uncertainty: 'departs' means beyond reading precision only.",
      Format("Chain (model/physics/physics.h): K = 3 alpha C_dl (1 + h/delta) V/(W L h^2) with "
             "C_dl ~ W "
             "L, so K does not depend on W or L and goes as (1 + h/delta)/h^2, ~1/h for h/delta "
             "= %.0f (it would be ~1/h^2 if only the double layer held charge); deflection is "
             "the arc of K over L (~K L^2/2). The predicted exponents depend on the illustrative "
             "parameters only through h/delta and the small arc correction.",
             r.parameters.h_m / r.parameters.delta_m),
      Format("Hold time: the seed does not state how long 5 V was held for Table 1. Its other 5 "
             "V tests hold %g s (220 s square wave, 50 %% duty) and %g s (0.0025 Hz square "
             "wave); the slowest diffusion time 4 h^2/(pi^2 D) of each beam is in 'beams' (D is "
             "illustrative).",
             kSeedSquareWaveHold_s, kSeedLowestFrequencyHold_s),
      Format("Weight against stiffness: with the illustrative E = %g Pa (not measured), a gel "
             "denser than the electrolyte by only %.0f (%s), %.0f (%s) or %.0f (%s) kg/m^3 "
             "makes 12 drho g L^3/(E h^2) = 1.",
             r.parameters.E_Pa, CriticalDensityContrast_kg_m3(r, Row(r, "S2")), "S2",
             CriticalDensityContrast_kg_m3(r, Row(r, "S1")), "S1",
             CriticalDensityContrast_kg_m3(r, Row(r, "S4")), "S4"),
      "One beam per dimension: the hypotheses are ranked by the signs of the departures, not "
      "fitted; telling them apart needs new measurements (their signatures).",
  };
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

void RunTable1(const PhysicsOptions& options) {
  // Table 1 was measured at 5 V and the analysis is of those measurements: the options that
  // change the chain's voltage or print its models do not apply.
  if (options.terms_option->count() > 0)
    throw UsageError("--table1 analyses Table 1 only; --terms does not apply");
  if (options.voltage_option->count() > 0)
    throw UsageError("--table1 compares with Table 1's 5 V measurements; --voltage does not apply");
  Table1Report report;
  try {
    report = ComputeTable1();
  } catch (const std::invalid_argument& e) {
    throw OperationError(std::string("physics --table1: ") + e.what());
  }
  if (options.json) {
    std::cout << Table1Json(report).dump(2) << "\n";
  } else {
    PrintTable1Human(report);
  }
}

void Run(const PhysicsOptions& options) {
  if (options.table1) return RunTable1(options);
  if (!std::isfinite(options.voltage_V) || !(options.voltage_V > 0.0)) {
    char value[32];
    std::snprintf(value, sizeof value, "%g", options.voltage_V);
    throw UsageError(std::string("--voltage must be finite and > 0, got ") + value);
  }
  if (options.terms_option->count() > 0 &&
      (options.terms < 1 || options.terms > model::kMaxTransferFunctionTerms))
    throw UsageError("--terms must be in 1.." + std::to_string(model::kMaxTransferFunctionTerms) +
                     ", got " + std::to_string(options.terms));
  PhysicsReport report;
  try {
    report = Compute(options);
  } catch (const std::invalid_argument& e) {
    throw OperationError(std::string("physics: ") + e.what());
  }
  if (options.json) {
    std::cout << ToJson(report, options.terms).dump(2) << "\n";
  } else {
    PrintHuman(report, options.terms);
  }
}

}  // namespace

void RegisterPhysicsCommand(CLI::App& app) {
  auto options = std::make_shared<PhysicsOptions>();
  CLI::App* sub = app.add_subcommand(
      "physics",
      "What the seed's physics chain (Eqs. 1-13) predicts for actuator S1: parameters, exact "
      "Eq. (11) vs the N-term rational model, and Table 1 predicted vs measured");
  sub->footer(
      "Examples:\n"
      "  flexid physics\n"
      "  flexid physics --terms 3 --voltage 2\n"
      "  flexid physics --json\n"
      "  flexid physics --table1          # how Table 1 departs from the chain's scaling\n"
      "  flexid physics --table1 --json\n");
  sub->add_flag(
      "--json", options->json,
      "Print one JSON document (parameters, truncation, table1; with --table1 only the Table 1 "
      "analysis)");
  options->terms_option =
      sub->add_option("--terms", options->terms,
                      "Also print the coefficients of the N-term model (1.." +
                          std::to_string(model::kMaxTransferFunctionTerms) + ")");
  options->voltage_option = sub->add_option("--voltage", options->voltage_V,
                                            "Applied voltage in V for the steady deflections (> 0)")
                                ->capture_default_str();
  sub->add_flag("--table1", options->table1,
                "Only Table 1: predicted vs measured scaling of the deflection with L, W and h, "
                "which dimension departs beyond reading precision, and hypotheses why");
  sub->callback([options] { Run(*options); });
}

}  // namespace flexid::cli
