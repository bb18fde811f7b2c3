#include "clients/rig/effects.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <optional>
#include <sstream>
#include <stdexcept>

#include "clients/rig/spec.h"

namespace flexid::rig {
namespace {

std::string FormatValue(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

// An interval with one open and one closed end, which SpecReader::InRange (both ends open
// or both closed) does not cover: low < value <= high, or low <= value < high.
struct HalfOpenInterval {
  double low = 0.0;
  bool low_included = true;
  double high = 1.0;
  bool high_included = false;
};

// The value of KEY checked against INTERVAL; nullopt if absent. Fails in the words of
// SpecReader::InRange: "loss must be >= 0 and < 1 (got 1)".
std::optional<double> InInterval(SpecReader& reader, const Spec& spec, const std::string& key,
                                 const HalfOpenInterval& interval) {
  const std::optional<double> value = reader.Number(key);
  if (!value) return value;
  const bool above = interval.low_included ? *value >= interval.low : *value > interval.low;
  const bool below = interval.high_included ? *value <= interval.high : *value < interval.high;
  if (!above || !below)
    spec.Fail(key + " must be " + (interval.low_included ? ">= " : "> ") +
              FormatValue(interval.low) + " and " + (interval.high_included ? "<= " : "< ") +
              FormatValue(interval.high) + " (got " + FormatValue(*value) + ")");
  return value;
}

// sign(v) * magnitude: the sign of the applied voltage carried over to a new magnitude.
double WithSignOf(double voltage_V, double magnitude_V) {
  return voltage_V < 0.0 ? -magnitude_V : magnitude_V;
}

}  // namespace

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

std::string CycleDegradation::Describe() const {
  std::ostringstream text;
  text << "cycle_degradation:loss=" << params_.loss << ",charge=" << params_.charge_Vs;
  return text.str();
}

double CycleDegradation::DriveVoltage(double t_s, double applied_V) {
  if (!started_) {
    started_ = true;  // Q(0) = 0
  } else {
    // Q(t_k) = Q(t_{k-1}) + |v_{k-1}| (t_k - t_{k-1}): the voltage is held between samples.
    const double h_s = t_s - previous_t_s_;
    if (!(h_s > 0.0)) throw std::invalid_argument("CycleDegradation: time not increasing");
    charge_Vs_ += previous_abs_V_ * h_s;
  }
  previous_t_s_ = t_s;
  previous_abs_V_ = std::abs(applied_V);
  // Eq. (3) as (1 - loss)^(Q / charge_Vs); log1p keeps a small loss accurate, and loss = 0
  // gives exactly 1.
  return applied_V * std::exp(charge_Vs_ / params_.charge_Vs * std::log1p(-params_.loss));
}

std::string Hysteresis::Describe() const {
  std::ostringstream text;
  text << "hysteresis:width=" << params_.width_mm;
  return text.str();
}

double Hysteresis::Deflection(double t_s, double applied_V, double deflection_mm) {
  static_cast<void>(t_s);
  static_cast<void>(applied_V);
  if (!started_) {
    started_ = true;
    output_mm_ = deflection_mm;  // out_0 = y_0
  } else {
    // Eq. (4).
    output_mm_ = std::min(deflection_mm + params_.width_mm,
                          std::max(deflection_mm - params_.width_mm, output_mm_));
  }
  return output_mm_;
}

std::string ElectrolysisSaturation::Describe() const {
  std::ostringstream text;
  text << "electrolysis_saturation:onset=" << params_.onset_V << ",slope=" << params_.slope;
  return text.str();
}

double ElectrolysisSaturation::DriveVoltage(double t_s, double applied_V) {
  static_cast<void>(t_s);
  // Eq. (5).
  const double magnitude_V = std::abs(applied_V);
  if (magnitude_V <= params_.onset_V) return applied_V;
  return WithSignOf(applied_V, params_.onset_V + params_.slope * (magnitude_V - params_.onset_V));
}

std::string SensorDrift::Describe() const {
  std::ostringstream text;
  text << "sensor_drift:rate=" << params_.rate_mm_s << ",warmup=" << params_.warmup_mm
       << ",tau=" << params_.tau_s;
  return text.str();
}

double SensorDrift::Deflection(double t_s, double applied_V, double deflection_mm) {
  static_cast<void>(applied_V);
  // Eq. (6); -expm1(-x) = 1 - exp(-x) without cancellation for small t.
  return deflection_mm + params_.rate_mm_s * t_s -
         params_.warmup_mm * std::expm1(-t_s / params_.tau_s);
}

std::string PolarityAsymmetry::Describe() const {
  std::ostringstream text;
  text << "polarity_asymmetry:ratio=" << params_.ratio;
  return text.str();
}

double PolarityAsymmetry::DriveVoltage(double t_s, double applied_V) {
  static_cast<void>(t_s);
  return applied_V >= 0.0 ? applied_V : params_.ratio * applied_V;  // Eq. (7)
}

std::string DeadZone::Describe() const {
  std::ostringstream text;
  text << "dead_zone:threshold=" << params_.threshold_V;
  return text.str();
}

double DeadZone::DriveVoltage(double t_s, double applied_V) {
  static_cast<void>(t_s);
  // Eq. (8).
  return WithSignOf(applied_V, std::max(std::abs(applied_V) - params_.threshold_V, 0.0));
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
  } else if (spec.name == "cycle_degradation") {
    CycleDegradation::Params params;
    params.loss = InInterval(reader, spec, "loss", {.low = 0.0, .high = 1.0}).value_or(params.loss);
    params.charge_Vs = reader.Positive("charge", "V*s").value_or(params.charge_Vs);
    effect = std::make_unique<CycleDegradation>(params);
  } else if (spec.name == "hysteresis") {
    Hysteresis::Params params;
    params.width_mm = reader.NonNegative("width", "mm").value_or(params.width_mm);
    effect = std::make_unique<Hysteresis>(params);
  } else if (spec.name == "electrolysis_saturation") {
    ElectrolysisSaturation::Params params;
    params.onset_V = reader.Positive("onset", "V").value_or(params.onset_V);
    params.slope = reader.InRange("slope", 0.0, 1.0, /*include_ends=*/true).value_or(params.slope);
    effect = std::make_unique<ElectrolysisSaturation>(params);
  } else if (spec.name == "sensor_drift") {
    SensorDrift::Params params;
    params.rate_mm_s = reader.Number("rate").value_or(params.rate_mm_s);
    params.warmup_mm = reader.Number("warmup").value_or(params.warmup_mm);
    params.tau_s = reader.Positive("tau", "s").value_or(params.tau_s);
    effect = std::make_unique<SensorDrift>(params);
  } else if (spec.name == "polarity_asymmetry") {
    PolarityAsymmetry::Params params;
    params.ratio =
        InInterval(reader, spec, "ratio",
                   {.low = 0.0, .low_included = false, .high = 2.0, .high_included = true})
            .value_or(params.ratio);
    effect = std::make_unique<PolarityAsymmetry>(params);
  } else if (spec.name == "dead_zone") {
    DeadZone::Params params;
    params.threshold_V = reader.NonNegative("threshold", "V").value_or(params.threshold_V);
    effect = std::make_unique<DeadZone>(params);
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

std::vector<std::string> EffectNames() {
  return {"back_relaxation", "cycle_degradation",  "hysteresis", "electrolysis_saturation",
          "sensor_drift",    "polarity_asymmetry", "dead_zone"};
}

}  // namespace flexid::rig
