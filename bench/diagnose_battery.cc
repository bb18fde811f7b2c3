// The mismatch diagnosis (model/diagnose/diagnose.h) on fresh cases of the effect battery
// (tests/effect_battery.h: the independent T-S test plant with at most one concealed effect
// formulated otherwise than the diagnosis's catalogue, on a protocol drawn from a lab's
// usual set). Case i has the seed SEED + i; every sixth case (i = 5, 11, ...) is clean, the
// others cycle through the six effect classes. Effects at 2.5-9 times the sensor noise
// (--faint: 0.7-2 times).
//   Without a model: Diagnose(recording, none).
//   --with-model: the trusted model is the global T-S identification (identify_global.h) on
//   the plant's clean identification recordings (a 1-8-1 V staircase and 600 s of random
//   levels of both signs), as a lab identifies first and diagnoses a later recording.
// Prints one line per case (with a model also its RMS error against the plant alone,
// noise-free, on the diagnosed recording, in noise deviations: "model/s"), then the share named per
// class, the clean recordings flagged and the wall time. Without SEED the base seed is fresh on
// every run (printed; pass it to repeat a run).
//
//   build/bench/diagnose_battery [COUNT] [SEED] [--with-model] [--faint]   (COUNT 24)
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <map>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "effect_battery.h"
#include "model/core/simulate.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify_global.h"

