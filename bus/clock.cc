#include "bus/clock.h"

#include <chrono>

namespace flexid::bus {

int64_t WallClockUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

}  // namespace flexid::bus
