// The online predictor's part of the loop: the active model of each actuator loaded (and
// hot-swapped), stepped on every voltage and deflection, its prediction published, and
// the residual handed to the actuator's monitor (model/diagnose/monitor.h), whose alerts go to the
// bus and the writer.
#include <flexid/alert_t.hpp>
#include <flexid/prediction_t.hpp>

#include "daemon/service.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"

namespace flexid::daemon {

Predictor PredictorOf(const std::string& model_json, int32_t version, bool in_steady_state) {
  const std::string source = "model version " + std::to_string(version);
  const model::ModelDocument doc = model::ParseModelJson(model_json, source);
  Predictor predictor;
  predictor.version = version;
  model::SimulationOptions options;
  options.start_in_steady_state = in_steady_state;
  try {
    predictor.simulator.emplace(model::AsTsModel(doc), model::EffectsOf(doc, source), options);
  } catch (const model::InputError& e) {
    const std::string what = e.what();
    throw model::InputError(what.starts_with(source) ? what : source + ": " + what);
  }
  return predictor;
}

void Service::LoadModel(ActuatorState* state, const storage::ModelRecord& record) {
  // Start at rest, or in steady state under the voltage in force: a model swapped in
  // during a hold starts where the actuator is assumed to be.
  state->predictor = PredictorOf(record.model_json, record.version,
                                 std::abs(state->voltage_V) > config.alerts.rest_band_V);
  // Alert thresholds are calibrated on the residual this model showed when it was
  // fitted (its RMSE), unless the configuration fixes the noise scale.
  MonitorOptions monitor_options = config.alerts;
  const nlohmann::json fit = nlohmann::json::parse(record.fit_json, nullptr, false);
  if (monitor_options.noise_mm <= 0.0 && fit.is_object() && fit.contains("rmse_mm") &&
      fit["rmse_mm"].is_number())
    monitor_options.noise_mm = fit["rmse_mm"].get<double>();
  // A model fitted to noise-free data claims a residual far below what a sensor resolves:
  // the monitor uses its floor instead (model/diagnose/monitor.h, "Floor"), and the log says so.
  if (monitor_options.noise_mm > 0.0 && monitor_options.noise_mm < monitor_options.sigma_floor_mm)
    spdlog::info(
        "model residual noise below the floor: alert thresholds use the floor [actuator: {}, "
        "version: {}, noise_mm: {:.3g}, sigma_floor_mm: {}]",
        state->info.id, record.version, monitor_options.noise_mm, monitor_options.sigma_floor_mm);
  state->monitor = std::make_unique<ResidualMonitor>(state->info.id, monitor_options);
  spdlog::info("model active [actuator: {}, version: {}]", state->info.id, record.version);
}

// The voltage in force from utime on: the predictor follows it, and the monitor sees the
// holds it makes.
void Service::PredictVoltage(ActuatorState* state, int64_t utime, double voltage_V) {
  if (state->predictor.ready()) state->predictor.Step(utime, voltage_V);
  Raise(state, state->monitor->OnVoltage(utime, voltage_V));
}

// The prediction at a deflection sample's time, published with the residual; the monitor
// judges the residual.
void Service::PublishPrediction(ActuatorState* state, const flexid::deflection_sample_t& message) {
  const double predicted = state->predictor.Step(message.utime, state->voltage_V);
  const double residual = message.deflection_mm - predicted;
  flexid::prediction_t out;
  out.utime = message.utime;
  out.actuator_id = message.actuator_id;
  out.voltage_V = state->voltage_V;
  out.measured_mm = message.deflection_mm;
  out.predicted_mm = predicted;
  out.residual_mm = residual;
  out.model_version = state->predictor.version;
  out.trial_id = static_cast<int32_t>(state->trial_id);
  out.memberships = state->predictor.memberships;
  out.num_memberships = static_cast<int16_t>(out.memberships.size());
  lcm.publish(channels.Prediction(message.actuator_id), &out);
  ++counters.predictions_published;
  Raise(state, state->monitor->OnDeflection(message.utime, state->voltage_V, residual));
}

// Queues an alert for the writer; counts it when the writer's alert queue is full.
void Service::StoreAlert(storage::AlertRecord record) {
  if (Store(std::move(record)) == 0) ++counters.alerts_dropped;
}

void Service::Raise(ActuatorState* state, const std::vector<Alert>& alerts) {
  for (const Alert& alert : alerts) {
    flexid::alert_t out;
    // Message time: the actuator's latest sample, or before it has any, the latest of any
    // actuator (or the wall clock), so that the alert is found by a query from time 0.
    out.utime = state->deflection_utime != kNoTime ? state->deflection_utime
                : state->voltage_utime != kNoTime  ? state->voltage_utime
                                                   : LatestUtime();
    out.actuator_id = state->info.id;
    out.kind = alert.kind;
    out.severity = static_cast<int8_t>(alert.severity);
    out.start_utime = alert.start_utime;
    out.end_utime = alert.end_utime;
    out.magnitude_mm = alert.magnitude_mm;
    out.threshold_mm = alert.threshold_mm;
    out.text = alert.text;
    lcm.publish(channels.Alert(), &out);
    ++counters.alerts_raised;
    storage::AlertRecord record{0,
                                out.actuator_id,
                                out.kind,
                                out.severity,
                                out.utime,
                                out.start_utime,
                                out.end_utime,
                                out.magnitude_mm,
                                out.threshold_mm,
                                out.text};
    StoreAlert(std::move(record));
    spdlog::log(alert.severity == 0 ? spdlog::level::info : spdlog::level::warn,
                "alert [actuator: {}, kind: {}, magnitude_mm: {:.3f}] {}", out.actuator_id,
                out.kind, out.magnitude_mm, out.text);
  }
}

// Tells the bus that a new model is active: an info alert of kind "model_changed".
void Service::AnnounceModel(ActuatorState* state, const storage::ModelRecord& record) {
  const nlohmann::json fit = nlohmann::json::parse(record.fit_json, nullptr, false);
  Alert alert;
  alert.kind = "model_changed";
  alert.severity = 0;
  alert.start_utime = alert.end_utime =
      state->deflection_utime != kNoTime ? state->deflection_utime : 0;
  alert.text = state->info.id + ": model version " + std::to_string(record.version) + " is active";
  if (fit.is_object() && fit.contains("fit_percent") && fit["fit_percent"].is_number()) {
    char figures[96];
    std::snprintf(figures, sizeof figures,
                  " (fit %.1f %%, RMSE %.3g mm on trials it was identified from)",
                  fit["fit_percent"].get<double>(), fit.value("rmse_mm", 0.0));
    alert.text += figures;
  }
  Raise(state, {alert});
}

}  // namespace flexid::daemon
