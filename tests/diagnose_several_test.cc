// One diagnosis from several recordings of one actuator (model::Diagnose over a list):
// each recording is predicted from rest, spans say which recording they are in, and an
// effect that no single recording can show is named from the evidence of two. The plant
// is the independent T-S test plant (ts_plant.h) with the effect battery's lagged negative
// polarity (effect_battery.h), formulated otherwise than the catalogue's polarity ratio.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "effect_battery.h"
#include "model/core/errors.h"
#include "model/core/presets.h"
#include "model/diagnose/diagnose.h"
#include "ts_plant.h"

namespace flexid {
namespace {

using testing::BatteryEffect;
using testing::BatteryEffectSettings;
using testing::TsProtocol;
using testing::battery_detail::AddHold;

// 20 s at rest, then `levels` for `hold_s` each, then 200 s at rest.
TsProtocol Holds(const std::vector<double>& levels_V, double hold_s) {
  TsProtocol protocol;
  double t_s = 20.0;
  for (double level : levels_V) {
    AddHold(&protocol, t_s, level);
    t_s += hold_s;
  }
  AddHold(&protocol, t_s, 0.0);
  protocol.samples = testing::TsSamplesIn(t_s + 200.0) + 1;
  return protocol;
}

// The plant of seed 1 with a strong lagged negative polarity (a share 0.6 of the negative
// drive through a species of gain 0.4: negative voltage acts with 0.64 times the gain).
struct PolarityPlant {
  testing::TsPlant plant = testing::DrawTsPlant(1);
  BatteryEffectSettings effect;
  PolarityPlant() {
    effect.kind = BatteryEffect::kPolarityAsymmetry;
    effect.amplitude = 0.6;
    effect.negative_gain = 0.4;
    effect.negative_tau_s = 8.0;
  }
  model::Recording Record(const TsProtocol& protocol, uint64_t noise_seed,
                          const std::string& name) const {
    return testing::RecordBatteryOutput(
        plant, protocol, testing::SimulateBattery(plant, protocol, effect), noise_seed, name);
  }
};

TEST(DiagnoseSeveral, EachRecordingIsPredictedFromRestAndSpansNameTheirRecording) {
  const PolarityPlant lab;
  const std::vector<model::Recording> recordings = {
      lab.Record(Holds({2, 5, 8}, 120.0), 11, "stairs.csv"),
      lab.Record(Holds({6, 0, 6, 0, 6}, 80.0), 12, "squares.csv")};
  const model::TsModel trusted = model::SingleRule(model::SeedModel8V());
  const model::Diagnosis d = model::Diagnose(recordings, trusted);
  ASSERT_EQ(d.recordings, (std::vector<std::string>{"stairs.csv", "squares.csv"}));
  ASSERT_EQ(d.baseline_mm.size(), recordings[0].t_s.size() + recordings[1].t_s.size());
  // The baseline's prediction of each recording is that of the recording alone: no state
  // carries over from the first into the second (up to rounding: the second is simulated
  // on shifted times).
  size_t offset = 0;
  for (const model::Recording& r : recordings) {
    const std::vector<double> alone = model::SimulateAugmented(trusted, r, {});
    double peak_mm = 0.0;
    for (double y : alone) peak_mm = std::max(peak_mm, std::abs(y));
    for (size_t k = 0; k < alone.size(); ++k)
      ASSERT_NEAR(d.baseline_mm[offset + k], alone[k], 1e-9 * peak_mm)
          << r.source << " sample " << k;
    offset += alone.size();
  }
  // Held-out blocks are spread over both recordings, each on its own times.
  bool in[2] = {false, false};
  for (const model::TimeSpan& s : d.heldout) {
    ASSERT_GE(s.recording, 0);
    ASSERT_LT(s.recording, 2);
    const model::Recording& r = recordings[static_cast<size_t>(s.recording)];
    EXPECT_GE(s.t_start_s, r.t_s.front());
    EXPECT_LE(s.t_end_s, r.t_s.back());
    EXPECT_LE(s.t_start_s, s.t_end_s);
    in[s.recording] = true;
  }
  EXPECT_TRUE(in[0] && in[1]);
  const nlohmann::json j = model::DiagnosisToJson(d);
  EXPECT_EQ(j.at("recordings").size(), 2u);
  EXPECT_TRUE(j.at("heldout").at(0).contains("recording"));
  // One recording: no recording index in the JSON, as before.
  const nlohmann::json one = model::DiagnosisToJson(model::Diagnose(recordings[0], trusted));
  EXPECT_FALSE(one.contains("recordings"));
  EXPECT_FALSE(one.at("heldout").at(0).contains("recording"));
}

// A lab drives one trial positive, the next negative and the third positive again:
// no trial alone shows an asymmetry (each drives one polarity), all three together do,
// without a model. (Two trials, one of each sign, cannot tell a weaker negative drive from
// a gain lost between the first trial and the second: the third trial decides.)
TEST(DiagnoseSeveral, PolarityAsymmetryIsNamedFromPositiveAndNegativeTrials) {
  const PolarityPlant lab;
  const std::vector<model::Recording> trials = {
      lab.Record(Holds({3, 6, 0, 6, 3}, 100.0), 21, "plus.csv"),
      lab.Record(Holds({-3, -6, 0, -6, -3}, 100.0), 22, "minus.csv"),
      lab.Record(Holds({6, 3, 0, 3, 6}, 100.0), 23, "plus-again.csv")};
  for (const model::Recording& alone : trials) {
    const model::Diagnosis d = model::Diagnose(alone, std::nullopt);
    EXPECT_NE(d.verdict, "polarity_asymmetry") << alone.source;
  }
  const model::Diagnosis all = model::Diagnose(trials, std::nullopt);
  EXPECT_EQ(all.verdict, "polarity_asymmetry");
  ASSERT_FALSE(all.findings.empty());
  // Negative voltage moves the beam less: 1 - 0.6 + 0.6 * 0.4 = 0.64 times in steady state.
  const model::Finding& found = all.findings.front();
  EXPECT_GT(found.model.params.at(0), 0.5);
  EXPECT_LT(found.model.params.at(0), 0.8);
  EXPECT_LT(found.heldout_rmse_after_mm, 0.6 * found.heldout_rmse_before_mm);
  for (const model::TimeSpan& s : found.where) EXPECT_EQ(s.recording, 1);
  EXPECT_FALSE(found.where.empty());
}

TEST(DiagnoseSeveral, BadListsAreRefusedNamingTheRecording) {
  const PolarityPlant lab;
  model::Recording good = lab.Record(Holds({5}, 100.0), 31, "good.csv");
  model::Recording short_one = good;
  short_one.source = "short.csv";
  short_one.t_s.resize(1);
  short_one.voltage_V.resize(1);
  short_one.deflection_mm.resize(1);
  try {
    model::Diagnose({good, short_one}, std::nullopt);
    FAIL() << "a one-sample recording was accepted";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("short.csv"), std::string::npos) << e.what();
  }
  model::Recording no_deflection = good;
  no_deflection.source = "blind.csv";
  no_deflection.deflection_mm.clear();
  try {
    model::Diagnose({good, no_deflection}, std::nullopt);
    FAIL() << "a recording without deflection was accepted";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("blind.csv"), std::string::npos) << e.what();
  }
  EXPECT_THROW(model::Diagnose(std::vector<model::Recording>{}, std::nullopt), model::InputError);
  EXPECT_THROW(
      model::Diagnose(std::vector<model::Recording>(model::kMaxDiagnosedRecordings + 1, good),
                      std::nullopt),
      model::InputError);
}

}  // namespace
}  // namespace flexid
