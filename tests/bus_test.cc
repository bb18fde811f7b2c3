// bus/: the rules every program on the bus shares.
#include <gtest/gtest.h>

#include <chrono>
#include <string>

#include "bus/clock.h"
#include "bus/ids.h"

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
