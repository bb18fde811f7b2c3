// flexid physics --table1 in words (physics_table1.h): for each dimension that departs from
// the chain's scaling, the hypotheses that could explain it, best supported first, with the
// signature that would tell them apart; the findings, one line each; and the notes on
// reading precision, the chain, hold times and weight.
#include <cctype>
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

#include "clients/cli/physics_table1.h"
#include "model/physics/physics.h"

namespace flexid::cli::physics {
namespace {

// Standard gravity, for the weight-to-stiffness number of a beam.
constexpr double kGravity_m_s2 = 9.81;

const model::Table1Row& Row(const Table1Report& r, const std::string& name) {
  for (const auto& row : r.rows)
    if (row.name == name) return row;
  throw std::invalid_argument("no Table 1 row " + name);
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

}  // namespace

void ExplainTable1(Table1Report* report) {
  Table1Report& r = *report;
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
}

}  // namespace flexid::cli::physics
