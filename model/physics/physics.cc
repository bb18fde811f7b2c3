#include "model/physics/physics.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <stdexcept>

#include "model/core/polynomial.h"

namespace flexid::model {
namespace {

using Complex = std::complex<double>;
constexpr double kPi = std::numbers::pi;

// Below this |K L| the arc formula is replaced by its series (relative error of the
// two-term series there is (K L)^4/360 < 1e-18).
constexpr double kSmallBendAngle_rad = 1e-4;

std::string Show(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", value);
  return text;
}

void RequireValid(const PhysicalParameters& p) {
  std::string error;
  if (!IsValid(p, &error)) throw std::invalid_argument("physical parameters: " + error);
}

void RequireTerms(int terms, int max_terms) {
  if (terms < 1 || terms > max_terms)
    throw std::invalid_argument("terms must be in 1.." + std::to_string(max_terms) + ", got " +
                                std::to_string(terms));
}

// tanh(x)/x for Re x >= 0. Near 0 its Taylor series (the next term, -1382 x^10/155925, is
// below 1e-15 for |x| < 0.05); elsewhere tanh(x) = (1 - e^{-2x})/(1 + e^{-2x}), where
// |e^{-2x}| <= 1 so nothing overflows for large |x| (tanh -> 1).
Complex TanhOverX(Complex x) {
  if (std::abs(x) < 0.05) {
    const Complex x2 = x * x;
    return 1.0 + x2 * (-1.0 / 3.0 + x2 * (2.0 / 15.0 + x2 * (-17.0 / 315.0 + x2 * 62.0 / 2835.0)));
  }
  const Complex t = std::exp(-2.0 * x);
  return (1.0 - t) / ((1.0 + t) * x);
}

// Residue a = 2 D/(h delta) of every term of the Mittag-Leffler series (Eq. 12 corrected).
double SeriesResidue_rad_s(const PhysicalParameters& p) {
  return 2.0 * p.D_m2_per_s / (p.h_m * p.delta_m);
}

double Remainder(const PhysicalParameters& p, int terms, SeriesRemainder remainder) {
  return remainder == SeriesRemainder::kStaticCorrection ? SeriesStaticRemainder(p, terms) : 0.0;
}

// K/V = phi/(W L h) / (s R_s + 1/C_eff) (Eq. 11), given C_eff(s) in F.
Complex CurvaturePerVoltFromCapacitance(const PhysicalParameters& p, Complex s, Complex C_eff_F) {
  return CurvaturePerCharge_per_m_C(p) / (s * p.R_s_ohm + 1.0 / C_eff_F);
}

// (1 - cos t)/t = 2 sin^2(t/2)/t, with its series near 0 (odd in t).
double ArcDeflectionOverLength(double angle_rad) {
  if (std::abs(angle_rad) < kSmallBendAngle_rad)
    return 0.5 * angle_rad * (1.0 - angle_rad * angle_rad / 12.0);
  const double half_sine = std::sin(0.5 * angle_rad);
  return 2.0 * half_sine * half_sine / angle_rad;
}

// The bend angle theta = K L at which the tip deflection (1 - cos theta)/theta * L is
// largest: d/dtheta = 0 <=> theta sin(theta) = 1 - cos(theta), a root in (2, 2.5).
double MaxDeflectionAngle_rad() {
  double lo = 2.0;
  double hi = 2.5;
  for (int i = 0; i < 200; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (mid <= lo || mid >= hi) break;
    (mid * std::sin(mid) - (1.0 - std::cos(mid)) > 0.0 ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

bool IsValid(const PhysicalParameters& p, std::string* error) {
  const struct {
    const char* name;
    double value;
  } fields[] = {
      {"D_m2_per_s", p.D_m2_per_s},
      {"delta_m", p.delta_m},
      {"C_dl_F", p.C_dl_F},
      {"R_s_ohm", p.R_s_ohm},
      {"alpha_m3_per_C", p.alpha_m3_per_C},
      {"E_Pa", p.E_Pa},
      {"L_m", p.L_m},
      {"W_m", p.W_m},
      {"h_m", p.h_m},
  };
  for (const auto& field : fields) {
    if (!std::isfinite(field.value) || !(field.value > 0.0)) {
      if (error)
        *error = std::string(field.name) + " must be finite and > 0, got " + Show(field.value);
      return false;
    }
  }
  return true;
}

PhysicalParameters SeedS1Parameters() {
  // The reasons for each value are in physics.h.
  const Table1Measurement& s1 = kSeedTable1[0];
  PhysicalParameters p;
  p.L_m = s1.L_mm * 1e-3;
  p.W_m = s1.W_mm * 1e-3;
  p.h_m = s1.h_mm * 1e-3;
  p.D_m2_per_s = 1.6e-8;
  p.delta_m = 1e-6;
  constexpr double kSpecificCapacitance_F_per_m2 = 0.2;
  p.C_dl_F = kSpecificCapacitance_F_per_m2 * p.W_m * p.L_m;
  p.R_s_ohm = 50.0;
  p.E_Pa = 1e5;
  p.alpha_m3_per_C = 1.0;  // placeholder, replaced by the calibration
  p.alpha_m3_per_C = CalibrateAlpha(p, kSeedTable1Voltage_V, s1.max_deflection_mm);
  return p;
}

std::complex<double> DiffusionTerm(const PhysicalParameters& p, std::complex<double> s) {
  // Z = sqrt(D)/(delta sqrt s) tanh(h sqrt(s/D)) = (h/delta) tanh(x)/x, x = h sqrt(s/D),
  // since sqrt(D)/sqrt(s) = h/x. The principal root gives Re x >= 0; sqrt(s)/sqrt(D)
  // rather than sqrt(s/D) so that s/D cannot overflow for huge |s|.
  const Complex x = p.h_m * std::sqrt(s) / std::sqrt(p.D_m2_per_s);
  return (p.h_m / p.delta_m) * TanhOverX(x);
}

double CurvaturePerCharge_per_m_C(const PhysicalParameters& p) {
  // rho = Q/(W L h) (Eq. 6), K = phi rho with phi = 3 alpha/h (Eq. 9, see physics.h on E).
  const double phi_m2_per_C = 3.0 * p.alpha_m3_per_C / p.h_m;
  return phi_m2_per_C / (p.W_m * p.L_m * p.h_m);
}

std::complex<double> CurvaturePerVoltExact(const PhysicalParameters& p, std::complex<double> s) {
  RequireValid(p);
  // Eq. (11): C_eff = C_dl [1 + Z(s)].
  return CurvaturePerVoltFromCapacitance(p, s, p.C_dl_F * (1.0 + DiffusionTerm(p, s)));
}

double DcCurvaturePerVolt(const PhysicalParameters& p) {
  RequireValid(p);
  // s -> 0 in Eq. (11): s R_s -> 0 and Z -> h/delta, so K/V = phi/(W L h) C_dl (1 + h/delta).
  return CurvaturePerCharge_per_m_C(p) * p.C_dl_F * (1.0 + p.h_m / p.delta_m);
}

double DiffusionPole_rad_s(const PhysicalParameters& p, int n) {
  const double odd = 2.0 * n + 1.0;
  return odd * odd * kPi * kPi * p.D_m2_per_s / (4.0 * p.h_m * p.h_m);
}

double SlowestDiffusionTimeConstant_s(const PhysicalParameters& p) {
  return 1.0 / DiffusionPole_rad_s(p, 0);
}

double SeriesStaticRemainder(const PhysicalParameters& p, int terms) {
  // a/p_n = 8 h/(delta pi^2 (2n+1)^2) and sum_{n>=0} 1/(2n+1)^2 = pi^2/8, so the terms
  // n >= N hold (h/delta)(1 - (8/pi^2) sum_{n<N} 1/(2n+1)^2).
  if (terms < 0) throw std::invalid_argument("terms must be >= 0");
  double partial = 0.0;
  for (int n = terms - 1; n >= 0; --n) {  // smallest first
    const double odd = 2.0 * n + 1.0;
    partial += 1.0 / (odd * odd);
  }
  return (p.h_m / p.delta_m) * (1.0 - 8.0 / (kPi * kPi) * partial);
}

TransferFunction CurvatureTransferFunction(const PhysicalParameters& p, int terms, double delay_s,
                                           SeriesRemainder remainder) {
  RequireValid(p);
  RequireTerms(terms, kMaxTransferFunctionTerms);
  if (!std::isfinite(delay_s) || delay_s < 0.0)
    throw std::invalid_argument("delay_s must be finite and >= 0");

  // C_eff_N / C_dl = (1 + r) + sum_n a/(s + p_n) = P(s) / Pi(s) with
  //   Pi(s) = prod_n (s + p_n),   P(s) = (1 + r) Pi(s) + a sum_n prod_{m != n} (s + p_m).
  const double a = SeriesResidue_rad_s(p);
  std::vector<double> pole_product = {1.0};
  for (int n = 0; n < terms; ++n)
    pole_product = MultiplyPolynomials(pole_product, {1.0, DiffusionPole_rad_s(p, n)});
  std::vector<double> p_poly = pole_product;
  for (double& c : p_poly) c *= 1.0 + Remainder(p, terms, remainder);
  for (int n = 0; n < terms; ++n) {
    std::vector<double> others = {a};
    for (int m = 0; m < terms; ++m)
      if (m != n) others = MultiplyPolynomials(others, {1.0, DiffusionPole_rad_s(p, m)});
    p_poly = AddPolynomials(p_poly, others);
  }

  // Q/V = C_eff_N / (s R_s C_eff_N + 1) = C_dl P / (s R_s C_dl P + Pi); times phi/(W L h)
  // (Eqs. 6, 9, 11). Numerator degree N, denominator degree N + 1.
  TransferFunction tf;
  tf.num = p_poly;
  for (double& c : tf.num) c *= CurvaturePerCharge_per_m_C(p) * p.C_dl_F;
  std::vector<double> s_p = MultiplyPolynomials(p_poly, {p.R_s_ohm * p.C_dl_F, 0.0});
  tf.den = AddPolynomials(s_p, pole_product);
  tf.delay_s = delay_s;
  return Normalised(tf);
}

std::complex<double> CurvaturePerVoltTruncated(const PhysicalParameters& p, int terms,
                                               std::complex<double> s, SeriesRemainder remainder) {
  RequireValid(p);
  RequireTerms(terms, 1 << 30);
  const double a = SeriesResidue_rad_s(p);
  Complex sum = 0.0;
  for (int n = terms - 1; n >= 0; --n) sum += a / (s + DiffusionPole_rad_s(p, n));
  const Complex C_eff_F = p.C_dl_F * (1.0 + Remainder(p, terms, remainder) + sum);
  return CurvaturePerVoltFromCapacitance(p, s, C_eff_F);
}

std::vector<double> DefaultTruncationGrid_rad_s(int points) {
  if (points < 2) throw std::invalid_argument("the frequency grid needs at least 2 points");
  constexpr double kLogMin = -4.0;
  constexpr double kLogMax = 1.0;
  std::vector<double> grid(static_cast<size_t>(points));
  for (int i = 0; i < points; ++i)
    grid[static_cast<size_t>(i)] = std::pow(10.0, kLogMin + (kLogMax - kLogMin) * i / (points - 1));
  return grid;
}

std::vector<TruncationErrorRow> TruncationErrors(const PhysicalParameters& p,
                                                 const std::vector<int>& terms,
                                                 const std::vector<double>& omega_rad_s) {
  RequireValid(p);
  for (double w : omega_rad_s)
    if (!std::isfinite(w) || w < 0.0)
      throw std::invalid_argument("frequencies must be finite and >= 0");
  std::vector<Complex> exact;
  exact.reserve(omega_rad_s.size());
  for (double w : omega_rad_s) exact.push_back(CurvaturePerVoltExact(p, Complex(0.0, w)));

  std::vector<TruncationErrorRow> rows;
  for (int n_terms : terms) {
    RequireTerms(n_terms, 1 << 30);
    TruncationErrorRow row;
    row.terms = n_terms;
    row.dc_exact_per_m_V = DcCurvaturePerVolt(p);
    row.dc_truncated_per_m_V = CurvaturePerVoltTruncated(p, n_terms, 0.0).real();
    row.dc_relative_error =
        (row.dc_truncated_per_m_V - row.dc_exact_per_m_V) / row.dc_exact_per_m_V;
    for (size_t i = 0; i < omega_rad_s.size(); ++i) {
      const Complex s(0.0, omega_rad_s[i]);
      const double dropped =
          std::abs(CurvaturePerVoltTruncated(p, n_terms, s) - exact[i]) / std::abs(exact[i]);
      if (dropped > row.max_relative_error) {
        row.max_relative_error = dropped;
        row.omega_at_max_rad_s = omega_rad_s[i];
      }
      const double corrected =
          std::abs(CurvaturePerVoltTruncated(p, n_terms, s, SeriesRemainder::kStaticCorrection) -
                   exact[i]) /
          std::abs(exact[i]);
      if (corrected > row.max_relative_error_static_correction) {
        row.max_relative_error_static_correction = corrected;
        row.omega_at_max_static_correction_rad_s = omega_rad_s[i];
      }
    }
    rows.push_back(row);
  }
  return rows;
}

double TipDeflectionFromCurvature_m(double curvature_per_m, double L_m) {
  // Circular arc of length L and curvature K (SEED-NOTES item 5; Eq. 11's right-hand
  // 1/K +- sqrt(1/K^2 - L^2) is a garbled form): y = (1 - cos K L)/K.
  return L_m * ArcDeflectionOverLength(curvature_per_m * L_m);
}

double CurvatureFromTipDeflection_per_m(double deflection_m, double L_m) {
  if (!std::isfinite(deflection_m) || !std::isfinite(L_m) || !(L_m > 0.0))
    throw std::invalid_argument("deflection and length must be finite, length > 0");
  const double u = std::abs(deflection_m) / L_m;  // (1 - cos theta)/theta = u
  const double theta_max = MaxDeflectionAngle_rad();
  const double u_max = ArcDeflectionOverLength(theta_max);
  if (u > u_max)
    throw std::invalid_argument("tip deflection " + Show(deflection_m) +
                                " m exceeds what an arc of length " + Show(L_m) + " m can reach (" +
                                Show(u_max * L_m) + " m)");
  double theta = 0.0;
  if (u < 0.5 * kSmallBendAngle_rad) {
    // Inverts u = theta/2 - theta^3/24 + O(theta^5): theta = 2u + (2/3)u^3 + O(u^5).
    theta = 2.0 * u + 2.0 / 3.0 * u * u * u;
  } else {
    double lo = 0.0;  // u is increasing in theta on [0, theta_max]
    double hi = theta_max;
    for (int i = 0; i < 200; ++i) {
      const double mid = 0.5 * (lo + hi);
      if (mid <= lo || mid >= hi) break;
      (ArcDeflectionOverLength(mid) < u ? lo : hi) = mid;
    }
    theta = 0.5 * (lo + hi);
  }
  return std::copysign(theta / L_m, deflection_m);
}

double SteadyTipDeflection_mm(const PhysicalParameters& p, double voltage_V) {
  if (!std::isfinite(voltage_V)) throw std::invalid_argument("voltage must be finite");
  return 1e3 * TipDeflectionFromCurvature_m(DcCurvaturePerVolt(p) * voltage_V, p.L_m);
}

double CalibrateAlpha(PhysicalParameters p, double voltage_V, double target_deflection_mm) {
  if (!std::isfinite(voltage_V) || !(voltage_V > 0.0))
    throw std::invalid_argument("calibration voltage must be finite and > 0");
  if (!std::isfinite(target_deflection_mm) || !(target_deflection_mm > 0.0))
    throw std::invalid_argument("target deflection must be finite and > 0");
  p.alpha_m3_per_C = 1.0;  // DC curvature is proportional to alpha
  RequireValid(p);
  const double target_curvature_per_m =
      CurvatureFromTipDeflection_per_m(1e-3 * target_deflection_mm, p.L_m);
  return target_curvature_per_m / (DcCurvaturePerVolt(p) * voltage_V);
}

PhysicalParameters WithGeometry(const PhysicalParameters& reference, double L_m, double W_m,
                                double h_m) {
  RequireValid(reference);
  for (double length : {L_m, W_m, h_m})
    if (!std::isfinite(length) || !(length > 0.0))
      throw std::invalid_argument("beam dimensions must be finite and > 0");
  PhysicalParameters p = reference;
  // C_dl scales with the face area W L; R_s, D, delta, alpha, E unchanged.
  p.C_dl_F = reference.C_dl_F * (W_m * L_m) / (reference.W_m * reference.L_m);
  p.L_m = L_m;
  p.W_m = W_m;
  p.h_m = h_m;
  return p;
}

std::vector<Table1Row> PredictTable1(const PhysicalParameters& s1_reference, double voltage_V) {
  if (!std::isfinite(voltage_V) || !(voltage_V > 0.0))
    throw std::invalid_argument("voltage must be finite and > 0");
  std::vector<Table1Row> rows;
  for (const Table1Measurement& m : kSeedTable1) {
    const PhysicalParameters p =
        WithGeometry(s1_reference, 1e-3 * m.L_mm, 1e-3 * m.W_mm, 1e-3 * m.h_mm);
    Table1Row row;
    row.name = std::string(m.name);
    row.L_mm = m.L_mm;
    row.W_mm = m.W_mm;
    row.h_mm = m.h_mm;
    row.predicted_curvature_per_m = DcCurvaturePerVolt(p) * voltage_V;
    row.predicted_deflection_mm =
        1e3 * TipDeflectionFromCurvature_m(row.predicted_curvature_per_m, p.L_m);
    row.measured_deflection_mm = m.max_deflection_mm;
    rows.push_back(row);
  }
  for (Table1Row& row : rows) {
    row.predicted_ratio_to_s1 = row.predicted_deflection_mm / rows.front().predicted_deflection_mm;
    row.measured_ratio_to_s1 = row.measured_deflection_mm / rows.front().measured_deflection_mm;
  }
  return rows;
}

double StepCurvature_per_m(const PhysicalParameters& p, double voltage_V, double t_s) {
  RequireValid(p);
  if (!std::isfinite(voltage_V)) throw std::invalid_argument("voltage must be finite");
  if (!std::isfinite(t_s) || !(t_s > 0.0))
    throw std::invalid_argument("step response time must be finite and > 0, got " + Show(t_s));
  // Fixed Talbot: f(t) = (r/M) [ F(r) e^{r t}/2 + sum_{k=1}^{M-1} Re( e^{t s_k} F(s_k)
  // (1 + i sigma_k) ) ] on the contour s(theta) = r theta (cot theta + i), theta_k = k pi/M,
  // r = 2 M/(5 t), sigma = theta + (theta cot theta - 1) cot theta, with F(s) = G(s)/s.
  constexpr int kNodes = 24;
  const double r = 2.0 * kNodes / (5.0 * t_s);
  double sum = 0.5 * std::exp(r * t_s) * CurvaturePerVoltExact(p, Complex(r, 0.0)).real() / r;
  for (int k = 1; k < kNodes; ++k) {
    const double theta = k * kPi / kNodes;
    const double cot = std::cos(theta) / std::sin(theta);
    const Complex s = r * theta * Complex(cot, 1.0);
    const double sigma = theta + (theta * cot - 1.0) * cot;
    sum += (std::exp(t_s * s) * CurvaturePerVoltExact(p, s) / s * Complex(1.0, sigma)).real();
  }
  return voltage_V * r / kNodes * sum;
}

std::vector<Table1Row> PredictTable1AfterHold(const PhysicalParameters& s1_reference, double hold_s,
                                              double voltage_V) {
  if (!std::isfinite(hold_s) || !(hold_s > 0.0))
    throw std::invalid_argument("hold time must be finite and > 0, got " + Show(hold_s));
  std::vector<Table1Row> rows = PredictTable1(s1_reference, voltage_V);
  for (Table1Row& row : rows) {
    const PhysicalParameters p =
        WithGeometry(s1_reference, 1e-3 * row.L_mm, 1e-3 * row.W_mm, 1e-3 * row.h_mm);
    row.predicted_curvature_per_m = StepCurvature_per_m(p, voltage_V, hold_s);
    row.predicted_deflection_mm =
        1e3 * TipDeflectionFromCurvature_m(row.predicted_curvature_per_m, p.L_m);
  }
  for (Table1Row& row : rows)
    row.predicted_ratio_to_s1 = row.predicted_deflection_mm / rows.front().predicted_deflection_mm;
  return rows;
}

double PowerLawExponent(double y_a, double y_b, double x_a, double x_b) {
  for (double value : {y_a, y_b, x_a, x_b})
    if (!std::isfinite(value) || !(value > 0.0))
      throw std::invalid_argument("power law points must be finite and > 0, got " + Show(value));
  if (x_a == x_b) throw std::invalid_argument("power law needs two different x, both " + Show(x_a));
  const double exponent = std::log(y_b / y_a) / std::log(x_b / x_a);
  return exponent == 0.0 ? 0.0 : exponent;  // no -0 for equal y
}

ExponentRange PowerLawExponentRange(double y_a, double y_b, double x_a, double x_b,
                                    double y_half_unit) {
  const double centre = PowerLawExponent(y_a, y_b, x_a, x_b);  // checks the points
  if (!std::isfinite(y_half_unit) || y_half_unit < 0.0 || !(y_half_unit < std::min(y_a, y_b)))
    throw std::invalid_argument("reading uncertainty must be >= 0 and below both values, got " +
                                Show(y_half_unit));
  // ln(y_b/y_a) is largest at (y_a - u, y_b + u); dividing by ln(x_b/x_a) may swap the ends.
  const double one = PowerLawExponent(y_a - y_half_unit, y_b + y_half_unit, x_a, x_b);
  const double other = PowerLawExponent(y_a + y_half_unit, y_b - y_half_unit, x_a, x_b);
  ExponentRange range{std::min(one, other), std::max(one, other)};
  range.low = std::min(range.low, centre);
  range.high = std::max(range.high, centre);
  return range;
}

std::string_view Name(BeamDimension dimension) {
  switch (dimension) {
    case BeamDimension::kLength:
      return "length";
    case BeamDimension::kWidth:
      return "width";
    case BeamDimension::kThickness:
      return "thickness";
  }
  return "unknown";
}

std::vector<Table1Scaling> AnalyseTable1Scaling(const std::vector<Table1Row>& rows,
                                                double deflection_half_unit_mm) {
  std::vector<Table1Scaling> out;
  if (rows.empty()) return out;
  const Table1Row& reference = rows.front();
  for (size_t i = 1; i < rows.size(); ++i) {
    const Table1Row& row = rows[i];
    const struct {
      BeamDimension dimension;
      double reference_mm, varied_mm;
    } dimensions[] = {{BeamDimension::kLength, reference.L_mm, row.L_mm},
                      {BeamDimension::kWidth, reference.W_mm, row.W_mm},
                      {BeamDimension::kThickness, reference.h_mm, row.h_mm}};
    int differing = 0;
    Table1Scaling scaling;
    for (const auto& d : dimensions) {
      if (d.reference_mm == d.varied_mm) continue;
      ++differing;
      scaling.dimension = d.dimension;
      scaling.reference_mm = d.reference_mm;
      scaling.varied_mm = d.varied_mm;
    }
    if (differing != 1) continue;
    scaling.reference_name = reference.name;
    scaling.varied_name = row.name;
    scaling.predicted_ratio = row.predicted_deflection_mm / reference.predicted_deflection_mm;
    scaling.measured_ratio = row.measured_deflection_mm / reference.measured_deflection_mm;
    scaling.predicted_exponent =
        PowerLawExponent(reference.predicted_deflection_mm, row.predicted_deflection_mm,
                         scaling.reference_mm, scaling.varied_mm);
    scaling.measured_exponent =
        PowerLawExponent(reference.measured_deflection_mm, row.measured_deflection_mm,
                         scaling.reference_mm, scaling.varied_mm);
    scaling.measured_exponent_range =
        PowerLawExponentRange(reference.measured_deflection_mm, row.measured_deflection_mm,
                              scaling.reference_mm, scaling.varied_mm, deflection_half_unit_mm);
    scaling.exponent_uncertainty =
        std::max(scaling.measured_exponent - scaling.measured_exponent_range.low,
                 scaling.measured_exponent_range.high - scaling.measured_exponent);
    scaling.departure = scaling.measured_exponent - scaling.predicted_exponent;
    scaling.departs = std::abs(scaling.departure) > scaling.exponent_uncertainty;
    out.push_back(scaling);
  }
  return out;
}

}  // namespace flexid::model
