// Which actuators this flexidd owns when several share one bus (docs/architecture.md,
// "Several daemons"). Pure bookkeeping on the loop's thread, with no LCM and no storage:
// the service tells it what it hears (other daemons' announcements, ownership_t on
// PREFIX/OWNERSHIP; the actuators its messages name) and acts on the events it returns.
//
// The rules:
//  - A daemon owns the actuators of its configuration (kConfigured) and, with
//    accept_unknown_actuators, an actuator it saw first that no other daemon claims
//    (kAdopted). An actuator its file knows from an earlier run is adopted again like an
//    unknown one.
//  - A new actuator is pending (kPending) for `wait` while the others' claims are heard;
//    its messages are held meanwhile, not dropped. Then the strongest claim wins: a
//    configured one, else the earliest first sighting (wall clock), else the smaller
//    daemon_id. A daemon that has been up for `wait` and hears no other adopts at once.
//  - Two daemons that both hold a claim (configured or adopted) on one actuator each
//    raise a conflict naming the other, once until the conflict ends. An adopted claim
//    that a stronger one beats is released; two configured claims both stay (the
//    configuration says so) until a person changes one.
//  - A daemon not heard for `peer_silence` is gone: its claims lapse. It is still named
//    (peers) for `peer_memory`, so that a client can say it did not answer.
#pragma once

#include <chrono>
#include <cstdint>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

namespace flexid::daemon {

// The values of ownership_t's claims; kNone is "no claim".
enum class Claim : int8_t { kNone = 0, kConfigured = 1, kAdopted = 2, kPending = 3 };
const char* ClaimName(Claim claim);  // "none", "configured", "adopted", "pending"

struct ActuatorClaim {
  std::string actuator_id;
  Claim claim = Claim::kNone;
  int64_t first_seen_utime = 0;  // wall clock; 0 for kConfigured
};

struct PeerHeard {
  std::string daemon_id;
  int64_t heard_utime = 0;  // wall clock
};

// One daemon's ownership_t, decoded and checked (ids valid, claims known, arrays agree).
struct Announcement {
  int64_t utime = 0;
  std::string daemon_id;
  std::string instance_id;
  std::vector<ActuatorClaim> claims;
  std::vector<PeerHeard> peers;
};

struct OwnershipOptions {
  std::chrono::milliseconds wait{500};  // config ownership_wait_s
  std::chrono::milliseconds peer_silence{3500};
  std::chrono::milliseconds peer_memory{600000};
  bool accept_unknown = true;  // config accept_unknown_actuators
};

struct OwnershipEvent {
  enum class Kind {
    kAdopted,      // a pending actuator is now ours: record it, replay its held messages
    kRefused,      // a pending actuator is another's (`other`): drop its held messages
    kConflict,     // `other` claims (`other_claim`) an actuator we hold
    kReleased,     // our adopted claim lost to `other`'s: stop recording the actuator
    kDuplicateId,  // another daemon runs with our daemon_id (instance `other`)
  };
  Kind kind = Kind::kAdopted;
  std::string actuator_id;
  std::string other;
  Claim other_claim = Claim::kNone;
  Claim our_claim = Claim::kNone;
};

class Ownership {
 public:
  using Clock = std::chrono::steady_clock;

  Ownership(std::string daemon_id, std::string instance_id, OwnershipOptions options,
            Clock::time_point started);

  // A configured actuator: owned from the start.
  void Configure(const std::string& actuator_id);

  // What to do with a message naming an actuator.
  enum class Verdict {
    kOwn,        // ours (it may have just been adopted: see TakeEvents)
    kHold,       // pending: hold the message until the decision
    kElsewhere,  // another daemon's: ignore it
    kUnknown,    // unknown and accept_unknown is off
  };
  // `wall_utime` is this host's wall clock (the first sighting's time).
  Verdict Sight(const std::string& actuator_id, int64_t wall_utime, Clock::time_point now);

  // Another daemon's announcement (our own, looped back, is ignored).
  void Hear(const Announcement& announcement, int64_t wall_utime, Clock::time_point now);

  // Decides the pending actuators whose wait is over and lets silent peers' claims lapse.
  void Tick(Clock::time_point now);

  // Events since the last call, in order.
  std::vector<OwnershipEvent> TakeEvents();

  // When Tick next has something to decide.
  std::optional<Clock::time_point> NextDeadline() const;

  Claim ClaimOn(const std::string& actuator_id) const;
  bool Owns(const std::string& actuator_id) const;
  // The daemon holding the strongest claim (configured or adopted) on an actuator we do
  // not hold, or "" when no daemon heard from claims it.
  std::string OwnerElsewhere(const std::string& actuator_id) const;
  // What we announce: our claims, the peers we remember.
  Announcement Announce(int64_t wall_utime) const;
  // True once since our claims changed or a new daemon was heard (announce at once).
  bool TakeChanged();
  // Daemons heard within peer_silence.
  size_t live_peers(Clock::time_point now) const;
  const std::string& daemon_id() const { return daemon_id_; }

 private:
  struct Peer {
    std::string instance_id;
    Clock::time_point heard;
    int64_t heard_utime = 0;
    std::vector<ActuatorClaim> claims;  // as last announced
  };
  struct Held {
    Claim claim = Claim::kNone;
    int64_t first_seen_utime = 0;
    Clock::time_point decide_at{};  // kPending
  };
  // The strongest claim on an actuator among live peers ("" when none).
  std::pair<std::string, ActuatorClaim> StrongestElsewhere(const std::string& actuator_id,
                                                           bool held_only) const;
  bool Alive(const Peer& peer, Clock::time_point now) const;
  void Adopt(const std::string& actuator_id, int64_t wall_utime);
  void CheckConflicts(Clock::time_point now);
  // owners_ from the live peers' held claims (after each announcement and Tick): the
  // lookup a sample of another daemon's actuator costs.
  void CacheOwners();

  std::string daemon_id_;
  std::string instance_id_;
  OwnershipOptions options_;
  Clock::time_point started_;
  Clock::time_point now_;  // of the latest call
  std::map<std::string, Held> ours_;
  std::map<std::string, Peer> peers_;
  std::set<std::pair<std::string, std::string>> conflicts_;  // (actuator, peer) raised
  std::set<std::string> duplicate_instances_;                // of our daemon_id, reported
  std::map<std::string, std::string> owners_;                // actuator -> strongest peer
  std::vector<OwnershipEvent> events_;
  bool changed_ = true;
};

// True when claim a (of daemon a_id) beats claim b (of daemon b_id): configured beats
// the others, then the earlier first sighting, then the smaller daemon_id.
bool Stronger(const ActuatorClaim& a, const std::string& a_id, const ActuatorClaim& b,
              const std::string& b_id);

}  // namespace flexid::daemon
