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
//   sweep:level=V[,frequencies=F1/F2/...][,cycles=N][,duty=D]
//                                          a frequency sweep: N square periods (default 3)
//                                          at each frequency in Hz in turn, each period
//                                          starting with level for duty / F s (duty in
//                                          (0, 1), default 0.5), then 0 V; default
//                                          frequencies the seed's (kSeedSweepFrequencies_Hz)
//   sine:[level=V,]amplitude=A,frequency=F,duration=S
//                                          level + amplitude sin(2 pi F t) for duration s
//                                          (level default 0); a period must last at least
//                                          4 sample periods
//   random:levels=V1/V2/...,dwell_min=S,dwell_max=S,duration=S[,seed=N]
//                                          multilevel random: a level drawn uniformly from
//                                          the list, held for a dwell drawn uniformly in
//                                          [dwell_min, dwell_max] s (0 < dwell_min <=
//                                          dwell_max), again and again until duration s; the
//                                          last dwell is cut at duration. A draw may repeat
//                                          the level before it. seed (a whole number >= 0,
//                                          default 1) fixes the schedule (RandomSchedule)
//
// The seed's frequency-response test (Figure 6: "the square voltage of 5 V was applied ...
// in various frequencies including 0.0025, 0.02, 0.031, 0.054, 0.11, 0.15, and 1.1 Hz") is
// "sweep:level=5": one round of the seven periods lasts 517.4 s (400 s of it at 0.0025 Hz),
// so the default 3 cycles take 1552 s of message time; use --speed to play it faster. The
// sample rate must resolve every frequency: the shorter part of a period, min(duty,
// 1 - duty) / F, must last at least 2 sample periods (1.1 Hz at duty 0.5 needs >= 4.4 Hz;
// the rig's default 10 Hz gives 4 or 5 samples per half period), and a random protocol's
// dwell_min at least 2 sample periods; Rig checks this (SamplingProblem).
//
// The seed's experiments in this form: the repeatability test is
// "square:level=5,period=220,cycles=5", an identification input "step:level=2,duration=600";
// "square:level=5,period=220,cycles=6,polarity=alternate" shows both polarities (+5, -5,
// +5, ...). A negative level is allowed everywhere.
// Voltages are in V, times in s. Every key is checked: an unknown key, a missing required
// key, a value that is not a finite number, a duration, period, dwell or frequency that is
// not > 0, a negative delay, dwell_max < dwell_min, a seed that is not a whole number >= 0,
// more than kMaxRandomDwells dwells, or a polarity other than same or alternate is a
// model::InputError with one line, e.g.
//   protocol "square:level=5,period=220": missing key "cycles"
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace flexid::rig {

struct Protocol {
  enum class Shape { kStep, kSquare, kStaircase, kHold, kSweep, kSine, kRandom };
  struct Dwell {
    double start_s = 0.0;  // from the start of the protocol
    double level_V = 0.0;  // held until the next dwell's start (the last: until the end)
  };
  Shape shape = Shape::kHold;
  std::string text;  // the specification as given (published with trial_control_t)

  double level_V = 0.0;                // step, square, hold, sweep; sine: its offset
  double amplitude_V = 0.0;            // sine
  double frequency_Hz = 0.0;           // sine
  double duration_s = 0.0;             // step (after the delay), hold, sine, random
  double delay_s = 0.0;                // step
  double period_s = 0.0;               // square
  double duty = 0.5;                   // square, sweep: fraction of each period at level_V
  int64_t cycles = 0;                  // square; sweep: periods per frequency
  bool alternate_polarity = false;     // square: the 2nd, 4th, ... periods at -level_V
  std::vector<double> levels_V;        // staircase, random (the levels to draw from)
  double dwell_s = 0.0;                // staircase
  std::vector<double> frequencies_Hz;  // sweep, in the order played
  double dwell_min_s = 0.0;            // random
  double dwell_max_s = 0.0;            // random
  uint64_t seed = 1;                   // random
  std::vector<Dwell> dwells;           // random: the schedule, RandomSchedule's
};

// The seed's square-wave frequencies (Figure 6), Hz: the default of sweep.
inline const std::vector<double> kSeedSweepFrequencies_Hz = {0.0025, 0.02, 0.031, 0.054,
                                                             0.11,   0.15, 1.1};
inline constexpr int64_t kDefaultSweepCycles = 3;
// A random protocol's schedule is computed when it is parsed; this bounds its size.
inline constexpr int64_t kMaxRandomDwells = 10'000'000;

// The schedule of a random protocol (levels_V, dwell_min_s, dwell_max_s, duration_s and seed
// set): from t = 0, per dwell, first the level, then the dwell, until the dwells reach
// duration_s (the last one is cut there). Both draws come from one std::mt19937_64 seeded
// with `seed`, mapped by code of our own so that a seed gives the same schedule with any
// standard library:
//   level index = r mod n, with r redrawn while r < 2^64 mod n (no modulo bias)
//   dwell       = dwell_min + u (dwell_max - dwell_min),  u = (r >> 11) 2^-53 in [0, 1)
// The inputs are assumed valid (ParseProtocol checks them before it calls this).
std::vector<Protocol::Dwell> RandomSchedule(const Protocol& protocol);

// Parses SPEC (see above). Throws model::InputError.
Protocol ParseProtocol(std::string_view spec);

// Total length in s: delay + duration (step), cycles * period (square),
// (levels + 1) * dwell (staircase), duration (hold, sine, random), the sum over the frequencies
// of cycles / F (sweep).
double ProtocolDuration(const Protocol& protocol);

// Empty if rate_Hz resolves the protocol; otherwise the problem in one clause, e.g.
// "at 4 Hz the shorter part of a period (0.125 s at duty 0.5) is under 2 sample periods
// (0.2 s at 10 Hz); raise --rate-hz to at least 16 or leave 4 Hz out". Checked: every
// sweep frequency's shorter part of a period, and a random protocol's dwell_min, must last
// at least 2 sample periods. (Step, square, staircase and hold are not checked, as before.)
std::string SamplingProblem(const Protocol& protocol, double rate_Hz);

// Voltage applied at t_s (s from the start; zero-order hold: a change at time T is in
// force at T). A boundary within kBoundaryTolerance_s (relative to max(1, t)) counts as
// reached, so that a sample time k / rate computed in floating point sees a change that
// falls on it exactly. Before 0 s the actuator rests at 0 V; after the end the last
// segment's voltage holds.
double VoltageAt(const Protocol& protocol, double t_s);

inline constexpr double kBoundaryTolerance_s = 1e-9;

}  // namespace flexid::rig
