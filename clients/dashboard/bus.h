// The dashboard on the bus: subscribes to PREFIX/<actuator>/PREDICTION and PREFIX/ALERT
// (bus/channels.h; PREFIX is flexidd's channel_prefix, default FLEXID),
// validates every message (lcmtypes/wire_check.h) before decoding it, and feeds the live
// store (live_store.h). Bad messages are counted there and ignored.
//
// It also asks flexidd over RPC (PREFIX/RPC/REQUEST -> PREFIX/RPC/REPLY/<client_id>), without
// ever waiting for a reply, so bus::RpcClient's blocking Call does not fit: requests are
// built with bus::MakeRequest and replies checked with bus::DecodeReply, and the table of
// requests in flight is this adapter's: "alerts" once at start-up (repeated until a daemon
// answers), and "model" {"actuator", "version"} whenever a prediction shows a model version the
// store has no summary of yet. Replies are handled as they arrive in the same loop;
// requests without a reply expire and are sent again after a pause.
//
// One thread runs Poll() (or Run()); LCM's handlers run inside it, so nothing here needs a
// lock. The store is the only state shared with the HTTP server.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <string>

#include "bus/channels.h"
#include "clients/dashboard/live_store.h"

namespace flexid::dashboard {

struct BusOptions {
  std::string channel_prefix = bus::kDefaultPrefix;  // flexidd's (bus::IsValidPrefix)
  std::string client_id;  // names the reply channel; empty: "dashboard-<pid>-<random>"
  std::chrono::milliseconds batch_interval{150};  // how often points go to the pages
  std::chrono::milliseconds rpc_timeout{3000};    // a request without a reply expires
  std::chrono::milliseconds rpc_retry{5000};      // pause before asking again
  int startup_alerts = 50;                        // recent alerts asked for at start-up
};

class BusAdapter {
 public:
  // Subscribes on `lcm`; `lcm` and `store` must outlive the adapter. Throws
  // std::invalid_argument for a channel prefix that breaks bus::IsValidPrefix.
  BusAdapter(lcm::LCM& lcm, LiveStore& store, BusOptions options = {});
  ~BusAdapter();
  BusAdapter(const BusAdapter&) = delete;
  BusAdapter& operator=(const BusAdapter&) = delete;

  // One turn of the loop: handles messages for up to `timeout`, then sends a batch of
  // points and RPC requests when due and expires unanswered ones.
  void Poll(std::chrono::milliseconds timeout);
  // Poll() until `stop` is set.
  void Run(const std::atomic<bool>& stop);

  const std::string& client_id() const { return options_.client_id; }
  int64_t rpc_requests_sent() const { return rpc_requests_sent_.load(); }

 private:
  using Clock = std::chrono::steady_clock;
  struct PendingCall {
    std::string method;
    std::string actuator_id;
    int32_t version = 0;
    Clock::time_point deadline;
  };
  struct ModelFetch {
    int32_t fetched = 0;    // version whose summary the store has
    int32_t requested = 0;  // version last asked for
    bool in_flight = false;
    Clock::time_point retry_after;
  };

  static void OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                           BusAdapter* self);
  static void OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string& channel, BusAdapter* self);
  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string& channel, BusAdapter* self);
  void HandlePrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleAlert(const lcm::ReceiveBuffer* rbuf);
  void HandleReply(const lcm::ReceiveBuffer* rbuf);
  void MaybeFetchModel(const std::string& actuator_id, int32_t version);
  void SendRequest(const std::string& method, const nlohmann::json& args, PendingCall call);
  void Tick(Clock::time_point now);

  lcm::LCM& lcm_;
  LiveStore& store_;
  BusOptions options_;
  bus::Channels channels_;
  std::vector<lcm::Subscription*> subscriptions_;
  std::map<std::string, PendingCall> pending_;  // by request id
  std::map<std::string, ModelFetch> models_;    // by actuator
  bool alerts_loaded_ = false;
  bool alerts_in_flight_ = false;
  Clock::time_point alerts_retry_after_;
  Clock::time_point next_batch_;
  std::atomic<int64_t> rpc_requests_sent_{0};
};

}  // namespace flexid::dashboard
