// DiagnosisToJson (diagnose.h): the diagnosis result of DESIGN.md plus what flexid adds.
#include <cmath>
#include <nlohmann/json.hpp>

#include "model/core/metrics.h"
#include "model/diagnose/diagnose.h"

namespace flexid::model {

namespace {

nlohmann::json Finite(double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json(); }

// `several`: the diagnosis covered several recordings; each span then says which.
nlohmann::json SpansToJson(const std::vector<TimeSpan>& spans, bool several) {
  nlohmann::json out = nlohmann::json::array();
  for (const TimeSpan& s : spans) {
    out.push_back({{"t_start_s", s.t_start_s}, {"t_end_s", s.t_end_s}});
    if (several) out.back()["recording"] = s.recording;
  }
  return out;
}

void ParamsToJson(const std::vector<ParameterEstimate>& params, nlohmann::json* out) {
  nlohmann::json values = nlohmann::json::object(), widths = nlohmann::json::object();
  for (const ParameterEstimate& p : params) {
    values[p.name] = Finite(p.value);
    widths[p.name] = Finite(p.half_width_95);
  }
  (*out)["params"] = values;
  (*out)["params_95"] = widths;
}

}  // namespace

nlohmann::json DiagnosisToJson(const Diagnosis& d) {
  nlohmann::json out;
  const bool several = d.recordings.size() > 1;
  out["verdict"] = d.verdict;
  if (several) out["recordings"] = d.recordings;
  out["baseline"] = {{"fit_percent", Finite(d.baseline_fit_percent)},
                     {"rmse_mm", Finite(d.baseline_rmse_mm)},
                     {"heldout_rmse_mm", Finite(d.baseline_heldout_rmse_mm)},
                     {"source", d.trusted_model ? "trusted model" : "identified on the recording"}};
  nlohmann::json findings = nlohmann::json::array();
  for (const Finding& f : d.findings) {
    nlohmann::json j = {{"effect", f.effect},
                        {"explanation", f.explanation},
                        {"where", SpansToJson(f.where, several)},
                        {"heldout_rmse_before_mm", Finite(f.heldout_rmse_before_mm)},
                        {"heldout_rmse_after_mm", Finite(f.heldout_rmse_after_mm)}};
    ParamsToJson(f.params, &j);
    nlohmann::json rivals = nlohmann::json::array();
    for (const Rival& r : f.rivals)
      rivals.push_back({{"effect", r.effect}, {"heldout_rmse_mm", Finite(r.heldout_rmse_mm)}});
    j["rivals"] = std::move(rivals);
    if (!f.chosen_by.empty()) j["chosen_by"] = f.chosen_by;
    findings.push_back(std::move(j));
  }
  out["findings"] = std::move(findings);
  out["noise_std_mm"] = d.noise_std_mm;
  out["heldout"] = SpansToJson(d.heldout, several);
  nlohmann::json candidates = nlohmann::json::array();
  for (const CandidateReport& c : d.candidates) {
    nlohmann::json j = {{"effect", c.name},
                        {"round", c.round},
                        {"claimed", c.claimed},
                        {"reason", c.reason},
                        {"train_rmse_mm", Finite(c.train_rmse_mm)},
                        {"heldout_rmse_mm", Finite(c.heldout_rmse_mm)},
                        {"effective_samples", Finite(c.effective_samples)},
                        {"likelihood_ratio", Finite(c.likelihood_ratio)},
                        {"heldout_likelihood_ratio", Finite(c.heldout_likelihood_ratio)},
                        {"bic", Finite(c.bic)},
                        {"effect_rms_mm", Finite(c.effect_rms_mm)}};
    ParamsToJson(c.params, &j);
    candidates.push_back(std::move(j));
  }
  out["candidates"] = std::move(candidates);
  nlohmann::json groups = nlohmann::json::array();
  for (const ResidualGroup& g : d.localisation.groups)
    groups.push_back({{"dimension", g.dimension},
                      {"group", g.group},
                      {"samples", g.samples},
                      {"mean_mm", Finite(g.mean_mm)},
                      {"rms_mm", Finite(g.rms_mm)}});
  out["localisation"] = {{"residual_groups", std::move(groups)},
                         {"baseline_fit", FitFiguresToJson(d.localisation.baseline_fit)}};
  nlohmann::json absorbed = nlohmann::json::array();
  for (const Absorbed& a : d.absorbed)
    absorbed.push_back({{"effect", a.effect},
                        {"level_V", a.level_V},
                        {"tau_s", Finite(a.tau_s)},
                        {"fall_back", a.fall_back},
                        {"amplitude_mm", a.amplitude_mm},
                        {"explanation", a.explanation}});
  out["absorbed"] = std::move(absorbed);
  nlohmann::json unexplained = nlohmann::json::array();
  for (const Misfit& m : d.unexplained)
    unexplained.push_back({{"resembles", m.resembles},
                           {"rms_mm", Finite(m.rms_mm)},
                           {"where", SpansToJson(m.where, several)},
                           {"explanation", m.explanation}});
  out["unexplained"] = std::move(unexplained);
  out["notes"] = d.notes;
  return out;
}

}  // namespace flexid::model
