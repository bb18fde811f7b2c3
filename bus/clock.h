// The wall clock the bus is stamped with.
#pragma once

#include <cstdint>

namespace flexid::bus {

// Microseconds since the Unix epoch (the utime of every flexid message: samples, trial
// control, RPC requests and replies, status).
int64_t WallClockUtime();

}  // namespace flexid::bus
