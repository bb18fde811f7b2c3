// The user's whole loop on the live service (issue 15): flexidd, the rig and the command
// line as separate processes on udpm (ttl=0, a random port) and SQLite (live_daemon.h).
// A model is identified; a trial with back-relaxation raises alerts; its diagnosis is
// proposed as a new inactive version with its lineage; activating it and replaying the
// same trial leaves a residual at the sensor's noise and no alert. Bad input on the way
// (a missing trial, an unknown version, a stale proposal) is refused in one line and
// changes nothing that is stored.
#include <gtest/gtest.h>

#include <chrono>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <string>
#include <thread>

#include "child_process.h"
#include "live_daemon.h"
#include "scratch_dir.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using nlohmann::json;
using testing::LiveDaemon;
using testing::ProcessResult;

constexpr char kSquare[] = "square:level=2,period=220,duty=0.5,cycles=2";
constexpr char kRelaxing[] = "--effect back_relaxation:fraction=0.3,tau=60";
constexpr double kNoise_mm = 0.02;  // the rig's (LiveDaemon::RecordTrial)

json Models(const LiveDaemon& daemon) {
  const ProcessResult r = daemon.Flexid("rpc models '{\"actuator\": \"S1\"}' --timeout 5");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  const json list = json::parse(r.out, nullptr, false);
  return list.is_array() ? list : json::array();
}

int ActiveVersion(const json& models) {
  for (const json& m : models)
    if (m.value("active", false)) return m.value("version", 0);
  return 0;
}

// One line, naming the problem: what a refused input must get.
void ExpectOneLineError(const ProcessResult& r, const std::string& words) {
  EXPECT_NE(r.exit_code, 0);
  EXPECT_NE(r.err.find(words), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
}

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(Story, AProposedAugmentedModelQuietsTheTrialItWasDiagnosedOn) {
  const testing::ScratchDir scratch;
  LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  daemon.RecordTrial(kSquare);
  daemon.RecordTrial("square:level=8,period=220,duty=0.5,cycles=2");
  const ProcessResult identified = daemon.Flexid("identify --actuator S1 --latest 2");
  ASSERT_EQ(identified.exit_code, 0) << identified.err;
  const int64_t relaxing_trial = daemon.RecordTrial(kSquare, kRelaxing);

  // A proposal for a trial that does not exist: refused, nothing stored.
  ExpectOneLineError(daemon.Flexid("diagnose --actuator S1 --trial 99 --propose"), "trial 99");
  ASSERT_EQ(Models(daemon).size(), 1u);

  const ProcessResult proposed = daemon.Flexid(
      "diagnose --actuator S1 --trial " + std::to_string(relaxing_trial) + " --propose --json");
  ASSERT_EQ(proposed.exit_code, 0) << proposed.err;
  const json diagnosis = json::parse(proposed.out, nullptr, false);
  ASSERT_TRUE(diagnosis.is_object()) << proposed.out;
  EXPECT_EQ(diagnosis.value("verdict", ""), "back_relaxation");
  ASSERT_EQ(diagnosis.value("proposed_version", 0), 2) << proposed.out;
  EXPECT_FALSE(diagnosis.value("adopted", true));

  // Version 2: inactive, with its lineage.
  json models = Models(daemon);
  ASSERT_EQ(models.size(), 2u);
  EXPECT_EQ(ActiveVersion(models), 1);
  const json lineage = models[0].value("lineage", json());
  ASSERT_TRUE(lineage.is_object()) << models[0].dump(2);
  EXPECT_EQ(lineage.value("parent_version", 0), 1);
  EXPECT_EQ(lineage.value("proposed_by", ""), "diagnose");
  EXPECT_EQ(lineage.value("trials", json()), json::array({relaxing_trial}));
  ASSERT_EQ(lineage.value("effects", json()).size(), 1u);
  EXPECT_EQ(lineage["effects"][0].value("effect", ""), "back_relaxation");
  EXPECT_TRUE(lineage["effects"][0]["params"]["tau_s"]["half_width_95"].is_number());
  EXPECT_GT(lineage.value("heldout_gain", 0.0), 2.0);
  const ProcessResult shown = daemon.Flexid("models show --actuator S1 --version 2");
  EXPECT_NE(shown.out.find("proposed on v1 by diagnose"), std::string::npos) << shown.out;
  const ProcessResult listed = daemon.Flexid("models list --actuator S1");
  EXPECT_NE(listed.out.find("v1 + back_relaxation"), std::string::npos) << listed.out;

  // An unknown version is refused; the proposal is activated.
  ExpectOneLineError(daemon.Flexid("models activate --actuator S1 99"), "no model version 99");
  EXPECT_EQ(ActiveVersion(Models(daemon)), 1);
  const ProcessResult activated = daemon.Flexid("models activate --actuator S1 2");
  ASSERT_EQ(activated.exit_code, 0) << activated.err;
  EXPECT_EQ(ActiveVersion(Models(daemon)), 2);

  // The same trial again, watched live: the residual is at the noise, nothing is raised.
  testing::ChildProcess watch({FLEXID_BINARY, "--lcm", daemon.url(), "watch", "--seconds", "15",
                               "--actuator", "S1", "--every", "1000"},
                              (scratch.path() / "watch.out").string(),
                              (scratch.path() / "watch.err").string());
  std::this_thread::sleep_for(1s);  // subscribed before the rig starts
  daemon.RecordTrial(kSquare, kRelaxing);
  ASSERT_TRUE(watch.Wait(30s).has_value());
  const std::string watched = ReadFile(scratch.path() / "watch.out");
  std::smatch summary;
  ASSERT_TRUE(std::regex_search(
      watched, summary,
      std::regex(R"(summary S1: (\d+) predictions \(model v2\), residual RMS ([0-9.e+-]+) mm; )"
                 R"(alerts: (.*)\n)")))
      << watched;
  EXPECT_GT(std::stoi(summary[1].str()), 4000);  // of 4400; a few may be lost on UDP
  EXPECT_LT(std::stod(summary[2].str()), 2.0 * kNoise_mm) << watched;
  EXPECT_EQ(summary[3].str().find("residual"), std::string::npos) << watched;
  EXPECT_EQ(summary[3].str().find("back_relaxation"), std::string::npos) << watched;

  // Identified again, version 3 is active: the proposal on version 1 is stale now.
  ASSERT_EQ(daemon.Flexid("identify --actuator S1 --latest 2").exit_code, 0);
  EXPECT_EQ(ActiveVersion(Models(daemon)), 3);
  ExpectOneLineError(daemon.Flexid("models activate --actuator S1 2"),
                     "version 2 is a proposal on version 1, but version 3 is active");
  EXPECT_EQ(ActiveVersion(Models(daemon)), 3);
}

}  // namespace
}  // namespace flexid
