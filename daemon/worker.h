// The identification worker (DESIGN.md: "identification worker"): identification and
// diagnosis of stored trials, one job at a time on a thread of its own with its own
// database connection (reads only). The loop takes the results (worker.cc).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "daemon/config.h"
#include "daemon/rpc.h"
#include "storage/database.h"

namespace flexid::daemon {

// A finished identification, handed from the worker to the loop.
// A finished diagnosis carries its result instead (diagnosis is an object).
struct IdentifyResult {
  RpcContext request;
  std::string actuator_id;
  std::optional<storage::ModelRecord> model;  // identified, to be stored (the writer) as active
  std::string error;
  nlohmann::json diagnosis = nullptr;  // the diagnose method's result
  // The diagnosed trials and their first samples' times (empty: an identification).
  std::vector<int64_t> trial_ids = {};
  std::vector<int64_t> trial_start_utimes = {};
};

// "trial 5" or "trials 4, 5, 7".
std::string TrialWords(const std::vector<int64_t>& ids);

// Diagnosis of stored trials of one actuator (one diagnosis from all of them, oldest
// first) against the actuator's active model (or, without one or when asked, against the
// seed's structure identified on the trials), on the worker thread with its own connection
// (reads only).
IdentifyResult RunDiagnosis(const std::string& database, const std::string& actuator_id,
                            const std::vector<int64_t>& trial_ids, bool use_model,
                            int64_t max_samples, RpcContext request);

// Identification of one actuator on stored trials, on the worker thread with its own
// connection (reads only): samples -> recordings -> T-S model -> the record of a new active
// model version, which the loop hands to the writer.
IdentifyResult RunIdentification(const std::string& database, const std::string& actuator_id,
                                 std::vector<int64_t> trial_ids, const IdentificationConfig& config,
                                 RpcContext request);

}  // namespace flexid::daemon
