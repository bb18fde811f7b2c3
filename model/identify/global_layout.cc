// The global T-S fit's parameters (identify_global.h, "Model"): a structure in words, its
// parameter layout (Layout: theta, the model it stands for, its bounds, its names), and
// the transfers of a fitted theta to another layout (other knots, one order more).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "model/core/polynomial.h"
#include "model/identify/global_fit.h"
#include "model/identify/identify_global.h"

namespace flexid::model {
namespace global_fit {
namespace {

// The lightest damping ratio a fitted pole pair may have (the seed's 8 V model has 0.013).
constexpr double kMinDamping = 1e-3;

}  // namespace

std::string Volts(double v) {
  char text[32];
  std::snprintf(text, sizeof text, "%.3g", v);
  return text;
}

std::string VoltList(const std::vector<double>& values) {
  std::string out;
  for (size_t i = 0; i < values.size(); ++i)
    out += (i == 0 ? "" : i + 1 == values.size() ? " and " : ", ") + Volts(values[i]);
  return out + " V";
}

const char* PremiseText(SchedulingVariable premise) {
  switch (premise) {
    case SchedulingVariable::kAbsVoltageDelayed:
      return "|u(t - T)|";
    case SchedulingVariable::kAbsVoltageHeld:
      return "|u| held through rest";
    case SchedulingVariable::kVoltage:
      return "u";
    case SchedulingVariable::kAbsVoltage:
      break;
  }
  return "|u(t)|";
}

// ---------------------------------------------------------------------------------------
// Layout
// ---------------------------------------------------------------------------------------

double Layout::CentreRange(int r, int side) const {
  const auto& k = s.knots_V;
  const size_t i = static_cast<size_t>(r);
  const double gap = side < 0 ? (i > 0 ? k[i] - k[i - 1] : k[i + 1] - k[i])
                              : (i + 1 < k.size() ? k[i + 1] - k[i] : k[i] - k[i - 1]);
  return 0.45 * gap;
}

std::vector<double> Layout::DynamicsAt(const double* theta, double v) const {
  const auto& k = s.dynamics_knots_V;
  int a = 0, b = 0;
  double w = 0.0;
  if (v >= k.back()) {
    a = b = DynamicsKnots() - 1;
  } else if (v > k.front()) {
    b = static_cast<int>(std::upper_bound(k.begin(), k.end(), v) - k.begin());
    a = b - 1;
    w = (v - k[static_cast<size_t>(a)]) / (k[static_cast<size_t>(b)] - k[static_cast<size_t>(a)]);
  }
  std::vector<double> out(static_cast<size_t>(PerDynamics()));
  const double* pa = Dynamics(theta, a);
  const double* pb = Dynamics(theta, b);
  for (int j = 0; j < PerDynamics(); ++j) {
    const bool factor = j < s.num_poles;
    const double x = factor ? std::exp(pa[j]) : pa[j], y = factor ? std::exp(pb[j]) : pb[j];
    out[static_cast<size_t>(j)] = (1 - w) * x + w * y;
  }
  // The bounds keep every factor's natural frequency sqrt(c0) in the band, but a real
  // pair can still put one root far below it: a near-integrator that absorbs drift or
  // an asymmetry as a huge DC gain. Such a root is held at w_min (the cost is flat
  // below it, so the fit cannot use it).
  // Likewise a complex pair's damping ratio c1 / (2 sqrt(c0)) is held at kMinDamping or
  // above: the box bound on c1 alone let a pair ring with a damping of 3e-6.
  for (int q = 0; q < s.num_poles / 2; ++q) {
    double& c1 = out[static_cast<size_t>(2 * q)];
    double& c0 = out[static_cast<size_t>(2 * q + 1)];
    c1 = std::max(c1, 2 * kMinDamping * std::sqrt(c0));
    const double disc = c1 * c1 - 4 * c0;
    if (disc < 0) continue;
    const double slow = 2 * c0 / (c1 + std::sqrt(disc)), fast = c0 / slow;
    if (slow >= w_min) continue;
    c1 = w_min + fast;
    c0 = w_min * fast;
  }
  return out;
}

TransferFunction Layout::Rule(const double* theta, int r) const {
  return RuleAt(theta, s.knots_V[static_cast<size_t>(r)], theta[1 + r]);
}

TransferFunction Layout::RuleAt(const double* theta, double v, double gain) const {
  const std::vector<double> d = DynamicsAt(theta, v);
  std::vector<double> den = {1.0};
  int j = 0;
  for (int q = 0; q < s.num_poles / 2; ++q, j += 2)
    den = MultiplyPolynomials(den, {1.0, d[static_cast<size_t>(j)], d[static_cast<size_t>(j + 1)]});
  if (s.num_poles % 2 == 1) den = MultiplyPolynomials(den, {1.0, d[static_cast<size_t>(j++)]});
  const double scale = gain * den.back();
  std::vector<double> num(static_cast<size_t>(s.num_zeros) + 1);
  num.back() = scale;
  for (int i = 1; i <= s.num_zeros; ++i)
    num[static_cast<size_t>(s.num_zeros - i)] = scale * d[static_cast<size_t>(j + i - 1)];
  return {num, den, theta[0]};
}

TsModel Layout::Model(const double* theta, double rest_band_V) const {
  std::vector<LocalModel> rules;
  for (int r = 0; r < Rules(); ++r)
    rules.push_back({s.knots_V[static_cast<size_t>(r)], Rule(theta, r), {}});
  const bool parallel = s.realisation == TsRealisation::kParallel;
  TsModel model = MakeTsModelOnLevels(
      std::move(rules), parallel ? SchedulingVariable::kAbsVoltage : s.premise, rest_band_V);
  if (Smooth()) {
    const double width_V = std::exp(theta[WidthIndex()]);
    for (int r = 0; r < Rules(); ++r) {
      LocalModel& rule = model.rules[static_cast<size_t>(r)];
      if (Centred()) rule.level_V = theta[CentreIndex(r)];
      rule.membership = {MembershipShape::kGaussian, {rule.level_V, width_V}};
    }
  }
  model.scheduling_delay_s = parallel ? 0.0 : theta[0];
  model.realisation = s.realisation;
  return model;
}

void Layout::Bounds(const Problem& problem, std::vector<double>* lo,
                    std::vector<double>* hi) const {
  lo->assign(static_cast<size_t>(Size()), -kInf);
  hi->assign(static_cast<size_t>(Size()), kInf);
  (*lo)[0] = 0.0;
  (*hi)[0] = problem.max_delay_s;
  const double lw = std::log(problem.w_min), hw = std::log(problem.w_max);
  for (int d = 0; d < DynamicsKnots(); ++d) {
    size_t j = static_cast<size_t>(1 + Rules() + d * PerDynamics());
    for (int q = 0; q < s.num_poles / 2; ++q, j += 2) {
      // c1 = 2 zeta w_n (damping down to 1e-3) = the sum of the roots when they are
      // real, so c1 <= w_max keeps real roots in the band; c0 = w_n^2 keeps complex ones.
      (*lo)[j] = std::log(2e-3) + lw;
      (*hi)[j] = hw;
      (*lo)[j + 1] = 2 * lw;
      (*hi)[j + 1] = 2 * hw;
    }
    if (s.num_poles % 2 == 1) {
      (*lo)[j] = lw;
      (*hi)[j] = hw;
    }
  }
  if (Smooth()) {
    // From a tenth of the knots' spacing (a nearly sharp switch) to three times their
    // span (nearly one blend of every rule).
    (*lo)[static_cast<size_t>(WidthIndex())] = std::log(0.1 * Spacing());
    (*hi)[static_cast<size_t>(WidthIndex())] =
        std::log(3.0 * (s.knots_V.back() - s.knots_V.front()));
  }
  if (Centred())
    for (int r = 0; r < Rules(); ++r) {
      const double knot = s.knots_V[static_cast<size_t>(r)];
      (*lo)[static_cast<size_t>(CentreIndex(r))] = knot - CentreRange(r, -1);
      (*hi)[static_cast<size_t>(CentreIndex(r))] = knot + CentreRange(r, +1);
    }
}

std::string Layout::ParameterName(int index) const {
  if (index == 0) return "dead time";
  if (Smooth() && index == WidthIndex()) return "membership width";
  if (Centred() && index > WidthIndex())
    return "membership centre of the rule at " +
           Volts(s.knots_V[static_cast<size_t>(index - WidthIndex() - 1)]) + " V";
  if (index <= Rules())
    return "DC gain at " + Volts(s.knots_V[static_cast<size_t>(index - 1)]) + " V";
  const int d = (index - 1 - Rules()) / PerDynamics(), j = (index - 1 - Rules()) % PerDynamics();
  const std::string where =
      " of the dynamics at " + Volts(s.dynamics_knots_V[static_cast<size_t>(d)]) + " V";
  if (j < s.num_poles) return "pole factor " + std::to_string(j / 2 + 1) + where;
  return "zero coefficient " + std::to_string(j - s.num_poles + 1) + where;
}

// ---------------------------------------------------------------------------------------
// Transfers between layouts
// ---------------------------------------------------------------------------------------

std::vector<double> Transfer(const Layout& from, const std::vector<double>& theta,
                             const Layout& to) {
  std::vector<double> out = {theta[0]};
  const TsModel model = from.Model(theta.data(), 0.0);
  for (double v : to.s.knots_V) {
    std::vector<double> mu;
    NormalisedMemberships(model, v, &mu);
    double k = 0.0;
    for (size_t i = 0; i < mu.size(); ++i) k += mu[i] * theta[1 + i];
    out.push_back(k);
  }
  for (double v : to.s.dynamics_knots_V) {
    const std::vector<double> d = from.DynamicsAt(theta.data(), v);
    for (int j = 0; j < to.PerDynamics(); ++j)
      out.push_back(j < to.s.num_poles ? std::log(d[static_cast<size_t>(j)])
                                       : d[static_cast<size_t>(j)]);
  }
  if (to.Smooth())
    out.push_back(from.Smooth() ? theta[static_cast<size_t>(from.WidthIndex())]
                                : std::log(0.5 * to.Spacing()));
  if (to.Centred()) {
    if (from.Centred() && from.s.knots_V == to.s.knots_V) {
      for (int r = 0; r < to.Rules(); ++r)
        out.push_back(theta[static_cast<size_t>(from.CentreIndex(r))]);
    } else {
      out.insert(out.end(), to.s.knots_V.begin(), to.s.knots_V.end());
    }
  }
  return out;
}

std::vector<double> RuleParameters(const TransferFunction& tf, const Layout& layout,
                                   const Problem& problem) {
  const TransferFunction g = Normalised(tf);
  std::vector<double> p(static_cast<size_t>(1 + layout.PerDynamics()), 0.0);
  p[0] = std::isfinite(DcGain(g)) ? DcGain(g) : 0.0;
  const double lw = std::log(problem.w_min), hw = std::log(problem.w_max);
  auto clamp_log = [](double c, double lo, double hi) {
    return std::clamp(std::log(std::max(c, 1e-300)), lo, hi);
  };
  size_t j = 1;
  for (const std::vector<double>& f : RealFactors(g.den)) {
    if (f.size() == 3 && j + 1 < 1 + static_cast<size_t>(layout.s.num_poles) + 1) {
      p[j] = clamp_log(f[1], std::log(2e-3) + lw, hw);
      p[j + 1] = clamp_log(f[2], 2 * lw, 2 * hw);
      j += 2;
    } else if (f.size() == 2) {
      p[j++] = clamp_log(f[1], lw, hw);
    }
  }
  const double num0 = g.num.back();
  for (int i = 1; i <= layout.s.num_zeros; ++i) {
    const long index = static_cast<long>(g.num.size()) - 1 - i;
    p[static_cast<size_t>(layout.s.num_poles + i)] =
        index >= 0 && num0 != 0.0 ? g.num[static_cast<size_t>(index)] / num0 : 0.0;
  }
  return p;
}

std::vector<double> RaiseOrder(const Layout& from, const std::vector<double>& theta,
                               const Layout& to, const Problem& problem, double a) {
  std::vector<double> out(theta.begin(), theta.begin() + 1 + from.Rules());
  if (!(a > 0.0)) a = problem.w_max / 4;
  for (double v : to.s.dynamics_knots_V) {
    TransferFunction tf = from.RuleAt(theta.data(), v, 1.0);
    tf.num = MultiplyPolynomials(tf.num, {1.0 / a, 1.0});
    tf.den = MultiplyPolynomials(tf.den, {1.0, a});
    const std::vector<double> p = RuleParameters(tf, to, problem);
    out.insert(out.end(), p.begin() + 1, p.end());
  }
  const std::vector<double> tail = from.MembershipTail(theta.data());
  out.insert(out.end(), tail.begin(), tail.end());
  return out;
}

}  // namespace global_fit

using namespace global_fit;  // NOLINT(google-build-using-namespace): the fit's own parts

int GlobalStructure::Parameters() const {
  return 1 + static_cast<int>(knots_V.size()) +
         static_cast<int>(dynamics_knots_V.size()) * (num_poles + num_zeros) +
         (membership == MembershipShape::kGaussian && knots_V.size() > 1
              ? 1 + (centres_fitted ? static_cast<int>(knots_V.size()) : 0)
              : 0);
}

std::string GlobalStructure::Describe() const {
  std::string text = std::to_string(num_poles) + (num_poles == 1 ? " pole, " : " poles, ") +
                     std::to_string(num_zeros) + (num_zeros == 1 ? " zero, " : " zeros, ");
  if (knots_V.size() == 1) return text + "one rule (linear)";
  text += std::to_string(knots_V.size()) + " rules at " + VoltList(knots_V) + ", ";
  text += dynamics_knots_V.size() == 1 ? std::string("one set of dynamics")
                                       : "dynamics at " + VoltList(dynamics_knots_V);
  if (membership == MembershipShape::kGaussian)
    text += centres_fitted ? ", smooth hand-over (Gaussian memberships, centres fitted)"
                           : ", smooth hand-over (Gaussian memberships)";
  if (realisation == TsRealisation::kParallel)
    return text + ", parallel rules (each driven by its share of u)";
  return text + ", premise " + PremiseText(premise);
}

}  // namespace flexid::model
