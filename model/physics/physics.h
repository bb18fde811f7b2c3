// The seed paper's physics chain (Zolfagharian et al. 2019, section 3.1-3.2, Eqs. 1-13)
// from applied voltage to tip deflection of an ionic hydrogel beam, and what it predicts
// for the geometry study of section 3.4 (Table 1).
//
// Notation (the paper's symbols; SI units throughout):
//   D      ion diffusion coefficient in the gel                      [m^2/s]
//   delta  double-layer thickness                                    [m]
//   C_dl   double-layer capacitance of this beam                     [F]
//   R_s    solution (electrolyte) resistance of the cell             [ohm]
//   alpha  strain-to-charge ratio, eps = alpha rho (Eq. 5)           [m^3/C]
//   E      Young's modulus of the gel                                [Pa]
//   L,W,h  beam length, width and thickness                          [m]
//   rho    charge density Q / (W L h) with Q(s) = I(s)/s (Eq. 6)     [C/m^3]
//   K      bending curvature (Eq. 7)                                 [1/m]
//
// Chain. Eqs. (1)-(3) (Fick diffusion through the thickness behind a double layer, in series
// with R_s, Figure 2) give I/V (Eq. 4). Dividing by s (Eq. 6) gives the stored charge
//
//   Q(s)/V(s) = 1 / ( s R_s + 1 / C_eff(s) ),
//   C_eff(s)  = C_dl [1 + Z(s)],   Z(s) = sqrt(D)/(delta sqrt(s)) tanh(h sqrt(s/D)),
//
// and the moment balance of Eq. (9) gives K = phi rho, so (Eq. 11, the "Y" on its left is
// this curvature)
//
//   K(s)/V(s) = phi/(W L h) * Q(s)/V(s).
//
// phi: the moment balance of Eq. (9) with the stress of Eq. (8) written as
// sigma = E (K y -+ alpha rho) (the paper drops the y) gives E K h^3/12 = E alpha rho h^2/4,
// i.e. phi = 3 alpha / h: E cancels. The paper prints phi = 3 alpha/(E h), which is
// dimensionally inconsistent with alpha as the strain-to-charge ratio of Eq. (5) (it would
// need alpha in Pa m^3/C, a stress-to-charge ratio). flexid uses phi = 3 alpha / h; the
// paper's form is recovered with alpha_paper = E alpha. Since alpha is calibrated to the
// measured deflection (below), the predictions are the same either way; only the reported
// alpha differs. E is kept in PhysicalParameters for completeness (it matters for blocking
// force, not for free bending).
//
// Z(s) in terms of x = h sqrt(s/D) is Z = (h/delta) tanh(x)/x, so Z(0) = h/delta and the
// static charge is Q = C_dl (1 + h/delta) V.
//
// Rational truncation (Eqs. 12-13; Eq. 12 is garbled in the paper, see SEED-NOTES item 6).
// The Mittag-Leffler expansion of tanh gives
//
//   Z(s) = sum_{n>=0} a / (s + p_n),   a = 2 D/(h delta),   p_n = (2n+1)^2 pi^2 D/(4 h^2),
//
// a sum of real negative poles with equal residues. Read as a circuit, every term is a
// branch R_d + C_n (R_d = 1/(C_dl a), C_n = C_dl a/p_n) in parallel with C_dl; with R_s in
// series the cell is an RC network, so the poles and zeros of Q/V are real, negative and
// interlaced (Foster). Keeping N terms
// gives N zeros and N+1 poles (N = 3: the 3 zeros / 4 poles of Eq. 13). The terms fall
// off as 1/n^2, so the truncation converges slowly: the left-out static part is
// sum_{n>=N} a/p_n ~ (2/pi^2) (h/delta) / N, and the N-term model's DC gain is below the
// exact one by about that fraction (6.7 % of the diffusion part for N = 3, 0.2 % for
// N = 100). SeriesRemainder::kStaticCorrection adds that left-out static part back as a
// constant capacitance so that DC is exact.
//
// Arc geometry (SEED-NOTES item 5). A beam of length L bent to a circular arc of curvature
// K has its tip at y = (1 - cos(K L)) / K from the initial tangent line (~ K L^2 / 2 for
// small bending). The right-hand side of Eq. (11), Y = 1/K +- sqrt(1/K^2 - L^2), is a
// garbled form of the same arc geometry: 1/K - sqrt(1/K^2 - L^2) is the height of a circle
// of radius 1/K above its tangent at a horizontal distance L, i.e. it takes L as the
// projected length instead of the arc length (and has no value for K L > 1); flexid uses
// the arc formula.
#pragma once

