// flexid-rig run again and again against a running flexidd (live_daemon.h: flexidd, the
// rig and the command line as separate processes on udpm, ttl=0, a random port): without
// --start-utime each run continues message time after the latest sample flexidd has seen,
// so an accelerated run followed by another is no source clock jump.
#include <gtest/gtest.h>

#include <chrono>
#include <nlohmann/json.hpp>
#include <regex>
#include <string>
#include <thread>

#include "bus/clock.h"
#include "live_daemon.h"
#include "scratch_dir.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using testing::LiveDaemon;
using testing::ProcessResult;

constexpr char kContinued[] = "flexid-rig: message time continues after flexidd's latest sample";

// The utime of the last sample a run published, from its summary line; -1 if none.
int64_t FinalUtime(const std::string& summary) {
  std::smatch match;
  if (!std::regex_search(summary, match, std::regex("final utime (\\d+)"))) return -1;
  return std::stoll(match[1].str());
}

// flexidd's "status" reply (an empty object if it did not answer).
nlohmann::json Status(const LiveDaemon& daemon) {
  const ProcessResult r = daemon.Flexid("rpc status --timeout 2");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json status = nlohmann::json::parse(r.out, nullptr, false);
  return status.is_object() ? status : nlohmann::json::object();
}

// S1's trials once `count` of them are stored and none is recording any more (newest
// first); what flexidd lists after 20 s otherwise.
nlohmann::json FinishedTrials(const LiveDaemon& daemon, size_t count) {
  nlohmann::json list = nlohmann::json::array();
  const auto end = std::chrono::steady_clock::now() + 20s;
  while (std::chrono::steady_clock::now() < end) {
    const ProcessResult r = daemon.Flexid("rpc trials '{\"actuator\": \"S1\"}' --timeout 2");
    list = nlohmann::json::parse(r.out, nullptr, false);
    bool finished = r.exit_code == 0 && list.is_array() && list.size() >= count;
    for (const auto& trial : list.is_array() ? list : nlohmann::json::array())
      finished = finished && trial.value("state", "") != "recording";
    if (finished) return list;
    std::this_thread::sleep_for(200ms);
  }
  return list;
}

// The README's command line, twice in a row: --speed 200 with trial control, no
// --start-utime. The first run covers 60 s of message time in 0.3 s of wall time; had the
// second started at the wall clock again, flexidd would have seen S1's clock jump back by
// about 60 s, raised "clock_jump" and ended the trial "interrupted".
TEST(RigLive, RunsInARowContinueMessageTimeAndCompleteTheirTrials) {
  const testing::ScratchDir scratch;
  LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  const nlohmann::json idle = Status(daemon);
  EXPECT_TRUE(idle.contains("latest_utime") && idle["latest_utime"].is_null()) << idle.dump(2);
  const std::string rig = std::string(FLEXID_RIG_BINARY) + " --lcm '" + daemon.url() +
                          "' --actuator S1 --protocol step:level=2,duration=60 --speed 200 "
                          "--noise-mm 0.02 --trial-control --key-file '" +
                          daemon.key_file().string() + "'";

  // flexidd has seen no sample: the first run starts at the wall clock, silently.
  const int64_t wall_before_utime = bus::WallClockUtime();
  const ProcessResult first = testing::RunCommand(rig, scratch.path());
  const int64_t wall_after_utime = bus::WallClockUtime();
  ASSERT_EQ(first.exit_code, 0) << first.err;
  EXPECT_EQ(first.err, "");
  const int64_t first_final_utime = FinalUtime(first.out);
  ASSERT_GT(first_final_utime, 0) << first.out;
  ASSERT_EQ(FinishedTrials(daemon, 1).size(), 1u);
  // flexidd's status now says where message time stands: the first run's last sample
  // (within its last second, should UDP have dropped the very last messages).
  const int64_t latest_utime = Status(daemon).value("latest_utime", int64_t{-1});
  EXPECT_LE(latest_utime, first_final_utime);
  EXPECT_GT(latest_utime, first_final_utime - 1'000'000);

  const ProcessResult second = testing::RunCommand(rig, scratch.path());
  ASSERT_EQ(second.exit_code, 0) << second.err;
  EXPECT_NE(second.err.find(kContinued), std::string::npos) << second.err;
  ASSERT_EQ(FinishedTrials(daemon, 2).size(), 2u);

  // --start-utime still decides: a third run 10 minutes of message time later, as given
  // (under health.clock_jump_forward_s, which would end its trial).
  const int64_t given_utime = FinalUtime(second.out) + 600'000'000;
  const ProcessResult third =
      testing::RunCommand(rig + " --start-utime " + std::to_string(given_utime), scratch.path());
  ASSERT_EQ(third.exit_code, 0) << third.err;
  EXPECT_EQ(third.err, "");

  const nlohmann::json trials = FinishedTrials(daemon, 3);
  ASSERT_EQ(trials.size(), 3u) << trials.dump(2);
  for (const auto& trial : trials) EXPECT_EQ(trial.value("state", ""), "complete") << trial.dump();
  // Newest first. The first at the wall clock; the second 1 s (kRestartGap_s) after the
  // latest sample flexidd had seen, after the first trial's stop; the third where it was
  // told.
  const int64_t first_start_utime = trials[2].at("start_utime").get<int64_t>();
  EXPECT_GE(first_start_utime, wall_before_utime);
  EXPECT_LE(first_start_utime, wall_after_utime);
  EXPECT_EQ(trials[1].at("start_utime").get<int64_t>(), latest_utime + 1'000'000);
  EXPECT_GT(trials[1].at("start_utime").get<int64_t>(), trials[2].at("end_utime").get<int64_t>());
  EXPECT_EQ(trials[0].at("start_utime").get<int64_t>(), given_utime);

  // No clock jump in what flexidd raised and stored, and no sample refused as out of order
  // (a jump back is confirmed only after clock_jump_messages refusals).
  const ProcessResult alerts = daemon.Flexid("rpc alerts '{}' --timeout 2");
  ASSERT_EQ(alerts.exit_code, 0) << alerts.err;
  const nlohmann::json stored = nlohmann::json::parse(alerts.out, nullptr, false);
  ASSERT_TRUE(stored.is_array()) << alerts.out;
  for (const auto& alert : stored) EXPECT_NE(alert.value("kind", ""), "clock_jump") << alert.dump();
  const nlohmann::json status = Status(daemon);
  EXPECT_EQ(status.value("rejected_out_of_order", int64_t{-1}), 0) << status.dump(2);
}

