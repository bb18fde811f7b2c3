// The fault matrix of issue 7, against the real flexidd binary. The documented behaviour
// (README, "Reliability so far"; daemon/health.h; configuration table [health]):
//
// Everywhere: a sample counts as acknowledged once STATUS (or the "status" reply) counts it
// in samples_stored, i.e. once its transaction has committed. No fault loses an
// acknowledged sample or corrupts the file (PRAGMA integrity_check, foreign keys, trial
// counts: Database::IntegrityCheck), except where the operator deletes the file itself.
// Health events are logged and published on FLEXID/ALERT (actuator_id empty when they
// concern the daemon as a whole) and stored with the alerts once the database takes writes.
//
// 1. kill -9 at any moment under load: every acknowledged sample is in the file, the file
//    is intact, and the next start marks the trial "interrupted", ending at its last
//    stored sample. Unacknowledged samples (at most ~one commit interval) may be lost.
// 2. Disk full (writes fail with ENOSPC): alert "storage_failing" ("storage failing: disk
//    full: ..."), critical. samples_stored stops; the samples wait in the writer's queue
//    (health.writer_queue_samples, default 2^18 = 32 s of 16 actuators x 500 Hz) and the
//    writer retries every commit interval. When the queue is full, alert "samples_dropped"
//    once, then the dropped samples are counted (STATUS dropped_queue_full, the log once a
//    second); they were never acknowledged. When a commit succeeds again, alert
//    "storage_recovered" saying for how long and how many were dropped; everything held is
//    committed.
// 3. A file system gone read-only (EROFS while running): the same.
//    SQLite reports such a write as "disk I/O error", so the alert says "I/O error".
//    Started on a database that cannot be written: flexidd exits 1 naming the file (a
//    read-only file is refused by Database::Open; as root, permissions do not stop writes,
//    so a chmod after start changes nothing until the next start).
//    Locked database (another connection holds the write lock beyond the 5 s busy
//    timeout): the same, "database locked"; commits resume when the lock is released.
// 4. Database file deleted (or replaced) under the daemon: noticed within a second (the
//    path no longer names the file the daemon opened): alert "database_replaced",
//    critical. A new database is created at the path (leftover -wal/-shm of the deleted
//    file removed first), actuators written again, each trial recording continues as a new
//    trial there (same protocol and start), and the writer moves its queued samples to it.
//    Everything in the deleted file is gone with it, including samples acknowledged before
//    it was noticed (samples_stored is not taken back: it counts commits); every sample
//    that arrives after the alert is in the new file.
// 5. A source that stops delivering (the rig dies, the network goes quiet): with a trial
//    recording, alert "input_silent" ("no input from S1 for N s") after
//    health.input_silence_s (default 5 s, wall time: message time stops with the source);
//    after health.input_silence_stop_s (default 60 s; 0: never) the trial ends
//    "interrupted" at its last sample. When messages return, alert "input_resumed"; an
//    automatic trial starts again by the usual rule.
// 6. Source clock jumps: a message at or before its stream's last utime is rejected and
//    counted (out of order), as is one more than clock_jump_forward_s (3600 s) ahead
//    while a trial records. When clock_jump_messages (10) consecutive messages agree on a
//    new time base at least clock_jump_back_s (5 s) behind, or that far ahead, the clock
//    jumped: alert "clock_jump" ("source clock of S1 jumped back by 3600.0 s"), the trial
//    ends "interrupted" at its last sample, a manual trial continues as a new trial (an
//    automatic one restarts by the usual rule), prediction and monitor start over. So a
//    trial never spans a jump, and a jump costs 9 rejected messages per stream. The host's
//    wall clock plays no part in recording (message time throughout; the wall clock only
//    stamps STATUS and RPC replies and times silences on the steady clock).
// 7. Sensor stops while voltage continues: alert "sensor_dropout" once the deflection
//    stream has been quiet for alerts.dropout_s (2 s) of message time while voltage
//    messages continue; recording goes on in the same trial when the sensor returns.
//
// Each test runs flexidd on its own udpm port (ttl=0) and scratch directory, and writes
// what it tried to $FLEXID_FAULT_LOG when set (bench/fault-table).
#include <gtest/gtest.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "child_process.h"
#include "daemon/health.h"
#include "fault_harness.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using testing::Bus;
using testing::ChildProcess;
using testing::DescribeStatus;
using testing::FaultRecord;
using testing::RandomUrl;
using testing::ReadFile;
using testing::RecordFault;
using testing::SamplePublisher;

