// The flexid command line against a running flexidd (live_daemon.h), and the recovery
// tools on its database file while it runs: flexid db check and flexid db backup.
#include <gtest/gtest.h>
#include <sqlite3.h>

#include <algorithm>
#include <filesystem>
#include <nlohmann/json.hpp>

#include "live_daemon.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using testing::LiveDaemon;

TEST(CliLive, StatusCountsWhatTheRigPublished) {
  const testing::ScratchDir scratch;
  LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  const int64_t trial = daemon.RecordTrial("step:level=2,duration=60");  // 600 samples sent
  const auto online = daemon.Flexid("rpc status");
  ASSERT_EQ(online.exit_code, 0) << online.err;
  const int64_t stored = nlohmann::json::parse(online.out).at("samples_stored").get<int64_t>();
  EXPECT_GT(stored, 500);  // UDP may drop a few on a loaded machine; what is acked is stored
  EXPECT_LE(stored, 600);
  storage::Database db = storage::Database::Open(daemon.db().string());
  EXPECT_EQ(static_cast<int64_t>(db.Samples(trial).size()), stored);
}

TEST(CliDb, CheckAndBackUpTheFileOfARunningDaemon) {
  const testing::ScratchDir scratch;
  LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  const int64_t trial = daemon.RecordTrial("step:level=2,duration=60");
  const std::string db = "--db '" + daemon.db().string() + "' ";

  const auto check = daemon.Flexid(db + "db check --json");
  ASSERT_EQ(check.exit_code, 0) << check.err;
  const auto report = nlohmann::json::parse(check.out);
  EXPECT_TRUE(report.at("ok").get<bool>());
  const int64_t samples = report.at("samples").get<int64_t>();
  EXPECT_GT(samples, 500);
  EXPECT_TRUE(report.at("problems").empty());

  const auto copy = scratch.path() / "backup.db";
  const auto backup = daemon.Flexid(db + "db backup '" + copy.string() + "'");
  ASSERT_EQ(backup.exit_code, 0) << backup.err;
  EXPECT_NE(backup.out.find("checks ok"), std::string::npos) << backup.out;
  {
    storage::Database restored = storage::Database::Open(copy.string());
    EXPECT_EQ(static_cast<int64_t>(restored.Samples(trial).size()), samples);
  }
  // Never over an existing file: exit 2, one line, the copy untouched.
  const auto size = std::filesystem::file_size(copy);
  const auto again = daemon.Flexid(db + "db backup '" + copy.string() + "'");
  EXPECT_EQ(again.exit_code, 2);
  EXPECT_NE(again.err.find("exists"), std::string::npos) << again.err;
  EXPECT_EQ(std::count(again.err.begin(), again.err.end(), '\n'), 1) << again.err;
  EXPECT_EQ(std::filesystem::file_size(copy), size);

  // Damage the copy behind flexid's back: a trial whose count disagrees with its samples.
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open(copy.string().c_str(), &raw), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(raw, "UPDATE trials SET sample_count = sample_count + 5", nullptr, nullptr,
                         nullptr),
            SQLITE_OK);
  sqlite3_close(raw);
  const auto damaged = daemon.Flexid("--db '" + copy.string() + "' db check");
  EXPECT_EQ(damaged.exit_code, 1);
  EXPECT_NE(damaged.out.find("trial " + std::to_string(trial) + ": sample_count is " +
                             std::to_string(samples + 5) + " but " + std::to_string(samples)),
            std::string::npos)
      << damaged.out;
  EXPECT_NE(damaged.err.find("1 problem(s) found"), std::string::npos) << damaged.err;
}

TEST(CliDb, NeedsAnExistingFlexidDatabase) {
  const testing::ScratchDir scratch;
  const std::string flexid = FLEXID_BINARY;
  const auto no_db = testing::RunCommand(flexid + " db check", scratch.path());
  EXPECT_EQ(no_db.exit_code, 2);
  EXPECT_NE(no_db.err.find("--db PATH"), std::string::npos) << no_db.err;
  const auto missing = testing::RunCommand(
      flexid + " --db '" + (scratch.path() / "absent.db").string() + "' db check", scratch.path());
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.err.find("no such database file"), std::string::npos) << missing.err;
  EXPECT_FALSE(std::filesystem::exists(scratch.path() / "absent.db"));
}

}  // namespace
}  // namespace flexid
