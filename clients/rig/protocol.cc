#include "clients/rig/protocol.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <string>

#include "clients/rig/spec.h"
#include "model/errors.h"

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

}  // namespace

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
  } else {
    spec.Fail("unknown protocol \"" + spec.name + "\" (expected step, square, staircase or hold)");
  }
  reader.RejectUnknownKeys();
  if (!std::isfinite(ProtocolDuration(protocol))) spec.Fail("the protocol is too long");
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
      return protocol.duration_s;
  }
  return 0.0;
}

double VoltageAt(const Protocol& protocol, double t_s) {
  // Shifting t forward by the tolerance makes "t >= boundary" true for a boundary that t
  // misses by rounding.
  const double t = t_s + kBoundaryTolerance_s * std::max(1.0, std::abs(t_s));
  if (t < 0.0) return 0.0;
  switch (protocol.shape) {
    case Protocol::Shape::kStep:
      return t < protocol.delay_s ? 0.0 : protocol.level_V;
    case Protocol::Shape::kSquare: {
      const double last_period = static_cast<double>(protocol.cycles - 1);
      const double period = std::min(std::floor(t / protocol.period_s), last_period);
      const double phase_s = t - period * protocol.period_s;
      if (phase_s >= protocol.duty * protocol.period_s) return 0.0;
      const bool negative = protocol.alternate_polarity && std::fmod(period, 2.0) == 1.0;
      return negative ? -protocol.level_V : protocol.level_V;
    }
    case Protocol::Shape::kStaircase: {
      const double step = std::floor(t / protocol.dwell_s);
      return step < static_cast<double>(protocol.levels_V.size())
                 ? protocol.levels_V[static_cast<size_t>(step)]
                 : 0.0;
    }
    case Protocol::Shape::kHold:
      return protocol.level_V;
  }
  return 0.0;
}

}  // namespace flexid::rig
