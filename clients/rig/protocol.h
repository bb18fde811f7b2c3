// Voltage protocols of the virtual rig (flexid-rig --protocol SPEC): what voltage the
// actuator gets when, from t = 0 s (the first sample) to the end of the protocol.
//
//   step:level=V,duration=S[,delay=S]      0 V for delay (default 0) s, then level for
//                                          duration s
//   square:level=V,period=S[,duty=D],cycles=N[,polarity=same|alternate]
//                                          N periods; each starts with level for duty *
//                                          period s (duty in (0, 1), default 0.5), then 0 V;
//                                          with polarity=alternate every second period
//                                          (the 2nd, 4th, ...) goes to -level instead
//                                          (a bipolar square wave with a rest between
//                                          pulses); default same: every period at level
//   staircase:levels=V1/V2/...,dwell=S     each level for dwell s in turn, then one more
//                                          dwell at 0 V
//   hold:level=V,duration=S                level for duration s
//
// The seed's experiments in this form: the repeatability test is
// "square:level=5,period=220,cycles=5", an identification input "step:level=2,duration=600";
// "square:level=5,period=220,cycles=6,polarity=alternate" shows both polarities (+5, -5,
// +5, ...). A negative level is allowed everywhere.
// Voltages are in V, times in s. Every key is checked: an unknown key, a missing required
// key, a value that is not a finite number, a duration, period or dwell that is not > 0 or
// a negative delay, or a polarity other than same or alternate is a model::InputError with
// one line, e.g.
//   protocol "square:level=5,period=220": missing key "cycles"
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace flexid::rig {

struct Protocol {
  enum class Shape { kStep, kSquare, kStaircase, kHold };
  Shape shape = Shape::kHold;
  std::string text;  // the specification as given (published with trial_control_t)

  double level_V = 0.0;             // step, square, hold
  double duration_s = 0.0;          // step (after the delay), hold
  double delay_s = 0.0;             // step
  double period_s = 0.0;            // square
  double duty = 0.5;                // square: fraction of each period at level_V
  int64_t cycles = 0;               // square
  bool alternate_polarity = false;  // square: the 2nd, 4th, ... periods at -level_V
  std::vector<double> levels_V;     // staircase
  double dwell_s = 0.0;             // staircase
};

// Parses SPEC (see above). Throws model::InputError.
Protocol ParseProtocol(std::string_view spec);

// Total length in s: delay + duration (step), cycles * period (square),
// (levels + 1) * dwell (staircase), duration (hold).
double ProtocolDuration(const Protocol& protocol);

// Voltage applied at t_s (s from the start; zero-order hold: a change at time T is in
// force at T). A boundary within kBoundaryTolerance_s (relative to max(1, t)) counts as
// reached, so that a sample time k / rate computed in floating point sees a change that
// falls on it exactly. Before 0 s the actuator rests at 0 V; after the end the last
// segment's voltage holds.
double VoltageAt(const Protocol& protocol, double t_s);

inline constexpr double kBoundaryTolerance_s = 1e-9;

}  // namespace flexid::rig
