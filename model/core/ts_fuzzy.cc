#include "model/core/ts_fuzzy.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "model/core/polynomial.h"

namespace flexid::model {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Linear ramp from 0 at `from` to 1 at `to` (from < to), clamped.
double Ramp(double z, double from, double to) {
  if (z <= from) return 0.0;
  if (z >= to) return 1.0;
  return (z - from) / (to - from);
}

bool Fail(std::string* error, std::string message) {
  if (error) *error = std::move(message);
  return false;
}

}  // namespace

double Membership::Evaluate(double z) const {
  switch (shape) {
    case MembershipShape::kTriangular: {
      const double a = params[0], b = params[1], c = params[2];
      if (z == b) return 1.0;
      if (z < b) return a < b ? Ramp(z, a, b) : 0.0;
      return b < c ? 1.0 - Ramp(z, b, c) : 0.0;
    }
    case MembershipShape::kTrapezoidal: {
      const double a = params[0], b = params[1], c = params[2], d = params[3];
      if (z >= b && z <= c) return 1.0;
      if (z < b) return (a < b && std::isfinite(b)) ? Ramp(z, a, b) : 0.0;
      return (c < d && std::isfinite(c)) ? 1.0 - Ramp(z, c, d) : 0.0;
    }
    case MembershipShape::kGaussian: {
      const double u = (z - params[0]) / params[1];
      return std::exp(-0.5 * u * u);
    }
    case MembershipShape::kSigmoid:
      return 1.0 / (1.0 + std::exp(-params[1] * (z - params[0])));
  }
  return 0.0;
}

bool IsValid(const Membership& membership, std::string* error) {
  const auto& p = membership.params;
  const std::string name = MembershipShapeName(membership.shape);
  auto count = [&](size_t n) {
    return p.size() == n || Fail(error, name + " membership needs " + std::to_string(n) +
                                            " parameters, got " + std::to_string(p.size()));
  };
  switch (membership.shape) {
    case MembershipShape::kTriangular:
      if (!count(3)) return false;
      if (!std::all_of(p.begin(), p.end(), [](double v) { return std::isfinite(v); }))
        return Fail(error, "triangular membership parameters must be finite");
      if (!(p[0] <= p[1] && p[1] <= p[2]))
        return Fail(error, "triangular membership needs a <= b <= c");
      return true;
    case MembershipShape::kTrapezoidal:
      if (!count(4)) return false;
      if (std::isnan(p[0]) || std::isnan(p[1]) || std::isnan(p[2]) || std::isnan(p[3]))
        return Fail(error, "trapezoidal membership parameters must not be NaN");
      if (p[0] == kInf || p[1] == kInf || p[2] == -kInf || p[3] == -kInf)
        return Fail(error, "trapezoidal membership: only a, b may be -inf and c, d +inf");
      if ((p[0] == -kInf) != (p[1] == -kInf) || (p[2] == kInf) != (p[3] == kInf))
        return Fail(error,
                    "trapezoidal membership: a shoulder needs both a and b (or c and d) infinite");
      if (!(p[0] <= p[1] && p[1] <= p[2] && p[2] <= p[3]))
        return Fail(error, "trapezoidal membership needs a <= b <= c <= d");
      return true;
    case MembershipShape::kGaussian:
      if (!count(2)) return false;
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || p[1] <= 0.0)
        return Fail(error, "gaussian membership needs a finite centre and sigma > 0");
      return true;
    case MembershipShape::kSigmoid:
      if (!count(2)) return false;
      if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || p[1] == 0.0)
        return Fail(error, "sigmoid membership needs a finite centre and a non-zero slope");
      return true;
  }
  return Fail(error, "unknown membership shape");
}

const char* MembershipShapeName(MembershipShape shape) {
  switch (shape) {
    case MembershipShape::kTriangular:
      return "triangular";
    case MembershipShape::kTrapezoidal:
      return "trapezoidal";
    case MembershipShape::kGaussian:
      return "gaussian";
    case MembershipShape::kSigmoid:
      return "sigmoid";
  }
  return "unknown";
}

bool ParseMembershipShape(const std::string& name, MembershipShape* shape) {
  for (auto s : {MembershipShape::kTriangular, MembershipShape::kTrapezoidal,
                 MembershipShape::kGaussian, MembershipShape::kSigmoid}) {
    if (name == MembershipShapeName(s)) {
      *shape = s;
      return true;
    }
  }
  return false;
}

const char* SchedulingVariableName(SchedulingVariable variable) {
  switch (variable) {
    case SchedulingVariable::kAbsVoltage:
      return "abs_voltage";
    case SchedulingVariable::kVoltage:
      return "voltage";
    case SchedulingVariable::kAbsVoltageHeld:
      return "abs_voltage_held";
    case SchedulingVariable::kAbsVoltageDelayed:
      return "abs_voltage_delayed";
  }
  return "unknown";
}

