// The RPC's read-only methods that are answered from the database alone (DESIGN.md "Bus"):
// trials, trial_samples, models, model and alerts. One source for flexidd and for the
// command line's offline form (`flexid --db PATH ...`), so both answer in the same shapes
// with the same bounds and the same errors.
//
// Arguments are the request's JSON object:
//   trials         {"actuator"?, "limit"? (1-10000, default 100)}
//   trial_samples  {"trial" (>= 1), "offset"? (>= 0), "after_utime"?, "limit"? (1-20000,
//                  default 5000)}: a page of samples, by offset or (cheaper for long
//                  trials) after the last utime of the previous page
//   models         {"actuator"}
//   model          {"actuator", "version"? (0 or absent: the active one)}
//   alerts         {"actuator"?, "since_utime"? (>= 0), "limit"? (1-10000, default 100)}
// An actuator must be known to the database (its actuators table): one it does not know
// is not found (QueryError::Kind::kNotFound; with several daemons, one that holds none).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

#include "storage/database.h"

namespace flexid::storage {

// A request the database cannot answer: a bad argument (naming it) or nothing found.
struct QueryError : std::runtime_error {
  enum class Kind { kBadArgument, kNotFound };
  explicit QueryError(const std::string& what, Kind error_kind = Kind::kBadArgument)
      : std::runtime_error(what), kind(error_kind) {}
  Kind kind;
};

// A request's integer argument in [min, max], or `fallback` when absent; throws QueryError
// naming the argument (a JSON integer above INT64_MAX is refused, never wrapped). flexidd's
// other methods read their integers with it too.
int64_t IntegerArgument(const nlohmann::json& args, const char* name, int64_t fallback, int64_t min,
                        int64_t max);

// True for the methods AnswerQuery answers.
bool IsStoredQuery(const std::string& method);

// The method's answer, as flexidd replies it. Throws QueryError for a bad argument, an
// unknown actuator, trial or model; StorageError if the file cannot be read;
// std::invalid_argument for a method IsStoredQuery refuses.
nlohmann::json AnswerQuery(Database& db, const std::string& method, const nlohmann::json& args);

}  // namespace flexid::storage
