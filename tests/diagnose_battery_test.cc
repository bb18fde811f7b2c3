// The mismatch diagnosis (model/diagnose/diagnose.h) on the effect battery (effect_battery.h): the
// independent T-S test plant with one concealed effect formulated otherwise than the
// diagnosis's catalogue (two relaxation time constants, a random-walk or delayed thermal
// drift, a Preisach model, a square-root-of-charge wear, current-limited electrolysis, a
// lagged negative polarity), at 2.5-9 times the sensor noise, on a protocol drawn from a
// lab's usual set; or no effect.
//
// The project's goals:
//   - without a model, Diagnose(recording, none): at least 90 % of the effects named
//     (verdict == the effect's name), at most 1 clean recording in 8 flagged;
//   - with a model, the trusted model being the global T-S identification
//     (identify_global.h) on the same plant's clean identification recordings (a 1-8-1 V
//     staircase, 120 s per level, and 600 s of random levels of both signs), as a lab
//     identifies first and diagnoses a later recording: at least 95 % named, no false alarm.
// 24 recordings each way (20 effects, 4 or 3 of each class in BatteryEffectClasses order,
// and 4 clean). The effect recordings are held to the goal together (90 % of 20 is 18, 95 %
// is 19); 1 in 8 of 4 clean recordings is 0.5, so none may be flagged.
//
// The seeds were drawn once from /dev/urandom when this test was written, before any of
// them was run, and are not to be changed or selected. Groups that do not meet the goals
// yet are named KnownGap... and registered WILL_FAIL (tests/CMakeLists.txt), as the
// project does for its other known gaps, so that they run in every build and show when the
// diagnosis reaches the goal: then they "fail", and the KnownGap prefix goes.
//
// Measured (the tables each test prints), with the diagnosis of this commit:
//   without a model: 12 of 20 named (back_relaxation 1/4, sensor_drift 4/4, hysteresis 2/3,
//     cycle_degradation 3/3, electrolysis_saturation 0/3, polarity_asymmetry 2/3), 0 of 4
//     clean recordings flagged (11 of 20 while the baseline's refits could fall back).
//     Back-relaxation with two time constants is mostly read as drift or missed;
//     saturation is missed on every draw (two of the three on a single level, where
//     without a model it is a gain; the diagnosis does not try it there).
//   with the identified model: 14 of 20 named, 1 of 4 clean recordings flagged (11 of 20
//     before the catalogue's degradation got an exponent on the charge and kept the rules
//     on the applied voltage; 8 of 20 and 2 of 4 while the identification left one
//     recording out, 5 of 20 before its few-rules stage tried both realisations). The
//     identified model's RMS error against the plant alone on the diagnosed recording
//     ("model/s" in the table) is within 1.5 noise deviations on 19 of the 24 recordings
//     (13 before), and 15 of those 19 are diagnosed right; elsewhere it is 1.6-16
//     deviations off, on voltages between the identification recordings' whole-volt
//     levels. With the model within 0.4 deviations two drifts are read as back-relaxation
//     and one lagged polarity is not named. (Every wear was missed, 3 of 3, as hysteresis
//     or back-relaxation, while the degradation also moved the rules' premise: their sharp
//     hand-over sits on a visited level, so a few per cent off the voltage predicted
//     quite another deflection.)
//   bench/diagnose_battery on fresh draws: without a model 13 of 20 named, 1 of 4 clean
//     recordings flagged (seed 834099763815: a step read as hysteresis), and 9 of 20, 1 of
//     4 (seed 737836793372: random levels read as a dead zone), so the clean group passing
//     is not yet the goal met.
// Diagnose takes 1-6 s per recording without a model (up to 25 s on 1000 s of bipolar
// levels), 1 s with one; the identification 4-18 s.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <exception>
#include <optional>
#include <string>
#include <vector>

#include "effect_battery.h"
#include "model/core/simulate.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify_global.h"

