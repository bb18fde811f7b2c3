// The stored-model commands of the flexid command line against a running flexidd
// (live_daemon.h) and offline on its database file (--db): identify --actuator, models
// list|show|diff|activate, and simulate/diagnose on stored models and trials.
//
// Each test starts its own daemon (ctest runs every test in its own process); the two
// square-wave trials at 2 V and 8 V take ~9 s of rig time at 100x, identification ~1 s.
#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "cli_process.h"
#include "live_daemon.h"
#include "scratch_dir.h"

namespace flexid {
namespace {

using nlohmann::json;
using testing::LiveDaemon;
using testing::ProcessResult;

size_t Lines(const std::string& text) {
  return static_cast<size_t>(std::count(text.begin(), text.end(), '\n'));
}

json ParseJson(const ProcessResult& r) {
  json j = json::parse(r.out, nullptr, false);
  EXPECT_FALSE(j.is_discarded()) << "not one JSON document:\n" << r.out;
  return j;
}

class CliModels : public ::testing::Test {
 protected:
  void SetUp() override { daemon_ = std::make_unique<LiveDaemon>(scratch_.path()); }

  // `flexid --db FILE ARGS` on the daemon's database file.
  ProcessResult Offline(const std::string& args) const {
    return testing::RunCommand(
        std::string(FLEXID_BINARY) + " --db '" + daemon_->db().string() + "' " + args,
        scratch_.path());
  }
  ProcessResult Online(const std::string& args) const { return daemon_->Flexid(args); }

  // A 2 V and an 8 V square-wave trial of S1.
  void RecordTwoTrials() {
    trial_2V_ = daemon_->RecordTrial("square:level=2,period=220,duty=0.5,cycles=2");
    trial_8V_ = daemon_->RecordTrial("square:level=8,period=220,duty=0.5,cycles=2");
  }