constexpr int64_t kStartUtime = 1'700'000'000'000'000;

// What a database file holds, read with a connection of its own.
struct DatabaseSummary {
  std::string integrity;
  std::vector<storage::Trial> trials;  // oldest first
  int64_t samples = 0;                 // over all trials
  std::vector<storage::Sample> all;    // every sample, by trial then utime
};

DatabaseSummary Summarise(const std::string& path) {
  DatabaseSummary out;
  storage::Database db = storage::Database::Open(path);
  out.integrity = db.IntegrityCheck();
  out.trials = db.Trials(std::nullopt, -1);
  std::reverse(out.trials.begin(), out.trials.end());
  for (const storage::Trial& t : out.trials) {
    out.samples += t.samples;
    const auto samples = db.Samples(t.id);
    out.all.insert(out.all.end(), samples.begin(), samples.end());
  }
  return out;
}

// flexidd on a scratch directory: the database in db/ (the only place the fault shim
// touches), logs beside it, the test's bus on the same random port.
class Flexidd {
 public:
  explicit Flexidd(const testing::ScratchDir& scratch)
      : scratch_(scratch), url_(RandomUrl()), bus_(url_, /*with_predictions=*/false) {
    std::filesystem::create_directories(scratch.path() / "db");
  }
  ~Flexidd() { FaultOff(); }

  bool good() { return bus_.good(); }
  Bus& bus() { return bus_; }
  const std::string& url() const { return url_; }
  std::string db() const { return scratch_.File("db/flexid.db"); }
  std::string Log() const {
    return ReadFile(scratch_.File("flexidd" + std::to_string(starts_) + ".err"));
  }

  // Starts flexidd with that TOML text as its configuration (none if empty), under the
  // fault shim if asked, and waits for its first STATUS. False if it sent none in 10 s.
  bool Start(const std::string& config = "", bool shim = false, const std::string& db_path = "") {
    bus_.Clear();
    ++starts_;
    std::vector<std::string> args = {
        FLEXIDD_BINARY, "--db",       db_path.empty() ? db() : db_path, "--lcm",
        url_,           "--log-file", scratch_.File("flexidd.log")};
    if (!config.empty()) {
      const std::string path = scratch_.File("flexidd.toml");
      std::ofstream(path) << config;
      args.insert(args.end(), {"--config", path});
    }
    std::vector<std::string> env;
    if (shim)
      env = {std::string("LD_PRELOAD=") + FLEXID_FAULT_SHIM,
             "FLEXID_FAULT_DIR=" + scratch_.File("db") + "/",
             "FLEXID_FAULT_CONTROL=" + scratch_.File("fault")};
    const std::string tag = std::to_string(starts_);
    process_ = std::make_unique<ChildProcess>(args, scratch_.File("flexidd" + tag + ".out"),
                                              scratch_.File("flexidd" + tag + ".err"), env);
    if (!process_->started()) return false;
    return bus_.PumpUntil([&] { return !bus_.statuses.empty() || !process_->Running(); }, 10s) &&
           !bus_.statuses.empty();
  }
  ChildProcess& process() { return *process_; }

  // SIGTERM; true if flexidd then exited with code 0 within 10 s.
  bool Stop() {
    if (!process_->Signal(SIGTERM)) return false;
    const auto status = process_->Wait(10s);
    EXPECT_TRUE(status.has_value()) << "flexidd ignored SIGTERM";
    if (!status) return false;
    EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0)
        << DescribeStatus(*status) << ": " << Log();
    return WIFEXITED(*status) && WEXITSTATUS(*status) == 0;
  }

  // The fault shim's switch: writes under db/ fail with that error while it is on.
  void FaultOn(const std::string& error) { std::ofstream(scratch_.File("fault")) << error << "\n"; }
  void FaultOff() { std::filesystem::remove(scratch_.File("fault")); }

  // Pumps (polling status) until `count` alerts of that kind have arrived.
  bool AwaitAlerts(const std::string& kind, size_t count, std::chrono::milliseconds timeout) {
    return bus_.PumpUntil([&] { return bus_.AlertsOf(kind).size() >= count; }, timeout, true);
  }
  // Waits until the writer has nothing queued and samples_stored holds still across two
  // STATUS messages (the publisher stopped); returns the last STATUS.
  flexid::status_t AwaitQuiet() {
    bus_.PumpUntil(
        [&] {
          const auto& s = bus_.statuses;
          return s.size() >= 2 && s.back().writer_queue_depth == 0 &&
                 s.back().samples_stored == s[s.size() - 2].samples_stored &&
                 s.back().samples_accepted == s[s.size() - 2].samples_accepted;
        },
        15s, true);
    return bus_.statuses.back();
  }

 private:
  const testing::ScratchDir& scratch_;
  std::string url_;
  Bus bus_;
  std::unique_ptr<ChildProcess> process_;
  int starts_ = 0;
};

