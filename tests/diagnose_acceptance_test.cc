// Acceptance test of the mismatch diagnosis (model/diagnose/diagnose.h), the criteria read
// literally, on recordings it has never seen from the independent lab (effect_plant.h):
//
//   "On recordings it has never seen, from an independent simulator, with one of the
//   effects above or none, concealed at 0.7 to 10 times the sensor noise (RMS over the
//   samples the effect touches): given the trusted model, the verdict names the right
//   effect in at least 19 of 20 cases, says none for every clean recording, and where the
//   effect is at least twice the noise the augmented model lowers held-out RMSE by at
//   least half (median); without a model, at least 3 of 4 are named and at most 1 in 4
//   clean recordings gets a false alarm. Recordings from a real voltage column are
//   sampled: handle a dead time that is not a whole number of samples, and do not mistake
//   the model's own small errors for an effect."
//
// Where the criteria leave a choice, the stricter reading is taken:
//   - "names the right effect": Diagnosis::verdict equals the simulated effect's name;
//     back_relaxation and creep count as different effects.
//   - held-out criterion: every case with effect-to-noise ratio >= 2 enters the median;
//     a case whose verdict is wrong or "none" enters with after/before = 1 (no credit for
//     an augmentation by the wrong effect); for an even count the upper median is used.
//   - the trusted model is exactly the lab's plant (the seed's 8 V model), so the model's
//     "own small errors" are those of predicting from the sampled voltage column: steps
//     between samples, the slew the column does not resolve, 1 mV voltage noise, and a
//     dead time of 3.67 s = 36.7 samples. Without a model, the lab's dead time is 1.2 s
//     plus a random fraction of a sample.
//
// Seeds of the first sets were chosen once, before the diagnosis existed; later sets were
// added as the diagnosis changed (see below). None is to be tuned.
#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <exception>
#include <optional>
#include <string>
#include <vector>

#include "effect_plant.h"
#include "model/core/presets.h"
#include "model/core/ts_fuzzy.h"
#include "model/diagnose/diagnose.h"

namespace flexid::testing {
namespace {

constexpr double kNoiseStd_mm = 0.02;

// The protocols: a 5 V square wave (period 220 s, duty 0.5, 5 cycles, ~1100 s at
// 10 Hz), the same alternating in polarity, and a 2-4-6-8 V staircase (150 s per level,
// then 150 s at rest).
const SquareWave kSquare{5.0, 220.0, 0.5, 5, false};
const SquareWave kAlternatingSquare{5.0, 220.0, 0.5, 5, true};
const Staircase kStaircase{{2.0, 4.0, 6.0, 8.0}, 150.0, 150.0};

// The protocol on which an effect can show: polarity asymmetry needs both polarities,
// saturation and dead zone need several levels; the rest show on the square wave.
Protocol ProtocolFor(LabEffect effect) {
  switch (effect) {
    case LabEffect::kPolarityAsymmetry:
      return kAlternatingSquare;
    case LabEffect::kElectrolysisSaturation:
    case LabEffect::kDeadZone:
      return kStaircase;
    default:
      return kSquare;
  }
}

struct CaseResult {
  int index = 0;
  std::string protocol;
  LabEffect effect = LabEffect::kNone;
  double ratio = 0.0;  // effect-to-noise ratio reached (0 for a clean recording)
  double amplitude = 0.0;
  std::string verdict;
  double heldout_before_mm = 0.0;  // the verdict's finding (baseline's when none)
  double heldout_after_mm = 0.0;
  double noise_estimate_mm = 0.0;
  double seconds = 0.0;
  std::string more;  // further findings and what a free fit absorbed (information only)

