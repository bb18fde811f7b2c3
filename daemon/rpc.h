// RPC over the bus (DESIGN.md): a request on FLEXID/RPC/REQUEST names its method and
// carries JSON arguments; the reply goes to FLEXID/RPC/REPLY/<client_id> with the request
// id, a status and a JSON result. Read-only methods: status, actuators, trials,
// trial_samples, models, model, alerts. Methods that change data (ChangesData(): identify,
// trial_start, trial_stop, model_activate, diagnose, any other) must be signed
// (lcmtypes/message_auth.h).
#pragma once

#include <cstdint>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "lcmtypes/message_auth.h"

namespace flexid::daemon {

// Which methods change data: one list, in lcmtypes/message_auth.h, because the clients
// decide by it whether to sign and flexidd whether to require a signature.
using auth::ChangesData;

struct RpcContext {
  std::string request_id;
  std::string client_id;
};

struct RpcOutcome {
  int8_t status = 0;  // rpc_reply_t::kOk, ...
  nlohmann::json result;
  std::string error;      // one line when status != kOk
  bool deferred = false;  // the reply comes later (identify, or once a write is done)
  uint64_t written = 0;   // deferred until the write with this ticket is done (0: not)
};

// Typed access to a request's JSON arguments; throws ArgumentError naming the argument.
struct ArgumentError : std::runtime_error {
  using std::runtime_error::runtime_error;
};
// A request's arguments (or any text from the bus) for the log: at most 200 bytes, control
// characters as '?'.
std::string ArgumentSummary(const std::string& args_json);

nlohmann::json ParseArguments(const std::string& args_json);
std::string StringArgument(const nlohmann::json& args, const char* name,
                           const std::string* fallback = nullptr);
int64_t IntegerArgument(const nlohmann::json& args, const char* name, int64_t fallback, int64_t min,
                        int64_t max);
int64_t RequiredIntegerArgument(const nlohmann::json& args, const char* name, int64_t min,
                                int64_t max);
bool BoolArgument(const nlohmann::json& args, const char* name, bool fallback);
// A list of 1 to max_count distinct trial ids (integers >= 1).
std::vector<int64_t> TrialIdsArgument(const nlohmann::json& args, const char* name,
                                      size_t max_count);

}  // namespace flexid::daemon
