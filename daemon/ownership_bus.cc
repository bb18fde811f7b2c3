// Several flexidd on one bus (docs/architecture.md, "Several daemons"): this daemon's side
// of daemon/ownership.h. It announces its claims on PREFIX/OWNERSHIP (ownership_t), hears
// the other daemons' announcements, holds the messages and requests about an actuator
// whose owner is being decided and replays them once it is, and raises the ownership
// alerts: "ownership_conflict" (two daemons claim one actuator) and "daemon_id_conflict"
// (two daemons run under one daemon_id), each once per conflict.
#include <flexid/ownership_t.hpp>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "daemon/service.h"

namespace flexid::daemon {
namespace {

// Messages held for one actuator while its owner is decided (ownership_wait_s; 500 Hz on
// two streams for 60 s fits), and for all of them; beyond, dropped and counted.
constexpr size_t kHeldPerActuator = 1 << 16;
constexpr size_t kHeldInAll = 1 << 18;
constexpr size_t kAnnouncedAtMost = 4096;  // claims and peers in one announcement

// The announcement in a message, if it is a valid one: ids by the bus rules, claims
// known, and at most one claim per actuator. Otherwise *problem says what is wrong.
std::optional<Announcement> Checked(const flexid::ownership_t& message, std::string* problem) {
  if (!bus::IsValidPrefix(message.daemon_id)) {
    *problem = "daemon_id is not " + std::string(bus::kPrefixRule);
    return std::nullopt;
  }
  if (message.instance_id.empty() || message.instance_id.size() > 64) {
    *problem = "instance_id must be 1 to 64 characters";
    return std::nullopt;
  }
  Announcement out;
  out.utime = message.utime;
  out.daemon_id = message.daemon_id;
  out.instance_id = message.instance_id;
  std::set<std::string> seen;
  for (int i = 0; i < message.num_claims; ++i) {
    const std::string& id = message.actuator_ids[static_cast<size_t>(i)];
    const int8_t claim = message.claims[static_cast<size_t>(i)];
    if (!bus::IsValidId(id) || !seen.insert(id).second) {
      *problem = "claim " + std::to_string(i) + ": actuator id invalid or repeated";
      return std::nullopt;
    }
    if (claim != flexid::ownership_t::kConfigured && claim != flexid::ownership_t::kAdopted &&
        claim != flexid::ownership_t::kPending) {
      *problem =
          "claim " + std::to_string(i) + " of " + id + ": unknown kind " + std::to_string(claim);
      return std::nullopt;
    }
    out.claims.push_back(
        {id, static_cast<Claim>(claim), message.first_seen_utime[static_cast<size_t>(i)]});
  }
  for (int i = 0; i < message.num_peers; ++i) {
    const std::string& id = message.peer_ids[static_cast<size_t>(i)];
    if (!bus::IsValidPrefix(id)) {
      *problem = "peer " + std::to_string(i) + ": daemon id invalid";
      return std::nullopt;
    }
    out.peers.push_back({id, message.peer_heard_utime[static_cast<size_t>(i)]});
  }
  return out;
}

}  // namespace

// Announcements are bookkeeping among daemons, not input: not counted in
// messages_received (its meaning, and the counts that rely on it, stay as they were).
void Service::OnOwnershipThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                               Service* self) {
  Contained("handler", "channel", channel, [&] { self->OnOwnership(*rbuf); });
}

void Service::OnOwnership(const lcm::ReceiveBuffer& rbuf) {
  flexid::ownership_t message;
  if (!Decode(rbuf, &message, wire::kOwnership)) return;
  std::string problem;
  const std::optional<Announcement> announcement = Checked(message, &problem);
  if (!announcement) {
    spdlog::warn("ownership announcement rejected [daemon: {}] {}",
                 ArgumentSummary(message.daemon_id), problem);
    return;
  }
  ++counters.announcements_heard;
  ownership.Hear(*announcement, bus::WallClockUtime(), loop_now);
  ApplyOwnershipEvents();
}

void Service::Announce() {
  const Announcement mine = ownership.Announce(bus::WallClockUtime());
  flexid::ownership_t message;
  message.utime = mine.utime;
  message.daemon_id = mine.daemon_id;
  message.instance_id = mine.instance_id;
  for (const ActuatorClaim& claim : mine.claims) {
    if (message.actuator_ids.size() == kAnnouncedAtMost) break;
    message.actuator_ids.push_back(claim.actuator_id);
    message.claims.push_back(static_cast<int8_t>(claim.claim));
    message.first_seen_utime.push_back(claim.first_seen_utime);
  }
  message.num_claims = static_cast<int16_t>(message.actuator_ids.size());
  for (const PeerHeard& peer : mine.peers) {
    if (message.peer_ids.size() == kAnnouncedAtMost) break;
    message.peer_ids.push_back(peer.daemon_id);
    message.peer_heard_utime.push_back(peer.heard_utime);
  }
  message.num_peers = static_cast<int16_t>(message.peer_ids.size());
  lcm.publish(channels.Ownership(), &message);
  last_announced = std::chrono::steady_clock::now();
}

