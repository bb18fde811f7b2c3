#include "clients/rig/effects.h"

#include <cmath>
#include <sstream>
#include <stdexcept>

#include "clients/rig/spec.h"

namespace flexid::rig {

std::string BackRelaxation::Describe() const {
  std::ostringstream text;
  text << "back_relaxation:fraction=" << params_.fraction << ",tau=" << params_.tau_s;
  return text.str();
}

double BackRelaxation::Deflection(double t_s, double applied_V, double deflection_mm) {
  static_cast<void>(applied_V);
  if (!started_) {
    started_ = true;  // at rest before the first sample: s = 0
  } else {
    // Eq. (2); (1 - a) through expm1 keeps (1 - a) / r accurate when h << tau.
    const double r = (t_s - previous_t_s_) / params_.tau_s;
    if (!(r > 0.0)) throw std::invalid_argument("BackRelaxation: time not increasing");
    const double a = std::exp(-r);
    const double one_minus_a = -std::expm1(-r);
    slow_mm_ = a * slow_mm_ + one_minus_a * previous_y_mm_ +
               (1.0 - one_minus_a / r) * (deflection_mm - previous_y_mm_);
  }
  previous_t_s_ = t_s;
  previous_y_mm_ = deflection_mm;
  return deflection_mm - params_.fraction * slow_mm_;
}

std::unique_ptr<Effect> ParseEffect(std::string_view text) {
  const Spec spec = Spec::Parse(text, "effect");
  SpecReader reader(spec);
  std::unique_ptr<Effect> effect;
  if (spec.name == "back_relaxation") {
    BackRelaxation::Params params;
    params.fraction =
        reader.InRange("fraction", 0.0, 1.0, /*include_ends=*/true).value_or(params.fraction);
    params.tau_s = reader.Positive("tau", "s").value_or(params.tau_s);
    effect = std::make_unique<BackRelaxation>(params);
  } else {
    std::string expected;
    const std::vector<std::string> names = EffectNames();
    for (size_t i = 0; i < names.size(); ++i)
      expected += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
    spec.Fail("unknown effect \"" + spec.name + "\" (expected " + expected + ")");
  }
  reader.RejectUnknownKeys();
  return effect;
}

std::vector<std::string> EffectNames() { return {"back_relaxation"}; }

}  // namespace flexid::rig
