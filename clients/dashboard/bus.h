// The dashboard on the bus: subscribes to PREFIX/<actuator>/VOLTAGE, .../DEFLECTION (the
// source's samples, so an actuator without a model has charts too), .../PREDICTION,
// .../COMMAND (a controller's commands, for the reference they carry) and
// PREFIX/ALERT (bus/channels.h; PREFIX is flexidd's channel_prefix, default FLEXID),
// validates every message (lcmtypes/wire_check.h, then the channel against the message's
// actuator) before the live store (live_store.h) takes it; the store decides which stream
// draws an actuator's points. Bad messages are counted there and ignored.
//
// It also asks flexidd over RPC (PREFIX/RPC/REQUEST -> PREFIX/RPC/REPLY/<client_id>), without
// ever waiting for a reply, so bus::RpcClient's blocking Call does not fit: requests are
// built with bus::MakeRequest and replies checked with bus::DecodeReply, and the table of
// requests in flight is this adapter's:
//   - "alerts" once at start-up (repeated until a daemon answers);
//   - "model" {"actuator", "version"} whenever a prediction shows a model version the store
//     has no summary of yet;
//   - "models" {"actuator"} (the version list, model_versions.h) when an actuator is first
//     seen, when a new alert of a "model_..." kind names it (flexidd's "model_changed" when
//     the active version changes, "model_proposed" when a diagnosis stores a proposal), and
//     when a page loads (at most once per models_refresh_min and actuator).
// Replies are handled as they arrive in the same loop; requests without a reply expire and
// are sent again after a pause; a reply that fails or does not parse is counted with its
// reason (LiveStore::NoteBadReply) and asked again later.
//
// Several flexidd on one bus (docs/architecture.md, "Several daemons"): the adapter hears
// their announcements (PREFIX/OWNERSHIP) and addresses "models" and "model" to the
// actuator's owner ("daemon_id" in the arguments; the others ignore it). Unaddressed, every
// daemon answers: the first that holds the actuator counts, and "not found" from the
// others only counts when nobody holds it. "alerts" takes every daemon's reply (each
// once) until the request expires. The page names each actuator's daemon.
//
// One thread runs Poll() (or Run()); LCM's handlers run inside it, so nothing here needs a
// lock. The store is the only state shared with the HTTP server.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <flexid/rpc_reply_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "clients/dashboard/live_store.h"

namespace flexid::dashboard {

struct BusOptions {
  std::string channel_prefix = bus::kDefaultPrefix;  // flexidd's (bus::IsValidPrefix)
  std::string client_id;  // names the reply channel; empty: "dashboard-<pid>-<random>"
  std::chrono::milliseconds batch_interval{150};       // how often points go to the pages
  std::chrono::milliseconds rpc_timeout{3000};         // a request without a reply expires
  std::chrono::milliseconds rpc_retry{5000};           // pause before asking again
  std::chrono::milliseconds models_refresh_min{1000};  // between page-load refreshes
  std::chrono::milliseconds models_retry_max{60000};   // failures double the pause up to this
  int startup_alerts = 50;                             // recent alerts asked for at start-up
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
    std::string not_found;           // a daemon's "not found", kept until one holds it
    std::set<std::string> answered;  // "alerts": the daemons whose alerts came
  };
  struct ModelFetch {
    int32_t fetched = 0;    // version whose summary the store has
    int32_t requested = 0;  // version last asked for
    bool in_flight = false;
    Clock::time_point retry_after;
  };
  // The "models" list of one actuator.
  struct VersionsFetch {
    bool wanted = true;  // ask when not_before has passed and nothing is in flight
    bool in_flight = false;
    int failures = 0;  // in a row
    Clock::time_point not_before;
  };

  // Subscribes `pattern` to kHandle, guarded (bus.cc), with that LCM queue depth.
  template <void (BusAdapter::*kHandle)(const lcm::ReceiveBuffer*, const std::string&)>
  void Subscribe(const std::string& pattern, int queue_capacity);
  void HandleVoltage(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleDeflection(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandlePrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleAlert(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleReply(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleOwnership(const lcm::ReceiveBuffer* rbuf, const std::string& channel);
  void HandleAlerts(PendingCall* call, const flexid::rpc_reply_t& reply);
  void HandleModel(const PendingCall& call, const flexid::rpc_reply_t& reply);
  void Expire(const PendingCall& call, Clock::time_point now);
  void HandleVersions(const PendingCall& call, const flexid::rpc_reply_t& reply);
  void VersionsFailed(const std::string& actuator_id, Clock::time_point now);
  void MaybeFetchModel(const std::string& actuator_id, int32_t version);
  void RequestVersions(Clock::time_point now);
  void SendRequest(const std::string& method, const nlohmann::json& args, PendingCall call);
  void Tick(Clock::time_point now);

  lcm::LCM& lcm_;
  LiveStore& store_;
  BusOptions options_;
  bus::Channels channels_;
  std::vector<lcm::Subscription*> subscriptions_;
  std::map<std::string, PendingCall> pending_;     // by request id
  std::map<std::string, ModelFetch> models_;       // by actuator
  std::map<std::string, VersionsFetch> versions_;  // by actuator
  std::map<std::string, std::string> owners_;      // actuator -> daemon that records it
  uint64_t page_loads_seen_ = 0;
  bool alerts_loaded_ = false;
  bool alerts_in_flight_ = false;
  Clock::time_point alerts_retry_after_;
  Clock::time_point next_batch_;
  std::atomic<int64_t> rpc_requests_sent_{0};
};

}  // namespace flexid::dashboard
