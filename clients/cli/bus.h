// The flexid command line on the bus: the LCM URL chosen with the global --lcm option,
// and a blocking RPC call to flexidd (DESIGN.md: FLEXID/RPC/REQUEST -> FLEXID/RPC/REPLY/<client>).
#pragma once

#include <chrono>
#include <nlohmann/json.hpp>
#include <string>

namespace flexid::cli {

// Default as in DESIGN.md; set by main() from --lcm.
std::string& LcmUrl();

struct RpcResult {
  int8_t status = 0;  // rpc_reply_t::kOk, ...
  nlohmann::json result;
  std::string error;
  std::string daemon_id;
};

// Sends one request and waits for its reply. Throws OperationError when no daemon
// answers within the timeout or the bus cannot be joined.
RpcResult CallDaemon(const std::string& method, const nlohmann::json& args,
                     std::chrono::milliseconds timeout);

}  // namespace flexid::cli
