// The field check of a voltage command (voltage_command_t, version 2) as it comes from the
// bus, shared by its readers: flexid-rig --closed-loop (which also checks the signature,
// message_auth.h) and flexid-dashboard (which draws the reference and holds no key).
// The structure (lengths, strings) is wire_check.h's; this checks the values.
#pragma once

#include <cmath>
#include <cstdint>
#include <flexid/voltage_command_t.hpp>
#include <sstream>
#include <string>

#include "bus/ids.h"

namespace flexid::wire {

// Deflections beyond this are no soft actuator's (and would wreck a chart's axis), mm.
inline constexpr double kMaxReferenceMagnitude_mm = 1000.0;
// A reference more than this before the command's utime is not the sample it answers, us.
inline constexpr int64_t kMaxReferenceLead_us = 60'000'000;

// Empty when every field holds a possible value; otherwise the first problem, one line
// naming the field: "reference_mm is not finite (nan)", "reference_utime 7 is after the
// command's utime 5", ...
inline std::string VoltageCommandProblem(const flexid::voltage_command_t& c) {
  std::ostringstream why;
  if (!bus::IsValidId(c.actuator_id))
    why << "actuator_id \"" << c.actuator_id.substr(0, 64) << "\" is not " << bus::kIdRule;
  else if (!bus::IsValidId(c.controller_id))
    why << "controller_id \"" << c.controller_id.substr(0, 64) << "\" is not " << bus::kIdRule;
  else if (c.utime <= 0)
    why << "utime " << c.utime << " is not > 0";
  else if (!std::isfinite(c.voltage_V))
    why << "voltage_V is not finite (" << c.voltage_V << ")";
  else if (c.sequence <= 0)
    why << "sequence " << c.sequence << " is not > 0";
  else if (c.mode != flexid::voltage_command_t::kTrack &&
           c.mode != flexid::voltage_command_t::kStop)
    why << "mode " << static_cast<int>(c.mode) << " is neither kTrack (1) nor kStop (2)";
  else if (c.mode == flexid::voltage_command_t::kStop && c.voltage_V != 0.0)
    why << "a stop commands " << c.voltage_V << " V, not 0 V";
  else if (c.mode == flexid::voltage_command_t::kStop &&
           (c.reference_utime != 0 || c.reference_mm != 0.0))
    why << "a stop carries no reference (reference_utime and reference_mm must be 0)";
  else if (c.mode == flexid::voltage_command_t::kTrack && !std::isfinite(c.reference_mm))
    why << "reference_mm is not finite (" << c.reference_mm << ")";
  else if (c.mode == flexid::voltage_command_t::kTrack &&
           std::abs(c.reference_mm) > kMaxReferenceMagnitude_mm)
    why << "reference_mm " << c.reference_mm << " is outside -" << kMaxReferenceMagnitude_mm
        << " .. " << kMaxReferenceMagnitude_mm << " mm";
  else if (c.mode == flexid::voltage_command_t::kTrack && c.reference_utime <= 0)
    why << "reference_utime " << c.reference_utime << " is not > 0";
  else if (c.mode == flexid::voltage_command_t::kTrack && c.reference_utime > c.utime)
    why << "reference_utime " << c.reference_utime << " is after the command's utime " << c.utime;
  else if (c.mode == flexid::voltage_command_t::kTrack &&
           c.utime - c.reference_utime > kMaxReferenceLead_us)
    why << "reference_utime " << c.reference_utime << " is more than "
        << kMaxReferenceLead_us / 1'000'000 << " s before the command's utime " << c.utime;
  else
    return "";
  return why.str();
}

}  // namespace flexid::wire
