#include "clients/rig/protocol.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <numbers>
#include <optional>
#include <random>
#include <sstream>
#include <string>

#include "clients/rig/spec.h"
#include "model/core/errors.h"

namespace flexid::rig {
namespace {

// SpecReader reads numbers only; a word-valued KEY is taken out of a copy of the
// specification here and its value returned (nullopt if absent). The caller asks the reader
// for KEY on the copy all the same, so that an unknown-key message lists it.
std::optional<std::string> TakeWord(Spec* spec, const std::string& key) {
  for (auto it = spec->params.begin(); it != spec->params.end(); ++it) {
    if (it->first != key) continue;
    std::string value = it->second;
    spec->params.erase(it);
    return value;
  }
  return std::nullopt;
}

// The sweep's frequency F_i (Hz) is played from SweepStart_s(i) for cycles / F_i s; the
// periods and segment lengths are computed here only, so that ProtocolDuration and
// VoltageAt agree to the last bit.
double SweepPeriod_s(double frequency_Hz) { return 1.0 / frequency_Hz; }
double SweepSegment_s(const Protocol& protocol, double frequency_Hz) {
  return static_cast<double>(protocol.cycles) * SweepPeriod_s(frequency_Hz);
}

// Level of a square wave with `cycles` periods of period_s starting at level_V for duty *
// period_s, at phase t_s >= 0 from its start (later than the end: the last period's).
double SquareWaveAt(double t_s, double level_V, double period_s, double duty, int64_t cycles,
                    bool alternate_polarity) {
  const double last_period = static_cast<double>(cycles - 1);
  const double period = std::min(std::floor(t_s / period_s), last_period);
  const double phase_s = t_s - period * period_s;
  if (phase_s >= duty * period_s) return 0.0;
  const bool negative = alternate_polarity && std::fmod(period, 2.0) == 1.0;
  return negative ? -level_V : level_V;
}

std::string Format(double value) {
  std::ostringstream text;
  text << value;
  return text.str();
}

}  // namespace

std::vector<Protocol::Dwell> RandomSchedule(const Protocol& protocol) {
  std::mt19937_64 generator(protocol.seed);
  const auto n = static_cast<uint64_t>(protocol.levels_V.size());
  const uint64_t threshold = (0 - n) % n;  // 2^64 mod n
  constexpr double kTwoToMinus53 = 1.0 / 9007199254740992.0;
  std::vector<Protocol::Dwell> dwells;
  double start_s = 0.0;
  while (start_s < protocol.duration_s) {
    uint64_t r = generator();
    while (r < threshold) r = generator();
    const double level_V = protocol.levels_V[static_cast<size_t>(r % n)];
    const double u = static_cast<double>(generator() >> 11) * kTwoToMinus53;
    dwells.push_back({start_s, level_V});
    start_s += protocol.dwell_min_s + u * (protocol.dwell_max_s - protocol.dwell_min_s);
  }
  return dwells;
}

Protocol ParseProtocol(std::string_view text) {
  Spec spec = Spec::Parse(text, "protocol");
  const std::optional<std::string> polarity =
      spec.name == "square" ? TakeWord(&spec, "polarity") : std::nullopt;
  SpecReader reader(spec);
  Protocol protocol;
  protocol.text = spec.text;
  if (spec.name == "step") {
    protocol.shape = Protocol::Shape::kStep;
    protocol.level_V = reader.Required("level", reader.Number("level"));
    protocol.duration_s = reader.Required("duration", reader.Positive("duration", "s"));
    protocol.delay_s = reader.NonNegative("delay", "s").value_or(0.0);
  } else if (spec.name == "square") {
    protocol.shape = Protocol::Shape::kSquare;
    protocol.level_V = reader.Required("level", reader.Number("level"));
    protocol.period_s = reader.Required("period", reader.Positive("period", "s"));
    protocol.duty = reader.InRange("duty", 0.0, 1.0, /*include_ends=*/false).value_or(0.5);
    protocol.cycles = reader.Required("cycles", reader.Count("cycles"));
    reader.Number("polarity");  // taken out above: names the key for RejectUnknownKeys
    if (polarity && *polarity != "same" && *polarity != "alternate")
      spec.Fail("polarity must be same or alternate (got \"" + *polarity + "\")");
    protocol.alternate_polarity = polarity == "alternate";
  } else if (spec.name == "staircase") {
    protocol.shape = Protocol::Shape::kStaircase;
    protocol.levels_V = reader.Required("levels", reader.NumberList("levels"));
    protocol.dwell_s = reader.Required("dwell", reader.Positive("dwell", "s"));
  } else if (spec.name == "hold") {
    protocol.shape = Protocol::Shape::kHold;
    protocol.level_V = reader.Required("level", reader.Number("level"));
    protocol.duration_s = reader.Required("duration", reader.Positive("duration", "s"));
  } else if (spec.name == "sweep") {
    protocol.shape = Protocol::Shape::kSweep;
    protocol.level_V = reader.Required("level", reader.Number("level"));
    protocol.frequencies_Hz = reader.NumberList("frequencies").value_or(kSeedSweepFrequencies_Hz);
    for (const double frequency_Hz : protocol.frequencies_Hz)
      if (!(frequency_Hz > 0.0))
        spec.Fail("frequencies must all be > 0 Hz (got " + Format(frequency_Hz) + ")");
    protocol.cycles = reader.Count("cycles").value_or(kDefaultSweepCycles);
    protocol.duty = reader.InRange("duty", 0.0, 1.0, /*include_ends=*/false).value_or(0.5);
  } else if (spec.name == "sine") {
    protocol.shape = Protocol::Shape::kSine;
    protocol.level_V = reader.Number("level").value_or(0.0);
    protocol.amplitude_V = reader.Required("amplitude", reader.Number("amplitude"));
    protocol.frequency_Hz = reader.Required("frequency", reader.Positive("frequency", "Hz"));
    protocol.duration_s = reader.Required("duration", reader.Positive("duration", "s"));
  } else if (spec.name == "random") {
    protocol.shape = Protocol::Shape::kRandom;
    protocol.levels_V = reader.Required("levels", reader.NumberList("levels"));
    protocol.dwell_min_s = reader.Required("dwell_min", reader.Positive("dwell_min", "s"));
    protocol.dwell_max_s = reader.Required("dwell_max", reader.Positive("dwell_max", "s"));
    protocol.duration_s = reader.Required("duration", reader.Positive("duration", "s"));
    protocol.seed = reader.WholeNumber("seed").value_or(1);
    if (protocol.dwell_max_s < protocol.dwell_min_s)
      spec.Fail("dwell_max must be >= dwell_min (got " + Format(protocol.dwell_max_s) + " < " +
                Format(protocol.dwell_min_s) + ")");
  } else {
    spec.Fail("unknown protocol \"" + spec.name +
              "\" (expected step, square, staircase, hold, sweep, sine or random)");
  }
  reader.RejectUnknownKeys();
  if (!std::isfinite(ProtocolDuration(protocol))) spec.Fail("the protocol is too long");
  if (protocol.shape == Protocol::Shape::kRandom) {
    // Checked before the schedule is built: at most duration / dwell_min + 1 dwells.
    if (!(protocol.duration_s / protocol.dwell_min_s < static_cast<double>(kMaxRandomDwells)))
      spec.Fail("duration / dwell_min must be < " + std::to_string(kMaxRandomDwells) +
                " (the schedule is computed in advance)");
    protocol.dwells = RandomSchedule(protocol);
  }
  return protocol;
}

double ProtocolDuration(const Protocol& protocol) {
  switch (protocol.shape) {
    case Protocol::Shape::kStep:
      return protocol.delay_s + protocol.duration_s;
    case Protocol::Shape::kSquare:
      return static_cast<double>(protocol.cycles) * protocol.period_s;
    case Protocol::Shape::kStaircase:
      return static_cast<double>(protocol.levels_V.size() + 1) * protocol.dwell_s;
    case Protocol::Shape::kHold:
    case Protocol::Shape::kSine:
    case Protocol::Shape::kRandom:
      return protocol.duration_s;
    case Protocol::Shape::kSweep: {
      double total_s = 0.0;
      for (const double frequency_Hz : protocol.frequencies_Hz)
        total_s += SweepSegment_s(protocol, frequency_Hz);
      return total_s;
    }
  }
  return 0.0;
}

std::string SamplingProblem(const Protocol& protocol, double rate_Hz) {
  const double two_samples_s = 2.0 / rate_Hz;
  std::ostringstream problem;
  if (protocol.shape == Protocol::Shape::kSweep) {
    const double shorter_share = std::min(protocol.duty, 1.0 - protocol.duty);
    for (const double frequency_Hz : protocol.frequencies_Hz) {
      const double shorter_s = shorter_share * SweepPeriod_s(frequency_Hz);
      // The tolerance keeps an exact fit (duty 0.8 at 1 Hz and 10 Hz: 1 - 0.8 is
      // 0.19999999999999996) from failing by rounding.
      if (shorter_s >= two_samples_s * (1.0 - 1e-9)) continue;
      problem << "at " << frequency_Hz << " Hz the shorter part of a period (" << shorter_s
              << " s at duty " << protocol.duty << ") is under 2 sample periods (" << two_samples_s
              << " s at " << rate_Hz << " Hz); raise --rate-hz to at least "
              << 2.0 * frequency_Hz / shorter_share << " or leave " << frequency_Hz << " Hz out";
      return problem.str();
    }
  }
  if (protocol.shape == Protocol::Shape::kSine &&
      1.0 / protocol.frequency_Hz < 2.0 * two_samples_s * (1.0 - 1e-9)) {
    problem << "at " << protocol.frequency_Hz << " Hz a period (" << 1.0 / protocol.frequency_Hz
            << " s) is under 4 sample periods (" << 2.0 * two_samples_s << " s at " << rate_Hz
            << " Hz); raise --rate-hz to at least " << 4.0 * protocol.frequency_Hz;
    return problem.str();
  }
  if (protocol.shape == Protocol::Shape::kRandom &&
      protocol.dwell_min_s < two_samples_s * (1.0 - 1e-9)) {
    problem << "dwell_min (" << protocol.dwell_min_s << " s) is under 2 sample periods ("
            << two_samples_s << " s at " << rate_Hz << " Hz); raise --rate-hz to at least "
            << 2.0 / protocol.dwell_min_s << " or lengthen dwell_min";
    return problem.str();
  }
  return "";
}

double VoltageAt(const Protocol& protocol, double t_s) {
  // Shifting t forward by the tolerance makes "t >= boundary" true for a boundary that t
  // misses by rounding.
  const double t = t_s + kBoundaryTolerance_s * std::max(1.0, std::abs(t_s));
  if (t < 0.0) return 0.0;
  switch (protocol.shape) {
    case Protocol::Shape::kStep:
      return t < protocol.delay_s ? 0.0 : protocol.level_V;
    case Protocol::Shape::kSquare:
      return SquareWaveAt(t, protocol.level_V, protocol.period_s, protocol.duty, protocol.cycles,
                          protocol.alternate_polarity);
    case Protocol::Shape::kStaircase: {
      const double step = std::floor(t / protocol.dwell_s);
      return step < static_cast<double>(protocol.levels_V.size())
                 ? protocol.levels_V[static_cast<size_t>(step)]
                 : 0.0;
    }
    case Protocol::Shape::kHold:
      return protocol.level_V;
    case Protocol::Shape::kSine:  // t_s itself: a sine has no boundaries to round to
      return protocol.level_V +
             protocol.amplitude_V * std::sin(2.0 * std::numbers::pi * protocol.frequency_Hz * t_s);
    case Protocol::Shape::kSweep: {
      // The segment t falls in (after the end: the last one, which ends at 0 V).
      double start_s = 0.0;
      for (size_t i = 0; i < protocol.frequencies_Hz.size(); ++i) {
        const double frequency_Hz = protocol.frequencies_Hz[i];
        const double end_s = start_s + SweepSegment_s(protocol, frequency_Hz);
        if (t < end_s || i + 1 == protocol.frequencies_Hz.size())
          return SquareWaveAt(t - start_s, protocol.level_V, SweepPeriod_s(frequency_Hz),
                              protocol.duty, protocol.cycles, /*alternate_polarity=*/false);
        start_s = end_s;
      }
      return 0.0;
    }
    case Protocol::Shape::kRandom: {
      // The last dwell starting at or before t.
      const auto after = std::upper_bound(
          protocol.dwells.begin(), protocol.dwells.end(), t,
          [](double time_s, const Protocol::Dwell& dwell) { return time_s < dwell.start_s; });
      return after == protocol.dwells.begin() ? 0.0 : std::prev(after)->level_V;
    }
  }
  return 0.0;
}

}  // namespace flexid::rig