#include <array>
#include <complex>
#include <string>
#include <string_view>
#include <vector>

#include "model/core/transfer_function.h"

namespace flexid::model {

struct PhysicalParameters {
  double D_m2_per_s = 0.0;      // ion diffusion coefficient D
  double delta_m = 0.0;         // double-layer thickness delta
  double C_dl_F = 0.0;          // double-layer capacitance C_dl of this beam
  double R_s_ohm = 0.0;         // solution resistance R_s
  double alpha_m3_per_C = 0.0;  // strain-to-charge ratio alpha (Eq. 5)
  double E_Pa = 0.0;            // Young's modulus E (cancels from free-bending curvature)
  double L_m = 0.0;             // beam length L
  double W_m = 0.0;             // beam width W
  double h_m = 0.0;             // beam thickness h
};

// True if every parameter is finite and > 0; otherwise false and a sentence naming the
// first bad parameter in *error (if error is not null).
bool IsValid(const PhysicalParameters& p, std::string* error);

// Table 1 of the seed paper (section 3.4): maximum tip deflection at 5 V in 0.12 M NaOH
// for four geometries of the same printed pattern. Measured data, not model output.
struct Table1Measurement {
  std::string_view name;
  double L_mm = 0.0;
  double W_mm = 0.0;
  double h_mm = 0.0;
  double max_deflection_mm = 0.0;
};
inline constexpr double kSeedTable1Voltage_V = 5.0;
inline constexpr std::array<Table1Measurement, 4> kSeedTable1 = {{
    {"S1", 40.0, 8.0, 2.0, 5.92},
    {"S2", 40.0, 8.0, 1.0, 8.27},
    {"S3", 40.0, 4.0, 2.0, 5.38},
    {"S4", 20.0, 8.0, 2.0, 1.83},
}};

// Illustrative parameters for actuator S1 (40 x 8 x 2 mm, 0.12 M NaOH). The paper gives no
// values; these are chosen as follows.
//   D     = 1.6e-8 m^2/s. The slowest diffusion pole p_0 = pi^2 D/(4 h^2) then has the time
//           constant 4 h^2/(pi^2 D) = 101 s, matching the seed's identified slow poles (tens
//           of seconds to ~120 s). This is an effective transport rate, 12 times the
//           diffusivity of free Na+ in water (1.33e-9 m^2/s, which would give ~1200 s);
//           read it as a fitted rate, not as a measured diffusivity.
//   C_dl  = 0.2 F/m^2 (20 uF/cm^2, the textbook double-layer capacitance of an aqueous
//           interface) times the face area W L = 3.2e-4 m^2: 6.4e-5 F.
//   R_s   = 50 ohm: 0.12 M NaOH conducts ~2.5 S/m; 2 cm of electrolyte of 1.6 cm^2 cross
//           section is ~50 ohm. R_s C_dl = 3.2 ms (well below "a few seconds").
//   delta = 1 um, so h/delta = 2000: the gel stores 2000 times the double layer's charge at
//           DC. This is an effective thickness, not the 0.9 nm Debye length: with the Debye
//           length, h/delta ~ 2e6 and the cell time constant R_s C_dl h/delta would be
//           hours, so the slow pole would be set by the cell, not by diffusion, against the
//           seed's identified time constants. With 1 um, R_s C_dl (8/pi^2) h/delta = 5.2 s
//           only shifts the slowest mode from 101 s to about 106 s.
//   E     = 1e5 Pa, a typical modulus of a soft chitosan hydrogel (cancels, see above).
//   alpha = CalibrateAlpha(..., 5 V, 5.92 mm): the only parameter fitted, chosen so that the
//           steady tip deflection at 5 V is Table 1's 5.92 mm (S1). Result: 4.97e-9 m^3/C
//           (actuation strain alpha rho = 5.0e-3 at the stored charge density of 1.0e6
//           C/m^3; steady curvature 7.46 1/m, bend angle K L = 0.30 rad).
PhysicalParameters SeedS1Parameters();

// ---- Exact model, Eq. (11) ----

// Diffusion term Z(s) = sqrt(D)/(delta sqrt(s)) tanh(h sqrt(s/D)) = (h/delta)
// tanh(x)/x, x = h sqrt(s/D) (principal root). Safe at s = 0 (Z = h/delta) and for large
// |s| (tanh is evaluated as (1 - e^{-2x})/(1 + e^{-2x}) with Re x >= 0, which cannot
// overflow). Dimensionless. Infinite at the poles s = -p_n on the negative real axis.
std::complex<double> DiffusionTerm(const PhysicalParameters& p, std::complex<double> s);

// Charge-to-curvature factor phi/(W L h) = 3 alpha/(W L h^2) [1/(m C)] (Eqs. 6 and 9).
double CurvaturePerCharge_per_m_C(const PhysicalParameters& p);

// K(s)/V(s) of Eq. (11) with the complex tanh, in 1/(m V). Precondition (checked,
// std::invalid_argument): IsValid(p).
std::complex<double> CurvaturePerVoltExact(const PhysicalParameters& p, std::complex<double> s);

// K(0)/V(0) = phi/(W L h) C_dl (1 + h/delta), in 1/(m V).
double DcCurvaturePerVolt(const PhysicalParameters& p);

// p_n = (2n+1)^2 pi^2 D/(4 h^2) in rad/s (n >= 0): the poles of the series for Z(s).
double DiffusionPole_rad_s(const PhysicalParameters& p, int n);

// 1/p_0 = 4 h^2/(pi^2 D): time constant of the slowest diffusion mode, in s.
double SlowestDiffusionTimeConstant_s(const PhysicalParameters& p);

// ---- Rational truncation, Eqs. (12)-(13) ----

enum class SeriesRemainder {
  // Eq. (13) as in the paper: the terms n >= N are dropped. DC gain below the exact one.
  kDropped,
  // The dropped terms' static value sum_{n>=N} a/p_n is added to C_eff as a constant
  // capacitance: same structure (N zeros, N+1 poles), DC gain exact. The dropped terms'
  // frequency dependence is still missing, and the constant sits in parallel with C_dl, so
  // it also slows the cell pole ~1/(R_s C_dl) by the factor 1 + r (r = 134 for S1 at
  // N = 3: 360 -> 2.7 rad/s). For S1 its largest error on the default grid exceeds
  // kDropped's for N <= 2 and is smaller from N = 3 on.
  kStaticCorrection,
};

// Largest number of terms CurvatureTransferFunction accepts. The polynomial coefficients
// span many orders of magnitude (p_n grows like n^2: 1 .. 8e14 at N = 20, 1 .. 9e28 at
// N = 30), and the roots found from them lose accuracy fast: for S1 they are good to ~1e-9
// at N = 15 and ~1e-6 at N = 20, while at N = 30 some come out complex or positive, so
// companion-form simulation would be meaningless. For accuracy studies with more terms use
// CurvaturePerVoltTruncated, which evaluates the same function in pole-residue form.
inline constexpr int kMaxTransferFunctionTerms = 20;

// The N-term model as a transfer function: curvature in 1/m per volt, with
//   C_eff_N(s) = C_dl [1 + r + sum_{n<N} a/(s + p_n)]   (r = 0, or the static remainder),
//   K/V = phi/(W L h) C_eff_N / (s R_s C_eff_N + 1),
// numerator degree N, denominator degree N+1, denominator monic. delay_s is the dead time
// (the seed's e^{beta s}, beta = -delay_s); the physics chain itself has none.
// Preconditions (checked, std::invalid_argument): IsValid(p); 1 <= terms <=
// kMaxTransferFunctionTerms; delay_s finite and >= 0.
TransferFunction CurvatureTransferFunction(const PhysicalParameters& p, int terms,
                                           double delay_s = 0.0,
                                           SeriesRemainder remainder = SeriesRemainder::kDropped);

// The same N-term function (without dead time) evaluated in pole-residue form, which stays
// accurate for any N >= 1 (no polynomial coefficients). 1/(m V).
std::complex<double> CurvaturePerVoltTruncated(
    const PhysicalParameters& p, int terms, std::complex<double> s,
    SeriesRemainder remainder = SeriesRemainder::kDropped);

// Static value of the dropped terms (terms = N >= 0, checked), sum_{n>=N} a/p_n = (h/delta)(1 -
// (8/pi^2) sum_{n<N} 1/(2n+1)^2) (dimensionless; it multiplies C_dl).
double SeriesStaticRemainder(const PhysicalParameters& p, int terms);

// ---- Truncation error study ----

struct TruncationErrorRow {
  int terms = 0;
  // max over the grid of |G_N(jw) - G(jw)| / |G(jw)|, and where it occurs.
  double max_relative_error = 0.0;
  double omega_at_max_rad_s = 0.0;
  // (G_N(0) - G(0)) / G(0): negative, the N-term model is low at DC.
  double dc_relative_error = 0.0;
  double dc_truncated_per_m_V = 0.0;
  double dc_exact_per_m_V = 0.0;
  // The same maximum for the kStaticCorrection variant (its DC error is zero).
  double max_relative_error_static_correction = 0.0;
  double omega_at_max_static_correction_rad_s = 0.0;
};

// Log-spaced frequencies from 1e-4 to 10 rad/s, both included (points >= 2).
std::vector<double> DefaultTruncationGrid_rad_s(int points = 241);

// One row per entry of terms (each >= 1). omega_rad_s: finite and >= 0. Uses the
// pole-residue evaluation, so any N is accurate. Preconditions checked
// (std::invalid_argument).
std::vector<TruncationErrorRow> TruncationErrors(const PhysicalParameters& p,
                                                 const std::vector<int>& terms,
                                                 const std::vector<double>& omega_rad_s);

// ---- Arc geometry ----

// Tip deflection y = (1 - cos(K L)) / K = 2 sin^2(K L/2) / K of a beam of length L bent to
// a circular arc of curvature K, measured from the initial tangent line, in m. For
// |K L| < 1e-4 the series K L^2/2 (1 - (K L)^2/12) is used (exact to double precision
// there). Odd in K: negative curvature gives negative deflection.
double TipDeflectionFromCurvature_m(double curvature_per_m, double L_m);

// Inverse of TipDeflectionFromCurvature_m on the branch 0 <= |K| L <= theta_max = 2.3311
// rad, where the tip deflection is largest (0.7246 L). Odd in y. Precondition (checked,
// std::invalid_argument): L > 0, |y| <= 0.7246 L, both finite.
double CurvatureFromTipDeflection_per_m(double deflection_m, double L_m);

// ---- Calibration and geometry ----

// Steady tip deflection under a constant voltage: exact DC curvature (Eq. 11 at s = 0)
// and the arc formula, in mm. Precondition (checked): IsValid(p), voltage finite.
double SteadyTipDeflection_mm(const PhysicalParameters& p, double voltage_V);

// The alpha (m^3/C) for which SteadyTipDeflection_mm(p, voltage_V) == target_deflection_mm.
// p.alpha_m3_per_C is ignored (the rest of p must be valid). The target curvature is found
// from the exact arc formula (CurvatureFromTipDeflection_per_m), and since the DC curvature
// is proportional to alpha, alpha = K_target / (K per unit alpha). Preconditions (checked,
// std::invalid_argument): voltage_V and target_deflection_mm finite and > 0, and the target
// reachable by an arc of length L (<= 0.7246 L).
double CalibrateAlpha(PhysicalParameters p, double voltage_V, double target_deflection_mm);

// Scaling assumption for another beam of the same gel in the same cell:
//   C_dl proportional to the face area W L that faces the electrolyte;
//   R_s set by the cell, independent of the beam;
//   D, delta, alpha, E material constants.
// Consequence: the DC curvature 3 alpha (C_dl/(W L)) (1 + h/delta) V / h^2 depends on h
// only (~ 1/(delta h) for h >> delta), so the steady deflection does not depend on W and
// grows like L^2 for small bending. Precondition (checked): lengths finite and > 0,
// IsValid(reference).
PhysicalParameters WithGeometry(const PhysicalParameters& reference, double L_m, double W_m,
                                double h_m);

struct Table1Row {
  std::string name;  // S1..S4
  double L_mm = 0.0;
  double W_mm = 0.0;
  double h_mm = 0.0;
  double predicted_curvature_per_m = 0.0;  // exact DC curvature at the voltage
  double predicted_deflection_mm = 0.0;    // arc formula
  double measured_deflection_mm = 0.0;     // kSeedTable1
  double predicted_ratio_to_s1 = 0.0;
  double measured_ratio_to_s1 = 0.0;
};

// Predicted steady deflections for the geometries of kSeedTable1, each built with
// WithGeometry from s1_reference (which should describe S1), next to the measured values.
// Rows in kSeedTable1 order; the first is S1.
std::vector<Table1Row> PredictTable1(const PhysicalParameters& s1_reference,
                                     double voltage_V = kSeedTable1Voltage_V);

// ---- Step response: Eq. (11) in the time domain ----

// Curvature t_s seconds after the voltage steps from 0 to voltage_V (the beam at rest and
// uncharged before), in 1/m: the inverse Laplace transform of voltage_V K(s)/(V(s) s) with
// the exact Eq. (11), by the fixed Talbot method (Abate and Valko 2004, Int. J. Numer.
// Meth. Eng. 60:979) with 24 nodes. Every singularity of Eq. (11) is real and negative (the
// RC network of the header), the case that contour is made for; the tests find it good to
// ~1e-9. The cell is an RC admittance, so the charge, and with it K, rises monotonically to
// DcCurvaturePerVolt(p) voltage_V. Early on (t << 4 h^2/(pi^2 D)) only a surface layer of
// depth ~sqrt(D t) holds charge, the same for every h, so K ~ 1/h^2 there instead of the
// steady ~1/h; and while t is not >> the cell time R_s C_dl (1 + h/delta), a beam of larger
// face area W L (C_dl ~ W L, R_s fixed) lags. Preconditions (checked,
// std::invalid_argument): IsValid(p), voltage_V finite, t_s finite and > 0.
double StepCurvature_per_m(const PhysicalParameters& p, double voltage_V, double t_s);

// PredictTable1 for a voltage held hold_s seconds from rest instead of until steady: each
// row's predicted curvature is StepCurvature_per_m at hold_s (the largest value during the
// hold, since the step response is monotone) and its deflection the arc formula of that.
// alpha stays s1_reference's (calibrated on the steady state), so S1's prediction falls
// below Table 1's for short holds; compare the ratios. Preconditions (checked): those of
// PredictTable1, hold_s finite and > 0.
std::vector<Table1Row> PredictTable1AfterHold(const PhysicalParameters& s1_reference, double hold_s,
                                              double voltage_V = kSeedTable1Voltage_V);

// ---- Table 1 scaling: exponents and reading precision ----

// Table 1 prints the deflections with two decimals, so each is known to +- half a unit in
// the last digit (the reading precision; the paper gives no trial-to-trial scatter for it).
inline constexpr double kSeedTable1DeflectionHalfUnit_mm = 0.005;

// Exponent n of the power law y ~ x^n through two points, n = ln(y_b/y_a) / ln(x_b/x_a):
// d ln y / d ln x over that step. Preconditions (checked, std::invalid_argument): all four
// finite and > 0, x_a != x_b.
double PowerLawExponent(double y_a, double y_b, double x_a, double x_b);

struct ExponentRange {
  double low = 0.0;
  double high = 0.0;
};

// Range of PowerLawExponent(y_a, y_b, x_a, x_b) when y_a and y_b are each known only to
// +- y_half_unit: the exponent is monotone in each, so the ends are at (y_a -+ u, y_b +- u).
// Preconditions (checked): those of PowerLawExponent, 0 <= y_half_unit < min(y_a, y_b).
ExponentRange PowerLawExponentRange(double y_a, double y_b, double x_a, double x_b,
                                    double y_half_unit);

enum class BeamDimension { kLength, kWidth, kThickness };
std::string_view Name(BeamDimension dimension);  // "length", "width", "thickness"

// How the deflection scales with one beam dimension between two rows of Table 1 that differ
// in that dimension only. Ratios and exponents are varied / reference.
struct Table1Scaling {
  BeamDimension dimension = BeamDimension::kLength;
  std::string reference_name;  // the first row (S1)
  std::string varied_name;     // the row that differs from it in this dimension only
  double reference_mm = 0.0;   // the dimension in the reference row
  double varied_mm = 0.0;      // ... and in the varied row
  double predicted_ratio = 0.0;
  double measured_ratio = 0.0;
  double predicted_exponent = 0.0;        // d ln(deflection) / d ln(dimension), the chain
  double measured_exponent = 0.0;         // the same from Table 1
  ExponentRange measured_exponent_range;  // from the reading precision of both deflections
  double exponent_uncertainty = 0.0;      // largest distance of that range's ends from measured
  double departure = 0.0;                 // measured_exponent - predicted_exponent
  bool departs = false;                   // |departure| > exponent_uncertainty
};

// One entry for every row after the first that differs from the first in exactly one of
// L, W and h, in row order (rows that differ in none or in several are skipped): for
// PredictTable1 thickness (S2), width (S3), length (S4). The predicted exponent uses the
// rows' predicted deflections, the measured one the measured deflections, each uncertain by
// +- deflection_half_unit_mm. Preconditions (checked, std::invalid_argument): deflections
// and dimensions finite and > 0, 0 <= deflection_half_unit_mm < every measured deflection.
std::vector<Table1Scaling> AnalyseTable1Scaling(
    const std::vector<Table1Row>& rows,
    double deflection_half_unit_mm = kSeedTable1DeflectionHalfUnit_mm);

}  // namespace flexid::model
