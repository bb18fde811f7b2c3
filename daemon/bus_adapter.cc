// The bus adapter (DESIGN.md): flexidd's subscriptions, the decoding and validation of
// every message (oversized, ill-formed, misaddressed, non-finite, out of order: rejected
// and counted), and the replies it publishes. What a valid sample then does is the
// recorder's and the predictor's.
#include <cmath>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "daemon/service.h"

namespace flexid::daemon {
namespace {

constexpr int kQueueCapacity = 1 << 17;  // messages per sample subscription

}  // namespace

// LCM keeps at most 30 undispatched messages per subscription by default and drops the
// rest silently; 16 actuators at 500 Hz need far more between two loop passes.
void Service::Subscribe() {
  lcm.subscribeFunction(channels.AllVoltages(), &Service::OnVoltageThunk, this)
      ->setQueueCapacity(kQueueCapacity);
  lcm.subscribeFunction(channels.AllDeflections(), &Service::OnDeflectionThunk, this)
      ->setQueueCapacity(kQueueCapacity);
  lcm.subscribeFunction(bus::Exactly(channels.RpcRequest()), &Service::OnRequestThunk, this)
      ->setQueueCapacity(1000);
  lcm.subscribeFunction(bus::Exactly(channels.TrialControl()), &Service::OnTrialControlThunk, this)
      ->setQueueCapacity(1000);
  lcm.subscribeFunction(bus::Exactly(channels.Ownership()), &Service::OnOwnershipThunk, this)
      ->setQueueCapacity(1000);
}

void Service::OnVoltageThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Service* self) {
  self->Guarded(channel, [&] { self->OnVoltage(*rbuf, channel); });
}

void Service::OnDeflectionThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                Service* self) {
  self->Guarded(channel, [&] { self->OnDeflection(*rbuf, channel); });
}

void Service::OnRequestThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Service* self) {
  self->Guarded(channel, [&] { self->OnRequest(*rbuf); });
}

void Service::OnTrialControlThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                  Service* self) {
  self->Guarded(channel, [&] { self->OnTrialControl(*rbuf); });
}

// True when a sample channel (PREFIX/<id>/KIND) names the message's actuator; counted
// as malformed (misaddressed) otherwise.
bool Service::ChannelNames(const std::string& channel, const std::string& message_id) {
  const size_t first = config.channel_prefix.size() + 1;
  const size_t second = channel.find('/', first);
  if (second == std::string::npos || channel.find('/', second + 1) != std::string::npos ||
      channel.compare(first, second - first, message_id) != 0) {
    ++counters.rejected_malformed;
    return false;
  }
  return true;
}

void Service::OnVoltage(const lcm::ReceiveBuffer& rbuf, const std::string& channel) {
  flexid::voltage_sample_t message;
  if (!Decode(rbuf, &message, wire::kVoltageSample)) return;
  if (ChannelNames(channel, message.actuator_id)) AcceptVoltage(message);
}

// A well-formed sample of its channel's actuator: recorded when this daemon owns the
// actuator, held while its owner is being decided (ownership_bus.cc), counted otherwise.
void Service::AcceptVoltage(const flexid::voltage_sample_t& message) {
  bool hold = false;
  ActuatorState* state = OwnedActuator(message.actuator_id, &hold);
  if (hold) Hold(message.actuator_id, [this, message] { AcceptVoltage(message); });
  if (!state) return;
  if (!std::isfinite(message.voltage_V)) {
    ++counters.rejected_nonfinite;
    return;
  }
  if (!InTimeOrder(state, message.utime, /*voltage=*/true)) return;
  ++counters.samples_accepted;
  state->voltage_utime = message.utime;
  state->voltage_V = message.voltage_V;
  FollowVoltage(state, message.utime, message.voltage_V);
  PredictVoltage(state, message.utime, message.voltage_V);
}

void Service::OnDeflection(const lcm::ReceiveBuffer& rbuf, const std::string& channel) {
  flexid::deflection_sample_t message;
  if (!Decode(rbuf, &message, wire::kDeflectionSample)) return;
  if (ChannelNames(channel, message.actuator_id)) AcceptDeflection(message);
}

