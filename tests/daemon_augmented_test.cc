// flexidd's live prediction of a model with augmentations (issue 15, item 1): a recording
// played on the bus to an in-process flexidd whose active model carries every kind of
// catalogue effect gets, at every sample, the prediction `flexid simulate` prints for that
// recording (model::SimulateAugmented, which simulate_command.cc calls), to 1e-9 mm. And an
// augmented model that cannot run live is refused by `models activate`, leaving the active
// version as it was.
#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <map>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "bus/clock.h"
#include "daemon/config.h"
#include "daemon/daemon.h"
#include "fault_harness.h"
#include "lcmtypes/message_auth.h"
#include "model/core/model_file.h"
#include "model/core/presets.h"
#include "model/core/recording.h"
#include "model/diagnose/diagnose.h"
#include "model/diagnose/effects.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;

constexpr int64_t kStartUtime = 1'700'000'000'000'000;
constexpr int64_t kPeriodUs = 100'000;  // 10 Hz

// The seed's two-rule model with one effect of every kind that can run live.
model::ModelDocument AugmentedSeedModel() {
  model::ModelDocument doc = model::FromTsModel(model::SeedTsModel());
  const std::vector<model::Effect> effects = {
      {model::EffectKind::kDeadZone, {0.4}},
      {model::EffectKind::kPolarityAsymmetry, {0.7}},
      {model::EffectKind::kCycleDegradation, {0.3, 1.0}, 600.0},
      {model::EffectKind::kBackRelaxation, {0.2, 30.0}},
      {model::EffectKind::kHysteresis, {0.15, 0.4}},
      {model::EffectKind::kSensorDrift, {0.3, 0.1, 20.0}, 250.0},
  };
  for (const model::Effect& e : effects) doc.augmentations.push_back(model::AugmentationOf(e));
  return doc;
}

// Holds of both signs and several lengths, 10 Hz, times relative to kStartUtime.
model::Recording Holds() {
  model::Recording rec;
  rec.source = "holds";
  const std::vector<double> levels_V = {0, 3, 8, 0, -5, 6, 2, 0};
  const std::vector<int> holds_samples = {30, 300, 200, 250, 300, 150, 300, 200};
  int64_t k = 0;
  for (size_t i = 0; i < levels_V.size(); ++i)
    for (int j = 0; j < holds_samples[i]; ++j, ++k) {
      rec.t_s.push_back(1e-6 * static_cast<double>(k * kPeriodUs));
      rec.voltage_V.push_back(levels_V[i]);
      rec.deflection_mm.push_back(0.0);
    }
  return rec;
}

class DaemonAugmented : public testing::InProcessDaemonTest {
 protected:
  DaemonAugmented() { with_predictions_ = true; }

  void StoreModel(const model::ModelDocument& doc, bool active) {
    storage::ModelRecord record;
    record.actuator_id = "S1";
    record.model_json = model::ModelToJson(doc).dump();
    record.fit_json = "{}";
    record.active = active;
    storage::Database::Open(config_.database).StoreModel(record);
  }
  bool Drive(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
    return testing::DriveInProcess(*daemon_, *bus_, done, timeout);
  }
};

