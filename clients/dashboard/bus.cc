// The dashboard's bus adapter (bus.h): validated predictions and alerts into the store,
// and non-blocking RPC to flexidd for model summaries and recent alerts.
#include "clients/dashboard/bus.h"

#include <unistd.h>

#include <algorithm>
#include <flexid/alert_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>

#include "bus/rpc_client.h"
#include "lcmtypes/wire_check.h"

namespace flexid::dashboard {

BusAdapter::BusAdapter(lcm::LCM& lcm, LiveStore& store, BusOptions options)
    : lcm_(lcm), store_(store), options_(std::move(options)), channels_(options_.channel_prefix) {
  if (options_.client_id.empty())
    options_.client_id =
        "dashboard-" + std::to_string(getpid()) + "-" + bus::RandomRequestId().substr(0, 8);
  // Queues as deep as `flexid watch` uses: a burst of 16 x 500 Hz predictions must not
  // be dropped by LCM before the loop gets to it.
  subscriptions_.push_back(
      lcm_.subscribeFunction(channels_.AllPredictions(), &BusAdapter::OnPrediction, this));
  subscriptions_.back()->setQueueCapacity(1 << 16);
  subscriptions_.push_back(
      lcm_.subscribeFunction(bus::Exactly(channels_.Alert()), &BusAdapter::OnAlert, this));
  subscriptions_.back()->setQueueCapacity(1000);
  subscriptions_.push_back(lcm_.subscribeFunction(
      bus::Exactly(channels_.RpcReply(options_.client_id)), &BusAdapter::OnReply, this));
  subscriptions_.back()->setQueueCapacity(100);
  next_batch_ = Clock::now() + options_.batch_interval;
}

BusAdapter::~BusAdapter() {
  for (lcm::Subscription* s : subscriptions_) lcm_.unsubscribe(s);
}

// Nothing may throw through LCM's C callback: each handler catches at the edge and counts.
void BusAdapter::OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                              BusAdapter* self) {
  try {
    self->HandlePrediction(rbuf, channel);
  } catch (...) {
    self->store_.CountBadMessage();
  }
}

void BusAdapter::OnAlert(const lcm::ReceiveBuffer* rbuf, const std::string&, BusAdapter* self) {
  try {
    self->HandleAlert(rbuf);
  } catch (...) {
    self->store_.CountBadMessage();
  }
}

void BusAdapter::OnReply(const lcm::ReceiveBuffer* rbuf, const std::string&, BusAdapter* self) {
  try {
    self->HandleReply(rbuf);
  } catch (...) {
    self->store_.CountBadMessage();
  }
}

void BusAdapter::HandlePrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  flexid::prediction_t message;
  if (!wire::WellFormed(rbuf->data, rbuf->data_size, wire::kPrediction) ||
      message.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0 ||
      channel != channels_.Prediction(message.actuator_id)) {
    store_.CountBadMessage();
    return;
  }
  Prediction p;
  p.actuator_id = message.actuator_id;
  p.point = {message.utime, message.voltage_V, message.measured_mm, message.predicted_mm,
             message.residual_mm};
  p.model_version = message.model_version;
  p.trial_id = message.trial_id;
  p.memberships = message.memberships;
  if (store_.AddPrediction(p) == AddOutcome::kAccepted && p.model_version > 0)
    MaybeFetchModel(p.actuator_id, p.model_version);
}

void BusAdapter::HandleAlert(const lcm::ReceiveBuffer* rbuf) {
  flexid::alert_t message;
  if (!wire::WellFormed(rbuf->data, rbuf->data_size, wire::kAlert) ||
      message.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) {
    store_.CountBadMessage();
    return;
  }
  Alert a;
  a.utime = message.utime;
  a.actuator_id = message.actuator_id;
  a.kind = message.kind;
  a.severity = message.severity;
  a.start_utime = message.start_utime;
  a.end_utime = message.end_utime;
  a.magnitude_mm = message.magnitude_mm;
  a.threshold_mm = message.threshold_mm;
  a.text = message.text;
  store_.AddAlert(a);
}