  bool Correct() const { return verdict == LabEffectName(effect); }
  // after / before of the verdict's finding; 1 when the verdict is wrong or none.
  double HeldoutRatio() const {
    if (!Correct() || effect == LabEffect::kNone || heldout_before_mm <= 0.0) return 1.0;
    return heldout_after_mm / heldout_before_mm;
  }
};

// Simulates one recording (effect scaled to target_ratio unless kNone), diagnoses it and
// records the outcome. Exceptions from Diagnose become the verdict text, so that the
// table still shows every case.
CaseResult RunCase(int index, const Protocol& protocol, const model::TransferFunction& plant,
                   LabEffect effect, double target_ratio, uint64_t seed, const RunOptions& options,
                   const std::optional<model::TsModel>& trusted_model) {
  CaseResult result;
  result.index = index;
  result.protocol = ProtocolName(protocol);
  result.effect = effect;
  LabRun run = MakeRun(protocol, plant, effect, seed, options);
  if (effect != LabEffect::kNone) result.ratio = ScaleEffectToNoise(&run, target_ratio);
  result.amplitude = run.effect.amplitude;
  const model::Recording recording = Record(run);
  const auto start = std::chrono::steady_clock::now();
  try {
    const model::Diagnosis diagnosis = model::Diagnose(recording, trusted_model);
    result.verdict = diagnosis.verdict;
    result.noise_estimate_mm = diagnosis.noise_std_mm;
    result.heldout_before_mm = diagnosis.baseline_heldout_rmse_mm;
    result.heldout_after_mm = diagnosis.baseline_heldout_rmse_mm;
    if (!diagnosis.findings.empty()) {
      result.heldout_before_mm = diagnosis.findings.front().heldout_rmse_before_mm;
      result.heldout_after_mm = diagnosis.findings.front().heldout_rmse_after_mm;
    }
    for (size_t i = 1; i < diagnosis.findings.size(); ++i)
      result.more += "+" + diagnosis.findings[i].effect + " ";
    for (const model::Absorbed& absorbed : diagnosis.absorbed)
      result.more += "absorbed:" + absorbed.effect + " ";
  } catch (const std::exception& error) {
    result.verdict = std::string("exception: ") + error.what();
  }
  result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return result;
}

void PrintTable(const char* title, const std::vector<CaseResult>& results) {
  std::printf("\n%s (noise std %.3f mm)\n", title, kNoiseStd_mm);
  std::printf("%4s  %-10s %-24s %7s %10s  %-24s %3s %10s %10s %6s %8s %6s  %s\n", "case",
              "protocol", "effect", "ratio", "amplitude", "verdict", "ok", "before_mm", "after_mm",
              "after/", "noise_mm", "sec", "more");
  for (const CaseResult& r : results)
    std::printf("%4d  %-10s %-24s %7.3f %10.3g  %-24s %3s %10.5f %10.5f %6.3f %8.5f %6.2f  %s\n",
                r.index, r.protocol.c_str(), LabEffectName(r.effect), r.ratio, r.amplitude,
                r.verdict.c_str(), r.Correct() ? "yes" : "NO", r.heldout_before_mm,
                r.heldout_after_mm, r.HeldoutRatio(), r.noise_estimate_mm, r.seconds,
                r.more.c_str());
  std::fflush(stdout);
}

int CountCorrect(const std::vector<CaseResult>& results) {
  return static_cast<int>(std::count_if(results.begin(), results.end(),
                                        [](const CaseResult& r) { return r.Correct(); }));
}

model::TsModel TrustedModel() {
  // The trusted model is the lab's plant: the seed's 8 V model, as a single-rule T-S model.
  const model::TransferFunction seed = model::SeedModel8V();
  const model::TransferFunction plant = LabSeedPlant8V();
  EXPECT_EQ(seed.num, plant.num);
  EXPECT_EQ(seed.den, plant.den);
  EXPECT_EQ(seed.delay_s, plant.delay_s);
  return model::SingleRule(seed);
}

RunOptions WithModelOptions() { return RunOptions{.noise_std_mm = kNoiseStd_mm}; }
RunOptions WithoutModelOptions() {
  return RunOptions{.fractional_delay = true, .noise_std_mm = kNoiseStd_mm};
}

// 20 recordings, the effect-to-noise ratios drawn from ratio_seed, recording seeds from
// seed_base: the criteria with a trusted model.
void ExpectNamesTheEffectAndHalvesHeldoutError(uint64_t seed_base, uint64_t ratio_seed) {
  // 20 recordings cycling over the catalogue (the first four effects three times, the
  // others twice), effect-to-noise ratio log-uniform in [0.7, 10].
  const model::TsModel trusted = TrustedModel();
  const std::vector<LabEffect> catalogue = LabCatalogue();
  LabRandom ratios(ratio_seed);
  std::vector<CaseResult> results;
  for (int i = 0; i < 20; ++i) {
    const LabEffect effect = catalogue[static_cast<size_t>(i) % catalogue.size()];
    const double target = ratios.LogUniform(0.7, 10.0);
    results.push_back(RunCase(i, ProtocolFor(effect), LabSeedPlant8V(), effect, target,
                              seed_base + static_cast<uint64_t>(i), WithModelOptions(), trusted));
  }
  PrintTable("With the trusted model: effect recordings", results);

  EXPECT_GE(CountCorrect(results), 19) << "the verdict must name the effect in >= 19 of 20";

  std::vector<double> heldout_ratios;
  for (const CaseResult& r : results)
    if (r.ratio >= 2.0) heldout_ratios.push_back(r.HeldoutRatio());
  ASSERT_FALSE(heldout_ratios.empty());
  std::sort(heldout_ratios.begin(), heldout_ratios.end());
  const double upper_median = heldout_ratios[heldout_ratios.size() / 2];
  std::printf("held-out after/before over %zu cases with ratio >= 2: upper median %.3f\n",
              heldout_ratios.size(), upper_median);
  EXPECT_LE(upper_median, 0.5) << "the augmented model must halve the held-out RMSE (median)";
}

// Four sets of 20 recordings. The first three were run while the diagnosis was developed
// (the first two led to changes); the fourth set, and the second set of clean recordings,
// were drawn after the last change and run once.
TEST(DiagnoseAcceptance, WithTrustedModelNamesTheEffectAndHalvesHeldoutError) {
  ExpectNamesTheEffectAndHalvesHeldoutError(1001, 0x5EED0001);
}

TEST(DiagnoseAcceptance, WithTrustedModelNamesTheEffectOnASecondSet) {
  ExpectNamesTheEffectAndHalvesHeldoutError(6001, 0x5EED0003);
}
TEST(DiagnoseAcceptance, WithTrustedModelNamesTheEffectOnAThirdSet) {
  ExpectNamesTheEffectAndHalvesHeldoutError(9001, 0x5EED0009);
}
TEST(DiagnoseAcceptance, WithTrustedModelNamesTheEffectOnAFourthSet) {
  ExpectNamesTheEffectAndHalvesHeldoutError(11001, 0x5EED000B);
}

void ExpectEveryCleanRecordingIsNone(uint64_t seed_base) {
  const model::TsModel trusted = TrustedModel();
  const std::vector<Protocol> protocols = {kSquare, kAlternatingSquare, kStaircase, kSquare,
                                           kStaircase};
  std::vector<CaseResult> results;
  for (size_t i = 0; i < protocols.size(); ++i)
    results.push_back(RunCase(static_cast<int>(i), protocols[i], LabSeedPlant8V(), LabEffect::kNone,
                              0.0, seed_base + i, WithModelOptions(), trusted));
  PrintTable("With the trusted model: clean recordings", results);
  for (const CaseResult& r : results)
    EXPECT_EQ(r.verdict, "none") << "clean case " << r.index << " (" << r.protocol << ")";
}

TEST(DiagnoseAcceptance, WithTrustedModelEveryCleanRecordingIsNone) {
  ExpectEveryCleanRecordingIsNone(2001);
}
TEST(DiagnoseAcceptance, WithTrustedModelEveryCleanRecordingIsNoneOnASecondSet) {
  ExpectEveryCleanRecordingIsNone(2101);
}

// Without a model: a physics-like plant (real poles and zeros, monotone step), dead time
// 1.2 s plus a random fraction of a sample; four effects twice each, ratio log-uniform in
// [2, 10]; at least 3 of 4 named.
void ExpectNamesThreeInFourWithoutModel(uint64_t seed_base, uint64_t ratio_seed) {
  const std::vector<LabEffect> effects = {LabEffect::kBackRelaxation, LabEffect::kHysteresis,
                                          LabEffect::kSensorDrift, LabEffect::kCycleDegradation};
  LabRandom ratios(ratio_seed);
  std::vector<CaseResult> results;
  for (int i = 0; i < 8; ++i) {
    const LabEffect effect = effects[static_cast<size_t>(i) % effects.size()];
    const double target = ratios.LogUniform(2.0, 10.0);
    results.push_back(RunCase(i, kSquare, LabPhysicsPlant(), effect, target,
                              seed_base + static_cast<uint64_t>(i), WithoutModelOptions(),
                              std::nullopt));
  }
  PrintTable("Without a model: effect recordings", results);
  EXPECT_GE(CountCorrect(results), 6) << "at least 3 of 4 (6 of 8) must be named";
}

// Without a model, at most 1 in 4 clean recordings flagged.
void ExpectFewFalseAlarmsWithoutModel(uint64_t seed_base) {
  const std::vector<Protocol> protocols = {kSquare, kStaircase, kSquare, kStaircase};
  std::vector<CaseResult> results;
  for (size_t i = 0; i < protocols.size(); ++i)
    results.push_back(RunCase(static_cast<int>(i), protocols[i], LabPhysicsPlant(),
                              LabEffect::kNone, 0.0, seed_base + i, WithoutModelOptions(),
                              std::nullopt));
  PrintTable("Without a model: clean recordings", results);
  const auto false_alarms = std::count_if(results.begin(), results.end(),
                                          [](const CaseResult& r) { return r.verdict != "none"; });
  EXPECT_LE(false_alarms, 1) << "at most 1 in 4 clean recordings may get a false alarm";
}

// Three sets each. The first two were run while the diagnosis was developed (the second
// one led to the last change: no linear relaxation candidate on top of a refitted transfer
// function); the third sets were drawn after that change, and run once before and once
// after the later change to the claim rule (training plus held-out evidence), with the
// same result.
TEST(DiagnoseAcceptance, WithoutModelNamesAtLeastThreeInFour) {
  ExpectNamesThreeInFourWithoutModel(3001, 0x5EED0002);
}
TEST(DiagnoseAcceptance, WithoutModelNamesAtLeastThreeInFourOnASecondSet) {
  ExpectNamesThreeInFourWithoutModel(8001, 0x5EED0008);
}
TEST(DiagnoseAcceptance, WithoutModelNamesAtLeastThreeInFourOnAThirdSet) {
  ExpectNamesThreeInFourWithoutModel(8201, 0x5EED000A);
}
TEST(DiagnoseAcceptance, WithoutModelAtMostOneInFourCleanFalseAlarms) {
  ExpectFewFalseAlarmsWithoutModel(4001);
}
TEST(DiagnoseAcceptance, WithoutModelAtMostOneInFourCleanFalseAlarmsOnASecondSet) {
  ExpectFewFalseAlarmsWithoutModel(8101);
}
TEST(DiagnoseAcceptance, WithoutModelAtMostOneInFourCleanFalseAlarmsOnAThirdSet) {
  ExpectFewFalseAlarmsWithoutModel(8301);
}

void ExpectSameDiagnosis(const model::Diagnosis& a, const model::Diagnosis& b) {
  EXPECT_EQ(a.verdict, b.verdict);
  EXPECT_EQ(a.noise_std_mm, b.noise_std_mm);
  EXPECT_EQ(a.baseline_rmse_mm, b.baseline_rmse_mm);
  EXPECT_EQ(a.baseline_heldout_rmse_mm, b.baseline_heldout_rmse_mm);
  EXPECT_EQ(a.baseline_mm, b.baseline_mm);
  EXPECT_EQ(a.augmented_mm, b.augmented_mm);
  ASSERT_EQ(a.findings.size(), b.findings.size());
  for (size_t i = 0; i < a.findings.size(); ++i) {
    EXPECT_EQ(a.findings[i].effect, b.findings[i].effect);
    EXPECT_EQ(a.findings[i].model.params, b.findings[i].model.params);
    EXPECT_EQ(a.findings[i].heldout_rmse_before_mm, b.findings[i].heldout_rmse_before_mm);
    EXPECT_EQ(a.findings[i].heldout_rmse_after_mm, b.findings[i].heldout_rmse_after_mm);
    ASSERT_EQ(a.findings[i].params.size(), b.findings[i].params.size());
    for (size_t j = 0; j < a.findings[i].params.size(); ++j) {
      EXPECT_EQ(a.findings[i].params[j].value, b.findings[i].params[j].value);
      EXPECT_EQ(a.findings[i].params[j].half_width_95, b.findings[i].params[j].half_width_95);
    }
  }
  ASSERT_EQ(a.candidates.size(), b.candidates.size());
  for (size_t i = 0; i < a.candidates.size(); ++i) {
    EXPECT_EQ(a.candidates[i].name, b.candidates[i].name);
    EXPECT_EQ(a.candidates[i].train_rmse_mm, b.candidates[i].train_rmse_mm);
    EXPECT_EQ(a.candidates[i].heldout_rmse_mm, b.candidates[i].heldout_rmse_mm);
    EXPECT_EQ(a.candidates[i].claimed, b.candidates[i].claimed);
    ASSERT_EQ(a.candidates[i].params.size(), b.candidates[i].params.size());
    for (size_t j = 0; j < a.candidates[i].params.size(); ++j)
      EXPECT_EQ(a.candidates[i].params[j].value, b.candidates[i].params[j].value);
  }
}

TEST(DiagnoseAcceptance, SameRecordingSameDiagnosis) {
  // With the trusted model (hysteresis at 3x the noise) and without a model (back
  // relaxation at 3x the noise, where the baseline is identified too).
  LabRun with_model =
      MakeRun(kSquare, LabSeedPlant8V(), LabEffect::kHysteresis, 5001, WithModelOptions());
  ScaleEffectToNoise(&with_model, 3.0);
  const model::Recording recording = Record(with_model);
  const model::TsModel trusted = TrustedModel();
  ExpectSameDiagnosis(model::Diagnose(recording, trusted), model::Diagnose(recording, trusted));

  LabRun without_model =
      MakeRun(kSquare, LabPhysicsPlant(), LabEffect::kBackRelaxation, 5002, WithoutModelOptions());
  ScaleEffectToNoise(&without_model, 3.0);
  const model::Recording free_recording = Record(without_model);
  ExpectSameDiagnosis(model::Diagnose(free_recording, std::nullopt),
                      model::Diagnose(free_recording, std::nullopt));
}

// Without a model a named effect must explain a share of the held-out misfit beyond the
// noise (DiagnoseOptions::min_share_of_misfit): a sensor drift at 6 times the noise is
// named with the default tenth; asked to explain all of it (which no effect does, the
// noise staying), the same candidate is an unexplained misfit, reported where it acts.
TEST(DiagnoseAcceptance, WithoutModelAnEffectThatExplainsTooLittleIsAMisfit) {
  LabRun run =
      MakeRun(kSquare, LabPhysicsPlant(), LabEffect::kSensorDrift, 5003, WithoutModelOptions());
  ScaleEffectToNoise(&run, 6.0);
  const model::Recording recording = Record(run);
  const model::Diagnosis named = model::Diagnose(recording, std::nullopt);
  ASSERT_EQ(named.verdict, "sensor_drift");
  EXPECT_TRUE(named.unexplained.empty());

  model::DiagnoseOptions strict;
  strict.min_share_of_misfit = 1.0;
  const model::Diagnosis misfit = model::Diagnose(recording, std::nullopt, strict);
  EXPECT_EQ(misfit.verdict, "none");
  EXPECT_TRUE(misfit.findings.empty());
  bool reported = false;
  for (const model::Misfit& m : misfit.unexplained)
    if (m.resembles == "sensor_drift") {
      reported = true;
      EXPECT_FALSE(m.where.empty());
      EXPECT_NE(m.explanation.find("of the held-out misfit beyond the noise"), std::string::npos)
          << m.explanation;
    }
  EXPECT_TRUE(reported) << "the drift is not reported as an unexplained misfit";

  for (double share : {-0.1, 1.5}) {
    model::DiagnoseOptions wrong;
    wrong.min_share_of_misfit = share;
    EXPECT_THROW(model::Diagnose(recording, std::nullopt, wrong), std::invalid_argument) << share;
  }
}

}  // namespace
}  // namespace flexid::testing
