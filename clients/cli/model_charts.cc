// Chart builders of model_charts.h: data of models and recordings as Chart values.
#include "clients/cli/model_charts.h"

#include <algorithm>
#include <cmath>
#include <complex>
#include <iterator>
#include <numbers>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "model/core/transfer_function.h"
#include "model/diagnose/diagnose.h"

namespace flexid::cli {
namespace {

const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};

std::string RuleName(const model::TsModel& model, size_t rule) {
  return model.rules.size() == 1 ? "G" : FormatNumber(model.rules[rule].level_V, 4) + " V";
}

}  // namespace

void CheckModelChoice(const ModelChoice& choice) {
  if (!choice.path.empty() && !choice.actuator.empty())
    throw UsageError("--model and --actuator both name a model; give one of them");
  if (choice.version && choice.actuator.empty())
    throw UsageError("--version " + std::to_string(*choice.version) +
                     " needs --actuator ID (the actuator whose stored model to use)");
  if (choice.version && *choice.version < 1)
    throw UsageError("--version must be 1 or more, got " + std::to_string(*choice.version));
}

LoadedModel LoadModel(const ModelChoice& choice) {
  if (!choice.path.empty()) return {model::ReadModelFile(choice.path), choice.path};
  const int32_t version = choice.version.value_or(0);
  return {
      StoredModel(choice.actuator, version),
      choice.actuator + (version == 0 ? " active model" : " model v" + std::to_string(version))};
}

LoadedRecording LoadRecording(const std::string& csv_path, std::optional<int64_t> trial) {
  if (!trial) return {model::ReadRecordingCsv(csv_path), csv_path, ""};
  if (*trial < 1) throw UsageError("--trial must be 1 or more, got " + std::to_string(*trial));
  Progress progress("trial " + std::to_string(*trial));
  const StoredTrial stored =
      LoadTrial(*trial, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  progress.Finish();
  LoadedRecording out;
  out.recording = RecordingOf(stored);
  out.name = out.recording.source;
  out.actuator = stored.trial.value("actuator", "");
  return out;
}

std::vector<double> PredictDeflection(const model::ModelDocument& doc,
                                      const model::Recording& recording,
                                      const std::string& model_name) {
  const std::vector<model::Effect> effects = model::EffectsOf(doc, model_name);
  std::vector<double> y = model::SimulateAugmented(model::AsTsModel(doc), recording, effects);
  for (size_t k = 0; k < y.size(); ++k)
    if (!std::isfinite(y[k]))
      throw OperationError(model_name + ": the prediction diverges at t = " +
                           FormatNumber(recording.t_s[k]) + " s (is the model stable?)");
  return y;
}

std::vector<Chart> FitCharts(const model::Recording& recording,
                             const std::vector<double>& predicted_mm, const std::string& title) {
  Chart deflection{title,
                   "time (s)",
                   "deflection (mm)",
                   {{"measured", recording.t_s, recording.deflection_mm, "#1f77b4", false, false},
                    {"predicted", recording.t_s, predicted_mm, "#d62728", true, false}},
                   {}};
  Chart voltage{"applied voltage",
                "time (s)",
                "voltage (V)",
                {{"voltage", recording.t_s, recording.voltage_V, "#555555", false, true}},
                {}};
  return {deflection, voltage};
}

Chart ResidualChart(const model::Recording& recording, const std::vector<double>& predicted_mm,
                    const std::string& title) {
  std::vector<double> residual(std::min(predicted_mm.size(), recording.deflection_mm.size()));
  for (size_t k = 0; k < residual.size(); ++k)
    residual[k] = recording.deflection_mm[k] - predicted_mm[k];
  return Chart{title,
               "time (s)",
               "residual (mm)",
               {{"residual", recording.t_s, residual, "#1f77b4", false, false}},
               {}};
}

std::vector<Chart> BodeCharts(const model::TsModel& model, const std::string& title,
                              std::optional<size_t> rule) {
  Chart magnitude{"Bode magnitude: " + title,
                  "log10 angular frequency (rad/s)",
                  "magnitude (dB, mm per V)",
                  {},
                  {}};
  Chart phase{"Bode phase (dead time included)",
              "log10 angular frequency (rad/s)",
              "phase (degrees)",
              {},
              {}};
  for (size_t r = 0; r < model.rules.size(); ++r) {
    if (rule && *rule != r) continue;
    const model::TransferFunction& tf = model.rules[r].tf;
    Series m{RuleName(model, r), {}, {}, kColours[r % std::size(kColours)], false, false};
    Series p = m;
    double previous = 0.0, unwrap = 0.0;
    for (int i = 0; i <= 400; ++i) {
      const double log_w = -4.0 + 6.0 * i / 400.0;  // 1e-4 .. 1e2 rad/s
      const double w = std::pow(10.0, log_w);
      const std::complex<double> g = model::FrequencyResponse(tf, w);
      // The rational part's phase is unwrapped on the grid; the dead time's -w T is exact
      // (it turns faster than any grid resolves at high frequency).
      const std::complex<double> rational = g * std::polar(1.0, w * tf.delay_s);
      double angle = std::arg(rational) * 180.0 / std::numbers::pi;
      if (i > 0) {
        while (angle + unwrap - previous > 180.0) unwrap -= 360.0;
        while (angle + unwrap - previous < -180.0) unwrap += 360.0;
      }
      previous = angle + unwrap;
      m.x.push_back(log_w);
      m.y.push_back(20.0 * std::log10(std::abs(g)));
      p.x.push_back(log_w);
      p.y.push_back(previous - w * tf.delay_s * 180.0 / std::numbers::pi);
    }
    magnitude.series.push_back(std::move(m));
    phase.series.push_back(std::move(p));
  }
  return {magnitude, phase};
}

Chart MembershipChart(const model::TsModel& model, const std::string& title) {
  double top = 1.0;
  for (const model::LocalModel& rule : model.rules) top = std::max(top, std::abs(rule.level_V));
  Chart chart{
      "rule memberships: " + title, "scheduling value (V)", "normalised membership", {}, {}};
  std::vector<double> mu;
  for (size_t r = 0; r < model.rules.size(); ++r) {
    Series s{FormatNumber(model.rules[r].level_V, 4) + " V",
             {},
             {},
             kColours[r % std::size(kColours)],
             false,
             false};
    for (int i = 0; i <= 400; ++i) {
      const double z = 1.25 * top * i / 400.0;
      model::NormalisedMemberships(model, z, &mu);
      s.x.push_back(z);
      s.y.push_back(mu[r]);
    }
    chart.series.push_back(std::move(s));
  }
  return chart;
}

}  // namespace flexid::cli
