// Ownership among several flexidd (daemon/ownership.h): who records an actuator, when a
// pending one is decided, conflicts raised once, adopted claims released to stronger ones.
// Pure logic on a clock the test moves; no bus.
#include "daemon/ownership.h"

#include <gtest/gtest.h>

namespace flexid::daemon {
namespace {

using namespace std::chrono_literals;
using Clock = Ownership::Clock;
using Kind = OwnershipEvent::Kind;

const Clock::time_point kStart{};
constexpr int64_t kWall = 1'700'000'000'000'000;

Announcement Of(const std::string& daemon_id, std::vector<ActuatorClaim> claims) {
  Announcement a;
  a.utime = kWall;
  a.daemon_id = daemon_id;
  a.instance_id = "instance-of-" + daemon_id;
  a.claims = std::move(claims);
  return a;
}

std::vector<Kind> Kinds(const std::vector<OwnershipEvent>& events) {
  std::vector<Kind> out;
  for (const OwnershipEvent& e : events) out.push_back(e.kind);
  return out;
}

Ownership Make(const std::string& id = "lab-b", bool accept_unknown = true) {
  OwnershipOptions options;
  options.accept_unknown = accept_unknown;
  return Ownership(id, "instance-of-" + id, options, kStart);
}

TEST(Ownership, ConfiguredActuatorsAreOwnedFromTheStart) {
  Ownership o = Make();
  o.Configure("S1");
  EXPECT_EQ(o.Sight("S1", kWall, kStart), Ownership::Verdict::kOwn);
  EXPECT_TRUE(o.Owns("S1"));
  EXPECT_EQ(o.ClaimOn("S1"), Claim::kConfigured);
}

TEST(Ownership, AnUnknownActuatorIsHeldDuringTheStartUpWaitThenAdopted) {
  Ownership o = Make();
  EXPECT_EQ(o.Sight("S9", kWall, kStart + 100ms), Ownership::Verdict::kHold);
  EXPECT_EQ(o.ClaimOn("S9"), Claim::kPending);
  ASSERT_TRUE(o.NextDeadline());
  EXPECT_EQ(*o.NextDeadline(), kStart + 600ms);
  o.Tick(kStart + 599ms);
  EXPECT_TRUE(o.TakeEvents().empty());
  o.Tick(kStart + 600ms);
  EXPECT_EQ(Kinds(o.TakeEvents()), std::vector<Kind>{Kind::kAdopted});
  EXPECT_TRUE(o.Owns("S9"));
  EXPECT_FALSE(o.NextDeadline());
}

TEST(Ownership, AloneAfterTheWaitAnUnknownActuatorIsAdoptedAtOnce) {
  Ownership o = Make();
  EXPECT_EQ(o.Sight("S9", kWall, kStart + 2s), Ownership::Verdict::kOwn);
  EXPECT_EQ(Kinds(o.TakeEvents()), std::vector<Kind>{Kind::kAdopted});
}

TEST(Ownership, WithoutAcceptUnknownAnUnknownActuatorIsRefused) {
  Ownership o = Make("lab-b", false);
  EXPECT_EQ(o.Sight("S9", kWall, kStart + 2s), Ownership::Verdict::kUnknown);
  EXPECT_FALSE(o.Owns("S9"));
}

TEST(Ownership, AnActuatorAnotherDaemonOwnsIsNeverRecordedHere) {
  Ownership o = Make();
  o.Hear(Of("lab-a", {{"S1", Claim::kConfigured, 0}}), kWall, kStart + 10ms);
  EXPECT_EQ(o.Sight("S1", kWall, kStart + 20ms), Ownership::Verdict::kElsewhere);
  EXPECT_EQ(o.OwnerElsewhere("S1"), "lab-a");
  EXPECT_FALSE(o.Owns("S1"));
  EXPECT_TRUE(o.TakeEvents().empty());
}

TEST(Ownership, APendingActuatorGoesToAClaimHeardDuringTheWait) {
  Ownership o = Make();
  EXPECT_EQ(o.Sight("S1", kWall, kStart + 10ms), Ownership::Verdict::kHold);
  o.Hear(Of("lab-a", {{"S1", Claim::kConfigured, 0}}), kWall, kStart + 300ms);
  o.Tick(kStart + 510ms);
  const std::vector<OwnershipEvent> events = o.TakeEvents();
  ASSERT_EQ(Kinds(events), std::vector<Kind>{Kind::kRefused});
  EXPECT_EQ(events[0].other, "lab-a");
  EXPECT_EQ(o.ClaimOn("S1"), Claim::kNone);
  EXPECT_EQ(o.Sight("S1", kWall, kStart + 520ms), Ownership::Verdict::kElsewhere);
}

TEST(Ownership, TwoPendingClaimsGoToTheEarlierSightingThenTheSmallerId) {
  Ownership b = Make("lab-b");
  EXPECT_EQ(b.Sight("S5", kWall + 10, kStart), Ownership::Verdict::kHold);
  b.Hear(Of("lab-a", {{"S5", Claim::kPending, kWall + 20}}), kWall, kStart + 100ms);
  b.Tick(kStart + 500ms);
  EXPECT_EQ(Kinds(b.TakeEvents()), std::vector<Kind>{Kind::kAdopted});  // seen 10 us earlier

  Ownership c = Make("lab-c");
  EXPECT_EQ(c.Sight("S5", kWall, kStart), Ownership::Verdict::kHold);
  c.Hear(Of("lab-a", {{"S5", Claim::kPending, kWall}}), kWall, kStart + 100ms);
  c.Tick(kStart + 500ms);
  EXPECT_EQ(Kinds(c.TakeEvents()), std::vector<Kind>{Kind::kRefused});  // same time: lab-a < lab-c
}

TEST(Ownership, TwoConfiguredClaimsRaiseOneConflictAndBothStay) {
  Ownership o = Make();
  o.Configure("S2");
  const Announcement a = Of("lab-a", {{"S2", Claim::kConfigured, 0}});
  o.Hear(a, kWall, kStart + 1s);
  std::vector<OwnershipEvent> events = o.TakeEvents();
  ASSERT_EQ(Kinds(events), std::vector<Kind>{Kind::kConflict});
  EXPECT_EQ(events[0].actuator_id, "S2");
  EXPECT_EQ(events[0].other, "lab-a");
  EXPECT_EQ(events[0].other_claim, Claim::kConfigured);
  // Every further heartbeat: no new alert.
  for (int i = 2; i < 6; ++i) {
    o.Hear(a, kWall, kStart + std::chrono::seconds(i));
    o.Tick(kStart + std::chrono::seconds(i));
  }
  EXPECT_TRUE(o.TakeEvents().empty());
  EXPECT_TRUE(o.Owns("S2"));
  // The conflict ends (lab-a's configuration changed), then comes back: raised again.
  o.Hear(Of("lab-a", {}), kWall, kStart + 7s);
  o.Hear(a, kWall, kStart + 8s);
  EXPECT_EQ(Kinds(o.TakeEvents()), std::vector<Kind>{Kind::kConflict});
}

TEST(Ownership, AnAdoptedClaimIsReleasedToAConfiguredOne) {
  Ownership o = Make();
  EXPECT_EQ(o.Sight("S3", kWall, kStart + 2s), Ownership::Verdict::kOwn);
  o.TakeEvents();
  o.Hear(Of("lab-a", {{"S3", Claim::kConfigured, 0}}), kWall, kStart + 3s);
  const std::vector<OwnershipEvent> events = o.TakeEvents();
  EXPECT_EQ(Kinds(events), (std::vector<Kind>{Kind::kConflict, Kind::kReleased}));
  EXPECT_FALSE(o.Owns("S3"));
  EXPECT_EQ(o.Sight("S3", kWall, kStart + 3s), Ownership::Verdict::kElsewhere);
}

TEST(Ownership, ASilentDaemonsClaimsLapseButItIsStillNamed) {
  Ownership o = Make();
  o.Hear(Of("lab-a", {{"S1", Claim::kConfigured, 0}}), kWall, kStart);
  EXPECT_EQ(o.live_peers(kStart + 1s), 1u);
  o.Tick(kStart + 4s);  // 3.5 s of silence
  EXPECT_EQ(o.live_peers(kStart + 4s), 0u);
  EXPECT_EQ(o.OwnerElsewhere("S1"), "");
  const Announcement mine = o.Announce(kWall);
  ASSERT_EQ(mine.peers.size(), 1u);
  EXPECT_EQ(mine.peers[0].daemon_id, "lab-a");
  o.Tick(kStart + 11min);
  EXPECT_TRUE(o.Announce(kWall).peers.empty());
}

TEST(Ownership, AnotherRunWithOurDaemonIdIsReportedOnceAndOurOwnEchoIgnored) {
  Ownership o = Make("lab-a");
  o.Hear(Of("lab-a", {}), kWall, kStart);  // our instance: our own announcement looped back
  EXPECT_TRUE(o.TakeEvents().empty());
  Announcement other = Of("lab-a", {});
  other.instance_id = "someone-else";
  o.Hear(other, kWall, kStart);
  o.Hear(other, kWall, kStart + 1s);
  EXPECT_EQ(Kinds(o.TakeEvents()), std::vector<Kind>{Kind::kDuplicateId});
}

TEST(Ownership, ANewDaemonMakesUsAnnounceAtOnce) {
  Ownership o = Make();
  EXPECT_TRUE(o.TakeChanged());  // the first announcement
  EXPECT_FALSE(o.TakeChanged());
  o.Hear(Of("lab-a", {}), kWall, kStart);
  EXPECT_TRUE(o.TakeChanged());
  o.Hear(Of("lab-a", {}), kWall, kStart + 1s);
  EXPECT_FALSE(o.TakeChanged());
}

TEST(Ownership, StrongerOrdersConfiguredThenFirstSeenThenId) {
  const ActuatorClaim configured{"S1", Claim::kConfigured, 0};
  const ActuatorClaim early{"S1", Claim::kAdopted, 5};
  const ActuatorClaim late{"S1", Claim::kPending, 9};
  EXPECT_TRUE(Stronger(configured, "z", early, "a"));
  EXPECT_FALSE(Stronger(early, "a", configured, "z"));
  EXPECT_TRUE(Stronger(early, "z", late, "a"));
  EXPECT_TRUE(Stronger(early, "a", early, "b"));
  EXPECT_FALSE(Stronger(early, "b", early, "a"));
}

}  // namespace
}  // namespace flexid::daemon
