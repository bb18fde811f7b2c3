// Where flexid-control's reference comes from: a CSV t_s,deflection_mm
// (model/control/reference.h), or a protocol of the rig's (clients/rig/protocol.h: step,
// square, staircase, hold, sweep, sine, random multilevel) read in millimetres instead of
// volts, sampled every Ts from 0 to its end.
#pragma once

#include <string>

#include "model/control/reference.h"

namespace flexid::control {

// Throws model::InputError naming the protocol (its syntax errors are the rig's).
model::control::Reference ReferenceFromProtocol(const std::string& spec, double sample_period_s);

}  // namespace flexid::control
