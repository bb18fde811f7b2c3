// RPC to flexidd (DESIGN.md, "Bus"): a client publishes rpc_request_t on PREFIX/RPC/REQUEST
// and flexidd answers with rpc_reply_t on PREFIX/RPC/REPLY/<client_id>, carrying the same
// request_id. Requests whose method changes data (auth::ChangesData) are signed.
//
// Two ways to use it:
//  - RpcClient: send one request and wait for its reply, for callers that can wait (the
//    command line, the load benchmark).
//  - MakeRequest and DecodeReply: the message building and the reply check alone, for a
//    caller that never waits (the dashboard keeps its own table of requests in flight and
//    handles replies in its loop).
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <mutex>
#include <optional>
#include <string>

#include "bus/channels.h"
#include "lcmtypes/message_auth.h"

namespace flexid::bus {

// 64 random bits as 16 hex digits: a request id no other request of the client shares.
std::string RandomRequestId();

// A request stamped with the wall clock (utime) and a fresh nonce; signed with `key` when
// the method changes data and a key is given. Without a key such a request goes unsigned,
// and flexidd refuses it with a reply that says so.
flexid::rpc_request_t MakeRequest(const std::string& client_id, const std::string& request_id,
                                  const std::string& method, const std::string& args_json,
                                  const auth::Key* key);

// The reply in a received buffer, if it is one: well formed (lcmtypes/wire_check.h) before
// it is decoded.
std::optional<flexid::rpc_reply_t> DecodeReply(const lcm::ReceiveBuffer& rbuf);

struct RpcReply {
  flexid::rpc_reply_t message;
  std::chrono::steady_clock::time_point received;  // when the reply handler saw it
};

class RpcClient {
 public:
  // Who runs LCM's handlers for `lcm`.
  enum class Dispatch {
    kInCall,     // Call() does (lcm.handleTimeout) while it waits: a client with no loop
    kElsewhere,  // another thread does; Call() only waits for the reply to be handed over
  };

  // Subscribes to PREFIX/RPC/REPLY/<client_id> on `lcm` (unsubscribed in the destructor).
  // `client_id` must satisfy bus::IsValidId; `lcm` and `key` must outlive the client. `key`
  // signs the methods that change data (nullptr: none are signed).
  RpcClient(lcm::LCM& lcm, const Channels& channels, std::string client_id,
            const auth::Key* key = nullptr, Dispatch dispatch = Dispatch::kInCall);
  ~RpcClient();
  RpcClient(const RpcClient&) = delete;
  RpcClient& operator=(const RpcClient&) = delete;

  // Sends `method` with `args_json` (a JSON object) and waits up to `timeout` for its
  // reply; nullopt when none came. Replies to other requests, and malformed ones, are
  // ignored. Thread-safe with Dispatch::kElsewhere (several calls may wait at once).
  std::optional<RpcReply> Call(const std::string& method, const std::string& args_json,
                               std::chrono::milliseconds timeout);

  const std::string& client_id() const { return client_id_; }

 private:
  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string& channel, RpcClient* self);

  lcm::LCM& lcm_;
  std::string request_channel_;
  std::string client_id_;
  const auth::Key* key_;
  Dispatch dispatch_;
  lcm::Subscription* subscription_ = nullptr;
  std::mutex mutex_;
  std::condition_variable replied_;
  // By request id: the calls waiting, and their reply once it has come.
  std::map<std::string, std::optional<RpcReply>> waiting_;
};

}  // namespace flexid::bus
