// The live prediction of one actuator (DESIGN.md: "online predictor"): its active model
// run on the voltage in force, in message time. The loop steps it on every voltage and
// deflection message and hands the residual to the actuator's residual monitor
// (model/diagnose/monitor.h); predictor.cc holds that part of the loop.
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <vector>

#include "model/core/simulate.h"

namespace flexid::daemon {

// A message time not seen yet.
constexpr int64_t kNoTime = INT64_MIN;

// The active model of one actuator, run on the live voltage in message time.
struct Predictor {
  int32_t version = 0;  // 0: no model
  std::optional<model::StreamingSimulator> simulator;
  int64_t base_utime = kNoTime;  // time origin of the simulator (keeps doubles precise)
  int64_t last_utime = kNoTime;
  double last_output_mm = NAN;
  std::vector<double> memberships;

  bool ready() const { return simulator.has_value(); }

  // Feeds the voltage in force from utime on; returns the prediction at utime.
  double Step(int64_t utime, double voltage_V) {
    if (!simulator) return NAN;
    if (base_utime == kNoTime) base_utime = utime;
    if (last_utime != kNoTime && utime <= last_utime) utime = last_utime + 1;  // same instant
    last_output_mm = simulator->Step(1e-6 * static_cast<double>(utime - base_utime), voltage_V);
    memberships = simulator->memberships();
    last_utime = utime;
    return last_output_mm;
  }
};

}  // namespace flexid::daemon
