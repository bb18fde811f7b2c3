#include "daemon/ownership.h"

#include <algorithm>

namespace flexid::daemon {

const char* ClaimName(Claim claim) {
  switch (claim) {
    case Claim::kConfigured:
      return "configured";
    case Claim::kAdopted:
      return "adopted";
    case Claim::kPending:
      return "pending";
    case Claim::kNone:
      break;
  }
  return "none";
}

bool Stronger(const ActuatorClaim& a, const std::string& a_id, const ActuatorClaim& b,
              const std::string& b_id) {
  const bool a_configured = a.claim == Claim::kConfigured;
  const bool b_configured = b.claim == Claim::kConfigured;
  if (a_configured != b_configured) return a_configured;
  if (!a_configured && a.first_seen_utime != b.first_seen_utime)
    return a.first_seen_utime < b.first_seen_utime;
  return a_id < b_id;
}

namespace {

bool Holds(Claim claim) { return claim == Claim::kConfigured || claim == Claim::kAdopted; }

}  // namespace

Ownership::Ownership(std::string daemon_id, std::string instance_id, OwnershipOptions options,
                     Clock::time_point started)
    : daemon_id_(std::move(daemon_id)),
      instance_id_(std::move(instance_id)),
      options_(options),
      started_(started),
      now_(started) {}

void Ownership::Configure(const std::string& actuator_id) {
  ours_[actuator_id] = {Claim::kConfigured, 0, {}};
  changed_ = true;
}

bool Ownership::Alive(const Peer& peer, Clock::time_point now) const {
  return now - peer.heard <= options_.peer_silence;
}

size_t Ownership::live_peers(Clock::time_point now) const {
  return static_cast<size_t>(std::count_if(
      peers_.begin(), peers_.end(), [&](const auto& entry) { return Alive(entry.second, now); }));
}

std::pair<std::string, ActuatorClaim> Ownership::StrongestElsewhere(const std::string& actuator_id,
                                                                    bool held_only) const {
  std::pair<std::string, ActuatorClaim> best;
  for (const auto& [id, peer] : peers_) {
    if (!Alive(peer, now_)) continue;
    for (const ActuatorClaim& claim : peer.claims) {
      if (claim.actuator_id != actuator_id || claim.claim == Claim::kNone) continue;
      if (held_only && !Holds(claim.claim)) continue;
      if (best.first.empty() || Stronger(claim, id, best.second, best.first)) best = {id, claim};
    }
  }
  return best;
}

void Ownership::Adopt(const std::string& actuator_id, int64_t wall_utime) {
  Held& held = ours_[actuator_id];
  if (held.claim != Claim::kPending) held.first_seen_utime = wall_utime;
  held.claim = Claim::kAdopted;
  changed_ = true;
  events_.push_back(
      {OwnershipEvent::Kind::kAdopted, actuator_id, "", Claim::kNone, Claim::kAdopted});
}

Ownership::Verdict Ownership::Sight(const std::string& actuator_id, int64_t wall_utime,
                                    Clock::time_point now) {
  now_ = now;
  const auto it = ours_.find(actuator_id);
  if (it != ours_.end())
    return it->second.claim == Claim::kPending ? Verdict::kHold : Verdict::kOwn;
  if (!options_.accept_unknown) return Verdict::kUnknown;
  if (owners_.count(actuator_id)) return Verdict::kElsewhere;
  // Alone on the bus once the others have had time to be heard: nobody to wait for.
  if (now - started_ >= options_.wait && live_peers(now) == 0) {
    Adopt(actuator_id, wall_utime);
    return Verdict::kOwn;
  }
  ours_[actuator_id] = {Claim::kPending, wall_utime, now + options_.wait};
  changed_ = true;
  return Verdict::kHold;
}

void Ownership::Hear(const Announcement& announcement, int64_t wall_utime, Clock::time_point now) {
  now_ = now;
  if (announcement.daemon_id == daemon_id_) {
    if (announcement.instance_id != instance_id_ &&
        duplicate_instances_.insert(announcement.instance_id).second)
      events_.push_back({OwnershipEvent::Kind::kDuplicateId, "", announcement.instance_id,
                         Claim::kNone, Claim::kNone});
    return;
  }
  auto [it, fresh] = peers_.try_emplace(announcement.daemon_id);
  // A daemon new to us, or back after silence, learns of us at once.
  if (fresh || !Alive(it->second, now)) changed_ = true;
  it->second = {announcement.instance_id, now, wall_utime, announcement.claims};
  CheckConflicts(now);
  CacheOwners();
}

void Ownership::CacheOwners() {
  owners_.clear();
  for (const auto& [id, peer] : peers_)
    if (Alive(peer, now_))
      for (const ActuatorClaim& claim : peer.claims)
        if (Holds(claim.claim) && !owners_.count(claim.actuator_id))
          owners_[claim.actuator_id] = StrongestElsewhere(claim.actuator_id, true).first;
}

void Ownership::Tick(Clock::time_point now) {
  now_ = now;
  std::vector<std::string> decided;
  for (const auto& [id, held] : ours_)
    if (held.claim == Claim::kPending && held.decide_at <= now) decided.push_back(id);
  for (const std::string& id : decided) {
    const Held mine = ours_.at(id);
    const auto [other, claim] = StrongestElsewhere(id, /*held_only=*/false);
    if (other.empty() ||
        Stronger({id, Claim::kPending, mine.first_seen_utime}, daemon_id_, claim, other)) {
      Adopt(id, mine.first_seen_utime);
    } else {
      ours_.erase(id);
      changed_ = true;
      events_.push_back({OwnershipEvent::Kind::kRefused, id, other, claim.claim, Claim::kPending});
    }
  }
  for (auto it = peers_.begin(); it != peers_.end();)
    it = now - it->second.heard > options_.peer_memory ? peers_.erase(it) : std::next(it);
  CheckConflicts(now);
  CacheOwners();
}

// Raises each (actuator, peer) conflict once, releases the adopted claims a stronger one
// beats, and forgets the conflicts that ended.
void Ownership::CheckConflicts(Clock::time_point now) {
  std::set<std::pair<std::string, std::string>> current;
  std::vector<std::string> released;
  for (const auto& [id, peer] : peers_) {
    if (!Alive(peer, now)) continue;
    for (const ActuatorClaim& theirs : peer.claims) {
      const auto mine = ours_.find(theirs.actuator_id);
      if (!Holds(theirs.claim) || mine == ours_.end() || !Holds(mine->second.claim)) continue;
      current.insert({theirs.actuator_id, id});
      if (!conflicts_.count({theirs.actuator_id, id}))
        events_.push_back({OwnershipEvent::Kind::kConflict, theirs.actuator_id, id, theirs.claim,
                           mine->second.claim});
      const ActuatorClaim ours{theirs.actuator_id, mine->second.claim,
                               mine->second.first_seen_utime};
      if (mine->second.claim == Claim::kAdopted && Stronger(theirs, id, ours, daemon_id_) &&
          std::find(released.begin(), released.end(), theirs.actuator_id) == released.end()) {
        released.push_back(theirs.actuator_id);
        events_.push_back({OwnershipEvent::Kind::kReleased, theirs.actuator_id, id, theirs.claim,
                           Claim::kAdopted});
      }
    }
  }
  for (const std::string& id : released) {
    if (ours_.erase(id) > 0) changed_ = true;
  }
  conflicts_ = std::move(current);
}

std::vector<OwnershipEvent> Ownership::TakeEvents() {
  std::vector<OwnershipEvent> out;
  out.swap(events_);
  return out;
}

std::optional<Ownership::Clock::time_point> Ownership::NextDeadline() const {
  std::optional<Clock::time_point> next;
  for (const auto& [id, held] : ours_)
    if (held.claim == Claim::kPending && (!next || held.decide_at < *next)) next = held.decide_at;
  return next;
}

Claim Ownership::ClaimOn(const std::string& actuator_id) const {
  const auto it = ours_.find(actuator_id);
  return it == ours_.end() ? Claim::kNone : it->second.claim;
}

bool Ownership::Owns(const std::string& actuator_id) const { return Holds(ClaimOn(actuator_id)); }

std::string Ownership::OwnerElsewhere(const std::string& actuator_id) const {
  const auto it = owners_.find(actuator_id);
  return it == owners_.end() ? "" : it->second;
}

Announcement Ownership::Announce(int64_t wall_utime) const {
  Announcement out;
  out.utime = wall_utime;
  out.daemon_id = daemon_id_;
  out.instance_id = instance_id_;
  for (const auto& [id, held] : ours_)
    out.claims.push_back({id, held.claim, held.first_seen_utime});
  for (const auto& [id, peer] : peers_) out.peers.push_back({id, peer.heard_utime});
  return out;
}

bool Ownership::TakeChanged() {
  const bool changed = changed_;
  changed_ = false;
  return changed;
}

}  // namespace flexid::daemon
