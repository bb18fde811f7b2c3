// The virtual actuator of flexid-rig: the sample stream of one run, independent of the
// bus (runner.h publishes it).
//
// Sample k is at t_k = k / rate_Hz seconds from the start, in message time
// utime_k = start_utime + round(k * 10^6 / rate_Hz) microseconds, whatever the playback
// speed. The stream is
//   voltage_V[k]     = VoltageAt(protocol, t_k)                               (protocol.h)
//   drive_V[k]       = the voltage after each effect's DriveVoltage             (effects.h)
//   model_mm         = SimulateUniform(model, 1 / rate_Hz, drive_V)  from rest  (simulate.h)
//   deflection_mm[k] = model_mm[k] through each effect's Deflection, in order,
//                      + noise_mm * N(0, 1)
// The model runs once over the whole protocol when the Rig is built (exact ZOH
// simulation, and an unstable model is reported before anything is published); effects
// and noise are applied sample by sample. The samples cover [0, ProtocolDuration): there
// are ceil(duration * rate_Hz) of them, at most kMaxRigSamples.
//
// Noise is white and Gaussian, from std::mt19937_64 seeded with `seed` and the Box-Muller
// transform written out here, so that a seed gives the same stream with any standard
// library.
//
// Several actuators (flexid-rig --actuator S1,S2): one Rig each, built by MakeActuatorRigs
// with the same model, protocol and options but their own effects and noise stream.
#pragma once

#include <cstdint>
#include <memory>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "clients/rig/effects.h"
#include "clients/rig/protocol.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::rig {

// 10^7 samples keep the precomputed run below 200 MB (e.g. 11.5 days at 10 Hz).
inline constexpr int64_t kMaxRigSamples = 10'000'000;
inline constexpr double kMaxRate_Hz = 1e6;  // utime (microseconds) must still increase

struct RigOptions {
  double rate_Hz = 10.0;          // samples per second of message time, (0, kMaxRate_Hz]
  int64_t start_utime = 0;        // utime of the first sample, microseconds, >= 0
  double noise_mm = 0.0;          // standard deviation of the sensor noise, mm, >= 0
  uint64_t seed = 1;              // of the noise generator
  double voltage_repeat_s = 1.0;  // the voltage is published at least this often, s (> 0)

  // On failure returns false and writes one sentence to *error.
  bool IsValid(std::string* error) const;
};

struct RigSample {
  int64_t index = 0;  // k
  int64_t utime = 0;  // message time, microseconds
  double t_s = 0.0;   // k / rate_Hz
  double voltage_V = 0.0;
  double deflection_mm = 0.0;
  bool voltage_changed = false;  // the first sample, or a voltage differing from the previous
  bool publish_voltage = false;  // voltage_changed, or voltage_repeat_s since the last time
};

// White Gaussian noise of the rig's sensor: std::mt19937_64 and the Box-Muller transform
// written out here, so that a seed gives the same values with any standard library.
class GaussianNoise {
 public:
  explicit GaussianNoise(uint64_t seed) : generator_(seed) {}
  double StandardNormal();

 private:
  std::mt19937_64 generator_;
  bool has_spare_ = false;
  double spare_ = 0.0;
};

class Rig {
 public:
  // Throws model::InputError for invalid options, a rate too low for the protocol
  // (SamplingProblem in protocol.h) or more than kMaxRigSamples samples,
  // std::runtime_error if the model's output is not finite (an unstable model), and
  // std::invalid_argument for an invalid model.
  Rig(const model::TsModel& model, Protocol protocol, std::vector<std::unique_ptr<Effect>> effects,
      const RigOptions& options);

  int64_t sample_count() const { return static_cast<int64_t>(voltage_V_.size()); }
  // The message time the samples cover, sample_count / rate_Hz, s.
  double duration_s() const;
  // utime of sample k; UtimeOf(sample_count()) is the end of the last sample's interval.
  int64_t UtimeOf(int64_t k) const;
  const Protocol& protocol() const { return protocol_; }
  const RigOptions& options() const { return options_; }

  // Moves the run in message time: sample 0 at start_utime (flexid-rig learns where to
  // start from flexidd only after its input is checked). Before the first Next() only;
  // throws model::InputError for a start the constructor would refuse.
  void SetStartUtime(int64_t start_utime);

  // Writes the next sample; false after the last one.
  bool Next(RigSample* sample);

 private:
  Protocol protocol_;
  std::vector<std::unique_ptr<Effect>> effects_;
  RigOptions options_;
  std::vector<double> voltage_V_;  // applied, per sample
  std::vector<double> model_mm_;   // the model's output, per sample
  int64_t next_ = 0;
  int64_t last_voltage_utime_ = 0;
  GaussianNoise noise_;
};

// An --effect of flexid-rig: "NAME[:k=v,...]" for every actuator, or "ID/NAME[:k=v,...]"
// for actuator ID only (the '/' is looked for before the first ':').
struct ActuatorEffect {
  std::string actuator_id;  // empty: every actuator
  std::string effect;       // NAME[:k=v,...], for ParseEffect
};
// Throws model::InputError for an empty ID ("effect \"/dead_zone\": empty actuator id
// before '/'").
ActuatorEffect ParseActuatorEffect(std::string_view text);

// One Rig per actuator id, in the order given, all with MODEL, PROTOCOL and OPTIONS except
// the noise seed: actuator i (from 0) gets options.seed + i (so a single actuator's stream
// is the one a plain Rig with options.seed gives). Each actuator gets its own instances of
// the effects meant for it (EFFECT_SPECS without an ID, and those with its ID), in the order
// given. Throws model::InputError for an effect whose ID is not among ACTUATOR_IDS, more
// than kMaxRigSamples samples over all actuators, and as ParseEffect and Rig.
std::vector<Rig> MakeActuatorRigs(const model::TsModel& model, const Protocol& protocol,
                                  const std::vector<std::string>& actuator_ids,
                                  const std::vector<std::string>& effect_specs,
                                  const RigOptions& options);

}  // namespace flexid::rig