bool ParseSchedulingVariable(const std::string& name, SchedulingVariable* variable) {
  for (auto v : {SchedulingVariable::kAbsVoltage, SchedulingVariable::kVoltage,
                 SchedulingVariable::kAbsVoltageHeld, SchedulingVariable::kAbsVoltageDelayed}) {
    if (name == SchedulingVariableName(v)) {
      *variable = v;
      return true;
    }
  }
  return false;
}

const char* TsRealisationName(TsRealisation realisation) {
  return realisation == TsRealisation::kParallel ? "parallel" : "frozen";
}

bool ParseTsRealisation(const std::string& name, TsRealisation* realisation) {
  for (auto r : {TsRealisation::kFrozen, TsRealisation::kParallel}) {
    if (name == TsRealisationName(r)) {
      *realisation = r;
      return true;
    }
  }
  return false;
}

bool IsValid(const TsModel& model, std::string* error) {
  if (model.rules.empty()) return Fail(error, "T-S model has no rules");
  if (!std::isfinite(model.rest_band_V) || model.rest_band_V < 0.0)
    return Fail(error, "rest_band_V must be finite and >= 0");
  if (!std::isfinite(model.scheduling_delay_s) || model.scheduling_delay_s < 0.0)
    return Fail(error, "the scheduling delay must be finite and >= 0");
  int order = -1;
  for (size_t i = 0; i < model.rules.size(); ++i) {
    const LocalModel& rule = model.rules[i];
    const std::string where = "local model " + std::to_string(i) + ": ";
    std::string why;
    if (!std::isfinite(rule.level_V)) return Fail(error, where + "level_V is not finite");
    if (!IsValid(rule.tf, &why)) return Fail(error, where + why);
    if (!IsValid(rule.membership, &why)) return Fail(error, where + why);
    const int this_order = Order(rule.tf);
    if (order >= 0 && this_order != order)
      return Fail(error, where + "order " + std::to_string(this_order) +
                             " differs from local model 0's order " + std::to_string(order) +
                             " (blending needs equal orders)");
    order = this_order;
  }
  if (model.realisation == TsRealisation::kParallel) {
    if (model.scheduling != SchedulingVariable::kAbsVoltage &&
        model.scheduling != SchedulingVariable::kVoltage)
      return Fail(error,
                  "parallel rules are scheduled on abs_voltage or voltage (each rule's share is "
                  "delayed with the voltage through its own dead time)");
    for (const LocalModel& rule : model.rules)
      if (rule.tf.delay_s != model.rules.front().tf.delay_s)
        return Fail(error, "parallel rules share one dead time");
  }
  return true;
}

double SchedulingValue(const TsModel& model, double voltage_V) {
  return model.scheduling == SchedulingVariable::kVoltage ? voltage_V : std::abs(voltage_V);
}

double Scheduler::Next(double voltage_V) {
  const double z = SchedulingValue(*model_, voltage_V);
  if (model_->scheduling != SchedulingVariable::kAbsVoltageHeld) return z;
  if (z > model_->rest_band_V) held_ = z;
  return held_;
}

void NormalisedMemberships(const TsModel& model, double z, std::vector<double>* mu) {
  const size_t m = model.rules.size();
  mu->resize(m);
  double total = 0.0;
  for (size_t i = 0; i < m; ++i) total += (*mu)[i] = model.rules[i].membership.Evaluate(z);
  if (total > 0.0) {
    for (double& w : *mu) w /= total;  // Eq. (16)
    return;
  }
  // No rule fires: the rule identified nearest to z takes it all.
  size_t nearest = 0;
  for (size_t i = 1; i < m; ++i)
    if (std::abs(model.rules[i].level_V - z) < std::abs(model.rules[nearest].level_V - z))
      nearest = i;
  std::fill(mu->begin(), mu->end(), 0.0);
  (*mu)[nearest] = 1.0;
}

TsModel MakeTsModelOnLevels(std::vector<LocalModel> local_models, SchedulingVariable scheduling,
                            double rest_band_V) {
  std::sort(local_models.begin(), local_models.end(),
            [](const LocalModel& a, const LocalModel& b) { return a.level_V < b.level_V; });
  const size_t m = local_models.size();
  for (size_t i = 0; i < m; ++i) {
    const double lower = i > 0 ? local_models[i - 1].level_V : -kInf;
    const double upper = i + 1 < m ? local_models[i + 1].level_V : kInf;
    const double level = local_models[i].level_V;
    local_models[i].membership = {MembershipShape::kTrapezoidal,
                                  {lower, i > 0 ? level : -kInf, i + 1 < m ? level : kInf, upper}};
  }
  return {scheduling, std::move(local_models), rest_band_V};
}

