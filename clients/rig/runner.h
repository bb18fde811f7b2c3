// Plays a Rig's sample stream onto the bus: paces it against the wall clock, decides
// which messages go out, counts them. The bus itself is behind BusSink, so tests can
// record the messages instead of sending them (rig_main.cc has the LCM sink).
//
// Per sample, in this order: the voltage message if the sample says publish_voltage, then
// the deflection message, both with the sample's utime. With trial control, a trial start
// at the first sample's utime goes before everything and a trial stop at the end of the
// last published sample's interval after everything.
//
// Pacing: sample k goes out at wall time start + t_k / speed; speed 0 publishes as fast as
// possible. Message time never depends on the speed.
//
// Several actuators (RunRigs) advance together: all trial starts (in the order given), then
// per sample k every actuator's voltage and deflection in turn, all with utime_k, then all
// trial stops. A stop request ends the run between samples, so every actuator has played
// the same samples.
#pragma once

#include <atomic>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "clients/rig/rig.h"

namespace flexid::rig {

enum class TrialAction { kStart, kStop };

class BusSink {
 public:
  virtual ~BusSink() = default;
  // Each returns false if the message could not be sent.
  virtual bool PublishVoltage(int64_t utime, double voltage_V) = 0;
  virtual bool PublishDeflection(int64_t utime, double deflection_mm) = 0;
  virtual bool PublishTrialControl(int64_t utime, TrialAction action,
                                   const std::string& protocol) = 0;
};

struct RunOptions {
  double speed = 1.0;          // times real time; 0: no pacing. 0 or finite and >= 1e-3.
  bool trial_control = false;  // publish trial start and stop
};

struct RunSummary {
  int64_t actuators = 1;            // played together (RunRigs)
  int64_t samples = 0;              // samples played per actuator (all unless interrupted)
  int64_t voltage_messages = 0;     // sent (failed ones are not counted here)
  int64_t deflection_messages = 0;  // sent
  int64_t trial_messages = 0;       // sent
  int64_t failed_messages = 0;      // the sink returned false
  double duration_s = 0.0;          // message time covered: samples / rate_Hz
  int64_t final_utime = 0;          // utime of the last sample played (0: none)
  double wall_s = 0.0;              // wall-clock time the run took
  bool interrupted = false;         // *stop became true before the last sample
};

// Plays every sample of `rig` (or until *stop is true; checked at least every 100 ms).
RunSummary RunRig(Rig& rig, BusSink& sink, const RunOptions& options,
                  const std::atomic<bool>* stop = nullptr);

// One actuator of RunRigs; neither is owned.
struct ActuatorOnBus {
  Rig* rig = nullptr;
  BusSink* sink = nullptr;
};

// Plays several rigs together (see above). They must agree in sample count, rate and start
// utime (MakeActuatorRigs's do); throws std::invalid_argument otherwise or if there are none.
RunSummary RunRigs(const std::vector<ActuatorOnBus>& actuators, const RunOptions& options,
                   const std::atomic<bool>* stop = nullptr);

// Where a run's message time starts without --start-utime: the wall clock, or just after
// the latest sample flexidd has seen (its status reply's latest_utime, nullopt when none
// is known) if that is later. A run at --speed 200 ends far ahead of the wall clock (440 s
// of message time in 2.2 s); the next run starting at the wall clock would go back in
// message time, and flexidd would take it for a source clock jump (daemon/health.h).
// "Just after" is kRestartGap_s, or one sample period at rates below 1 Hz: after the
// previous run's trial stop (one period after its last sample), so the trials do not
// touch. Saturates at INT64_MAX rather than overflow (the rig then refuses the start).
inline constexpr double kRestartGap_s = 1.0;
int64_t ContinuedStartUtime(int64_t wall_utime, std::optional<int64_t> latest_utime,
                            double rate_Hz);

// One line: "published 100 samples (100 deflection, 10 voltage, 2 trial-control
// messages) covering 10 s of message time in 0.0021 s, final utime 1700000009900000";
// with several actuators "published 100 samples for each of 2 actuators (200 deflection,
// ...". Message counts are totals over the actuators.
std::string SummaryLine(const RunSummary& summary);

}  // namespace flexid::rig