std::string Text(const std::vector<flexid::alert_t>& alerts) {
  std::string out;
  for (const auto& a : alerts) out += "[" + a.kind + "] " + a.text + "\n";
  return out;
}

int64_t Lost(int64_t acknowledged, int64_t stored) {
  return std::max<int64_t>(0, acknowledged - stored);
}

// ---------------------------------------------------------------------------------------
// 1. kill -9 at random moments under load
// ---------------------------------------------------------------------------------------

TEST(FaultMatrix, Kill9AtRandomMomentsUnderLoadLosesNoAcknowledgedSample) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  Bus& bus = daemon.bus();
  const char* rounds_env = std::getenv("FLEXID_KILL_ROUNDS");
  const int rounds = rounds_env ? std::max(1, std::atoi(rounds_env)) : 25;
  const char* seed_env = std::getenv("FLEXID_FAULT_SEED");
  const uint32_t seed = seed_env ? static_cast<uint32_t>(std::strtoul(seed_env, nullptr, 10))
                                 : std::random_device{}();
  std::cout << "kill -9 rounds: " << rounds << ", seed " << seed << " (FLEXID_FAULT_SEED=" << seed
            << " repeats this run)\n";
  std::mt19937 random(seed);
  std::uniform_int_distribution<int> delay_ms(200, 2000);
  constexpr double kPairsPerS = 2500;  // 5,000 messages/s, 2,500 samples/s stored

  int64_t acknowledged_total = 0, lost_total = 0, beyond_total = 0;
  std::string integrity = "ok";
  int64_t previous_trial = 0, previous_samples = 0, previous_last_utime = 0;
  int interrupted_ok = 0;
  for (int round = 0; round <= rounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round) + " (seed " + std::to_string(seed) + ")");
    ASSERT_TRUE(daemon.Start()) << "flexidd sent no STATUS: " << daemon.Log();
    // The start marked the trial the previous kill left "recording" as interrupted, ending
    // at its last stored sample.
    if (previous_trial != 0) {
      storage::Database db = storage::Database::Open(daemon.db());
      const auto trial = db.FindTrial(previous_trial);
      ASSERT_TRUE(trial.has_value());
      EXPECT_EQ(trial->state, storage::TrialState::kInterrupted);
      EXPECT_EQ(trial->end_utime, previous_last_utime);
      EXPECT_EQ(trial->samples, previous_samples);
      interrupted_ok += trial->state == storage::TrialState::kInterrupted &&
                        trial->end_utime == previous_last_utime;
    }
    if (round == rounds) break;

    const int delay = delay_ms(random);
    const int64_t start_utime = kStartUtime + round * 1'000'000'000LL;
    int64_t acknowledged = 0;
    {
      SamplePublisher publisher(daemon.url(), kPairsPerS, start_utime, 400);
      bus.Pump(std::chrono::milliseconds(delay), /*poll_status=*/true);
      ASSERT_TRUE(daemon.process().Signal(SIGKILL));
      const auto killed = daemon.process().Wait(5s);
      ASSERT_TRUE(killed.has_value());
      EXPECT_TRUE(WIFSIGNALED(*killed) && WTERMSIG(*killed) == SIGKILL) << DescribeStatus(*killed);
      bus.Pump(30ms);  // replies still in flight were sent before the kill
      acknowledged = std::max<int64_t>(0, bus.MaxStored());
    }

    storage::Database db = storage::Database::Open(daemon.db());
    const std::string check = db.IntegrityCheck();
    EXPECT_EQ(check, "ok");
    if (check != "ok") integrity = check;
    const auto trials = db.Trials(std::string("S1"), 1);
    int64_t stored = 0;
    if (!trials.empty() && trials.front().start_utime >= start_utime) {
      const storage::Trial& trial = trials.front();
      EXPECT_EQ(trial.state, storage::TrialState::kRecording);
      stored = trial.samples;
      const auto samples = db.Samples(trial.id);
      ASSERT_EQ(static_cast<int64_t>(samples.size()), stored);
      previous_trial = trial.id;
      previous_samples = stored;
      previous_last_utime = samples.empty() ? trial.start_utime : samples.back().utime;
    } else {
      previous_trial = 0;  // killed before the trial started
    }
    EXPECT_GE(stored, acknowledged) << "acknowledged samples are missing after kill -9";
    std::cout << "round " << round << ": kill after " << delay << " ms, acknowledged "
              << acknowledged << ", in the file " << stored << "\n";
    acknowledged_total += acknowledged;
    lost_total += Lost(acknowledged, stored);
    beyond_total += std::max<int64_t>(0, stored - acknowledged);
  }
  EXPECT_TRUE(daemon.Stop());
  EXPECT_EQ(lost_total, 0);
  RecordFault({"kill -9 at a random moment under 5,000 messages/s", rounds, acknowledged_total,
               lost_total, integrity, interrupted_ok == rounds ? "yes" : "no",
               "seed " + std::to_string(seed) + "; delays 0.2-2 s; restart marked " +
                   std::to_string(interrupted_ok) + " of " + std::to_string(rounds) +
                   " trials interrupted; " + std::to_string(beyond_total) +
                   " samples stored beyond the last acknowledgement"});
}

