// The page's view of flexidd's "models" RPC: an actuator's stored model versions, each
// identified (from trials) or proposed (an augmented model a diagnosis stored, inactive,
// with its lineage). The dashboard only shows them: activating one is a signed change
// (`flexid models activate`).
//
// The reply is a JSON array of storage's ModelSummaryJson rows: "actuator", "version",
// "active", "created_utime", "trials", "fit" and, from issue 15 item 2 on, "lineage" (null
// for an identified model; flexidd before it sends no "lineage": read as null). A proposal's
// lineage:
//   {"parent_version": 3, "proposed_by": "diagnose", "trials": [12],
//    "effects": [{"effect": "back_relaxation",
//                 "params": {"fraction": {"value": 0.21, "half_width_95": 0.03}, ...}}],
//    "heldout_rmse_before_mm": 0.085, "heldout_rmse_after_mm": 0.021, "heldout_gain": 4.05}
// where parent_version 0 means no model was active (the baseline was identified on the
// diagnosed trials), proposed_by is "diagnose" or "policy" (flexidd's on_alert) and
// heldout_gain = before / after (daemon/proposal.h).
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>

namespace flexid::dashboard {

// The rows of a "models" result for `actuator_id`, newest version first, each
//   {"version", "active", "created_utime" (or null), "trials", "fit": {"fit_percent",
//    "rmse_mm"} (or null), "lineage": null or {"parent_version", "proposed_by", "trials",
//    "effects": [{"effect", "params": {NAME: {"value", "half_width_95"}}}],
//    "heldout_rmse_before_mm", "heldout_rmse_after_mm", "heldout_gain"}}
// with numbers rounded to 4 significant digits, and heldout_gain computed from the RMSEs
// when the reply has both but not it. nullopt, with *error saying which row and field and
// what was expected (one line), when the result is not such a list: not an array, a row
// of another actuator, a version that is not an integer >= 1 or appears twice, "active"
// not a boolean, two active versions, a lineage that is neither null nor an object with
// an integer parent_version >= 0 below its version, an effect without a name, a number
// field holding something else or a negative RMSE.
std::optional<nlohmann::json> ModelVersionsFromJson(const nlohmann::json& rpc_result,
                                                    const std::string& actuator_id,
                                                    std::string* error);

}  // namespace flexid::dashboard
