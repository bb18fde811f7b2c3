// bus/: the rules every program on the bus shares.
#include <gtest/gtest.h>

#include <chrono>
#include <lcm/lcm-cpp.hpp>
#include <stdexcept>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "bus/lcm_url.h"

namespace flexid::bus {
namespace {

TEST(BusIds, OneRuleForActuatorAndClientIds) {
  for (const char* ok : {"S1", "a", "gel_3-b", "Z9"}) EXPECT_TRUE(IsValidId(ok)) << ok;
  EXPECT_TRUE(IsValidId(std::string(64, 'x')));
  EXPECT_FALSE(IsValidId(std::string(65, 'x')));
  EXPECT_FALSE(IsValidId(""));
  // '.' is a regular expression in a channel subscription; '/' separates channel parts.
  for (const char* bad : {"S.1", "S/1", "S 1", "S*", "é", "S1\n"})
    EXPECT_FALSE(IsValidId(bad)) << bad;
  EXPECT_FALSE(
      IsValidId(std::string("S\0"
                            "1",
                            3)));
}

TEST(BusLcmUrl, ReceiveBufferOnlyWhereUdpmAndNotGiven) {
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667", 4096),
            "udpm://239.255.76.67:7667?recv_buf_size=4096");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667?ttl=0", 8388608),
            "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667?recv_buf_size=1024", 4096),
            "udpm://239.255.76.67:7667?recv_buf_size=1024");
  EXPECT_EQ(WithReceiveBuffer("memq://", 4096), "memq://");
}

TEST(BusClock, WallClockIsMicrosecondsSinceTheEpoch) {
  const int64_t system_us = std::chrono::duration_cast<std::chrono::microseconds>(
                                std::chrono::system_clock::now().time_since_epoch())
                                .count();
  const int64_t utime = WallClockUtime();
  EXPECT_GE(utime, system_us);
  EXPECT_LT(utime - system_us, 5'000'000);
}

TEST(BusChannels, NamesFollowThePrefix) {
  const Channels standard;  // the default
  EXPECT_EQ(standard.prefix(), "FLEXID");
  EXPECT_EQ(standard.Voltage("S1"), "FLEXID/S1/VOLTAGE");
  EXPECT_EQ(standard.Deflection("S1"), "FLEXID/S1/DEFLECTION");
  EXPECT_EQ(standard.Prediction("S1"), "FLEXID/S1/PREDICTION");
  EXPECT_EQ(standard.Alert(), "FLEXID/ALERT");
  EXPECT_EQ(standard.Status(), "FLEXID/STATUS");
  EXPECT_EQ(standard.TrialControl(), "FLEXID/TRIAL");
  EXPECT_EQ(standard.RpcRequest(), "FLEXID/RPC/REQUEST");
  EXPECT_EQ(standard.RpcReply("cli-12"), "FLEXID/RPC/REPLY/cli-12");

  const Channels lab("lab.2-b_c");
  EXPECT_EQ(lab.Voltage("S1"), "lab.2-b_c/S1/VOLTAGE");
  EXPECT_EQ(lab.RpcReply("dashboard-1"), "lab.2-b_c/RPC/REPLY/dashboard-1");
  // A subscription is a regular expression: the prefix's '.' is escaped there.
  EXPECT_EQ(lab.AllVoltages(), "lab\\.2-b_c/.*/VOLTAGE");
  EXPECT_EQ(lab.AllDeflections(), "lab\\.2-b_c/.*/DEFLECTION");
  EXPECT_EQ(lab.AllPredictions(), "lab\\.2-b_c/.*/PREDICTION");
  EXPECT_EQ(Exactly(lab.Alert()), "lab\\.2-b_c/ALERT");
  EXPECT_EQ(Exactly("a.b*c+d?e(f)[g]{h}|i^j$k\\l"),
            "a\\.b\\*c\\+d\\?e\\(f\\)\\[g\\]\\{h\\}\\|i\\^j\\$k\\\\l");
}

TEST(BusChannels, PrefixRuleIsTheIdRuleWithDots) {
  for (const char* ok : {"FLEXID", "lab.2", "a-b_c", "L", "..", "9"})
    EXPECT_TRUE(IsValidPrefix(ok)) << ok;
  EXPECT_TRUE(IsValidPrefix(std::string(64, 'x')));
  EXPECT_FALSE(IsValidPrefix(std::string(65, 'x')));
  EXPECT_FALSE(IsValidPrefix(""));
  for (const char* bad : {"A/B", "A B", "A*", "A|B", "é", "A\n"})
    EXPECT_FALSE(IsValidPrefix(bad)) << bad;
  EXPECT_EQ(PrefixProblem("lab.2"), "");
  EXPECT_EQ(PrefixProblem("A/B"), std::string("must be ") + kPrefixRule + " (got \"A/B\")");
  try {
    Channels bad("A/B");
    FAIL() << "a prefix with '/' was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("\"A/B\""), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(kPrefixRule), std::string::npos) << e.what();
  }
}

// Handles `lcm` until `done` or 2 s have passed.
template <typename Done>
void HandleUntil(lcm::LCM& lcm, Done done) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  while (!done() && std::chrono::steady_clock::now() < end) lcm.handleTimeout(10);
}

// What a subscription received: channel names, in order.
struct Heard {
  std::vector<std::string> channels;
  void On(const lcm::ReceiveBuffer*, const std::string& channel) { channels.push_back(channel); }
};

TEST(BusChannels, SubscriptionPatternsHearOnlyTheirPrefix) {
  lcm::LCM lcm("memq://");
  ASSERT_TRUE(lcm.good());
  const Channels lab("lab.2");
  Heard predictions, alerts;
  lcm.subscribe(lab.AllPredictions(), &Heard::On, &predictions);
  lcm.subscribe(Exactly(lab.Alert()), &Heard::On, &alerts);
  const char byte = 0;
  // Unescaped, "lab.2" would match "labx2" too: another installation's channels.
  for (const std::string& channel : {std::string("labx2/S1/PREDICTION"), lab.Prediction("S1"),
                                     std::string("labx2/ALERT"), lab.Alert()})
    lcm.publish(channel, &byte, 1);
  HandleUntil(lcm, [&] { return predictions.channels.size() + alerts.channels.size() >= 2; });
  lcm.handleTimeout(50);  // anything else that would (wrongly) come
  EXPECT_EQ(predictions.channels, std::vector<std::string>{"lab.2/S1/PREDICTION"});
  EXPECT_EQ(alerts.channels, std::vector<std::string>{"lab.2/ALERT"});
}

}  // namespace
}  // namespace flexid::bus