// ---------------------------------------------------------------------------------------
// 2, 3. Storage that cannot be written: disk full, read-only file system, locked database
// ---------------------------------------------------------------------------------------

// One episode of a storage fault with samples coming in at 1,000/s: it is reported, no
// sample is acknowledged meanwhile, and the recovery is reported. Returns the samples
// dropped (counted) during the episode.
struct Episode {
  std::string expect_problem;  // in the storage_failing alert, e.g. "disk full"
  std::chrono::milliseconds length;
  bool expect_drops = false;
};

int64_t RunEpisode(Flexidd& daemon, const Episode& episode, const std::function<void()>& on,
                   const std::function<void()>& off) {
  Bus& bus = daemon.bus();
  const size_t failing = bus.AlertsOf("storage_failing").size();
  const size_t recovered = bus.AlertsOf("storage_recovered").size();
  const size_t dropped_alerts = bus.AlertsOf("samples_dropped").size();
  const int64_t dropped_before = bus.statuses.back().dropped_queue_full;
  const auto began = Clock::now();
  on();
  EXPECT_TRUE(daemon.AwaitAlerts("storage_failing", failing + 1, 8s))
      << "no storage_failing alert: " << Text(bus.alerts) << daemon.Log();
  if (bus.AlertsOf("storage_failing").size() > failing) {
    const std::string text = bus.AlertsOf("storage_failing").back().text;
    EXPECT_NE(text.find("storage failing: " + episode.expect_problem), std::string::npos) << text;
  }
  bus.Pump(300ms, true);
  const int64_t stored_when_failing = bus.MaxStored();
  bus.PumpUntil([&] { return Clock::now() >= began + episode.length; }, episode.length, true);
  bus.Pump(200ms, true);
  EXPECT_EQ(bus.MaxStored(), stored_when_failing)
      << "samples were acknowledged while storage was failing";
  if (episode.expect_drops) {
    EXPECT_EQ(bus.AlertsOf("samples_dropped").size(), dropped_alerts + 1) << Text(bus.alerts);
  }
  off();
  EXPECT_TRUE(daemon.AwaitAlerts("storage_recovered", recovered + 1, 12s))
      << "no storage_recovered alert: " << Text(bus.alerts) << daemon.Log();
  bus.Pump(1100ms, true);
  EXPECT_GT(bus.MaxStored(), stored_when_failing) << "commits did not resume";
  const int64_t dropped = bus.statuses.back().dropped_queue_full - dropped_before;
  if (episode.expect_drops) {
    EXPECT_GT(dropped, 0);
  } else {
    EXPECT_EQ(dropped, 0);
  }
  if (bus.AlertsOf("storage_recovered").size() > recovered)
    std::cout << "recovered: " << bus.AlertsOf("storage_recovered").back().text << "\n";
  return dropped;
}

// Stops the publisher and the daemon; checks that every acknowledged sample is stored
// and that stored + dropped (counted) + rejected == published. Returns the summary.
struct Outcome {
  int64_t acknowledged = 0, lost = 0, dropped = 0, published = 0, stored = 0;
  std::string integrity;
  DatabaseSummary summary;
};