TEST_F(DaemonAugmented, LivePredictionEqualsTheBatchSimulationOfTheRecording) {
  const model::ModelDocument doc = AugmentedSeedModel();
  StoreModel(doc, true);
  StartDaemon();
  const model::Recording rec = Holds();
  // Each sample's voltage and deflection, stamped alike, as a DAQ sends them; the loop
  // runs until its prediction is out, so nothing queues in the socket.
  for (size_t k = 0; k < rec.t_s.size(); ++k) {
    const int64_t utime = kStartUtime + static_cast<int64_t>(k) * kPeriodUs;
    bus_->Publish("FLEXID/S1/VOLTAGE", testing::Voltage(utime, rec.voltage_V[k]));
    bus_->Publish("FLEXID/S1/DEFLECTION", testing::Deflection(utime, 0.0));
    ASSERT_TRUE(Drive([&] { return bus_->predictions.size() == k + 1; }, 3s))
        << "no prediction for sample " << k;
  }
  const std::vector<double> batch =
      model::SimulateAugmented(model::AsTsModel(doc), rec, model::EffectsOf(doc, "test"));
  const std::vector<double> plain = model::SimulateAugmented(model::AsTsModel(doc), rec, {});
  double worst = 0.0, effects_add = 0.0;
  for (size_t k = 0; k < rec.t_s.size(); ++k) {
    const flexid::prediction_t& p = bus_->predictions[k];
    ASSERT_EQ(p.utime, kStartUtime + static_cast<int64_t>(k) * kPeriodUs);
    worst = std::max(worst, std::abs(p.predicted_mm - batch[k]));
    effects_add = std::max(effects_add, std::abs(batch[k] - plain[k]));
  }
  EXPECT_LT(worst, 1e-9);
  EXPECT_GT(effects_add, 0.1) << "the augmentations should move the prediction";
}

TEST_F(DaemonAugmented, ActivatingAModelThatCannotRunLiveIsRefusedAndChangesNothing) {
  StoreModel(model::FromTsModel(model::SeedTsModel()), true);  // version 1, active
  model::ModelDocument doc = model::FromTsModel(model::SeedTsModel());
  doc.augmentations.push_back(
      model::AugmentationOf({model::EffectKind::kCycleDegradation, {0.3, 1.0}}));  // no charge_Vs
  StoreModel(doc, false);                                                          // version 2
  model::ModelDocument wrong = model::FromTsModel(model::SeedTsModel());
  wrong.augmentations.push_back({"back_relaxation", {{"fraction", 1.5}, {"tau_s", 30.0}}});
  StoreModel(wrong, false);  // version 3: a fraction out of [0, 1)
  StartDaemon();
  for (const auto& [version, problem] :
       {std::pair{2, "charge_Vs"}, std::pair{3, "fraction must be [0, 1), not 1.5"}}) {
    flexid::rpc_request_t r;
    r.utime = bus::WallClockUtime();
    r.request_id = "activate" + std::to_string(version);
    r.client_id = "augmented_test";
    r.method = "model_activate";
    r.args_json = nlohmann::json{{"actuator", "S1"}, {"version", version}}.dump();
    auth::Sign(key_, &r);
    ASSERT_EQ(bus_->Publish("FLEXID/RPC/REQUEST", r), 0);
    ASSERT_TRUE(Drive([&] { return !bus_->RepliesTo(r.request_id).empty(); }, 5s));
    const flexid::rpc_reply_t reply = bus_->RepliesTo(r.request_id).front().second;
    EXPECT_EQ(reply.status, flexid::rpc_reply_t::kBadRequest);
    EXPECT_NE(reply.error.find("model version " + std::to_string(version)), std::string::npos)
        << reply.error;
    EXPECT_NE(reply.error.find(problem), std::string::npos) << reply.error;
    EXPECT_EQ(reply.error.find('\n'), std::string::npos);
    const auto active = storage::Database::Open(config_.database).ActiveModel("S1");
    ASSERT_TRUE(active.has_value());
    EXPECT_EQ(active->version, 1);
  }
}

