// The rules of a fan-out to several flexidd (bus/fan_out.h), without a bus: who is expected
// to answer, duplicates, late replies, replies of daemons not heard of, the notes.
#include "bus/fan_out.h"

#include <gtest/gtest.h>

#include <algorithm>

namespace flexid::bus {
namespace {

constexpr int64_t kNow = 1'700'000'000'000'000;

flexid::rpc_reply_t ReplyOf(const std::string& daemon_id, const std::string& request_id = "r1") {
  flexid::rpc_reply_t reply;
  reply.utime = kNow;
  reply.request_id = request_id;
  reply.daemon_id = daemon_id;
  reply.status = flexid::rpc_reply_t::kOk;
  reply.result_json = "[]";
  return reply;
}

flexid::ownership_t AnnouncementOf(const std::string& daemon_id,
                                   std::vector<std::pair<std::string, int64_t>> peers = {}) {
  flexid::ownership_t a{};
  a.utime = kNow;
  a.daemon_id = daemon_id;
  a.instance_id = "i-" + daemon_id;
  a.num_claims = 0;
  for (const auto& [id, heard] : peers) {
    a.peer_ids.push_back(id);
    a.peer_heard_utime.push_back(heard);
  }
  a.num_peers = static_cast<int16_t>(a.peer_ids.size());
  return a;
}

bool Mentions(const std::vector<std::string>& notes, const std::string& text) {
  return std::any_of(notes.begin(), notes.end(),
                     [&](const std::string& n) { return n.find(text) != std::string::npos; });
}

using Taken = FanOutCollector::Taken;

TEST(FanOutCollector, CompleteOnceEveryDaemonHeardOfHasAnswered) {
  FanOutCollector c("r1", {});
  EXPECT_FALSE(c.Complete());  // nothing yet
  c.Heard(AnnouncementOf("lab-a", {{"lab-b", kNow - 500'000}}), kNow);
  EXPECT_EQ(c.Reply(ReplyOf("lab-a"), false), Taken::kKept);
  EXPECT_FALSE(c.Complete());  // lab-b, named by lab-a, has not answered
  EXPECT_EQ(c.Reply(ReplyOf("lab-b"), false), Taken::kKept);
  EXPECT_TRUE(c.Complete());
  EXPECT_EQ(c.replies().size(), 2u);
  EXPECT_TRUE(c.Notes(std::chrono::seconds(3)).empty());
}

TEST(FanOutCollector, ADaemonNamedByAnotherButSilentIsNamedAsNotAnswering) {
  FanOutCollector c("r1", {});
  c.Heard(AnnouncementOf("lab-a", {{"lab-c", kNow - 12'000'000}}), kNow);
  c.Reply(ReplyOf("lab-a"), false);
  EXPECT_FALSE(c.Complete());
  const std::vector<RollCallEntry> roll = c.RollCall();
  ASSERT_EQ(roll.size(), 2u);
  EXPECT_EQ(roll[1].daemon_id, "lab-c");
  EXPECT_FALSE(roll[1].answered);
  ASSERT_TRUE(roll[1].last_heard_s);
  EXPECT_DOUBLE_EQ(*roll[1].last_heard_s, 12.0);
  const auto notes = c.Notes(std::chrono::seconds(3));
  EXPECT_TRUE(Mentions(notes, "lab-c did not answer within 3 s (last heard 12 s ago by lab-a)"))
      << notes.front();
}

TEST(FanOutCollector, ADuplicateReplyIsCountedOnce) {
  FanOutCollector c("r1", {});
  EXPECT_EQ(c.Reply(ReplyOf("lab-a"), false), Taken::kKept);
  EXPECT_EQ(c.Reply(ReplyOf("lab-a"), false), Taken::kDuplicate);
  EXPECT_EQ(c.Reply(ReplyOf("lab-a"), false), Taken::kDuplicate);
  EXPECT_EQ(c.replies().size(), 1u);
  EXPECT_TRUE(Mentions(c.Notes(std::chrono::seconds(3)), "2 duplicate replies from lab-a ignored"));
}

TEST(FanOutCollector, ALateReplyIsIgnoredAndTheDaemonNamedAsNotAnswering) {
  FanOutCollector c("r1", {"lab-a", "lab-b"});
  c.Reply(ReplyOf("lab-a"), false);
  EXPECT_EQ(c.Reply(ReplyOf("lab-b"), true), Taken::kLate);
  EXPECT_EQ(c.replies().size(), 1u);
  const auto notes = c.Notes(std::chrono::milliseconds(1500));
  EXPECT_TRUE(Mentions(notes, "lab-b did not answer within 1.5 s"));
  EXPECT_TRUE(Mentions(notes, "1 reply from lab-b came after the 1.5 s timeout and was ignored"));
}

TEST(FanOutCollector, AReplyFromADaemonNotHeardOfIsKeptAndMarked) {
  FanOutCollector c("r1", {});
  c.Heard(AnnouncementOf("lab-a"), kNow);
  c.Reply(ReplyOf("lab-a"), false);
  EXPECT_EQ(c.Reply(ReplyOf("ghost"), false), Taken::kKept);
  EXPECT_TRUE(c.Complete());
  const std::vector<RollCallEntry> roll = c.RollCall();
  ASSERT_EQ(roll.size(), 2u);
  EXPECT_EQ(roll[0].daemon_id, "ghost");
  EXPECT_TRUE(roll[0].answered);
  EXPECT_FALSE(roll[0].announced);
  EXPECT_FALSE(roll[0].named);
  EXPECT_TRUE(Mentions(c.Notes(std::chrono::seconds(3)), "ghost answered but was not heard of"));
}

TEST(FanOutCollector, WithDaemonsNamedOnlyTheyCount) {
  FanOutCollector c("r1", {"lab-b"});
  c.Heard(AnnouncementOf("lab-a", {{"lab-c", kNow}}), kNow);
  EXPECT_EQ(c.Reply(ReplyOf("lab-a"), false), Taken::kNotAsked);
  EXPECT_FALSE(c.Complete());
  EXPECT_EQ(c.Reply(ReplyOf("lab-b"), false), Taken::kKept);
  EXPECT_TRUE(c.Complete());  // lab-c was not asked for
  ASSERT_EQ(c.RollCall().size(), 1u);
  EXPECT_EQ(c.RollCall()[0].daemon_id, "lab-b");
}

TEST(FanOutCollector, RepliesToOtherRequestsAndWithoutAValidDaemonIdAreIgnored) {
  FanOutCollector c("r1", {});
  EXPECT_EQ(c.Reply(ReplyOf("lab-a", "r2"), false), Taken::kOtherRequest);
  EXPECT_EQ(c.Reply(ReplyOf("lab/a"), false), Taken::kNotAsked);
  EXPECT_EQ(c.Reply(ReplyOf(""), false), Taken::kNotAsked);
  EXPECT_TRUE(c.replies().empty());
}

}  // namespace
}  // namespace flexid::bus