Outcome Finish(Flexidd& daemon, SamplePublisher& publisher, int64_t expect_rejected = 0) {
  publisher.Stop();
  const flexid::status_t last = daemon.AwaitQuiet();
  Outcome out;
  out.acknowledged = std::max<int64_t>(0, daemon.bus().MaxStored());
  out.dropped = last.dropped_queue_full;
  out.published = publisher.PublishedCount();
  EXPECT_TRUE(daemon.Stop());
  out.summary = Summarise(daemon.db());
  out.integrity = out.summary.integrity;
  out.stored = out.summary.samples;
  out.lost = Lost(out.acknowledged, out.stored);
  EXPECT_EQ(out.integrity, "ok");
  EXPECT_GE(out.stored, out.acknowledged) << "acknowledged samples are missing";
  EXPECT_EQ(out.stored + out.dropped + expect_rejected, out.published)
      << "samples unaccounted for (stored " << out.stored << ", dropped " << out.dropped
      << ", rejected " << expect_rejected << ", published " << out.published << ")";
  return out;
}

TEST(FaultMatrix, DiskFullIsReportedHeldInMemoryAndRecovered) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start("[health]\nwriter_queue_samples = 3000\n", /*shim=*/true))
      << daemon.Log();
  SamplePublisher publisher(daemon.url(), 1000, kStartUtime, 1000);
  daemon.bus().Pump(1500ms, true);
  ASSERT_GT(daemon.bus().MaxStored(), 0);
  auto on = [&] { daemon.FaultOn("ENOSPC"); };
  auto off = [&] { daemon.FaultOff(); };
  // 2 s: 2,000 samples fit in the queue of 3,000; 5 s: 2,000 of 5,000 do not.
  const int64_t dropped_short = RunEpisode(daemon, {"disk full", 2000ms, false}, on, off);
  const int64_t dropped_long = RunEpisode(daemon, {"disk full", 5000ms, true}, on, off);
  const Outcome out = Finish(daemon, publisher);
  RecordFault({"disk full (ENOSPC), 2 s and 5 s", 2, out.acknowledged, out.lost, out.integrity,
               "yes",
               "held in memory, bound 3,000 samples: 2 s dropped " + std::to_string(dropped_short) +
                   ", 5 s dropped " + std::to_string(dropped_long) +
                   " unacknowledged samples, counted and announced"});
}

TEST(FaultMatrix, ReadOnlyFileSystemIsReportedAndRecovered) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  // Started on a database that cannot be written: exit 1, naming the file.
  daemon.FaultOn("EROFS");
  EXPECT_FALSE(daemon.Start("", /*shim=*/true, scratch.File("db/refused.db")));
  const auto refused = daemon.process().Wait(10s);
  ASSERT_TRUE(refused.has_value()) << "flexidd runs on a database it cannot write";
  EXPECT_TRUE(WIFEXITED(*refused) && WEXITSTATUS(*refused) == 1) << DescribeStatus(*refused);
  EXPECT_NE(daemon.Log().find("refused.db"), std::string::npos) << daemon.Log();
  daemon.FaultOff();

  ASSERT_TRUE(daemon.Start("", /*shim=*/true)) << daemon.Log();
  SamplePublisher publisher(daemon.url(), 1000, kStartUtime, 1000);
  daemon.bus().Pump(1500ms, true);
  ASSERT_GT(daemon.bus().MaxStored(), 0);
  RunEpisode(
      daemon, {"I/O error", 3000ms, false}, [&] { daemon.FaultOn("EROFS"); },
      [&] { daemon.FaultOff(); });
  const Outcome out = Finish(daemon, publisher);
  RecordFault({"file system read-only (EROFS) for 3 s; start on an unwritable database", 2,
               out.acknowledged, out.lost, out.integrity, "yes",
               "start refused with exit 1 naming the file; while running: reported, held, "
               "committed on recovery, 0 dropped"});
}

TEST(FaultMatrix, LockedDatabaseIsReportedAndRecovered) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start()) << daemon.Log();
  SamplePublisher publisher(daemon.url(), 1000, kStartUtime, 1000);
  daemon.bus().Pump(1500ms, true);
  ASSERT_GT(daemon.bus().MaxStored(), 0);
  sqlite3* other = nullptr;
  ASSERT_EQ(sqlite3_open_v2(daemon.db().c_str(), &other, SQLITE_OPEN_READWRITE, nullptr),
            SQLITE_OK);
  sqlite3_busy_timeout(other, 5000);
  // 8 s: longer than the daemon's 5 s busy timeout.
  RunEpisode(
      daemon, {"database locked", 8000ms, false},
      [&] {
        ASSERT_EQ(sqlite3_exec(other, "BEGIN EXCLUSIVE", nullptr, nullptr, nullptr), SQLITE_OK)
            << sqlite3_errmsg(other);
      },
      [&] { EXPECT_EQ(sqlite3_exec(other, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK); });
  sqlite3_close(other);
  const Outcome out = Finish(daemon, publisher);
  RecordFault({"database locked by another connection for 8 s", 1, out.acknowledged, out.lost,
               out.integrity, "yes",
               "reported after the 5 s busy timeout; held, committed when released, 0 dropped"});
}

