#include "storage/record_json.h"

#include <cmath>

namespace flexid::storage {
namespace {

nlohmann::json FiniteOrNull(double value) {
  return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(nullptr);
}

}  // namespace

nlohmann::json TrialJson(const Trial& trial) {
  return {{"id", trial.id},
          {"actuator", trial.actuator_id},
          {"protocol", trial.protocol},
          {"start_utime", trial.start_utime},
          {"end_utime", trial.end_utime},
          {"state", TrialStateName(trial.state)},
          {"samples", trial.samples}};
}

nlohmann::json AlertJson(const AlertRecord& alert) {
  return {{"id", alert.id},
          {"actuator", alert.actuator_id},
          {"kind", alert.kind},
          {"severity", alert.severity},
          {"utime", alert.utime},
          {"start_utime", alert.start_utime},
          {"end_utime", alert.end_utime},
          {"magnitude_mm", FiniteOrNull(alert.magnitude_mm)},
          {"threshold_mm", FiniteOrNull(alert.threshold_mm)},
          {"text", alert.text}};
}

nlohmann::json LineageJson(const ModelRecord& model) {
  if (model.lineage_json.empty()) return nullptr;
  nlohmann::json lineage = nlohmann::json::parse(model.lineage_json, nullptr, false);
  return lineage.is_object() ? lineage : nlohmann::json(nullptr);
}

nlohmann::json ModelSummaryJson(const ModelRecord& model) {
  nlohmann::json fit = model.fit_json.empty()
                           ? nlohmann::json(nullptr)
                           : nlohmann::json::parse(model.fit_json, nullptr, false);
  if (fit.is_discarded()) fit = nullptr;
  return {{"actuator", model.actuator_id},
          {"version", model.version},
          {"created_utime", model.created_utime},
          {"active", model.active},
          {"trials", model.trial_ids},
          {"samples_hash", model.samples_hash},
          {"flexid_version", model.flexid_version},
          {"fit", fit},
          {"lineage", LineageJson(model)}};
}

nlohmann::json SamplesPageJson(const Trial& trial, int64_t offset,
                               const std::vector<Sample>& page) {
  nlohmann::json utime = nlohmann::json::array(), volts = nlohmann::json::array(),
                 mm = nlohmann::json::array();
  for (const Sample& s : page) {
    utime.push_back(s.utime);
    volts.push_back(s.voltage_V);
    mm.push_back(s.deflection_mm);
  }
  return {{"trial", TrialJson(trial)}, {"offset", offset},
          {"total", trial.samples},    {"utime", utime},
          {"voltage_V", volts},        {"deflection_mm", mm}};
}

nlohmann::json ActuatorJson(const Actuator& actuator) {
  return {{"id", actuator.id},
          {"length_mm", actuator.length_mm},
          {"width_mm", actuator.width_mm},
          {"thickness_mm", actuator.thickness_mm},
          {"material", actuator.material},
          {"electrolyte", actuator.electrolyte},
          {"concentration_M", actuator.concentration_M}};
}

}  // namespace flexid::storage
