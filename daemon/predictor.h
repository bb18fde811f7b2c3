// The live prediction of one actuator (DESIGN.md: "online predictor"): its active model
// run on the voltage in force, in message time. The loop steps it on every voltage and
// deflection message and hands the residual to the actuator's residual monitor
// (model/diagnose/monitor.h); predictor.cc holds that part of the loop.
#pragma once

#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "model/diagnose/effects.h"

namespace flexid::daemon {

// A message time not seen yet.
constexpr int64_t kNoTime = INT64_MIN;

// The active model of one actuator, run on the live voltage in message time, with the
// effects its file's augmentations add (model/diagnose/effects.h), sample by sample.
struct Predictor {
  int32_t version = 0;  // 0: no model
  std::optional<model::AugmentedStreamingSimulator> simulator;
  int64_t base_utime = kNoTime;  // time origin of the simulator (keeps doubles precise)
  int64_t last_utime = kNoTime;
  double last_output_mm = NAN;
  double last_voltage_V = NAN;
  std::vector<double> memberships;

  bool ready() const { return simulator.has_value(); }

  // Feeds the voltage in force from utime on; returns the prediction at utime. A sample at
  // the instant of the last step under the same voltage (a deflection stamped with its
  // voltage's time) is that step's prediction: stepping again would move the output
  // effects' states by a spurious microsecond.
  double Step(int64_t utime, double voltage_V) {
    if (!simulator) return NAN;
    if (base_utime == kNoTime) base_utime = utime;
    if (utime == last_utime && voltage_V == last_voltage_V) return last_output_mm;
    if (last_utime != kNoTime && utime <= last_utime) utime = last_utime + 1;  // same instant
    last_output_mm = simulator->Step(1e-6 * static_cast<double>(utime - base_utime), voltage_V);
    memberships = simulator->memberships();
    last_utime = utime;
    last_voltage_V = voltage_V;
    return last_output_mm;
  }
};

// The predictor of a stored model (its JSON and version), with its augmentations, at rest
// or in steady state under the first voltage. Throws model::InputError naming the version
// and the problem when the model cannot run live (a malformed file, an augmentation not in
// the catalogue, lacking a parameter or its scale).
Predictor PredictorOf(const std::string& model_json, int32_t version, bool in_steady_state);

}  // namespace flexid::daemon