// ---------------------------------------------------------------------------------------
// 4. The database file deleted under the daemon
// ---------------------------------------------------------------------------------------

TEST(FaultMatrix, DeletedDatabaseIsNoticedAndRecreated) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start()) << daemon.Log();
  Bus& bus = daemon.bus();
  SamplePublisher publisher(daemon.url(), 1000, kStartUtime, 1000);
  bus.Pump(1500ms, true);
  const int64_t acknowledged_in_deleted = bus.MaxStored();
  ASSERT_GT(acknowledged_in_deleted, 0);
  for (const char* suffix : {"", "-wal", "-shm"}) std::filesystem::remove(daemon.db() + suffix);
  ASSERT_TRUE(daemon.AwaitAlerts("database_replaced", 1, 5s)) << Text(bus.alerts) << daemon.Log();
  const int64_t noticed_utime = publisher.LastUtime();
  std::cout << bus.AlertsOf("database_replaced").front().text << "\n";
  // The writer moves to the new file at its next commit; from then on what is
  // acknowledged is in the new file.
  bus.Pump(300ms, true);
  const int64_t stored_in_new_file_from = bus.MaxStored();
  bus.Pump(1500ms, true);
  publisher.Stop();
  daemon.AwaitQuiet();
  const int64_t acknowledged = bus.MaxStored() - stored_in_new_file_from;
  EXPECT_TRUE(daemon.Stop());

  const DatabaseSummary summary = Summarise(daemon.db());
  EXPECT_EQ(summary.integrity, "ok");
  ASSERT_FALSE(summary.trials.empty());
  EXPECT_EQ(summary.trials.front().start_utime, kStartUtime) << "the trial did not continue";
  int64_t published_after = 0, stored_after = 0;
  for (int64_t utime : publisher.Published()) published_after += utime > noticed_utime;
  for (const storage::Sample& s : summary.all) stored_after += s.utime > noticed_utime;
  EXPECT_EQ(stored_after, published_after) << "samples that came after the alert are missing";
  EXPECT_GE(summary.samples, acknowledged);
  storage::Database db = storage::Database::Open(daemon.db());
  EXPECT_FALSE(db.Alerts(std::nullopt, 0, 100).empty()) << "the alert is not in the new file";
  RecordFault({"database file deleted under the daemon (db, -wal, -shm)", 1, acknowledged,
               Lost(acknowledged, summary.samples), summary.integrity, "yes",
               "noticed within 1 s, new file created, trial continued; the " +
                   std::to_string(acknowledged_in_deleted) +
                   "+ samples acknowledged into the deleted file went with it (by design)"});
}

// ---------------------------------------------------------------------------------------
// 5. A source that stops delivering
// ---------------------------------------------------------------------------------------

TEST(FaultMatrix, SilentSourceIsReportedAndItsTrialInterrupted) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start("[health]\ninput_silence_s = 1.0\ninput_silence_stop_s = 3.0\n"))
      << daemon.Log();
  Bus& bus = daemon.bus();
  SamplePublisher publisher(daemon.url(), 500, kStartUtime, 2000);
  bus.Pump(1000ms, true);
  // A short silence: said, and said when it ends; the trial goes on.
  publisher.Pause(true);
  const auto paused = Clock::now();
  ASSERT_TRUE(daemon.AwaitAlerts("input_silent", 1, 4s)) << Text(bus.alerts);
  const double said_after_s = std::chrono::duration<double>(Clock::now() - paused).count();
  EXPECT_NE(bus.AlertsOf("input_silent")[0].text.find("no input from S1"), std::string::npos);
  EXPECT_LE(said_after_s, 1.0 + 1.5);  // input_silence_s + the 1 s check + slack
  publisher.Pause(false);
  ASSERT_TRUE(daemon.AwaitAlerts("input_resumed", 1, 3s)) << Text(bus.alerts);
  bus.Pump(1000ms, true);
  EXPECT_EQ(bus.statuses.back().trials_recording, 1);
  // A long one: the trial ends interrupted; recording resumes in a new trial.
  publisher.Pause(true);
  ASSERT_TRUE(daemon.AwaitAlerts("input_silent", 3, 7s)) << Text(bus.alerts);
  EXPECT_NE(bus.AlertsOf("input_silent")[2].text.find("ended interrupted"), std::string::npos);
  publisher.Pause(false);
  ASSERT_TRUE(daemon.AwaitAlerts("input_resumed", 2, 3s)) << Text(bus.alerts);
  bus.Pump(1000ms, true);
  const Outcome out = Finish(daemon, publisher);
  ASSERT_EQ(out.summary.trials.size(), 2u);
  const storage::Trial& first = out.summary.trials[0];
  EXPECT_EQ(first.state, storage::TrialState::kInterrupted);
  EXPECT_GT(first.samples, 0);
  RecordFault({"LCM source stops delivering (1.8 s, then 4 s)", 2, out.acknowledged, out.lost,
               out.integrity, "yes",
               "\"no input from S1\" after 1 s (configured); after 3 s the trial ended "
               "interrupted; input_resumed and a new trial when it returned"});
}

