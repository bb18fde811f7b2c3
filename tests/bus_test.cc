// bus/: the rules every program on the bus shares.
#include <gtest/gtest.h>

#include <chrono>
#include <string>

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

}  // namespace
}  // namespace flexid::bus
