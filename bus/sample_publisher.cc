#include "bus/sample_publisher.h"

#include "bus/clock.h"

namespace flexid::bus {

SamplePublisher::SamplePublisher(lcm::LCM& lcm, const Channels& channels,
                                 const std::string& actuator_id, const auth::Key* key)
    : lcm_(&lcm),
      key_(key),
      actuator_id_(actuator_id),
      voltage_channel_(channels.Voltage(actuator_id)),
      deflection_channel_(channels.Deflection(actuator_id)),
      trial_channel_(channels.TrialControl()) {
  voltage_.actuator_id = actuator_id;
  deflection_.actuator_id = actuator_id;
}

bool SamplePublisher::PublishVoltage(int64_t utime, double voltage_V) {
  voltage_.utime = utime;
  voltage_.voltage_V = voltage_V;
  return lcm_->publish(voltage_channel_, &voltage_) == 0;
}

bool SamplePublisher::PublishDeflection(int64_t utime, double deflection_mm) {
  deflection_.utime = utime;
  deflection_.deflection_mm = deflection_mm;
  return lcm_->publish(deflection_channel_, &deflection_) == 0;
}

bool SamplePublisher::PublishTrialControl(int64_t utime, TrialAction action,
                                          const std::string& protocol) {
  if (key_ == nullptr) return false;
  flexid::trial_control2_t message;
  message.utime = utime;
  message.actuator_id = actuator_id_;
  message.action = action == TrialAction::kStart ? flexid::trial_control2_t::kStart
                                                 : flexid::trial_control2_t::kStop;
  message.protocol = protocol;
  message.sent_utime = WallClockUtime();
  auth::Sign(*key_, &message);
  return lcm_->publish(trial_channel_, &message) == 0;
}

}  // namespace flexid::bus