// Each pass of the loop: the pending actuators whose wait is over (and, `periodic`, once a
// second: the claims of silent daemons lapse), then an announcement at once when the
// claims changed or a daemon new to us was heard.
void Service::DecideOwnership(bool periodic) {
  const auto deadline = ownership.NextDeadline();
  if (periodic || (deadline && *deadline <= loop_now)) {
    ownership.Tick(loop_now);
    ApplyOwnershipEvents();
  }
  if (ownership.TakeChanged()) Announce();
}

void Service::ApplyOwnershipEvents() {
  for (const OwnershipEvent& event : ownership.TakeEvents()) OnOwnershipEvent(event);
}

void Service::OnOwnershipEvent(const OwnershipEvent& event) {
  const std::string& id = event.actuator_id;
  const int64_t utime = LatestUtime();
  switch (event.kind) {
    case OwnershipEvent::Kind::kAdopted:
    case OwnershipEvent::Kind::kRefused: {
      if (event.kind == OwnershipEvent::Kind::kAdopted) {
        if (!actuators.count(id)) {
          storage::Actuator info;
          info.id = id;
          Store(info);
          AddActuator(info);
          spdlog::info("new actuator [id: {}]", id);
        } else {
          spdlog::info("actuator adopted [id: {}]", id);
        }
        actuators.at(id).owned = true;
      } else {
        spdlog::info("actuator owned by another daemon, not recorded here [id: {}, owner: {}, {}]",
                     id, event.other, ClaimName(event.other_claim));
      }
      // What came meanwhile, in order: recorded now, or refused as another daemon's.
      const auto it = held.find(id);
      if (it == held.end()) break;
      std::vector<std::function<void()>> replay = std::move(it->second);
      held.erase(it);
      held_count -= replay.size();
      for (const auto& run : replay) run();
      break;
    }
    case OwnershipEvent::Kind::kConflict:
      RaiseHealth(id, "ownership_conflict", 1, utime, utime,
                  fmt::format("{} is claimed by flexidd {} too ({} there, {} here){}", id,
                              event.other, ClaimName(event.other_claim), ClaimName(event.our_claim),
                              event.our_claim == Claim::kConfigured &&
                                      event.other_claim == Claim::kConfigured
                                  ? ": both record it; configure it on one daemon only"
                                  : ""));
      break;
    case OwnershipEvent::Kind::kReleased: {
      ActuatorState* state = actuators.count(id) ? &actuators.at(id) : nullptr;
      if (state) {
        state->owned = false;
        if (state->trial_id != 0)
          StopTrial(state, state->last_sample_utime != kNoTime ? state->last_sample_utime : utime,
                    storage::TrialState::kInterrupted);
      }
      RaiseHealth(id, "ownership_conflict", 1, utime, utime,
                  fmt::format("{}: released to flexidd {} ({} there, adopted here); {} no "
                              "longer records it",
                              id, event.other, ClaimName(event.other_claim), config.daemon_id));
      break;
    }
    case OwnershipEvent::Kind::kDuplicateId:
      RaiseHealth("", "daemon_id_conflict", 2, utime, utime,
                  fmt::format("another flexidd runs with daemon_id {} (instance {}): give each "
                              "daemon its own daemon_id",
                              config.daemon_id, ArgumentSummary(event.other)));
      break;
  }
}

Ownership::Verdict Service::RouteTo(const std::string& actuator_id) {
  const Ownership::Verdict verdict = ownership.Sight(actuator_id, bus::WallClockUtime(), loop_now);
  if (verdict == Ownership::Verdict::kOwn) ApplyOwnershipEvents();  // adopted at once
  return verdict;
}

ActuatorState* Service::OwnedActuator(const std::string& actuator_id, bool* hold) {
  *hold = false;
  const auto it = actuators.find(actuator_id);
  if (it != actuators.end() && it->second.owned) return &it->second;
  if (!bus::IsValidId(actuator_id)) {
    ++counters.rejected_unknown_actuator;
    return nullptr;
  }
  switch (RouteTo(actuator_id)) {
    case Ownership::Verdict::kOwn: {
      const auto adopted = actuators.find(actuator_id);
      return adopted != actuators.end() && adopted->second.owned ? &adopted->second : nullptr;
    }
    case Ownership::Verdict::kHold:
      *hold = true;
      return nullptr;
    case Ownership::Verdict::kElsewhere:
      ++counters.samples_not_owned;
      return nullptr;
    case Ownership::Verdict::kUnknown:
      break;
  }
  ++counters.rejected_unknown_actuator;
  return nullptr;
}

void Service::Hold(const std::string& actuator_id, std::function<void()> replay) {
  std::vector<std::function<void()>>& queue = held[actuator_id];
  if (queue.size() >= kHeldPerActuator || held_count >= kHeldInAll) {
    ++counters.dropped_queue_full;
    return;
  }
  queue.push_back(std::move(replay));
  ++held_count;
}

std::string Service::NotOwnerText(const std::string& actuator_id) const {
  const std::string owner = ownership.OwnerElsewhere(actuator_id);
  const std::string head = config.daemon_id + " does not own actuator \"" + actuator_id + "\"";
  if (!owner.empty())
    return head + ": flexidd " + owner + " does; send the request there (flexid --daemon " + owner +
           ")";
  if (ownership.ClaimOn(actuator_id) == Claim::kPending)
    return head + " yet: its owner is being decided; try again in a second";
  return head + ", and no daemon on the bus claims it";
}

}  // namespace flexid::daemon