namespace {

bool ParseUnsigned(const std::string& text, uint64_t* value) {
  if (text.empty() || text.size() > 20) return false;
  uint64_t result = 0;
  for (char c : text) {
    if (c < '0' || c > '9') return false;
    const auto digit = static_cast<uint64_t>(c - '0');
    if (result > (UINT64_MAX - digit) / 10) return false;
    result = result * 10 + digit;
  }
  *value = result;
  return true;
}

int Usage(const std::string& problem) {
  std::fprintf(stderr,
               "diagnose_battery: %s (usage: diagnose_battery [COUNT] [SEED] [--with-model] "
               "[--faint])\n",
               problem.c_str());
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace flexid;
  uint64_t count = 24;
  std::optional<uint64_t> base_seed;
  bool with_model = false, faint = false;
  int positional = 0;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--with-model") {
      with_model = true;
    } else if (arg == "--faint") {
      faint = true;
    } else if (arg == "-h" || arg == "--help") {
      std::printf("usage: diagnose_battery [COUNT] [SEED] [--with-model] [--faint]\n");
      return 0;
    } else if (!arg.empty() && arg[0] == '-') {
      return Usage("unknown option '" + arg + "'");
    } else if (positional == 0) {
      if (!ParseUnsigned(arg, &count) || count < 1 || count > 100000)
        return Usage("COUNT must be an integer from 1 to 100000, not '" + arg + "'");
      ++positional;
    } else if (positional == 1) {
      uint64_t seed = 0;
      if (!ParseUnsigned(arg, &seed))
        return Usage("SEED must be an unsigned 64-bit integer, not '" + arg + "'");
      base_seed = seed;
      ++positional;
    } else {
      return Usage("too many arguments ('" + arg + "')");
    }
  }
  if (!base_seed) {
    std::random_device device;
    base_seed = (static_cast<uint64_t>(device()) << 32 | device()) % 1000000000000ull;
  }
  const char* mode = with_model ? "with model" : "without model";
  std::printf("diagnose_battery: %llu cases from seed %llu, %s, effects at %s the noise\n",
              static_cast<unsigned long long>(count), static_cast<unsigned long long>(*base_seed),
              mode, faint ? "0.7-2 times" : "2.5-9 times");
  std::printf("%4s  %-14s %-10s %-24s %6s  %-24s %3s %7s %7s  %s\n", "case", "seed", "protocol",
              "effect", "ratio", "verdict", "ok", "model/s", "sec", "case drawn");
  std::fflush(stdout);

  const auto start = std::chrono::steady_clock::now();
  const std::vector<testing::BatteryEffect> classes = testing::BatteryEffectClasses();
  std::map<std::string, std::pair<int, int>> per_class;  // named, cases
  int named = 0, effects = 0, flagged = 0, clean = 0;
  double diagnose_s = 0.0, identify_s = 0.0;
  for (uint64_t i = 0; i < count; ++i) {
    const uint64_t seed = *base_seed + i;
    const testing::BatteryEffect effect =
        i % 6 == 5 ? testing::BatteryEffect::kNone : classes[static_cast<size_t>(i - i / 6) % 6];
    std::string verdict, protocol = "?", description;
    double ratio = 0.0, seconds = 0.0, model_error = NAN;
    try {
      const testing::BatteryCase battery_case = testing::DrawBatteryCase(seed, {effect, faint});
      protocol = battery_case.protocol.name;
      ratio = battery_case.ratio;
      description = battery_case.description;
      std::optional<model::TsModel> trusted;
      if (with_model) {
        const auto identify_start = std::chrono::steady_clock::now();
        trusted = model::IdentifyGlobalTs(testing::RecordBatteryIdentification(battery_case)).model;
        identify_s +=
            std::chrono::duration<double>(std::chrono::steady_clock::now() - identify_start)
                .count();
        const std::vector<double> predicted =
            model::Simulate(*trusted, battery_case.recording.t_s, battery_case.recording.voltage_V);
        double squares = 0.0;
        for (size_t k = 0; k < predicted.size(); ++k)
          squares +=
              (predicted[k] - battery_case.plant_mm[k]) * (predicted[k] - battery_case.plant_mm[k]);
        model_error = std::sqrt(squares / static_cast<double>(predicted.size())) /
                      battery_case.plant.noise_std_mm;
      }
      const auto diagnose_start = std::chrono::steady_clock::now();
      verdict = model::Diagnose(battery_case.recording, trusted).verdict;
      seconds =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - diagnose_start).count();
      diagnose_s += seconds;
    } catch (const std::exception& error) {
      verdict = std::string("exception: ") + error.what();
    }
    const std::string name = testing::BatteryEffectName(effect);
    const bool ok = verdict == name;
    if (effect == testing::BatteryEffect::kNone) {
      ++clean;
      flagged += !ok;
    } else {
      ++effects;
      named += ok;
      per_class[name].first += ok;
      ++per_class[name].second;
    }
    std::printf("%4llu  %-14llu %-10s %-24s %6.2f  %-24s %3s %7.2f %7.2f  %s\n",
                static_cast<unsigned long long>(i), static_cast<unsigned long long>(seed),
                protocol.c_str(), name.c_str(), ratio, verdict.c_str(), ok ? "yes" : "NO",
                model_error, seconds, description.c_str());
    std::fflush(stdout);
  }
  const double wall_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::string summary =
      std::string(mode) + ": named " + std::to_string(named) + "/" + std::to_string(effects);
  if (effects > 0) summary += " (" + std::to_string(100 * named / effects) + " %)";
  summary +=
      ", clean flagged " + std::to_string(flagged) + "/" + std::to_string(clean) + "; per class:";
  bool first = true;
  for (testing::BatteryEffect effect : classes) {
    const auto found = per_class.find(testing::BatteryEffectName(effect));
    if (found == per_class.end()) continue;
    summary += std::string(first ? " " : ", ") + found->first + " " +
               std::to_string(found->second.first) + "/" + std::to_string(found->second.second);
    first = false;
  }
  std::printf("%s\n", summary.c_str());
  std::printf("wall time %.1f s (%.2f s per case: diagnosis %.2f s", wall_s,
              wall_s / static_cast<double>(count), diagnose_s / static_cast<double>(count));
  if (with_model) std::printf(", identification %.2f s", identify_s / static_cast<double>(count));
  std::printf(")\n");
  return 0;
}