void BusAdapter::HandleReply(const lcm::ReceiveBuffer* rbuf) {
  const std::optional<flexid::rpc_reply_t> decoded = bus::DecodeReply(*rbuf);
  if (!decoded) {
    store_.CountBadMessage();
    return;
  }
  const flexid::rpc_reply_t& reply = *decoded;
  const auto it = pending_.find(reply.request_id);
  if (it == pending_.end()) return;  // expired, or another dashboard's
  const PendingCall call = it->second;
  pending_.erase(it);
  const bool ok = reply.status == flexid::rpc_reply_t::kOk;
  const nlohmann::json result =
      ok ? nlohmann::json::parse(reply.result_json, nullptr, false) : nlohmann::json();
  const auto retry_after = Clock::now() + options_.rpc_retry;
  if (call.method == "alerts") {
    alerts_in_flight_ = false;
    if (!ok || !result.is_array()) {
      alerts_retry_after_ = retry_after;
      return;
    }
    alerts_loaded_ = true;
    for (const nlohmann::json& item : result)
      if (const std::optional<Alert> a = AlertFromJson(item)) store_.AddAlert(*a);
    return;
  }
  if (call.method == "model") {
    ModelFetch& fetch = models_[call.actuator_id];
    fetch.in_flight = false;
    const std::optional<nlohmann::json> summary = ok ? SummarizeModel(result) : std::nullopt;
    if (!summary) {
      fetch.retry_after = retry_after;
      return;
    }
    store_.SetModel(*summary);
    fetch.fetched = call.version;
  }
}

void BusAdapter::MaybeFetchModel(const std::string& actuator_id, int32_t version) {
  ModelFetch& fetch = models_[actuator_id];
  if (version == fetch.fetched || fetch.in_flight) return;
  if (version == fetch.requested && Clock::now() < fetch.retry_after) return;
  fetch.requested = version;
  fetch.in_flight = true;
  SendRequest("model", {{"actuator", actuator_id}, {"version", version}},
              {"model", actuator_id, version, {}});
}

void BusAdapter::SendRequest(const std::string& method, const nlohmann::json& args,
                             PendingCall call) {
  // Read-only methods only: the dashboard holds no key.
  const flexid::rpc_request_t request =
      bus::MakeRequest(options_.client_id, bus::RandomRequestId(), method, args.dump(), nullptr);
  call.deadline = Clock::now() + options_.rpc_timeout;
  pending_[request.request_id] = std::move(call);
  lcm_.publish(channels_.RpcRequest(), &request);
  ++rpc_requests_sent_;
}

void BusAdapter::Tick(Clock::time_point now) {
  if (now >= next_batch_) {
    store_.FlushBatch();
    next_batch_ = now + options_.batch_interval;
  }
  for (auto it = pending_.begin(); it != pending_.end();) {
    if (it->second.deadline > now) {
      ++it;
      continue;
    }
    if (it->second.method == "alerts") {
      alerts_in_flight_ = false;
      alerts_retry_after_ = now + options_.rpc_retry;
    } else {
      ModelFetch& fetch = models_[it->second.actuator_id];
      fetch.in_flight = false;
      fetch.retry_after = now + options_.rpc_retry;
    }
    it = pending_.erase(it);
  }
  if (!alerts_loaded_ && !alerts_in_flight_ && now >= alerts_retry_after_ &&
      options_.startup_alerts > 0) {
    alerts_in_flight_ = true;
    SendRequest("alerts", {{"limit", options_.startup_alerts}}, {"alerts", "", 0, {}});
  }
}

void BusAdapter::Poll(std::chrono::milliseconds timeout) {
  const auto now = Clock::now();
  const auto until_batch =
      std::chrono::duration_cast<std::chrono::milliseconds>(next_batch_ - now).count();
  const auto wait_ms =
      std::clamp<int64_t>(std::min<int64_t>(until_batch, timeout.count()), 0, 1000);
  lcm_.handleTimeout(static_cast<int>(wait_ms));
  Tick(Clock::now());
}

void BusAdapter::Run(const std::atomic<bool>& stop) {
  while (!stop.load()) Poll(std::chrono::milliseconds(50));
}

}  // namespace flexid::dashboard