// flexidd restarted between two runs: its status still says where message time stands
// (the stored trials' latest time), so the second run continues after the first trial
// instead of starting at the wall clock, a minute of message time before that trial's end.
TEST(RigLive, AfterARestartARunContinuesAfterTheStoredTrials) {
  const testing::ScratchDir scratch;
  const std::string protocol =
      " --actuator S1 --protocol step:level=2,duration=60 --speed 200 "
      "--noise-mm 0.02 --trial-control --key-file '";
  int64_t first_end_utime = 0;
  {
    LiveDaemon daemon(scratch.path());
    ASSERT_TRUE(daemon.ready());
    const ProcessResult first =
        testing::RunCommand(std::string(FLEXID_RIG_BINARY) + " --lcm '" + daemon.url() + "'" +
                                protocol + daemon.key_file().string() + "'",
                            scratch.path());
    ASSERT_EQ(first.exit_code, 0) << first.err;
    const nlohmann::json trials = FinishedTrials(daemon, 1);
    ASSERT_EQ(trials.size(), 1u) << trials.dump(2);
    first_end_utime = trials[0].at("end_utime").get<int64_t>();
    // The accelerated run ran ahead of the wall clock: a restart at the wall clock would
    // start before this trial's end.
    ASSERT_GT(first_end_utime, bus::WallClockUtime() + 30'000'000);
  }
  LiveDaemon daemon(scratch.path());  // the same file, a new process
  ASSERT_TRUE(daemon.ready());
  const nlohmann::json status = Status(daemon);
  ASSERT_TRUE(status.contains("latest_utime") && status["latest_utime"].is_number_integer())
      << status.dump(2);
  EXPECT_EQ(status["latest_utime"].get<int64_t>(), first_end_utime);

  const ProcessResult second =
      testing::RunCommand(std::string(FLEXID_RIG_BINARY) + " --lcm '" + daemon.url() + "'" +
                              protocol + daemon.key_file().string() + "'",
                          scratch.path());
  ASSERT_EQ(second.exit_code, 0) << second.err;
  EXPECT_NE(second.err.find(kContinued), std::string::npos) << second.err;
  const nlohmann::json trials = FinishedTrials(daemon, 2);
  ASSERT_EQ(trials.size(), 2u) << trials.dump(2);
  // Newest first: the second trial starts 1 s (kRestartGap_s) after the first one's end.
  EXPECT_EQ(trials[0].at("start_utime").get<int64_t>(), first_end_utime + 1'000'000);
  for (const auto& trial : trials) EXPECT_EQ(trial.value("state", ""), "complete") << trial.dump();
}

}  // namespace
}  // namespace flexid