namespace {

// kParallel: sum of mu_i G_i over the firing rules (one dead time, IsValid).
TransferFunction ParallelSum(const TsModel& model, const std::vector<double>& mu) {
  TransferFunction sum{{0.0}, {1.0}, model.rules.front().tf.delay_s};
  for (size_t i = 0; i < model.rules.size(); ++i) {
    if (mu[i] == 0.0) continue;
    const TransferFunction& g = model.rules[i].tf;
    std::vector<double> weighted = g.num;
    for (double& c : weighted) c *= mu[i];
    const std::vector<double> a = MultiplyPolynomials(sum.num, g.den),
                              b = MultiplyPolynomials(weighted, sum.den);
    std::vector<double> num(std::max(a.size(), b.size()), 0.0);
    for (size_t j = 0; j < a.size(); ++j) num[num.size() - a.size() + j] += a[j];
    for (size_t j = 0; j < b.size(); ++j) num[num.size() - b.size() + j] += b[j];
    sum.num = std::move(num);
    sum.den = MultiplyPolynomials(sum.den, g.den);
  }
  return sum;
}

}  // namespace

PreparedRules PrepareRules(const TsModel& model) {
  PreparedRules prepared;
  if (model.realisation == TsRealisation::kParallel) return prepared;
  for (const LocalModel& rule : model.rules) {
    prepared.normalised.push_back(Normalised(rule.tf));
    const TransferFunction& local = prepared.normalised.back();
    prepared.factors.push_back(RealFactors(local.den));
    prepared.dc_gain.push_back(local.den.back() != 0.0 ? DcGain(local) : 0.0);
  }
  return prepared;
}

TransferFunction BlendedTransferFunction(const TsModel& model, const std::vector<double>& mu) {
  if (model.realisation == TsRealisation::kParallel) return ParallelSum(model, mu);
  return BlendedTransferFunction(model, PrepareRules(model), mu);
}

TransferFunction BlendedTransferFunction(const TsModel& model, const PreparedRules& prepared,
                                         const std::vector<double>& mu) {
  if (model.realisation == TsRealisation::kParallel) return ParallelSum(model, mu);
  const size_t order = static_cast<size_t>(Order(model.rules.front().tf));
  // Weighted sums of the real factors, the gain-normalised numerators, gains and delays.
  std::vector<std::vector<double>> factors;
  std::vector<double> shape(order + 1, 0.0), plain(order + 1, 0.0);
  double gain = 0.0, delay_s = 0.0;
  bool normalisable = true;
  for (size_t i = 0; i < model.rules.size(); ++i) {
    if (mu[i] == 0.0) continue;
    const TransferFunction& local = prepared.normalised[i];
    const std::vector<std::vector<double>>& local_factors = prepared.factors[i];
    if (factors.empty()) {
      factors = local_factors;
      for (auto& f : factors)
        for (double& c : f) c = 0.0;
    }
    for (size_t q = 0; q < factors.size(); ++q)
      for (size_t j = 0; j < factors[q].size(); ++j) factors[q][j] += mu[i] * local_factors[q][j];
    const double num0 = local.num.back();
    normalisable = normalisable && num0 != 0.0 && local.den.back() != 0.0;
    const size_t offset = shape.size() - local.num.size();
    for (size_t j = 0; j < local.num.size(); ++j) {
      plain[offset + j] += mu[i] * local.num[j];
      if (num0 != 0.0) shape[offset + j] += mu[i] * local.num[j] / num0;
    }
    if (local.den.back() != 0.0) gain += mu[i] * prepared.dc_gain[i];
    delay_s += mu[i] * local.delay_s;
  }
  std::vector<double> den = {1.0};
  for (const auto& f : factors) den = MultiplyPolynomials(den, f);
  TransferFunction blend{plain, den, delay_s};
  if (normalisable) {
    // num(mu) = K(mu) den(mu)(0) shape(s), so that num(0) / den(0) = K(mu).
    for (double& c : shape) c *= gain * den.back();
    blend.num = shape;
  }
  return blend;
}

TransferFunction FrozenModelAt(const TsModel& model, double z) {
  std::vector<double> mu;
  NormalisedMemberships(model, z, &mu);
  return BlendedTransferFunction(model, mu);
}

TsModel SingleRule(const TransferFunction& tf) {
  return {SchedulingVariable::kAbsVoltage,
          {{0.0, tf, {MembershipShape::kTrapezoidal, {-kInf, -kInf, kInf, kInf}}}}};
}

double LargestFallBack(const TsModel& model) {
  double largest = 0.0;
  for (const LocalModel& rule : model.rules)
    largest = std::max(largest, StepFallBack(rule.tf).share);
  return largest;
}

}  // namespace flexid::model