// ---------------------------------------------------------------------------------------
// 6. Source clock jumps
// ---------------------------------------------------------------------------------------

TEST(FaultMatrix, SourceClockJumpsSplitTheTrial) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start()) << daemon.Log();
  Bus& bus = daemon.bus();
  SamplePublisher publisher(daemon.url(), 500, kStartUtime, 2000);
  bus.Pump(1000ms, true);
  publisher.ShiftClock(-3'600'000'000);  // back by an hour
  ASSERT_TRUE(daemon.AwaitAlerts("clock_jump", 1, 3s)) << Text(bus.alerts) << daemon.Log();
  EXPECT_NE(bus.alerts.back().text.find("jumped back by 3600.0 s"), std::string::npos)
      << bus.alerts.back().text;
  bus.Pump(1000ms, true);
  publisher.ShiftClock(86'400'000'000);  // forward by a day
  ASSERT_TRUE(daemon.AwaitAlerts("clock_jump", 2, 3s)) << Text(bus.alerts);
  EXPECT_NE(bus.AlertsOf("clock_jump")[1].text.find("jumped forward by 864"), std::string::npos)
      << bus.AlertsOf("clock_jump")[1].text;
  bus.Pump(1000ms, true);
  // Each jump: 9 messages per stream rejected before the new time base is taken.
  const Outcome out = Finish(daemon, publisher, /*expect_rejected=*/18);
  EXPECT_EQ(bus.statuses.back().rejected_out_of_order, 36);
  ASSERT_EQ(out.summary.trials.size(), 3u);
  for (const storage::Trial& t : out.summary.trials) {
    EXPECT_EQ(t.state, storage::TrialState::kInterrupted);  // by a jump, or SIGTERM
    EXPECT_LT(t.end_utime - t.start_utime, 10'000'000) << "a trial spans a clock jump";
    EXPECT_GT(t.samples, 0);
  }
  RecordFault({"source clock jumps: back 1 h, forward 1 day", 2, out.acknowledged, out.lost,
               out.integrity, "yes",
               "each split the trial (interrupted + new trial); 9 samples rejected and counted "
               "per jump while it is confirmed; host wall clock not used for recording"});
}

// ---------------------------------------------------------------------------------------
// 7. The sensor stops while the voltage continues
// ---------------------------------------------------------------------------------------

TEST(FaultMatrix, SensorDropoutIsReportedAndRecordingResumes) {
  testing::ScratchDir scratch;
  Flexidd daemon(scratch);
  if (!daemon.good()) GTEST_SKIP() << "no LCM multicast on this host";
  ASSERT_TRUE(daemon.Start()) << daemon.Log();
  Bus& bus = daemon.bus();
  SamplePublisher publisher(daemon.url(), 200, kStartUtime, 5000);  // real-time message time
  bus.Pump(1000ms, true);
  publisher.DeflectionOff(true);
  const auto stopped = Clock::now();
  bus.Pump(50ms);
  const int64_t last_deflection = publisher.LastUtime();
  ASSERT_TRUE(daemon.AwaitAlerts("sensor_dropout", 1, 5s)) << Text(bus.alerts);
  const double said_after_s = std::chrono::duration<double>(Clock::now() - stopped).count();
  const flexid::alert_t alert = bus.AlertsOf("sensor_dropout").front();
  EXPECT_EQ(alert.actuator_id, "S1");
  EXPECT_EQ(alert.start_utime, last_deflection);
  // dropout_s (2 s of message time) plus one voltage period.
  EXPECT_LE(alert.utime - last_deflection, 2'000'000 + 5000 + 1);
  EXPECT_LE(said_after_s, 2.0 + 0.5);
  publisher.DeflectionOff(false);
  bus.Pump(1500ms, true);
  EXPECT_TRUE(bus.AlertsOf("input_silent").empty()) << "voltage messages went on";
  const Outcome out = Finish(daemon, publisher);
  ASSERT_EQ(out.summary.trials.size(), 1u) << "the trial did not go on";
  EXPECT_GT(out.summary.all.back().utime, last_deflection + 2'000'000);
  std::cout << "sensor_dropout after " << said_after_s << " s: " << alert.text << "\n";
  RecordFault({"sensor stops while voltage continues (3 s)", 1, out.acknowledged, out.lost,
               out.integrity, "yes",
               "sensor_dropout after " + std::to_string(said_after_s).substr(0, 4) +
                   " s (limit 2 s of message time); recording went on in the same trial"});
}

// ---------------------------------------------------------------------------------------
// The pieces of daemon/health.h on their own
// ---------------------------------------------------------------------------------------

TEST(HealthPieces, ClockJumpNeedsConsecutiveAgreeingMessages) {
  using Verdict = daemon::ClockJumpDetector::Verdict;
  daemon::ClockJumpDetector clock(5'000'000, 3'600'000'000, 3);
  const int64_t t = 1'000'000'000'000;
  EXPECT_EQ(clock.Check(INT64_MIN, t, true), Verdict::kAccept);
  EXPECT_EQ(clock.Check(t, t + 1000, true), Verdict::kAccept);
  EXPECT_EQ(clock.Check(t, t, true), Verdict::kReject);              // duplicate
  EXPECT_EQ(clock.Check(t, t - 1'000'000, true), Verdict::kReject);  // a little back
  EXPECT_EQ(clock.Check(t, INT64_MAX, false), Verdict::kAccept);     // between trials
  // A stray message far back, then the stream goes on: nothing but a rejection.
  EXPECT_EQ(clock.Check(t, t - 3'600'000'000, true), Verdict::kReject);
  EXPECT_EQ(clock.Check(t, t + 2000, true), Verdict::kAccept);
  // Three in order, an hour back: a jump, on the third.
  EXPECT_EQ(clock.Check(t, t - 3'600'000'000, true), Verdict::kReject);
  EXPECT_EQ(clock.Check(t, t - 3'599'999'000, true), Verdict::kReject);
  EXPECT_EQ(clock.Check(t, t - 3'599'998'000, true), Verdict::kJumped);
  EXPECT_EQ(clock.jump_us(), -3'599'998'000);
  // Forward by a day during a trial, with one message out of order among them.
  EXPECT_EQ(clock.Check(t, t + 86'400'000'000, true), Verdict::kReject);
  EXPECT_EQ(clock.Check(t, t + 86'399'000'000, true), Verdict::kReject);  // restarts the count
  EXPECT_EQ(clock.Check(t, t + 86'399'001'000, true), Verdict::kReject);
  EXPECT_EQ(clock.Check(t, t + 86'399'002'000, true), Verdict::kJumped);
  EXPECT_EQ(clock.jump_us(), 86'399'002'000);
  // Hostile extremes do not overflow.
  EXPECT_EQ(clock.Check(INT64_MAX, INT64_MIN + 1, true), Verdict::kReject);
}

TEST(HealthPieces, StorageProblemNamesTheFault) {
  EXPECT_EQ(daemon::StorageProblem("x.db: cannot execute \"COMMIT\": database or disk is full"),
            "disk full");
  EXPECT_EQ(daemon::StorageProblem("x.db: cannot execute \"BEGIN IMMEDIATE\": database is locked "
                                   "(another connection held it for more than 5 s)"),
            "database locked");
  EXPECT_EQ(daemon::StorageProblem("x.db: cannot execute \"COMMIT\": disk I/O error"), "I/O error");
  EXPECT_EQ(daemon::StorageProblem("x.db: attempt to write a readonly database"),
            "file system read-only");
  testing::ScratchDir scratch;
  const std::string path = scratch.File("a");
  EXPECT_FALSE(daemon::IdentityOf(path).has_value());
  std::ofstream(path) << "x";
  const auto first = daemon::IdentityOf(path);
  ASSERT_TRUE(first.has_value());
  std::ofstream(scratch.File("b")) << "y";  // both exist at once: another inode
  std::filesystem::rename(scratch.File("b"), path);
  EXPECT_FALSE(*daemon::IdentityOf(path) == *first);
}

}  // namespace
}  // namespace flexid
