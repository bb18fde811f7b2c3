#include "clients/control/reference_input.h"

#include <cmath>
#include <vector>

#include "clients/rig/protocol.h"
#include "model/core/errors.h"

namespace flexid::control {

model::control::Reference ReferenceFromProtocol(const std::string& spec, double sample_period_s) {
  const rig::Protocol protocol = rig::ParseProtocol(spec);
  const std::string name = "reference protocol \"" + protocol.text + "\"";
  const double rate_Hz = 1.0 / sample_period_s;
  const std::string why = rig::SamplingProblem(protocol, rate_Hz);
  if (!why.empty()) throw model::InputError(name + ": " + why);
  const double duration_s = rig::ProtocolDuration(protocol);
  const double count = std::ceil(duration_s / sample_period_s - 1e-9);
  if (!(count <= 1e8)) throw model::InputError(name + ": too long for the sample period");
  std::vector<double> t_s, deflection_mm;
  for (long k = 0; k <= static_cast<long>(count); ++k) {
    const double t = std::min(static_cast<double>(k) * sample_period_s, duration_s);
    if (!t_s.empty() && !(t > t_s.back())) break;
    t_s.push_back(t);
    deflection_mm.push_back(rig::VoltageAt(protocol, t));  // the protocol's level, read in mm
  }
  return model::control::Reference(std::move(t_s), std::move(deflection_mm), name);
}

}  // namespace flexid::control