// The on_alert policy (issue 15, item 3): a trial whose residual the model does not
// explain (the plant relaxes back, the model does not) is diagnosed when it ends, and with
// on_alert = adopt its augmented model becomes the active version; each step is an alert.
class DaemonPolicy : public DaemonAugmented {
 protected:
  // Two 2 V square cycles (110 s on, 110 s off) of the seed's model with back-relaxation,
  // at 10 Hz with 0.02 mm noise; then rest until the automatic trial ends.
  void PlayRelaxingTrial() {
    model::AugmentedStreamingSimulator plant(model::SeedTsModel(),
                                             {{model::EffectKind::kBackRelaxation, {0.3, 60.0}}});
    std::mt19937 rng(3);
    std::normal_distribution<double> noise_mm(0.0, 0.02);
    const int64_t samples = 4400 + 400;  // 440 s, then 40 s at rest
    for (int64_t k = 0; k < samples; ++k) {
      const int64_t utime = kStartUtime + k * kPeriodUs;
      const double volts = k < 4400 && (k / 1100) % 2 == 0 ? 2.0 : 0.0;
      const double mm =
          plant.Step(1e-6 * static_cast<double>(k * kPeriodUs), volts) + noise_mm(rng);
      bus_->Publish("FLEXID/S1/VOLTAGE", testing::Voltage(utime, volts));
      bus_->Publish("FLEXID/S1/DEFLECTION", testing::Deflection(utime, mm));
      ASSERT_TRUE(
          Drive([&] { return bus_->predictions.size() == static_cast<size_t>(k + 1); }, 3s));
    }
  }
  std::vector<flexid::alert_t> AlertsOf(const std::string& kind) const {
    return bus_->AlertsOf(kind);
  }
};

TEST_F(DaemonPolicy, AdoptActivatesTheAugmentedModelOfATrialThatRaisedAlerts) {
  StoreModel(model::FromTsModel(model::SeedTsModel()), true);  // version 1
  config_.policy.on_alert = "adopt";
  config_.policy.adopt_min_gain = 3.0;
  config_.trial_idle_stop_s = 20.0;
  StartDaemon();
  PlayRelaxingTrial();
  ASSERT_TRUE(Drive(
      [&] {
        for (const flexid::alert_t& a : AlertsOf("model_changed"))
          if (a.text.find("model version 2 is active") != std::string::npos) return true;
        return false;
      },
      60s))
      << "the augmented model was not adopted";
  ASSERT_FALSE(AlertsOf("policy").empty());
  EXPECT_NE(AlertsOf("policy").front().text.find("diagnosing it (policy.on_alert adopt)"),
            std::string::npos)
      << AlertsOf("policy").front().text;
  ASSERT_EQ(AlertsOf("model_proposed").size(), 1u);
  EXPECT_NE(AlertsOf("model_proposed").front().text.find("adopted"), std::string::npos);
  ASSERT_TRUE(Drive(
      [&] {
        const auto active = storage::Database::Open(config_.database).ActiveModel("S1");
        return active && active->version == 2;
      },
      10s));
  const auto active = storage::Database::Open(config_.database).ActiveModel("S1");
  const nlohmann::json lineage = nlohmann::json::parse(active->lineage_json);
  EXPECT_EQ(lineage.value("proposed_by", ""), "policy");
  EXPECT_EQ(lineage.value("parent_version", 0), 1);
  EXPECT_GE(lineage.value("heldout_gain", 0.0), 3.0);
}

TEST_F(DaemonPolicy, NoneLeavesATrialThatRaisedAlertsAlone) {
  StoreModel(model::FromTsModel(model::SeedTsModel()), true);
  config_.policy.on_alert = "none";
  config_.trial_idle_stop_s = 20.0;
  StartDaemon();
  PlayRelaxingTrial();
  Drive([] { return false; }, 2s);
  EXPECT_FALSE(bus_->AlertsOf("residual").empty() && bus_->AlertsOf("back_relaxation").empty());
  EXPECT_TRUE(AlertsOf("policy").empty());
  EXPECT_TRUE(AlertsOf("model_proposed").empty());
  EXPECT_EQ(storage::Database::Open(config_.database).Models("S1").size(), 1u);
}

TEST(DaemonPolicyConfig, AnOnAlertValueNotOfTheFourIsRefusedInOneLine) {
  daemon::Config config;
  config.policy.on_alert = "always";
  try {
    daemon::Validate(config);
    FAIL() << "on_alert = always was accepted";
  } catch (const daemon::ConfigError& e) {
    EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("policy.on_alert"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("\"always\""), std::string::npos) << e.what();
  }
  config.policy.on_alert = "propose";
  EXPECT_NO_THROW(daemon::Validate(config));
}

}  // namespace
}  // namespace flexid
