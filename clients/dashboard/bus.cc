// The dashboard's bus adapter (bus.h): validated samples, predictions and alerts into the
// store, and non-blocking RPC to flexidd for model summaries, model versions and recent
// alerts.
#include "clients/dashboard/bus.h"

#include <unistd.h>

#include <algorithm>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/voltage_command_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <limits>

#include "bus/fan_out.h"
#include "bus/ids.h"
#include "bus/rpc_client.h"
#include "clients/dashboard/model_versions.h"
#include "lcmtypes/command_check.h"
#include "lcmtypes/wire_check.h"

namespace flexid::dashboard {
namespace {

// A message from the bus, walked by wire::WellFormed before lcm-gen's decoder sees it.
template <typename Message>
bool Decode(const lcm::ReceiveBuffer* rbuf, std::initializer_list<wire::Field> layout,
            Message* message) {
  return wire::WellFormed(rbuf->data, rbuf->data_size, layout) &&
         message->decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0;
}

}  // namespace

// Nothing may throw through LCM's C callback: the handler runs inside a catch-all that
// counts what escaped as a bad message.
template <void (BusAdapter::*kHandle)(const lcm::ReceiveBuffer*, const std::string&)>
void BusAdapter::Subscribe(const std::string& pattern, int queue_capacity) {
  void (*guarded)(const lcm::ReceiveBuffer*, const std::string&, BusAdapter*) =
      [](const lcm::ReceiveBuffer* rbuf, const std::string& channel, BusAdapter* self) {
        try {
          (self->*kHandle)(rbuf, channel);
        } catch (...) {
          self->store_.CountBadMessage();
        }
      };
  subscriptions_.push_back(lcm_.subscribeFunction(pattern, guarded, this));
  subscriptions_.back()->setQueueCapacity(queue_capacity);
}

BusAdapter::BusAdapter(lcm::LCM& lcm, LiveStore& store, BusOptions options)
    : lcm_(lcm), store_(store), options_(std::move(options)), channels_(options_.channel_prefix) {
  if (options_.client_id.empty())
    options_.client_id =
        "dashboard-" + std::to_string(getpid()) + "-" + bus::RandomRequestId().substr(0, 8);
  // Queues as deep as `flexid watch` uses: a burst of 16 x 500 Hz samples and predictions
  // must not be dropped by LCM before the loop gets to it.
  Subscribe<&BusAdapter::HandleVoltage>(channels_.AllVoltages(), 1 << 16);
  Subscribe<&BusAdapter::HandleDeflection>(channels_.AllDeflections(), 1 << 16);
  Subscribe<&BusAdapter::HandlePrediction>(channels_.AllPredictions(), 1 << 16);
  // Every actuator's commands, as AllPredictions() is built (bus/channels.cc).
  Subscribe<&BusAdapter::HandleCommand>(bus::Exactly(channels_.prefix()) + "/.*/COMMAND", 1 << 16);
  Subscribe<&BusAdapter::HandleAlert>(bus::Exactly(channels_.Alert()), 1000);
  Subscribe<&BusAdapter::HandleReply>(bus::Exactly(channels_.RpcReply(options_.client_id)), 100);
  Subscribe<&BusAdapter::HandleOwnership>(bus::Exactly(channels_.Ownership()), 1000);
  next_batch_ = Clock::now() + options_.batch_interval;
}

BusAdapter::~BusAdapter() {
  for (lcm::Subscription* s : subscriptions_) lcm_.unsubscribe(s);
}

void BusAdapter::HandleVoltage(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  flexid::voltage_sample_t message;
  if (!Decode(rbuf, wire::kVoltageSample, &message) ||
      channel != channels_.Voltage(message.actuator_id)) {
    store_.CountBadMessage();
    return;
  }
  store_.AddVoltage({message.actuator_id, message.utime, message.voltage_V});
}

void BusAdapter::HandleDeflection(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  flexid::deflection_sample_t message;
  if (!Decode(rbuf, wire::kDeflectionSample, &message) ||
      channel != channels_.Deflection(message.actuator_id)) {
    store_.CountBadMessage();
    return;
  }
  store_.AddDeflection({message.actuator_id, message.utime, message.deflection_mm});
}

void BusAdapter::HandlePrediction(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  flexid::prediction_t message;
  if (!Decode(rbuf, wire::kPrediction, &message) ||
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
  const AddOutcome outcome = store_.AddPrediction(p);
  if ((outcome == AddOutcome::kAccepted || outcome == AddOutcome::kCovered) && p.model_version > 0)
    MaybeFetchModel(p.actuator_id, p.model_version);
}

// A controller's command: the reference it follows (live_store.h). The dashboard holds no
// key, so the signature is not checked; the values are, and a bad one is named in the
// last problem.
void BusAdapter::HandleCommand(const lcm::ReceiveBuffer* rbuf, const std::string& channel) {
  flexid::voltage_command_t message;
  if (!Decode(rbuf, wire::kVoltageCommand, &message)) {
    store_.NoteBadMessage("a command on " + channel + " is not a voltage_command_t (version 2)");
    return;
  }
  if (channel != channels_.Command(message.actuator_id)) {
    store_.NoteBadMessage("a command on " + channel + " is for actuator \"" +
                          message.actuator_id.substr(0, 64) + "\"");
    return;
  }
  if (const std::string problem = wire::VoltageCommandProblem(message); !problem.empty()) {
    store_.NoteBadMessage("a command on " + channel + ": " + problem);
    return;
  }
  if (message.mode == flexid::voltage_command_t::kStop)
    store_.AddReference(
        {message.actuator_id, message.utime, std::numeric_limits<double>::quiet_NaN()});
  else
    store_.AddReference({message.actuator_id, message.reference_utime, message.reference_mm});
}

void BusAdapter::HandleAlert(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  flexid::alert_t message;
  if (!Decode(rbuf, wire::kAlert, &message)) {
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
  // A new alert about models (the active version changed, a version was proposed): the
  // version list changed; ask now rather than after the usual pause.
  if (store_.AddAlert(a) && a.kind.starts_with("model_") && bus::IsValidId(a.actuator_id)) {
    VersionsFetch& fetch = versions_[a.actuator_id];
    fetch.wanted = true;
    if (fetch.failures == 0) fetch.not_before = Clock::now();
  }
}

void BusAdapter::HandleReply(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  const std::optional<flexid::rpc_reply_t> decoded = bus::DecodeReply(*rbuf);
  if (!decoded) {
    store_.CountBadMessage();
    return;
  }
  const flexid::rpc_reply_t& reply = *decoded;
  const auto it = pending_.find(reply.request_id);
  if (it == pending_.end()) return;  // expired, answered, or another dashboard's
  if (it->second.method == "alerts") {
    HandleAlerts(&it->second, reply);
    return;
  }
  // A daemon that does not hold the actuator: another may (several daemons, unaddressed).
  if (reply.status == flexid::rpc_reply_t::kNotFound) {
    it->second.not_found = reply.daemon_id + ": " + reply.error;
    return;
  }
  const PendingCall call = it->second;
  pending_.erase(it);
  if (call.method == "models")
    HandleVersions(call, reply);
  else if (call.method == "model")
    HandleModel(call, reply);
}

// Every daemon's recent alerts, each daemon's reply once, until the request expires.
void BusAdapter::HandleAlerts(PendingCall* call, const flexid::rpc_reply_t& reply) {
  if (!call->answered.insert(reply.daemon_id).second) return;  // a duplicate
  const bool ok = reply.status == flexid::rpc_reply_t::kOk;
  const nlohmann::json result =
      ok ? nlohmann::json::parse(reply.result_json, nullptr, false) : nlohmann::json();
  if (!ok || !result.is_array()) {
    store_.NoteBadReply("alerts: " +
                        (ok ? std::string("expected an array of alerts")
                            : "flexidd " + reply.daemon_id + " answered: " + reply.error));
    return;
  }
  alerts_loaded_ = true;
  for (const nlohmann::json& item : result)
    if (const std::optional<Alert> a = AlertFromJson(item)) store_.AddAlert(*a);
}

void BusAdapter::HandleModel(const PendingCall& call, const flexid::rpc_reply_t& reply) {
  const bool ok = reply.status == flexid::rpc_reply_t::kOk;
  const nlohmann::json result =
      ok ? nlohmann::json::parse(reply.result_json, nullptr, false) : nlohmann::json();
  ModelFetch& fetch = models_[call.actuator_id];
  fetch.in_flight = false;
  const std::optional<nlohmann::json> summary = ok ? SummarizeModel(result) : std::nullopt;
  if (!summary) {
    store_.NoteBadReply("model " + std::to_string(call.version) + " of " + call.actuator_id + ": " +
                        (ok ? std::string("expected an object with actuator and version")
                            : "flexidd answered: " + reply.error));
    fetch.retry_after = Clock::now() + options_.rpc_retry;
    return;
  }
  store_.SetModel(*summary);
  fetch.fetched = call.version;
}

// Announcements (ownership_t): which daemon records which actuator, to address requests
// to it and to name it on the page.
void BusAdapter::HandleOwnership(const lcm::ReceiveBuffer* rbuf, const std::string&) {
  const std::optional<flexid::ownership_t> message = bus::DecodeOwnership(*rbuf);
  if (!message) {
    store_.CountBadMessage();
    return;
  }
  for (size_t i = 0; i < message->actuator_ids.size() && i < message->claims.size(); ++i) {
    const std::string& id = message->actuator_ids[i];
    const int8_t claim = message->claims[i];
    if (!bus::IsValidId(id) ||
        (claim != flexid::ownership_t::kConfigured && claim != flexid::ownership_t::kAdopted))
      continue;
    owners_[id] = message->daemon_id;
    store_.SetDaemon(id, message->daemon_id);
  }
}

void BusAdapter::HandleVersions(const PendingCall& call, const flexid::rpc_reply_t& reply) {
  const auto now = Clock::now();
  VersionsFetch& fetch = versions_[call.actuator_id];
  fetch.in_flight = false;
  std::string problem;
  if (reply.status != flexid::rpc_reply_t::kOk) {
    problem = "flexidd answered: " + reply.error;
  } else {
    const nlohmann::json result = nlohmann::json::parse(reply.result_json, nullptr, false);
    if (result.is_discarded()) {
      problem = "the result is not JSON";
    } else if (const std::optional<nlohmann::json> versions =
                   ModelVersionsFromJson(result, call.actuator_id, &problem)) {
      store_.SetModelVersions(call.actuator_id, *versions);
      store_.SetDaemon(call.actuator_id, reply.daemon_id);
      fetch.failures = 0;
      fetch.not_before = now + options_.models_refresh_min;
      return;
    }
  }
  store_.NoteBadReply("models of " + call.actuator_id + ": " + problem);
  store_.SetModelVersionsProblem(call.actuator_id, problem);
  VersionsFailed(call.actuator_id, now);
}

// Asks again after rpc_retry, doubled with every failure in a row up to models_retry_max
// (an actuator flexidd does not know stays unknown for a while).
void BusAdapter::VersionsFailed(const std::string& actuator_id, Clock::time_point now) {
  VersionsFetch& fetch = versions_[actuator_id];
  fetch.in_flight = false;
  fetch.wanted = true;
  fetch.failures = std::min(fetch.failures + 1, 16);
  const auto pause = std::min<Clock::duration>(options_.rpc_retry * (1 << (fetch.failures - 1)),
                                               options_.models_retry_max);
  fetch.not_before = now + pause;
}

void BusAdapter::RequestVersions(Clock::time_point now) {
  // Actuators seen for the first time are wanted (VersionsFetch starts so); a page load
  // wants every actuator again.
  const uint64_t page_loads = store_.page_loads();
  const bool page_loaded = page_loads != page_loads_seen_;
  page_loads_seen_ = page_loads;
  for (const std::string& id : store_.ActuatorIds()) {
    VersionsFetch& fetch = versions_[id];
    if (page_loaded) fetch.wanted = true;
    if (!fetch.wanted || fetch.in_flight || now < fetch.not_before) continue;
    fetch.wanted = false;
    fetch.in_flight = true;
    SendRequest("models", {{"actuator", id}}, {"models", id, 0, {}, "", {}});
  }
}

void BusAdapter::MaybeFetchModel(const std::string& actuator_id, int32_t version) {
  ModelFetch& fetch = models_[actuator_id];
  if (version == fetch.fetched || fetch.in_flight) return;
  if (version == fetch.requested && Clock::now() < fetch.retry_after) return;
  fetch.requested = version;
  fetch.in_flight = true;
  SendRequest("model", {{"actuator", actuator_id}, {"version", version}},
              {"model", actuator_id, version, {}, "", {}});
}

void BusAdapter::SendRequest(const std::string& method, const nlohmann::json& args,
                             PendingCall call) {
  // Read-only methods only: the dashboard holds no key. About an actuator whose owner was
  // heard: to that daemon alone.
  nlohmann::json addressed = args;
  const auto owner = owners_.find(call.actuator_id);
  if (!call.actuator_id.empty() && owner != owners_.end()) addressed["daemon_id"] = owner->second;
  const flexid::rpc_request_t request = bus::MakeRequest(options_.client_id, bus::RandomRequestId(),
                                                         method, addressed.dump(), nullptr);
  call.deadline = Clock::now() + options_.rpc_timeout;
  pending_[request.request_id] = std::move(call);
  lcm_.publish(channels_.RpcRequest(), &request);
  ++rpc_requests_sent_;
}

// A request's time is up: "alerts" is done (asked again if no daemon answered); the
// others failed, with a daemon's "not found" if one said so.
void BusAdapter::Expire(const PendingCall& call, Clock::time_point now) {
  if (call.method == "alerts") {
    alerts_in_flight_ = false;
    if (!alerts_loaded_) alerts_retry_after_ = now + options_.rpc_retry;
    return;
  }
  if (!call.not_found.empty()) {
    flexid::rpc_reply_t reply;
    reply.status = flexid::rpc_reply_t::kNotFound;
    reply.daemon_id = call.not_found.substr(0, call.not_found.find(':'));
    reply.error = call.not_found.substr(call.not_found.find(':') + 2);
    if (call.method == "models")
      HandleVersions(call, reply);
    else
      HandleModel(call, reply);
    return;
  }
  if (call.method == "models") {
    VersionsFailed(call.actuator_id, now);
  } else {
    ModelFetch& fetch = models_[call.actuator_id];
    fetch.in_flight = false;
    fetch.retry_after = now + options_.rpc_retry;
  }
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
    const PendingCall call = it->second;
    it = pending_.erase(it);
    Expire(call, now);
  }
  if (!alerts_loaded_ && !alerts_in_flight_ && now >= alerts_retry_after_ &&
      options_.startup_alerts > 0) {
    alerts_in_flight_ = true;
    SendRequest("alerts", {{"limit", options_.startup_alerts}}, {"alerts", "", 0, {}, "", {}});
  }
  RequestVersions(now);
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
