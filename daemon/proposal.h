// Proposed model versions (issue 15): a diagnosis that names effects becomes a new, inactive
// version of the actuator's model, the parent with the findings as augmentations, stored
// with its lineage so that a person (or the on_alert policy) can compare and activate it.
//
// Lineage (storage::ModelRecord::lineage_json, and the model file's "lineage" member):
//   {"parent_version": 4,            0: no active model; the baseline was identified on
//                                    the diagnosed trials and refitted with the effects
//    "proposed_by": "diagnose",      or "policy" (on_alert = propose | adopt)
//    "trials": [12],                 the diagnosed trials, oldest first
//    "effects": [{"effect": "back_relaxation",
//                 "params": {"fraction": {"value": 0.21, "half_width_95": 0.03}, ...}}],
//    "heldout_rmse_before_mm": 0.085, "heldout_rmse_after_mm": 0.021,
//    "heldout_gain": 4.05}           before / after: how many times smaller the error on
//                                    the held-out samples is with the effects
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "model/core/recording.h"
#include "model/diagnose/diagnose.h"
#include "storage/database.h"

namespace flexid::daemon {

struct ProposalSource {
  std::string actuator_id;
  const model::Diagnosis* diagnosis = nullptr;
  const std::vector<model::Recording>* recordings = nullptr;  // as diagnosed, in order
  const storage::ModelRecord* parent = nullptr;               // the model diagnosed against, if any
  std::vector<int64_t> trial_ids;
  std::string samples_hash;  // storage::HashSamples of the diagnosed trials' samples
  std::string proposed_by;   // "diagnose" | "policy"
  int64_t created_utime = 0;
};

// The proposed version's record (inactive, version assigned when stored), or nothing when
// the diagnosis named no effect. Its fit figures are the augmented model's on the diagnosed
// trials. Throws model::InputError when the augmented model cannot run live (an effect out
// of its range, an accruing effect without its scale): nothing is stored then.
std::optional<storage::ModelRecord> ProposalOf(const ProposalSource& source);

// One line about a proposal for alerts and logs: "model version 5 proposed (version 4 with
// back_relaxation): held-out RMSE 0.085 -> 0.021 mm, 4.0 times smaller, on trial 12".
std::string ProposalWords(const storage::ModelRecord& proposal);

}  // namespace flexid::daemon
