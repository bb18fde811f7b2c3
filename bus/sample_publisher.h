// One actuator's messages as a source sends them to flexidd: voltage_sample_t on
// PREFIX/<id>/VOLTAGE, deflection_sample_t on PREFIX/<id>/DEFLECTION, and trial start and
// stop as trial_control2_t on PREFIX/TRIAL, signed (lcmtypes/message_auth.h) because
// flexidd refuses unsigned trial control. Used by every program that plays a source: the
// virtual rig, `flexid trials import` replaying a file, the load benchmark. They keep their
// own pacing and counting; this class builds and publishes each message.
//
// Times: utime is message time (the source's clock, as the samples carry it); a trial
// control's sent_utime is this host's wall clock, whatever message time does (a replay, a
// rig faster than real time), because flexidd judges a signature's freshness by it.
#pragma once

#include <cstdint>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <string>

#include "bus/channels.h"
#include "lcmtypes/message_auth.h"

namespace flexid::bus {

enum class TrialAction { kStart, kStop };

class SamplePublisher {
 public:
  // Publishes on `lcm` for `actuator_id` (bus::IsValidId; the caller checks it); trial
  // control is signed with `key`. `lcm` and `key` must outlive the publisher; without a key
  // (nullptr) PublishTrialControl sends nothing and returns false.
  SamplePublisher(lcm::LCM& lcm, const Channels& channels, const std::string& actuator_id,
                  const auth::Key* key = nullptr);

  // Each returns true when LCM took the message (false: it could not be sent).
  bool PublishVoltage(int64_t utime, double voltage_V);
  bool PublishDeflection(int64_t utime, double deflection_mm);
  // `utime` is the trial's start or stop in message time.
  bool PublishTrialControl(int64_t utime, TrialAction action, const std::string& protocol);

  const std::string& actuator_id() const { return actuator_id_; }

 private:
  lcm::LCM* lcm_;
  const auth::Key* key_;
  std::string actuator_id_;
  std::string voltage_channel_, deflection_channel_, trial_channel_;
  // Kept between calls with the actuator id filled in: a source at 500 Hz builds no
  // string per sample.
  flexid::voltage_sample_t voltage_;
  flexid::deflection_sample_t deflection_;
};

}  // namespace flexid::bus