namespace flexid::testing {
namespace {

// Drawn from /dev/urandom once (see the file header).
constexpr uint64_t kWithoutModelEffectSeeds[20] = {
    225237679384, 157079970376, 335847382003, 416317393451, 833971275850,
    30153536894,  274869808868, 302706762393, 332562052654, 457244923149,
    349939573911, 224802012426, 639436711393, 816688509502, 887980467876,
    776836130104, 595649782567, 758640958386, 331921297629, 83526853370};
constexpr uint64_t kWithoutModelCleanSeeds[4] = {995013235950, 73935040208, 612806475504,
                                                 959770334861};
constexpr uint64_t kWithModelEffectSeeds[20] = {
    324881733448, 826200427143, 186836195315, 299352635663, 714790328655,
    705743490777, 827932196213, 950339451544, 611590730562, 553122424194,
    708007901329, 111885471108, 793715271523, 348342144913, 114770098957,
    932950276638, 328672173389, 905026992724, 821486244450, 759957618355};
constexpr uint64_t kWithModelCleanSeeds[4] = {755583549676, 770345188266, 140262061553,
                                              23477610079};

struct Outcome {
  uint64_t seed = 0;
  std::string protocol;
  std::string effect;
  double ratio = 0.0;
  std::string verdict;
  double identify_s = 0.0;
  double diagnose_s = 0.0;
  // With a model: its RMS error against the plant alone (noise-free) on the diagnosed
  // recording, in noise deviations: what the trusted model itself gets wrong.
  double model_error = 0.0;
  std::string description;
  bool Named() const { return verdict == effect; }
};

double ModelError(const model::TsModel& trusted, const BatteryCase& battery_case) {
  const std::vector<double> predicted =
      model::Simulate(trusted, battery_case.recording.t_s, battery_case.recording.voltage_V);
  double squares = 0.0;
  for (size_t k = 0; k < predicted.size(); ++k)
    squares +=
        (predicted[k] - battery_case.plant_mm[k]) * (predicted[k] - battery_case.plant_mm[k]);
  return std::sqrt(squares / static_cast<double>(predicted.size())) /
         battery_case.plant.noise_std_mm;
}

// Draws the case, identifies the trusted model if asked, diagnoses. An exception becomes
// the verdict's text, so that the table shows every case.
Outcome RunCase(uint64_t seed, BatteryEffect effect, bool with_model) {
  Outcome outcome;
  outcome.seed = seed;
  outcome.effect = BatteryEffectName(effect);
  try {
    const BatteryCase battery_case = DrawBatteryCase(seed, {.effect = effect});
    outcome.protocol = battery_case.protocol.name;
    outcome.ratio = battery_case.ratio;
    outcome.description = battery_case.description;
    std::optional<model::TsModel> trusted;
    if (with_model) {
      const auto start = std::chrono::steady_clock::now();
      trusted = model::IdentifyGlobalTs(RecordBatteryIdentification(battery_case)).model;
      outcome.identify_s =
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      outcome.model_error = ModelError(*trusted, battery_case);
    }
    const auto start = std::chrono::steady_clock::now();
    outcome.verdict = model::Diagnose(battery_case.recording, trusted).verdict;
    outcome.diagnose_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  } catch (const std::exception& error) {
    outcome.verdict = std::string("exception: ") + error.what();
  }
  return outcome;
}

void PrintTable(const std::string& title, const std::vector<Outcome>& outcomes) {
  std::printf("\n%s\n%4s  %-13s %-10s %-24s %6s  %-24s %3s %7s %7s %7s  %s\n", title.c_str(),
              "case", "seed", "protocol", "effect", "ratio", "verdict", "ok", "model/s", "ident s",
              "diag s", "case drawn");
  for (size_t i = 0; i < outcomes.size(); ++i) {
    const Outcome& o = outcomes[i];
    std::printf("%4zu  %-13llu %-10s %-24s %6.2f  %-24s %3s %7.2f %7.2f %7.2f  %s\n", i,
                static_cast<unsigned long long>(o.seed), o.protocol.c_str(), o.effect.c_str(),
                o.ratio, o.verdict.c_str(), o.Named() ? "yes" : "NO", o.model_error, o.identify_s,
                o.diagnose_s, o.description.c_str());
  }
  std::fflush(stdout);
}

// Effect recordings first..first+count-1 of the 20 (class = index mod 6), held to the goal.
void ExpectEffectsNamed(const uint64_t (&seeds)[20], size_t first, size_t count, bool with_model) {
  const std::vector<BatteryEffect> classes = BatteryEffectClasses();
  std::vector<Outcome> outcomes;
  for (size_t i = first; i < first + count; ++i)
    outcomes.push_back(RunCase(seeds[i], classes[i % classes.size()], with_model));
  const std::string mode = with_model ? "with the identified model" : "without a model";
  PrintTable("Effect battery, " + mode + ": effects " + std::to_string(first) + "-" +
                 std::to_string(first + count - 1),
             outcomes);
  const auto named =
      std::count_if(outcomes.begin(), outcomes.end(), [](const Outcome& o) { return o.Named(); });
  const double goal = with_model ? 0.95 : 0.90;
  std::printf("named %ld of %zu (goal %.0f %%)\n", static_cast<long>(named), count, 100 * goal);
  EXPECT_GE(static_cast<double>(named), goal * static_cast<double>(count))
      << mode << ": named " << named << " of " << count;
}

void ExpectCleanNotFlagged(const uint64_t (&seeds)[4], bool with_model) {
  std::vector<Outcome> outcomes;
  for (uint64_t seed : seeds) outcomes.push_back(RunCase(seed, BatteryEffect::kNone, with_model));
  const std::string mode = with_model ? "with the identified model" : "without a model";
  PrintTable("Effect battery, " + mode + ": clean recordings", outcomes);
  const auto flagged =
      std::count_if(outcomes.begin(), outcomes.end(), [](const Outcome& o) { return !o.Named(); });
  std::printf("flagged %ld of %zu\n", static_cast<long>(flagged), outcomes.size());
  if (with_model) {
    EXPECT_EQ(flagged, 0) << "no clean recording may be flagged with the trusted model";
  } else {
    EXPECT_LE(8 * flagged, static_cast<long>(outcomes.size()))
        << "at most 1 clean recording in 8 may be flagged without a model";
  }
}

// The goals hold for the whole set of 20 effect recordings each way (the issue's
// criterion), not for each handful: 18 of 20 without a model, 19 of 20 with one.
TEST(DiagnoseBattery, KnownGapWithoutModelNamesNineInTen) {
  ExpectEffectsNamed(kWithoutModelEffectSeeds, 0, 20, false);
}
TEST(DiagnoseBattery, WithoutModelCleanRecordings) {
  ExpectCleanNotFlagged(kWithoutModelCleanSeeds, false);
}
TEST(DiagnoseBattery, KnownGapWithModelNamesNineteenInTwenty) {
  ExpectEffectsNamed(kWithModelEffectSeeds, 0, 20, true);
}
TEST(DiagnoseBattery, KnownGapWithModelCleanRecordings) {
  ExpectCleanNotFlagged(kWithModelCleanSeeds, true);
}

// A clean 1.2-5.8 V staircase up and down on a 3-rule plant (seed drawn by
// bench/diagnose_battery): with one set of dynamics, no gain per level switches plausibly
// (the jump from 1.2 to 2.3 V swings beyond both levels' frozen models), and the baseline's
// identification used to end there with "no structure could be fitted". Its pilot is now one
// linear model, and the rules stage offers smooth rules against it.
TEST(DiagnoseBattery, AStaircaseWhosePilotCannotSwitchStillGetsABaseline) {
  const BatteryCase battery_case = DrawBatteryCase(212747392653, {.effect = BatteryEffect::kNone});
  ASSERT_EQ(battery_case.protocol.name, "stairs-ud");
  const model::Diagnosis diagnosis = model::Diagnose(battery_case.recording, std::nullopt);
  bool linear_pilot = false;
  for (const std::string& note : diagnosis.notes)
    linear_pilot |= note.find("one linear pilot instead") != std::string::npos;
  EXPECT_TRUE(linear_pilot) << "the pilot with a gain per level switched plausibly after all";
  EXPECT_EQ(diagnosis.verdict, "none");
}

// A square wave of 2.5 V and 0 V, then -2.5 V, with a 0.37 back-relaxation (seed drawn by
// bench/diagnose_battery). The baseline's refit on every sample after the structure was
// chosen on a coarser grid fell back 17 %, the model of one more pole and zero 22 %, and
// every candidate's refit was free to as well: back-relaxation was absorbed and the
// diagnosis said "none". Every one of them is now held to the physics chain's prior.
TEST(DiagnoseBattery, EveryRefitOfTheBaselineIsHeldToThePrior) {
  const BatteryCase battery_case =
      DrawBatteryCase(331921297629, {.effect = BatteryEffect::kBackRelaxation});
  ASSERT_EQ(battery_case.protocol.name, "square+0-0");
  const model::Diagnosis diagnosis = model::Diagnose(battery_case.recording, std::nullopt);
  for (const model::LocalModel& rule : diagnosis.baseline_model.rules)
    EXPECT_LE(model::StepFallBack(rule.tf).share, 0.0101);
  for (const model::LocalModel& rule : diagnosis.augmented_baseline_model.rules)
    EXPECT_LE(model::StepFallBack(rule.tf).share, 0.0101);
  EXPECT_EQ(diagnosis.verdict, "back_relaxation");
}

// Random levels with a delayed warm-up drift (seed drawn by bench/diagnose_battery): every
// pilot fell back a little (2.5 %), and the diagnosis ended with "no baseline could be
// identified". Now the baseline is identified without the prior, in a note.
TEST(DiagnoseBattery, NoStructureMeetsThePriorStillGetsADiagnosis) {
  const BatteryCase battery_case =
      DrawBatteryCase(294763963681, {.effect = BatteryEffect::kSensorDrift});
  const model::Diagnosis diagnosis = model::Diagnose(battery_case.recording, std::nullopt);
  bool without_prior = false;
  for (const std::string& note : diagnosis.notes)
    without_prior |= note.find("identified without the physics chain's prior") != std::string::npos;
  EXPECT_TRUE(without_prior) << "a structure met the prior after all";
  EXPECT_FALSE(diagnosis.baseline_model.rules.empty());
}

}  // namespace
}  // namespace flexid::testing
