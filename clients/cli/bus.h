// The flexid command line on the bus: the LCM URL and the channel prefix chosen with the
// global --lcm and --channel-prefix options, the keys (--key-file, --key-dir), and a
// blocking RPC call to one flexidd (bus/rpc_client.h: PREFIX/RPC/REQUEST ->
// PREFIX/RPC/REPLY/<client>); asking every daemon is source.h's Gather.
#pragma once

#include <signal.h>

#include <chrono>
#include <lcm/lcm-cpp.hpp>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

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

// The --key-file values (set by main()): PATH, the key for any daemon, or ID=PATH, the key
// of daemon ID (each daemon may have its own key). With none: $FLEXID_KEY_FILE, else
// var/flexidd.key.
std::vector<std::string>& KeyFileOptions();
// The --key-dir DIR (set by main()): the key of daemon ID is DIR/ID.key.
std::string& KeyDir();
// Empty when a --key-file value is well formed; otherwise what is wrong with it.
std::string KeyFileOptionProblem(const std::string& value);
// The key file for a request to `daemon_id` ("": a daemon not known by name): ID=PATH for
// it, else --key-dir's DIR/ID.key, else a plain --key-file PATH, else the default.
std::string KeyFileFor(const std::string& daemon_id);
// The key for requests that change data on that daemon (lcmtypes/message_auth.h), read
// once per file. Throws OperationError "cannot read key file PATH: ..." (exit 1).
const auth::Key& SigningKey(const std::string& daemon_id = "");

struct RpcResult {
  int8_t status = 0;  // rpc_reply_t::kOk, ...
  nlohmann::json result;
  std::string error;
  std::string daemon_id;
};

// The bus of LcmUrl(), joined with a receive buffer that holds a whole reply (a page of
// trial samples is up to ~1 MB of JSON). Throws OperationError when it cannot be joined.
std::unique_ptr<lcm::LCM> JoinBus();

// Sends one request and waits for its reply; with `daemon_id` it is addressed to that
// daemon ("daemon_id" in its arguments: the others ignore it), otherwise the first reply
// counts. A method that changes data (auth::ChangesData) is signed with
// SigningKey(daemon_id). Throws OperationError when no daemon answers within the timeout,
// the bus cannot be joined or the key cannot be read.
RpcResult CallDaemon(const std::string& method, const nlohmann::json& args,
                     std::chrono::milliseconds timeout, const std::string& daemon_id = "");

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
