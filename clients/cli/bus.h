// The flexid command line on the bus: the LCM URL and the channel prefix chosen with the
// global --lcm and --channel-prefix options, and a blocking RPC call to flexidd
// (bus/rpc_client.h: PREFIX/RPC/REQUEST -> PREFIX/RPC/REPLY/<client>).
#pragma once

#include <signal.h>

#include <chrono>
#include <nlohmann/json.hpp>
#include <string>

#include "bus/channels.h"
#include "lcmtypes/message_auth.h"

namespace flexid::cli {

// Default as in DESIGN.md; set by main() from --lcm.
std::string& LcmUrl();

// The channel prefix, flexidd's channel_prefix (default FLEXID); set by main() from
// --channel-prefix, which checks it against bus::IsValidPrefix.
std::string& ChannelPrefix();
// The channels named from ChannelPrefix().
bus::Channels BusChannels();

// The --key-file option (empty: $FLEXID_KEY_FILE, else var/flexidd.key); set by main().
std::string& KeyFilePath();
// The key for requests that change data (lcmtypes/message_auth.h), read once from the file
// KeyFilePath() names. Throws OperationError "cannot read key file PATH: ..." (exit 1).
const auth::Key& SigningKey();

struct RpcResult {
  int8_t status = 0;  // rpc_reply_t::kOk, ...
  nlohmann::json result;
  std::string error;
  std::string daemon_id;
};

// Sends one request and waits for its reply; a method that changes data
// (auth::ChangesData) is signed with SigningKey(). Throws OperationError when no daemon
// answers within the timeout, the bus cannot be joined or the key cannot be read.
RpcResult CallDaemon(const std::string& method, const nlohmann::json& args,
                     std::chrono::milliseconds timeout);

// While it exists, SIGINT and SIGTERM only set a flag (requested()) that a long-running bus
// command polls in its loop, so that it can end cleanly (close what it opened, exit 0 or
// report). The previous handlers come back in the destructor. One at a time.
class StopOnSignal {
 public:
  StopOnSignal();
  ~StopOnSignal();
  StopOnSignal(const StopOnSignal&) = delete;
  StopOnSignal& operator=(const StopOnSignal&) = delete;
  bool requested() const;

 private:
  struct sigaction previous_interrupt_ {};
  struct sigaction previous_terminate_ {};
};

}  // namespace flexid::cli
