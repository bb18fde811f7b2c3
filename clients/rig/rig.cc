#include "clients/rig/rig.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <sstream>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/simulate.h"

namespace flexid::rig {
namespace {

// Throws model::InputError unless `count` samples from start_utime keep utime well within
// int64_t.
void CheckStartUtime(int64_t start_utime, size_t count, double rate_Hz) {
  if (static_cast<double>(start_utime) + static_cast<double>(count) * 1e6 / rate_Hz > 9e18)
    throw model::InputError("the start utime is too large for the protocol");
}

}  // namespace

bool RigOptions::IsValid(std::string* error) const {
  if (!(rate_Hz > 0.0 && rate_Hz <= kMaxRate_Hz)) {
    *error = "the sample rate must be > 0 and <= 1e6 Hz";
    return false;
  }
  if (start_utime < 0) {
    *error = "the start utime must be >= 0";
    return false;
  }
  if (!(noise_mm >= 0.0 && std::isfinite(noise_mm))) {
    *error = "the noise standard deviation must be finite and >= 0 mm";
    return false;
  }
  if (!(voltage_repeat_s > 0.0 && std::isfinite(voltage_repeat_s))) {
    *error = "the voltage repeat interval must be finite and > 0 s";
    return false;
  }
  return true;
}

Rig::Rig(const model::TsModel& model, Protocol protocol,
         std::vector<std::unique_ptr<Effect>> effects, const RigOptions& options)
    : protocol_(std::move(protocol)),
      effects_(std::move(effects)),
      options_(options),
      noise_(options.seed) {
  std::string why;
  if (!options_.IsValid(&why)) throw model::InputError(why);
  why = SamplingProblem(protocol_, options_.rate_Hz);
  if (!why.empty()) throw model::InputError("protocol \"" + protocol_.text + "\": " + why);
  const double duration_s = ProtocolDuration(protocol_);
  const double exact_count = duration_s * options_.rate_Hz;
  // A count that is whole up to rounding (10 s at 10 Hz) is not rounded up.
  const double count = std::ceil(exact_count - 1e-9 * std::max(1.0, exact_count));
  if (!(count <= static_cast<double>(kMaxRigSamples))) {
    std::ostringstream text;
    text << "protocol \"" << protocol_.text << "\" at " << options_.rate_Hz << " Hz needs "
         << exact_count << " samples; at most " << kMaxRigSamples
         << " (lower --rate-hz or shorten the protocol)";
    throw model::InputError(text.str());
  }
  const auto n = static_cast<size_t>(std::max(1.0, count));
  CheckStartUtime(options_.start_utime, n, options_.rate_Hz);

  voltage_V_.resize(n);
  std::vector<double> drive_V(n);
  for (size_t k = 0; k < n; ++k) {
    const double t_s = static_cast<double>(k) / options_.rate_Hz;
    voltage_V_[k] = VoltageAt(protocol_, t_s);
    drive_V[k] = voltage_V_[k];
    for (const auto& effect : effects_) drive_V[k] = effect->DriveVoltage(t_s, drive_V[k]);
  }
  model_mm_ = model::SimulateUniform(model, 1.0 / options_.rate_Hz, drive_V);
  for (size_t k = 0; k < n; ++k) {
    if (std::isfinite(model_mm_[k])) continue;
    std::ostringstream text;
    text << "the model's output diverges at t = " << static_cast<double>(k) / options_.rate_Hz
         << " s (is the model stable?)";
    throw std::runtime_error(text.str());
  }
}

void Rig::SetStartUtime(int64_t start_utime) {
  if (next_ > 0) throw std::logic_error("Rig::SetStartUtime after the first sample");
  if (start_utime < 0) throw model::InputError("the start utime must be >= 0");
  CheckStartUtime(start_utime, voltage_V_.size(), options_.rate_Hz);
  options_.start_utime = start_utime;
}

double Rig::duration_s() const { return static_cast<double>(sample_count()) / options_.rate_Hz; }

int64_t Rig::UtimeOf(int64_t k) const {
  return options_.start_utime + std::llround(static_cast<double>(k) * 1e6 / options_.rate_Hz);
}

bool Rig::Next(RigSample* sample) {
  if (next_ >= sample_count()) return false;
  const int64_t k = next_++;
  const auto i = static_cast<size_t>(k);
  sample->index = k;
  sample->utime = UtimeOf(k);
  sample->t_s = static_cast<double>(k) / options_.rate_Hz;
  sample->voltage_V = voltage_V_[i];
  sample->voltage_changed = k == 0 || voltage_V_[i] != voltage_V_[i - 1];
  const auto repeat_us = static_cast<int64_t>(std::llround(options_.voltage_repeat_s * 1e6));
  sample->publish_voltage =
      sample->voltage_changed || sample->utime - last_voltage_utime_ >= repeat_us;
  if (sample->publish_voltage) last_voltage_utime_ = sample->utime;
  double deflection_mm = model_mm_[i];
  for (const auto& effect : effects_)
    deflection_mm = effect->Deflection(sample->t_s, sample->voltage_V, deflection_mm);
  if (options_.noise_mm > 0.0) deflection_mm += options_.noise_mm * noise_.StandardNormal();
  sample->deflection_mm = deflection_mm;
  return true;
}

// Box-Muller: two independent N(0, 1) values from two uniforms on (0, 1].
double GaussianNoise::StandardNormal() {
  if (has_spare_) {
    has_spare_ = false;
    return spare_;
  }
  constexpr double kTwoToMinus53 = 1.0 / 9007199254740992.0;
  const double u1 = static_cast<double>((generator_() >> 11) + 1) * kTwoToMinus53;  // (0, 1]
  const double u2 = static_cast<double>(generator_() >> 11) * kTwoToMinus53;        // [0, 1)
  const double radius = std::sqrt(-2.0 * std::log(u1));
  const double angle = 2.0 * std::numbers::pi * u2;
  spare_ = radius * std::sin(angle);
  has_spare_ = true;
  return radius * std::cos(angle);
}

ActuatorEffect ParseActuatorEffect(std::string_view text) {
  const std::string_view name = text.substr(0, text.find(':'));
  const size_t slash = name.find('/');
  if (slash == std::string_view::npos) return {"", std::string(text)};
  if (slash == 0)
    throw model::InputError("effect \"" + std::string(text) +
                            "\": empty actuator id before '/' (expected ID/NAME[:k=v,...])");
  return {std::string(text.substr(0, slash)), std::string(text.substr(slash + 1))};
}

std::vector<Rig> MakeActuatorRigs(const model::TsModel& model, const Protocol& protocol,
                                  const std::vector<std::string>& actuator_ids,
                                  const std::vector<std::string>& effect_specs,
                                  const RigOptions& options) {
  std::vector<ActuatorEffect> effects;
  for (const std::string& spec : effect_specs) {
    effects.push_back(ParseActuatorEffect(spec));
    const std::string& id = effects.back().actuator_id;
    if (id.empty() || std::find(actuator_ids.begin(), actuator_ids.end(), id) != actuator_ids.end())
      continue;
    std::string known;  // an offline run without --actuator has one actuator named ""
    for (const std::string& actuator : actuator_ids)
      if (!actuator.empty()) known += (known.empty() ? "" : ", ") + actuator;
    throw model::InputError(
        "effect \"" + spec + "\": no actuator \"" + id + "\" (" +
        (known.empty() ? std::string("no --actuator given") : "actuators: " + known) + ")");
  }
  std::vector<Rig> rigs;
  rigs.reserve(actuator_ids.size());
  for (size_t i = 0; i < actuator_ids.size(); ++i) {
    std::vector<std::unique_ptr<Effect>> own;
    for (const ActuatorEffect& effect : effects)
      if (effect.actuator_id.empty() || effect.actuator_id == actuator_ids[i])
        own.push_back(ParseEffect(effect.effect));
    RigOptions own_options = options;
    own_options.seed = options.seed + i;
    rigs.emplace_back(model, protocol, std::move(own), own_options);
    if (i > 0) continue;
    const double total =
        static_cast<double>(rigs.front().sample_count()) * static_cast<double>(actuator_ids.size());
    if (total > static_cast<double>(kMaxRigSamples)) {
      std::ostringstream text;
      text << actuator_ids.size() << " actuators of " << rigs.front().sample_count()
           << " samples each need " << total << " samples; at most " << kMaxRigSamples
           << " in all (fewer actuators, lower --rate-hz or a shorter protocol)";
      throw model::InputError(text.str());
    }
  }
  return rigs;
}

}  // namespace flexid::rig
