// Proposed model versions (proposal.h): the augmented model of a diagnosis as a record.
#include "daemon/proposal.h"

#include <cmath>
#include <cstdio>

#include "daemon/worker.h"
#include "flexid/version.h"
#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/model_file.h"
#include "model/diagnose/effects.h"
#include "storage/record_json.h"

namespace flexid::daemon {
namespace {

nlohmann::json EffectsJson(const std::vector<model::Finding>& findings) {
  nlohmann::json effects = nlohmann::json::array();
  for (const model::Finding& f : findings) {
    nlohmann::json params = nlohmann::json::object();
    for (const model::ParameterEstimate& p : f.params) {
      nlohmann::json half_width = nullptr;  // not determined by the data
      if (std::isfinite(p.half_width_95)) half_width = p.half_width_95;
      params[p.name] = {{"value", p.value}, {"half_width_95", half_width}};
    }
    effects.push_back({{"effect", f.effect}, {"params", params}});
  }
  return effects;
}

// The augmented model's fit figures on the diagnosed recordings, laid end to end as the
// diagnosis laid them (its augmented_mm).
nlohmann::json FitOn(const std::vector<model::Recording>& recordings, const model::Diagnosis& d) {
  std::vector<double> measured, voltage;
  for (const model::Recording& r : recordings) {
    measured.insert(measured.end(), r.deflection_mm.begin(), r.deflection_mm.end());
    voltage.insert(voltage.end(), r.voltage_V.begin(), r.voltage_V.end());
  }
  if (measured.size() != d.augmented_mm.size())
    throw std::logic_error("the diagnosis's prediction does not match its recordings");
  return model::FitFiguresToJson(model::FitFiguresOf(measured, d.augmented_mm, voltage));
}

}  // namespace

std::optional<storage::ModelRecord> ProposalOf(const ProposalSource& source) {
  const model::Diagnosis& d = *source.diagnosis;
  if (d.findings.empty()) return std::nullopt;
  const int32_t parent_version = source.parent ? source.parent->version : 0;
  // The parent's file (its structure, its metadata and earlier augmentations) or, with no
  // parent, the baseline the diagnosis identified and refitted with the effects.
  model::ModelDocument doc =
      source.parent ? model::ParseModelJson(source.parent->model_json,
                                            "model version " + std::to_string(parent_version))
                    : model::FromTsModel(d.augmented_baseline_model);
  for (const model::Finding& f : d.findings) doc.augmentations.push_back(AugmentationOf(f.model));
  const double before_mm = d.findings.front().heldout_rmse_before_mm;
  const double after_mm = d.findings.back().heldout_rmse_after_mm;
  nlohmann::json lineage = {{"parent_version", parent_version},
                            {"proposed_by", source.proposed_by},
                            {"trials", source.trial_ids},
                            {"effects", EffectsJson(d.findings)},
                            {"heldout_rmse_before_mm", before_mm},
                            {"heldout_rmse_after_mm", after_mm},
                            {"heldout_gain", after_mm > 0 ? nlohmann::json(before_mm / after_mm)
                                                          : nlohmann::json(nullptr)}};
  const nlohmann::json fit = FitOn(*source.recordings, d);
  doc.extra["lineage"] = lineage;
  doc.extra["fit"] = fit;
  doc.extra["flexid_version"] = kVersion;
  storage::ModelRecord record;
  record.actuator_id = source.actuator_id;
  record.created_utime = source.created_utime;
  record.model_json = model::ModelToJson(doc).dump();
  record.fit_json = fit.dump();
  record.trial_ids = source.trial_ids;
  record.samples_hash = source.samples_hash;
  record.flexid_version = kVersion;
  record.active = false;
  record.lineage_json = lineage.dump();
  // It must run live: every effect in its range, an accruing one with its scale.
  model::AugmentedStreamingSimulator(model::AsTsModel(doc),
                                     model::EffectsOf(doc, "the augmented model"));
  return record;
}

std::string ProposalWords(const storage::ModelRecord& proposal) {
  const nlohmann::json lineage = storage::LineageJson(proposal);
  if (!lineage.is_object()) return "model version " + std::to_string(proposal.version);
  std::string effects;
  for (const nlohmann::json& e : lineage.value("effects", nlohmann::json::array()))
    effects += (effects.empty() ? "" : ", ") + e.value("effect", std::string("?"));
  const int parent = lineage.value("parent_version", 0);
  std::vector<int64_t> trials;
  for (const nlohmann::json& t : lineage.value("trials", nlohmann::json::array()))
    if (t.is_number_integer()) trials.push_back(t.get<int64_t>());
  char figures[160];
  std::snprintf(figures, sizeof figures, "held-out RMSE %.3g -> %.3g mm, %.1f times smaller",
                lineage.value("heldout_rmse_before_mm", 0.0),
                lineage.value("heldout_rmse_after_mm", 0.0), lineage.value("heldout_gain", 0.0));
  return "model version " + std::to_string(proposal.version) + " proposed (" +
         (parent > 0 ? "version " + std::to_string(parent) : std::string("identified")) + " with " +
         effects + "): " + figures + (trials.empty() ? "" : ", on " + TrialWords(trials));
}

}  // namespace flexid::daemon
