// The id rule of actuators and RPC clients: their ids name LCM channels
// (FLEXID/<actuator>/VOLTAGE, FLEXID/RPC/REPLY/<client>), so one rule holds on every
// side of the bus.
#pragma once

#include <string_view>

namespace flexid::bus {

// What IsValidId accepts, in words (for error messages).
inline constexpr char kIdRule[] = "1 to 64 of A-Z a-z 0-9 _ -";

// 1 to 64 characters of [A-Za-z0-9_-]. No '.', which a channel subscription reads as a
// regular expression.
bool IsValidId(std::string_view id);

}  // namespace flexid::bus