  testing::ScratchDir scratch_;
  std::unique_ptr<LiveDaemon> daemon_;
  int64_t trial_2V_ = 0, trial_8V_ = 0;
};

// identify --actuator (v1 on both trials, v2 on the 8 V one), then every models
// subcommand online and on the file, and activation both ways.
TEST_F(CliModels, IdentifyListShowDiffActivate) {
  ASSERT_TRUE(daemon_->ready());
  RecordTwoTrials();
  const std::string t2 = std::to_string(trial_2V_), t8 = std::to_string(trial_8V_);

  auto r = Online("identify --actuator S1 --latest 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json v1 = ParseJson(r);
  EXPECT_EQ(v1["version"], 1);
  EXPECT_EQ(v1["active"], true);
  EXPECT_EQ(v1["trials"].size(), 2u);
  EXPECT_EQ(v1["model"]["kind"], "ts_fuzzy");
  ASSERT_EQ(v1["model"]["local_models"].size(), 2u);
  for (const json& local : v1["model"]["local_models"])  // each rule's DC gain and interval
    EXPECT_GT(local["dc_gain"]["half_width_95"].get<double>(), 0.0) << local.dump();
  EXPECT_EQ(v1["model"]["structure"]["method"], "global");  // the path `flexid identify` takes
  EXPECT_GT(v1["fit"]["fit_percent"].get<double>(), 80.0);

  r = Online("identify --actuator S1 --trials " + t8 + " --out " + scratch_.File("v2.json"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("S1 model v2 identified in flexidd from trials " + t8 + " and made active"),
            std::string::npos)
      << r.out;
  EXPECT_NE(r.out.find("DC gain mm/V"), std::string::npos) << r.out;
  EXPECT_TRUE(std::filesystem::exists(scratch_.path() / "v2.json"));

  // list: two versions, v2 active; the file gives the same document.
  r = Online("models list --actuator S1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("S1: 2 models (v2 active)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("RMSE mm"), std::string::npos) << r.out;
  EXPECT_EQ(Lines(r.out), 4u) << r.out;  // title, header, two rows
  r = Online("models list --actuator S1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json list = testing::RowsWithoutSource(r.out, "models");
  ASSERT_EQ(list.size(), 2u);
  EXPECT_EQ(list[0]["version"], 2);
  EXPECT_EQ(list[0]["active"], true);
  EXPECT_EQ(list[1]["active"], false);
  auto offline = Offline("models list --actuator S1 --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(testing::RowsWithoutSource(offline.out, "models"), list);

  // show: summary and model; --json is the stored record; --out a usable model file.
  r = Online("models show --actuator S1 --version 1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* text : {"S1 model v1 (not active)", "identified from trials",
                           "T-S fuzzy model, 2 rules", "DC gain:", "dead time:", "zeros:"})
    EXPECT_NE(r.out.find(text), std::string::npos) << text << "\n" << r.out;
  r = Online("models show --actuator S1 --version 1 --json --out " + scratch_.File("v1.json"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json shown = ParseJson(r);
  EXPECT_EQ(shown["version"], 1);
  EXPECT_EQ(shown["model"], v1["model"]);
  offline = Offline("models show --actuator S1 --version 1 --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(ParseJson(offline), shown);
  r = Online("tf show " + scratch_.File("v1.json") + " --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ParseJson(r)["local_models"].size(), 2u);

  // diff v1 v2: the 8 V models compared, the 2 V one only in v1; step responses.
  r = Online("models diff --actuator S1 1 2");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* text :
       {"S1 model v1 -> S1 model v2", "local model at 8 V", "local model at 2 V (only in v1)",
        "DC gain mm/V", "dead time s", "largest difference mm", "fit %"})
    EXPECT_NE(r.out.find(text), std::string::npos) << text << "\n" << r.out;
  r = Online("models diff --actuator S1 1 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json diff = ParseJson(r);
  ASSERT_EQ(diff["local_models"].size(), 2u);
  EXPECT_NEAR(diff["local_models"][0]["level_V"].get<double>(), 2.0, 0.3);
  EXPECT_TRUE(diff["local_models"][0]["b"].is_null());
  const json& at8 = diff["local_models"][1];
  EXPECT_NEAR(at8["level_V"].get<double>(), 8.0, 0.5);
  EXPECT_TRUE(at8["change"]["dc_gain_percent"].is_number()) << at8.dump();
  EXPECT_TRUE(diff["fit_change"]["fit_percent"].is_number());
  ASSERT_EQ(diff["step_responses"].size(), 2u);
  // v1 blends 2 V and 8 V, v2 knows only 8 V: at 2 V they must differ clearly.
  EXPECT_GT(diff["step_responses"][0]["max_abs_difference_mm"].get<double>(), 0.01);
  offline = Offline("models diff --actuator S1 1 2 --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(ParseJson(offline), diff);
  // A version against its own file: no difference at all.
  r = Online("models diff --actuator S1 2 " + scratch_.File("v2.json") + " --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json same = ParseJson(r);  // named: a range-for over a member of a temporary dangles
  for (const json& step : same.at("step_responses"))
    EXPECT_EQ(step["max_abs_difference_mm"].get<double>(), 0.0) << step.dump();

  // activate: online switches at once; offline writes the file and says so.
  r = Online("models activate --actuator S1 1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out, "S1: model v1 active (was v2)\n");
  r = Online("models list --actuator S1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ParseJson(r)["models"][1]["active"], true);  // v1
  r = Online("rpc actuators");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(ParseJson(r)[0]["model_version"], 1);  // flexidd predicts with it
  offline = Offline("models activate --actuator S1 2 --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(ParseJson(offline)["previous_version"], 1);
  offline = Offline("models activate --actuator S1 2");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_NE(offline.out.find("S1: model v2 was already active"), std::string::npos) << offline.out;
  EXPECT_NE(offline.out.find("until it is restarted"), std::string::npos) << offline.out;

  // Offline identification reads the stored trials and stores nothing.
  offline = Offline("identify --trials " + t2 + "," + t8 + " --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  const json local = ParseJson(offline);
  EXPECT_EQ(local["kind"], "ts_fuzzy");
  EXPECT_EQ(local["identified_from_trials"], json::array({trial_2V_, trial_8V_}));
  EXPECT_GT(local["fit"]["fit_percent"].get<double>(), 80.0);
  // flexidd's model file of the same trials, in the same order (v1: its latest two,
  // newest first), has the same members: one document builder serves both.
  std::string v1_trials;
  for (const json& id : v1["model"]["identified_from_trials"])
    v1_trials += (v1_trials.empty() ? "" : ",") + std::to_string(id.get<int64_t>());
  offline = Offline("identify --trials " + v1_trials + " --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  const json offline_v1 = ParseJson(offline);
  for (const auto& [key, value] : offline_v1.items())
    EXPECT_TRUE(v1["model"].contains(key)) << "flexidd's model file lacks \"" << key << "\"";
  for (const auto& [key, value] : v1["model"].items())
    EXPECT_TRUE(offline_v1.contains(key)) << "the offline model file lacks \"" << key << "\"";
  EXPECT_EQ(v1["model"]["identified_from"], offline_v1["identified_from"]);
  offline = Offline("models list --actuator S1 --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(ParseJson(offline)["models"].size(), 2u);
}

// simulate and diagnose on stored models and trials, online and on the file.
TEST_F(CliModels, SimulateAndDiagnoseStoredTrials) {
  ASSERT_TRUE(daemon_->ready());
  RecordTwoTrials();
  const std::string t2 = std::to_string(trial_2V_);
  auto r = Online("identify --actuator S1 --latest 2");
  ASSERT_EQ(r.exit_code, 0) << r.err;

  r = Online("simulate --actuator S1 --trial " + t2);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out.rfind("t_s,voltage_V,predicted_mm\n", 0), 0u);
  r = Online("rpc trials '{\"actuator\": \"S1\"}'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  int64_t samples = 0;
  for (const json& t : ParseJson(r))
    if (t["id"] == trial_2V_) samples = t["samples"].get<int64_t>();
  EXPECT_GT(samples, 1000);
  EXPECT_EQ(Lines(Online("simulate --actuator S1 --trial " + t2).out),
            static_cast<size_t>(samples) + 1);
  auto offline = Offline("simulate --actuator S1 --version 1 --trial " + t2 + " --out " +
                         scratch_.File("pred.csv"));
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  const size_t at = offline.out.find("fit ");
  ASSERT_NE(at, std::string::npos) << offline.out;
  EXPECT_GT(std::stod(offline.out.substr(at + 4)), 80.0) << offline.out;  // identified on it

  r = Online("diagnose --actuator S1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json online = ParseJson(r);
  EXPECT_TRUE(online["verdict"].is_string());
  EXPECT_EQ(online["model_version"], 1);
  EXPECT_TRUE(online["baseline"]["rmse_mm"].is_number());

  const auto report = scratch_.path() / "trial.html";
  offline = Offline("diagnose --trial " + t2 + " --actuator S1 --json --report " + report.string());
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  const json here = ParseJson(offline);
  EXPECT_TRUE(here["verdict"].is_string());
  EXPECT_EQ(here["trial"], trial_2V_);
  EXPECT_EQ(here["model_version"], 1);
  EXPECT_TRUE(std::filesystem::exists(report));

  // Both trials in one diagnosis: in flexidd (its latest two, oldest first) and here.
  r = Online("diagnose --actuator S1 --recent 2 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const json recent = ParseJson(r);
  EXPECT_EQ(recent["trials"], json::array({trial_2V_, trial_8V_}));
  EXPECT_EQ(recent["recordings"].size(), 2u);
  EXPECT_TRUE(recent["verdict"].is_string());
  offline = Offline("diagnose --trial " + t2 + " --trial " + std::to_string(trial_8V_) +
                    " --no-model --json");
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  const json both = ParseJson(offline);
  EXPECT_EQ(both["trials"], json::array({trial_2V_, trial_8V_}));
  EXPECT_EQ(both["model_version"], 0);
  r = Online("diagnose --actuator S1 --trial " + t2 + " --trial " + t2);
  EXPECT_EQ(r.exit_code, 2) << r.out;
  EXPECT_NE(r.err.find("given twice"), std::string::npos) << r.err;
  r = Online("rpc diagnose '{\"actuator\": \"S1\", \"trial\": " + t2 + ", \"recent\": 2}'");
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find("one of"), std::string::npos) << r.err;
}

TEST_F(CliModels, BadInputExitsTwoWithOneLine) {
  ASSERT_TRUE(daemon_->ready());
  testing::WriteFile(scratch_.path() / "rec.csv", "t_s,voltage_V,deflection_mm\n0,0,0\n0.1,1,0\n");
  const std::string rec = scratch_.File("rec.csv");
  for (const std::string& args : std::vector<std::string>{
           "models list --actuator S9", "models show --actuator S1 --version 99",
           "models show --actuator S1 --version abc", "models activate --actuator S1 99",
           "models diff --actuator S1 1 99", "models diff 1 2",
           "identify " + rec + " --actuator S1", "identify --actuator S1 --trials abc",
           "identify --actuator S1 --trials 3 --latest 2", "identify --trials 3",
           "diagnose " + rec + " --actuator S1", "diagnose",
           "simulate --actuator S1 " + rec + " --model x.json", "simulate --model x.json",
           "simulate --actuator S1 --trial 99"}) {
    const ProcessResult r = Online(args);
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.out << r.err;
    EXPECT_EQ(Lines(r.err), 1u) << args << "\n" << r.err;
  }
  for (const std::string args : {"models list --actuator S9", "models show --actuator S1",
                                 "identify --trials 99", "diagnose --trial 99"}) {
    const ProcessResult r = Offline(args);
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.out << r.err;
    EXPECT_EQ(Lines(r.err), 1u) << args << "\n" << r.err;
  }
  for (const char* command : {"models list", "models show", "models diff", "models activate"}) {
    const ProcessResult r = Online(std::string(command) + " --help");
    EXPECT_EQ(r.exit_code, 0) << command;
    EXPECT_NE(r.out.find("Example"), std::string::npos) << command << "\n" << r.out;
  }
}

}  // namespace
}  // namespace flexid
