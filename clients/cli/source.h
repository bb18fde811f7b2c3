// Where the data of a flexid command comes from (DESIGN.md, "Command lines"): flexidd over
// the bus by default (global --lcm URL), or, with the global --db PATH, a database file read
// directly with no daemon running. Both give the same JSON documents
// (storage/record_json.h), so a command formats one shape whichever way its data came.
//
// Read-only requests use flexidd's RPC method names and arguments (daemon/rpc.h):
//   status, actuators, trials {actuator?, limit?}, trial_samples {trial, after_utime?,
//   offset?, limit?}, models {actuator}, model {actuator, version?}, alerts {actuator?,
//   since_utime?, limit?}.
// Offline, `status` describes the file instead of a running daemon.
#pragma once

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "storage/database.h"

namespace flexid::cli {

// The database file given with --db; empty when commands talk to flexidd.
std::string& DbPath();
inline bool Offline() { return !DbPath().empty(); }

// Seconds to wait for flexidd's reply to a read-only request.
inline constexpr double kQueryTimeout_s = 10.0;

// The --db file, opened for an offline command. Throws UsageError without --db and
// OperationError when the file is missing or is not a flexid database.
storage::Database OpenDbFile();

// A read-only request, answered by flexidd or (offline) from the --db file. Throws
// UsageError for a bad request or something that does not exist (exit 2), OperationError
// when no daemon answers or the file cannot be read (exit 1).
nlohmann::json Query(const std::string& method, const nlohmann::json& args,
                     double timeout_s = kQueryTimeout_s);

// A request only flexidd can carry out (identify, diagnose, model_activate, trial_start,
// trial_stop): refused with a UsageError naming the method when --db is given, otherwise
// as Query.
nlohmann::json CallOnline(const std::string& method, const nlohmann::json& args, double timeout_s);

// The samples of a stored trial, in utime order.
struct StoredTrial {
  nlohmann::json trial;  // storage::TrialJson
  std::vector<int64_t> utime;
  std::vector<double> voltage_V, deflection_mm;
};

// Reads a trial page by page; progress(done, total) after each page.
StoredTrial LoadTrial(int64_t trial_id,
                      const std::function<void(int64_t done, int64_t total)>& progress = {});

// The trial as a recording, t_s from its first sample; source "trial ID". Throws UsageError
// when it has fewer than min_samples samples.
model::Recording RecordingOf(const StoredTrial& trial, size_t min_samples = 2);

// A stored model of an actuator (version 0: the active one) as a model document; its
// source name is "S1 model v3". Throws UsageError when there is no such model.
model::ModelDocument StoredModel(const std::string& actuator, int32_t version = 0);

}  // namespace flexid::cli