void Service::AcceptDeflection(const flexid::deflection_sample_t& message) {
  bool hold = false;
  ActuatorState* state = OwnedActuator(message.actuator_id, &hold);
  if (hold) Hold(message.actuator_id, [this, message] { AcceptDeflection(message); });
  if (!state) return;
  if (!std::isfinite(message.deflection_mm)) {
    ++counters.rejected_nonfinite;
    return;
  }
  if (!InTimeOrder(state, message.utime, /*voltage=*/false)) return;
  ++counters.samples_accepted;
  state->deflection_utime = message.utime;
  RecordSample(state, message.utime, message.deflection_mm);
  PublishPrediction(state, message);
}

// Trial control changes stored data, so it is signed: trial_control2_t with a valid
// signature, within the window of its sent_utime (wall clock; utime is message time and
// may be accelerated or replayed), with a nonce not seen before. The unsigned
// trial_control_t of earlier versions is refused (and counted) like a bad signature.
void Service::OnTrialControl(const lcm::ReceiveBuffer& rbuf) {
  if (rbuf.data_size >= 8 && FingerprintOf(rbuf) == flexid::trial_control_t::getHash()) {
    flexid::trial_control_t old;
    const bool decoded = Decode(rbuf, &old, wire::kTrialControl);
    ++counters.refused_unauthorized;
    spdlog::warn(
        "trial control refused [actuator: {}, action: {}] not authorised: unsigned "
        "trial_control_t (send a signed trial_control2_t)",
        decoded ? old.actuator_id : "?", decoded ? old.action : 0);
    return;
  }
  flexid::trial_control2_t message;
  if (!Decode(rbuf, &message, wire::kTrialControl2)) return;
  // Another daemon's actuator: its owner checks the signature (with its own key) and acts.
  if (!ownership.Owns(message.actuator_id) &&
      !ownership.OwnerElsewhere(message.actuator_id).empty()) {
    ++counters.samples_not_owned;
    spdlog::debug("trial control for another daemon's actuator ignored [actuator: {}, owner: {}]",
                  ArgumentSummary(message.actuator_id),
                  ownership.OwnerElsewhere(message.actuator_id));
    return;
  }
  const std::string refusal = verifier.Check(message, bus::WallClockUtime());
  if (!refusal.empty()) {
    ++counters.refused_unauthorized;
    spdlog::warn(
        "trial control refused [actuator: {}, action: {}, protocol: {}] not "
        "authorised: {}",
        message.actuator_id, message.action, ArgumentSummary(message.protocol), refusal);
    return;
  }
  if (message.action != flexid::trial_control2_t::kStart &&
      message.action != flexid::trial_control2_t::kStop) {
    ++counters.rejected_malformed;
    spdlog::warn("trial control rejected [actuator: {}, action: {}] unknown action",
                 message.actuator_id, message.action);
    return;
  }
  spdlog::info("trial control accepted [actuator: {}, action: {}, protocol: {}]",
               message.actuator_id,
               message.action == flexid::trial_control2_t::kStart ? "start" : "stop",
               ArgumentSummary(message.protocol));
  ApplyTrialControl(message);
}

// Signed trial control that passed its checks, for an actuator this daemon owns (held
// while its owner is being decided, like a sample).
void Service::ApplyTrialControl(const flexid::trial_control2_t& message) {
  bool hold = false;
  ActuatorState* state = OwnedActuator(message.actuator_id, &hold);
  if (hold) Hold(message.actuator_id, [this, message] { ApplyTrialControl(message); });
  if (!state) return;
  if (state->trial_id != 0) StopTrial(state, message.utime, storage::TrialState::kComplete);
  if (message.action == flexid::trial_control2_t::kStart)
    StartTrial(state, message.protocol, message.utime, false);
}

// The type fingerprint an encoded LCM message starts with (8 bytes, big-endian).
int64_t Service::FingerprintOf(const lcm::ReceiveBuffer& rbuf) {
  const auto* bytes = static_cast<const uint8_t*>(rbuf.data);
  uint64_t value = 0;
  for (int i = 0; i < 8; ++i) value = (value << 8) | bytes[i];
  return static_cast<int64_t>(value);
}

void Service::Reply(const RpcContext& context, const RpcOutcome& outcome) {
  if (!bus::IsValidId(context.client_id)) return;  // nowhere to reply to
  flexid::rpc_reply_t reply;
  reply.utime = bus::WallClockUtime();
  reply.request_id = context.request_id;
  reply.daemon_id = config.daemon_id;
  reply.status = outcome.status;
  reply.result_json = outcome.result.dump();
  reply.error = outcome.error;
  lcm.publish(channels.RpcReply(context.client_id), &reply);
}

}  // namespace flexid::daemon
