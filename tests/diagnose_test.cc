// Diagnosis on the recordings shipped in examples/concealed/ (made by flexid-rig with one
// effect or none concealed at a few times the sensor noise): the verdict is checked against
// tests/concealed_answers.txt, which the diagnosis never sees. Plus the catalogue's
// augmentation round trip and bad input.
#include "model/diagnose/diagnose.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "model/core/errors.h"
#include "model/core/model_file.h"
#include "model/core/presets.h"
#include "model/core/recording.h"
#include "model/diagnose/diagnose_fit.h"

namespace flexid {
namespace {

std::map<std::string, std::string> Answers() {
  std::ifstream in(std::string(FLEXID_SOURCE_DIR) + "/tests/concealed_answers.txt");
  std::map<std::string, std::string> answers;
  std::string file, effect;
  while (in >> file >> effect) answers[file] = effect;
  return answers;
}

// A finding's rivals are the other candidates claimed in its round, each once, with the
// held-out RMSE of its candidate report; the finding says how it was chosen among them.
void ExpectRivalsAreTheRoundsOtherClaims(const model::Diagnosis& d, const std::string& file,
                                         size_t* with_rivals) {
  for (size_t round = 0; round < d.findings.size(); ++round) {
    const model::Finding& f = d.findings[round];
    std::vector<const model::CandidateReport*> others;
    for (const model::CandidateReport& c : d.candidates)
      if (c.claimed && c.round == static_cast<int>(round) && c.name != f.effect)
        others.push_back(&c);
    ASSERT_EQ(f.rivals.size(), others.size()) << file << " round " << round;
    for (const model::Rival& r : f.rivals) {
      const auto match = std::find_if(others.begin(), others.end(), [&](const auto* c) {
        return c->name == r.effect && c->heldout_rmse_mm == r.heldout_rmse_mm;
      });
      EXPECT_NE(match, others.end()) << file << ": rival " << r.effect;
    }
    EXPECT_EQ(f.chosen_by.empty(), f.rivals.empty()) << file;
    if (!f.rivals.empty()) ++*with_rivals;
  }
}

TEST(DiagnoseConcealed, NamesEveryShippedRecordingsEffect) {
  const auto answers = Answers();
  ASSERT_EQ(answers.size(), 8u);
  const model::TsModel trusted = model::AsTsModel(
      model::ReadModelFile(std::string(FLEXID_SOURCE_DIR) + "/examples/seed-8V.json"));
  size_t with_rivals = 0;
  for (const auto& [file, effect] : answers) {
    const model::Recording rec =
        model::ReadRecordingCsv(std::string(FLEXID_SOURCE_DIR) + "/examples/concealed/" + file);
    const model::Diagnosis d = model::Diagnose(rec, trusted);
    EXPECT_EQ(d.verdict, effect) << file;
    ExpectRivalsAreTheRoundsOtherClaims(d, file, &with_rivals);
    if (effect == "none") {
      EXPECT_TRUE(d.findings.empty()) << file;
      continue;
    }
    ASSERT_FALSE(d.findings.empty()) << file;
    // Concealed at 2.5-3.5 times the noise: the augmented model halves the held-out error.
    EXPECT_LT(d.findings[0].heldout_rmse_after_mm, 0.5 * d.findings[0].heldout_rmse_before_mm)
        << file;
    EXPECT_FALSE(d.findings[0].where.empty()) << file;
    // The augmented model file (its augmentations, an accruing effect's scale fixed at
    // the recording's own) predicts what the diagnosis predicted.
    std::vector<model::Effect> effects;
    for (const model::Finding& f : d.findings)
      effects.push_back(model::EffectFromAugmentation(model::AugmentationOf(f.model)));
    const std::vector<double> from_file = model::SimulateAugmented(trusted, rec, effects);
    ASSERT_EQ(from_file.size(), d.augmented_mm.size());
    for (size_t k = 0; k < from_file.size(); ++k)
      ASSERT_NEAR(from_file[k], d.augmented_mm[k], 1e-9) << file << " sample " << k;
    if (model::EffectScaleName(d.findings[0].model.kind)) {
      EXPECT_GT(d.findings[0].model.scale, 0.0) << file;
    }
    EXPECT_NE(d.findings[0].explanation.find(effect == "electrolysis_saturation"
                                                 ? "electrolysis"
                                                 : effect.substr(0, effect.find('_'))),
              std::string::npos)
        << d.findings[0].explanation;
  }
  // Six of the eight are claimed by more than one effect against the seed's model: the
  // rivals are no formality.
  EXPECT_GE(with_rivals, 4u);
}

// What the final model leaves on the held-out samples beyond 3 times the noise is reported
// as an unexplained misfit that nothing in the catalogue resembles: a clean recording
// against its own model leaves nothing; against the same model 3 s late, no effect of the
// catalogue explains the error, and a verdict alone would not say so.
TEST(DiagnoseLeftOver, AHeldOutErrorNoEffectExplainsIsReported) {
  const model::Recording rec =
      model::ReadRecordingCsv(std::string(FLEXID_SOURCE_DIR) + "/examples/concealed/rec-02.csv");
  model::TsModel trusted = model::AsTsModel(
      model::ReadModelFile(std::string(FLEXID_SOURCE_DIR) + "/examples/seed-8V.json"));
  auto left_over = [](const model::Diagnosis& d) {
    for (const model::Misfit& m : d.unexplained)
      if (m.resembles.empty()) return &m;
    return static_cast<const model::Misfit*>(nullptr);
  };
  const model::Diagnosis right = model::Diagnose(rec, trusted);
  EXPECT_EQ(left_over(right), nullptr);

  trusted.rules[0].tf.delay_s += 3.0;
  const model::Diagnosis late = model::Diagnose(rec, trusted);
  const model::Misfit* misfit = left_over(late);
  ASSERT_NE(misfit, nullptr) << "verdict " << late.verdict;
  EXPECT_NE(misfit->explanation.find("times the sensor noise"), std::string::npos)
      << misfit->explanation;
  EXPECT_EQ(misfit->where.size(), late.heldout.size());
  EXPECT_GT(misfit->rms_mm, 3.0 * late.noise_std_mm);
}

TEST(DiagnoseCatalogue, AugmentationsRoundTripAndBadOnesAreNamed) {
  for (model::EffectKind kind : model::AllEffects()) {
    model::Effect e{kind, {}};
    for (size_t i = 0; i < model::EffectParameterNames(kind).size(); ++i)
      e.params.push_back(0.1 * static_cast<double>(i + 1));
    const model::Effect back = model::EffectFromAugmentation(model::AugmentationOf(e));
    EXPECT_EQ(back.kind, kind);
    EXPECT_EQ(back.params, e.params);
  }
  model::Augmentation unknown{"gremlins", nlohmann::json::object()};
  EXPECT_THROW(model::EffectFromAugmentation(unknown), model::InputError);
  model::Augmentation missing{"back_relaxation", {{"fraction", 0.1}}};
  try {
    model::EffectFromAugmentation(missing);
    FAIL() << "a missing parameter was accepted";
  } catch (const model::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("tau_s"), std::string::npos) << e.what();
  }
  // A degradation written before its exponent existed reads as the law it was fitted with
  // (a steady loss per charge, exponent 1); the loss itself is still required.
  const model::Effect older =
      model::EffectFromAugmentation({"cycle_degradation", {{"loss", 0.2}, {"charge_Vs", 900.0}}});
  EXPECT_EQ(older.params, (std::vector<double>{0.2, 1.0}));
  EXPECT_EQ(older.scale, 900.0);
  EXPECT_THROW(model::EffectFromAugmentation({"cycle_degradation", {{"exponent", 0.5}}}),
               model::InputError);
  EXPECT_THROW(
      model::EffectFromAugmentation({"cycle_degradation", {{"loss", 0.2}, {"exponent", -1.0}}}),
      model::InputError);
}

// A fit's simulations are reused only when every input is the same: the model's numbers,
// the drive and the premise. A stale hit would give an effect's fit the previous point's
// prediction.
TEST(DiagnoseFit, TheSimulationMemoReusesOnlyAnIdenticalSimulation) {
  model::Recording rec;
  for (int k = 0; k < 400; ++k) {
    rec.t_s.push_back(0.1 * k);
    rec.voltage_V.push_back(k < 50 ? 0.0 : k < 200 ? 2.0 : k < 300 ? 6.0 : 4.0);
    rec.deflection_mm.push_back(0.0);
  }
  model::diagnosis::Data data;
  data.rec = &rec;
  const model::TsModel seed = model::SeedTsModel();
  model::diagnosis::SimulationMemo memo;
  const std::vector<double>& u = rec.voltage_V;
  const std::vector<double> y = memo.Simulate(data, seed, u, {});
  EXPECT_EQ(y, data.SimulateFromRest(seed, u));
  EXPECT_EQ(memo.Simulate(data, seed, u, {}), y);
  EXPECT_EQ(memo.simulations(), 1u);

  std::vector<double> moved = u;  // one sample of the drive
  moved[250] = 5.9;
  EXPECT_EQ(memo.Simulate(data, seed, moved, {}), data.SimulateFromRest(seed, moved));
  EXPECT_EQ(memo.simulations(), 2u);
  model::TsModel other = seed;  // one coefficient of one rule
  other.rules.back().tf.den.back() *= 1.0 + 1e-12;
  EXPECT_EQ(memo.Simulate(data, other, u, {}), data.SimulateFromRest(other, u));
  EXPECT_EQ(memo.simulations(), 3u);
  // The same drive scheduled on another premise (a wear effect's applied voltage).
  std::vector<double> worn = u;
  for (double& v : worn) v *= 0.9;
  EXPECT_EQ(memo.Simulate(data, seed, worn, u), data.SimulateFromRest(seed, worn, u));
  EXPECT_EQ(memo.simulations(), 4u);
  EXPECT_NE(memo.Simulate(data, seed, worn, u), memo.Simulate(data, seed, worn, {}));
  EXPECT_EQ(memo.simulations(), 5u);
  // At most kEntries are kept: the first is made again.
  static_assert(model::diagnosis::SimulationMemo::kEntries == 3);
  EXPECT_EQ(memo.Simulate(data, seed, u, {}), y);
  EXPECT_EQ(memo.simulations(), 6u);
}

TEST(DiagnoseInput, ShortOrConstantRecordingsAreRefused) {
  model::Recording rec;
  rec.source = "short.csv";
  for (int k = 0; k < 50; ++k) {
    rec.t_s.push_back(0.1 * k);
    rec.voltage_V.push_back(k > 10 ? 5.0 : 0.0);
    rec.deflection_mm.push_back(0.0);
  }
  EXPECT_THROW(model::Diagnose(rec, model::SingleRule(model::SeedModel8V())), model::InputError);
  for (int k = 50; k < 400; ++k) {
    rec.t_s.push_back(0.1 * k);
    rec.voltage_V.push_back(0.0);
    rec.deflection_mm.push_back(0.0);
  }
  for (double& v : rec.voltage_V) v = 0.0;
  EXPECT_THROW(model::Diagnose(rec, model::SingleRule(model::SeedModel8V())), model::InputError);
}

}  // namespace
}  // namespace flexid
