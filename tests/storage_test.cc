// storage/: the database API and the batched sample writer, each test on its own SQLite
// file in a scratch directory. Raw SQL appears here only to inspect the file or to
// damage it on purpose (orphan rows, a newer schema version, a foreign SQLite file).
#include <gtest/gtest.h>
#include <poll.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "scratch_dir.h"
#include "storage/database.h"
#include "storage/sample_writer.h"

namespace flexid::storage {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using testing::ScratchDir;

// A raw SQLite connection for inspecting or damaging a file behind the API's back.
// Foreign keys are off (SQLite's default), so orphan rows can be inserted.
class RawConnection {
 public:
  explicit RawConnection(const std::string& path) {
    if (sqlite3_open_v2(path.c_str(), &db_, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE, nullptr) !=
        SQLITE_OK)
      ADD_FAILURE() << "cannot open " << path;
  }
  ~RawConnection() { sqlite3_close_v2(db_); }
  RawConnection(const RawConnection&) = delete;
  RawConnection& operator=(const RawConnection&) = delete;

  void Exec(const std::string& sql) {
    char* error = nullptr;
    if (sqlite3_exec(db_, sql.c_str(), nullptr, nullptr, &error) != SQLITE_OK)
      ADD_FAILURE() << sql << ": " << (error ? error : "?");
    sqlite3_free(error);
  }
  // The first column of the first row, as text ("" if there is no row).
  std::string Query(const std::string& sql) {
    sqlite3_stmt* stmt = nullptr;
    std::string value;
    if (sqlite3_prepare_v2(db_, sql.c_str(), -1, &stmt, nullptr) != SQLITE_OK) {
      ADD_FAILURE() << sql << ": " << sqlite3_errmsg(db_);
      return value;
    }
    if (sqlite3_step(stmt) == SQLITE_ROW && sqlite3_column_text(stmt, 0))
      value = reinterpret_cast<const char*>(sqlite3_column_text(stmt, 0));
    sqlite3_finalize(stmt);
    return value;
  }

 private:
  sqlite3* db_ = nullptr;
};

// The message of the StorageError that opening `path` throws ("" if it opens).
std::string OpenError(const std::string& path) {
  try {
    Database::Open(path);
  } catch (const StorageError& e) {
    return e.what();
  }
  return "";
}

// A deterministic sample for index k: utime k microseconds, values that need all 64 bits.
Sample SampleAt(int64_t k) {
  const double x = static_cast<double>(k);
  return {k, 0.5 * static_cast<double>(k % 17) - 4.0 + 1e-9 * x, 3.7 * std::sin(1e-3 * x) + 0.1};
}

Actuator Named(const std::string& id, const std::string& pattern = "") {
  Actuator actuator;
  actuator.id = id;
  actuator.pattern = pattern;
  return actuator;
}

bool SameBits(double a, double b) {
  return std::bit_cast<uint64_t>(a) == std::bit_cast<uint64_t>(b);
}

bool SameSample(const Sample& a, const Sample& b) {
  return a.utime == b.utime && SameBits(a.voltage_V, b.voltage_V) &&
         SameBits(a.deflection_mm, b.deflection_mm);
}

// --- opening, schema, migrations ---------------------------------------------------

TEST(Database, CreatesOpensAndReopens) {
  ScratchDir dir;
  const std::string path = dir.File("flexid.db");
  {
    Database db = Database::Open(path);
    EXPECT_TRUE(fs::exists(path));
    EXPECT_EQ(db.path(), path);
    EXPECT_EQ(db.SchemaVersion(), Database::kSchemaVersion);
    db.UpsertActuator(Named("S1", "serpentine"));
    Database moved = std::move(db);
    EXPECT_EQ(moved.Actuators().size(), 1u);
  }
  Database db = Database::Open(path);
  EXPECT_EQ(db.SchemaVersion(), Database::kSchemaVersion);
  ASSERT_TRUE(db.FindActuator("S1").has_value());
  EXPECT_EQ(db.FindActuator("S1")->pattern, "serpentine");
  RawConnection raw(path);
  EXPECT_EQ(raw.Query("PRAGMA journal_mode"), "wal");
  EXPECT_EQ(raw.Query("PRAGMA application_id"), "1179408452");  // 'FLXD'
}

TEST(Database, MigratesAnEmptyFileAndLeavesACurrentDatabaseAsItIs) {
  ScratchDir dir;
  const std::string path = dir.File("empty.db");
  std::ofstream(path).close();  // a 0-byte file is an empty SQLite database: version 0
  { EXPECT_EQ(Database::Open(path).SchemaVersion(), Database::kSchemaVersion); }
  {
    RawConnection raw(path);
    EXPECT_EQ(raw.Query("SELECT count(*) FROM schema_version"),
              std::to_string(Database::kSchemaVersion));
    EXPECT_EQ(raw.Query("SELECT description FROM schema_version WHERE version = 1"),
              "initial schema");
    EXPECT_EQ(raw.Query("SELECT description FROM schema_version WHERE version = 2"),
              "model lineage");
  }
  // A database created at the current version, opened again: nothing re-applied.
  {
    Database db = Database::Open(path);
    db.StartTrial("S1", "step:level=2", 10);
  }
  Database db = Database::Open(path);
  EXPECT_EQ(db.SchemaVersion(), Database::kSchemaVersion);
  EXPECT_EQ(db.Trials().size(), 1u);
  RawConnection raw(path);
  EXPECT_EQ(raw.Query("SELECT count(*) FROM schema_version"),
            std::to_string(Database::kSchemaVersion));
}

// A model record whose contents the database does not interpret, active.
ModelRecord ActiveTestModel(const std::string& actuator_id) {
  ModelRecord m;
  m.actuator_id = actuator_id;
  m.model_json = R"({"kind": "test model"})";
  m.fit_json = R"({"fit_percent": 90})";
  m.active = true;
  return m;
}

TEST(Database, MigratesAVersion1FileKeepingItsModels) {
  ScratchDir dir;
  const std::string path = dir.File("v1.db");
  {
    Database db = Database::Open(path);
    db.StoreModel(ActiveTestModel("S1"));
  }
  {  // as flexid with schema version 1 left it
    RawConnection raw(path);
    raw.Exec(
        "ALTER TABLE models DROP COLUMN lineage_json; DELETE FROM schema_version WHERE version = "
        "2");
  }
  Database db = Database::Open(path);
  EXPECT_EQ(db.SchemaVersion(), 2);
  const auto models = db.Models("S1");
  ASSERT_EQ(models.size(), 1u);
  EXPECT_TRUE(models[0].active);
  EXPECT_EQ(models[0].lineage_json, "");
}

TEST(Database, AModelKeepsItsLineage) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("lineage.db"));
  const ModelRecord parent = ActiveTestModel("S1");
  db.StoreModel(parent);
  ModelRecord proposal = parent;
  proposal.active = false;
  proposal.lineage_json = R"({"parent_version":1,"heldout_gain":3.5})";
  EXPECT_EQ(db.StoreModel(proposal).version, 2);
  EXPECT_EQ(db.FindModel("S1", 2)->lineage_json, proposal.lineage_json);
  EXPECT_EQ(db.FindModel("S1", 1)->lineage_json, "");
  EXPECT_EQ(db.ActiveModel("S1")->version, 1);
}

// --- actuators and trials ----------------------------------------------------------

// What a restarted flexidd's status reports as the latest message time before any sample.
TEST(Database, TheLatestTrialUtimeIsTheLatestStartOrEnd) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("a.db"));
  EXPECT_FALSE(db.LatestTrialUtime().has_value());
  const int64_t first = db.StartTrial("S1", "step:level=2,duration=60", 1'000'000);
  EXPECT_EQ(db.LatestTrialUtime(), 1'000'000);  // recording: its start
  db.EndTrial(first, 61'000'000, TrialState::kComplete);
  db.StartTrial("S2", "step:level=2,duration=60", 5'000'000);
  EXPECT_EQ(db.LatestTrialUtime(), 61'000'000);  // S1's end, after S2's start
}

TEST(Database, UpsertsAndFindsActuators) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("a.db"));
  EXPECT_FALSE(db.FindActuator("S1").has_value());
  db.UpsertActuator(Named("S2"));
  db.UpsertActuator({.id = "S1", .length_mm = 30, .pattern = "grid", .concentration_M = 0.2});
  Actuator changed{.id = "S1",
                   .length_mm = 35,
                   .width_mm = 9,
                   .thickness_mm = 1.5,
                   .pattern = "lines",
                   .material = "chitosan-PEDOT",
                   .electrolyte = "NaCl",
                   .concentration_M = 0.5};
  db.UpsertActuator(changed);
  const std::vector<Actuator> all = db.Actuators();
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].id, "S1");  // by id
  EXPECT_EQ(all[0].length_mm, 35);
  EXPECT_EQ(all[0].width_mm, 9);
  EXPECT_EQ(all[0].thickness_mm, 1.5);
  EXPECT_EQ(all[0].pattern, "lines");
  EXPECT_EQ(all[0].material, "chitosan-PEDOT");
  EXPECT_EQ(all[0].electrolyte, "NaCl");
  EXPECT_EQ(all[0].concentration_M, 0.5);
  EXPECT_EQ(all[1].id, "S2");
  EXPECT_EQ(all[1].material, "chitosan");  // the seed's defaults
  EXPECT_EQ(all[1].concentration_M, 0.12);
  EXPECT_THROW(db.UpsertActuator(Named("")), StorageError);
}

TEST(Database, StartsEndsAndListsTrialsWithSampleCounts) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("t.db"));
  const int64_t first = db.StartTrial("S1", "square:level=5,period=220", 1'000'000);
  const int64_t second = db.StartTrial("S2", "step:level=2", 2'000'000);
  const int64_t third = db.StartTrial("S1", "staircase:levels=2/4", 3'000'000);
  ASSERT_TRUE(db.FindActuator("S2").has_value());  // created with defaults
  EXPECT_EQ(db.FindActuator("S2")->length_mm, 40);

  const Sample samples[] = {{1'000'000, 5, 0.1}, {1'000'100, 5, 0.2}, {1'000'200, 5, 0.3}};
  EXPECT_EQ(db.AppendSamples(first, samples).inserted, 3);
  db.EndTrial(first, 1'000'200, TrialState::kComplete);

  std::optional<Trial> trial = db.FindTrial(first);
  ASSERT_TRUE(trial.has_value());
  EXPECT_EQ(trial->actuator_id, "S1");
  EXPECT_EQ(trial->protocol, "square:level=5,period=220");
  EXPECT_EQ(trial->start_utime, 1'000'000);
  EXPECT_EQ(trial->end_utime, 1'000'200);
  EXPECT_EQ(trial->state, TrialState::kComplete);
  EXPECT_EQ(trial->samples, 3);
  EXPECT_EQ(db.FindTrial(second)->state, TrialState::kRecording);
  EXPECT_EQ(db.FindTrial(second)->end_utime, 0);
  EXPECT_FALSE(db.FindTrial(9999).has_value());

  const std::vector<Trial> all = db.Trials();
  ASSERT_EQ(all.size(), 3u);
  EXPECT_EQ(all[0].id, third);  // newest first
  EXPECT_EQ(all[1].id, second);
  EXPECT_EQ(all[2].id, first);
  EXPECT_EQ(all[2].samples, 3);
  EXPECT_EQ(all[0].samples, 0);
  const std::vector<Trial> of_s1 = db.Trials("S1");
  ASSERT_EQ(of_s1.size(), 2u);
  EXPECT_EQ(of_s1[0].id, third);
  EXPECT_EQ(of_s1[1].id, first);
  EXPECT_EQ(db.Trials(std::nullopt, 1).size(), 1u);
  EXPECT_TRUE(db.Trials("S9").empty());

  EXPECT_THROW(db.EndTrial(9999, 5, TrialState::kComplete), StorageError);
  EXPECT_THROW(db.EndTrial(second, 5, TrialState::kRecording), StorageError);
  EXPECT_STREQ(TrialStateName(TrialState::kInterrupted), "interrupted");
}

TEST(Database, MarksRecordingTrialsInterruptedAtTheirLastSample) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("m.db"));
  const int64_t with_samples = db.StartTrial("S1", "p", 100);
  const int64_t without_samples = db.StartTrial("S2", "p", 200);
  const int64_t complete = db.StartTrial("S3", "p", 300);
  const Sample samples[] = {{150, 1, 1}, {500, 1, 2}, {400, 1, 3}};
  db.AppendSamples(with_samples, samples);
  db.EndTrial(complete, 350, TrialState::kComplete);

  EXPECT_EQ(db.MarkRecordingTrialsInterrupted(), 2);
  EXPECT_EQ(db.FindTrial(with_samples)->state, TrialState::kInterrupted);
  EXPECT_EQ(db.FindTrial(with_samples)->end_utime, 500);
  EXPECT_EQ(db.FindTrial(without_samples)->state, TrialState::kInterrupted);
  EXPECT_EQ(db.FindTrial(without_samples)->end_utime, db.FindTrial(without_samples)->start_utime);
  EXPECT_EQ(db.FindTrial(complete)->state, TrialState::kComplete);
  EXPECT_EQ(db.FindTrial(complete)->end_utime, 350);
  EXPECT_EQ(db.MarkRecordingTrialsInterrupted(), 0);
}

// --- samples -----------------------------------------------------------------------

TEST(Database, SamplesRoundTripBitExactInUtimeOrder) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("s.db"));
  const int64_t trial = db.StartTrial("S1", "p", 0);
  std::mt19937_64 rng(7);
  std::vector<Sample> samples;
  for (int64_t k = 0; k < 5000; ++k) {
    // Arbitrary finite bit patterns: random signs, exponents and mantissas.
    double v, d;
    do v = std::bit_cast<double>(rng());
    while (!std::isfinite(v) || v == 0.0);
    do d = std::bit_cast<double>(rng());
    while (!std::isfinite(d) || d == 0.0);
    samples.push_back({k * 2000 - 3'000'000, v, d});
  }
  samples.push_back({-5, std::numeric_limits<double>::denorm_min(), -1e-310});
  samples.push_back({std::numeric_limits<int64_t>::max(), 2.0, -3.0});  // integral doubles
  samples.push_back({std::numeric_limits<int64_t>::min(), 1e300, -1e-300});
  std::vector<Sample> shuffled = samples;
  std::shuffle(shuffled.begin(), shuffled.end(), rng);
  const AppendResult result = db.AppendSamples(trial, shuffled);
  EXPECT_EQ(result.inserted, static_cast<int64_t>(samples.size()));
  EXPECT_EQ(result.duplicates, 0);
  EXPECT_EQ(result.invalid, 0);

  std::sort(samples.begin(), samples.end(),
            [](const Sample& a, const Sample& b) { return a.utime < b.utime; });
  const std::vector<Sample> stored = db.Samples(trial);
  ASSERT_EQ(stored.size(), samples.size());
  for (size_t k = 0; k < samples.size(); ++k)
    ASSERT_TRUE(SameSample(stored[k], samples[k])) << "sample " << k;
  EXPECT_EQ(db.SampleCount(trial), static_cast<int64_t>(samples.size()));
  EXPECT_EQ(HashSamples(stored), HashSamples(samples));
  EXPECT_TRUE(db.Samples(9999).empty());
  EXPECT_EQ(db.SampleCount(9999), 0);
}

TEST(Database, DuplicateAndNonFiniteSamplesAreIgnoredAndCounted) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("d.db"));
  const int64_t trial = db.StartTrial("S1", "p", 0);
  const Sample first[] = {{10, 1, 1}, {20, 1, 2}, {30, 1, 3}};
  EXPECT_EQ(db.AppendSamples(trial, first).inserted, 3);

  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  const Sample second[] = {{20, 9, 9},    {40, 1, 4}, {40, 9, 9}, {50, nan, 1},
                           {60, 1, -inf}, {10, 9, 9}, {70, 1, 7}};
  const AppendResult result = db.AppendSamples(trial, second);
  EXPECT_EQ(result.inserted, 2);    // 40, 70
  EXPECT_EQ(result.duplicates, 3);  // 20, the second 40, 10: the stored rows are kept
  EXPECT_EQ(result.invalid, 2);     // NaN, -inf
  const std::vector<Sample> stored = db.Samples(trial);
  ASSERT_EQ(stored.size(), 5u);
  EXPECT_TRUE(SameSample(stored[0], {10, 1, 1}));
  EXPECT_TRUE(SameSample(stored[1], {20, 1, 2}));
  EXPECT_TRUE(SameSample(stored[3], {40, 1, 4}));
  EXPECT_EQ(db.SampleCount(trial), 5);
  EXPECT_EQ(db.FindTrial(trial)->samples, 5);

  // One trial that does not exist: an error for the one-trial form, a count for the other.
  EXPECT_THROW(db.AppendSamples(9999, first), StorageError);
  const TrialSample mixed[] = {{trial, {80, 1, 8}}, {9999, {80, 1, 8}}, {trial, {80, 2, 2}}};
  const AppendResult mixed_result = db.AppendSamples(mixed);
  EXPECT_EQ(mixed_result.inserted, 1);
  EXPECT_EQ(mixed_result.duplicates, 1);
  EXPECT_EQ(mixed_result.invalid, 1);
  EXPECT_EQ(db.SampleCount(trial), 6);
  EXPECT_EQ(db.IntegrityCheck(), "ok");
}

TEST(Database, NegativeZeroReadsBackAsZeroAndHashesAlike) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("z.db"));
  const int64_t trial = db.StartTrial("S1", "p", 0);
  const Sample samples[] = {{1, -0.0, -0.0}};
  db.AppendSamples(trial, samples);
  const std::vector<Sample> stored = db.Samples(trial);
  ASSERT_EQ(stored.size(), 1u);
  EXPECT_EQ(stored[0].voltage_V, 0.0);
  EXPECT_EQ(HashSamples(stored), HashSamples(samples));
}

// --- models ------------------------------------------------------------------------

TEST(Database, ModelVersionsIncrementPerActuatorAndActivationIsExclusive) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("models.db"));
  const int64_t t1 = db.StartTrial("S1", "p", 100);
  const int64_t t2 = db.StartTrial("S1", "p", 200);
  const Sample samples[] = {{1, 2, 3}, {2, 2, 4}};
  const std::string hash = HashSamples(samples);

  ModelRecord record;
  record.actuator_id = "S1";
  record.created_utime = 5000;
  record.model_json = R"({"format": "flexid.model/1", "kind": "tf", "num": [1], "den": [1, 2]})";
  record.fit_json = R"({"fit_percent": 93.5})";
  record.trial_ids = {t2, t1};
  record.samples_hash = hash;
  record.active = true;
  record.version = 42;  // ignored
  const ModelRecord v1 = db.StoreModel(record);
  EXPECT_EQ(v1.version, 1);
  EXPECT_GT(v1.id, 0);
  EXPECT_FALSE(v1.flexid_version.empty());  // this build's version

  record.flexid_version = "0.0.9";
  const ModelRecord v2 = db.StoreModel(record);  // active: v1 is deactivated
  EXPECT_EQ(v2.version, 2);
  record.active = false;
  record.trial_ids = {};
  const ModelRecord v3 = db.StoreModel(record);
  EXPECT_EQ(v3.version, 3);
  record.actuator_id = "S7";  // unknown: created with defaults, its own numbering
  EXPECT_EQ(db.StoreModel(record).version, 1);
  EXPECT_TRUE(db.FindActuator("S7").has_value());

  const std::vector<ModelRecord> models = db.Models("S1");
  ASSERT_EQ(models.size(), 3u);
  EXPECT_EQ(models[0].version, 3);  // newest first
  EXPECT_EQ(models[2].version, 1);
  EXPECT_FALSE(models[2].active);
  EXPECT_TRUE(models[1].active);
  ASSERT_TRUE(db.ActiveModel("S1").has_value());
  EXPECT_EQ(db.ActiveModel("S1")->version, 2);

  const std::optional<ModelRecord> found = db.FindModel("S1", 1);
  ASSERT_TRUE(found.has_value());
  EXPECT_EQ(found->id, v1.id);
  EXPECT_EQ(found->trial_ids, (std::vector<int64_t>{t2, t1}));  // order kept
  EXPECT_EQ(found->samples_hash, hash);
  EXPECT_EQ(found->model_json, record.model_json);
  EXPECT_EQ(found->fit_json, record.fit_json);
  EXPECT_EQ(found->created_utime, 5000);
  EXPECT_EQ(found->flexid_version, v1.flexid_version);
  EXPECT_EQ(db.FindModel("S1", 2)->flexid_version, "0.0.9");
  EXPECT_TRUE(db.FindModel("S1", 3)->trial_ids.empty());
  EXPECT_FALSE(db.FindModel("S1", 4).has_value());

  db.ActivateModel("S1", 1);
  EXPECT_EQ(db.ActiveModel("S1")->version, 1);
  EXPECT_FALSE(db.FindModel("S1", 2)->active);
  int active = 0;
  for (const ModelRecord& m : db.Models("S1")) active += m.active ? 1 : 0;
  EXPECT_EQ(active, 1);
  EXPECT_FALSE(db.ActiveModel("S7").has_value());
  EXPECT_THROW(db.ActivateModel("S1", 9), StorageError);
  EXPECT_EQ(db.ActiveModel("S1")->version, 1);  // unchanged by the failed call

  // A model citing a trial that does not exist is refused as a whole.
  record.actuator_id = "S1";
  record.trial_ids = {t1, 9999};
  EXPECT_THROW(db.StoreModel(record), StorageError);
  EXPECT_EQ(db.Models("S1").size(), 3u);
  EXPECT_EQ(db.IntegrityCheck(), "ok");
}

// --- alerts ------------------------------------------------------------------------

TEST(Database, StoresAndListsAlertsWithFilters) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("alerts.db"));
  auto alert = [](std::string actuator, std::string kind, int64_t utime) {
    return AlertRecord{.actuator_id = actuator,
                       .kind = kind,
                       .severity = 2,
                       .utime = utime,
                       .start_utime = utime - 100,
                       .end_utime = utime,
                       .magnitude_mm = 0.4,
                       .threshold_mm = 0.25,
                       .text = kind + " on " + actuator};
  };
  const int64_t a = db.StoreAlert(alert("S1", "drift", 1000));
  const int64_t b = db.StoreAlert(alert("S2", "residual", 2000));
  const int64_t c = db.StoreAlert(alert("S1", "back_relaxation", 3000));
  AlertRecord odd = alert("S1", "residual", 3000);  // same utime as c: newer id first
  odd.magnitude_mm = std::numeric_limits<double>::quiet_NaN();
  odd.threshold_mm = std::numeric_limits<double>::infinity();
  const int64_t d = db.StoreAlert(odd);

  const std::vector<AlertRecord> all = db.Alerts();
  ASSERT_EQ(all.size(), 4u);
  EXPECT_EQ(all[0].id, d);
  EXPECT_EQ(all[1].id, c);
  EXPECT_EQ(all[2].id, b);
  EXPECT_EQ(all[3].id, a);
  EXPECT_EQ(all[3].kind, "drift");
  EXPECT_EQ(all[3].severity, 2);
  EXPECT_EQ(all[3].start_utime, 900);
  EXPECT_EQ(all[3].end_utime, 1000);
  EXPECT_EQ(all[3].magnitude_mm, 0.4);
  EXPECT_EQ(all[3].threshold_mm, 0.25);
  EXPECT_EQ(all[3].text, "drift on S1");
  EXPECT_TRUE(std::isnan(all[0].magnitude_mm));
  EXPECT_EQ(all[0].threshold_mm, std::numeric_limits<double>::infinity());

  const std::vector<AlertRecord> s1 = db.Alerts("S1");
  ASSERT_EQ(s1.size(), 3u);
  EXPECT_EQ(s1[2].id, a);
  const std::vector<AlertRecord> recent = db.Alerts(std::nullopt, 2000);
  ASSERT_EQ(recent.size(), 3u);
  EXPECT_EQ(recent[2].id, b);
  EXPECT_EQ(db.Alerts("S1", 2000).size(), 2u);
  EXPECT_EQ(db.Alerts(std::nullopt, 0, 2).size(), 2u);
  EXPECT_TRUE(db.Alerts("S9").empty());
}

// --- backup and integrity ----------------------------------------------------------

TEST(Database, BackupHasTheSameRowsAndRefusesAnExistingDestination) {
  ScratchDir dir;
  Database db = Database::Open(dir.File("live.db"));
  db.UpsertActuator(Named("S1", "grid"));
  const int64_t trial = db.StartTrial("S1", "p", 0);
  std::vector<Sample> samples;
  for (int64_t k = 0; k < 20'000; ++k) samples.push_back(SampleAt(k));
  db.AppendSamples(trial, samples);
  ModelRecord model;
  model.actuator_id = "S1";
  model.model_json = "{}";
  model.trial_ids = {trial};
  model.samples_hash = HashSamples(samples);
  model.active = true;
  db.StoreModel(model);
  AlertRecord alert;
  alert.actuator_id = "S1";
  alert.kind = "drift";
  alert.utime = 7;
  db.StoreAlert(alert);

  const std::string copy_path = dir.File("copy.db");
  db.Backup(copy_path);
  db.StartTrial("S1", "after the backup", 1);  // the live file goes on

  Database copy = Database::Open(copy_path);
  EXPECT_EQ(copy.IntegrityCheck(), "ok");
  EXPECT_EQ(copy.Actuators().size(), 1u);
  EXPECT_EQ(copy.FindActuator("S1")->pattern, "grid");
  ASSERT_EQ(copy.Trials().size(), 1u);
  const std::vector<Sample> copied = copy.Samples(trial);
  ASSERT_EQ(copied.size(), samples.size());
  EXPECT_EQ(HashSamples(copied), HashSamples(samples));
  ASSERT_TRUE(copy.ActiveModel("S1").has_value());
  EXPECT_EQ(copy.ActiveModel("S1")->trial_ids, std::vector<int64_t>{trial});
  EXPECT_EQ(copy.Alerts().size(), 1u);

  const auto size_before = fs::file_size(copy_path);
  try {
    db.Backup(copy_path);
    ADD_FAILURE() << "a backup overwrote " << copy_path;
  } catch (const StorageError& e) {
    EXPECT_NE(std::string(e.what()).find("exists"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("copy.db"), std::string::npos) << e.what();
  }
  EXPECT_EQ(fs::file_size(copy_path), size_before);
  EXPECT_EQ(copy.Trials().size(), 1u);
  EXPECT_THROW(db.Backup(dir.File("no/such/dir/copy.db")), StorageError);
}

TEST(Database, IntegrityCheckFindsOrphansAndWrongCounts) {
  ScratchDir dir;
  const std::string path = dir.File("i.db");
  Database db = Database::Open(path);
  const int64_t trial = db.StartTrial("S1", "p", 0);
  const Sample samples[] = {{1, 1, 1}, {2, 1, 2}};
  db.AppendSamples(trial, samples);
  EXPECT_EQ(db.IntegrityCheck(), "ok");
  {
    RawConnection raw(path);  // foreign keys off: the orphan goes in
    raw.Exec(
        "INSERT INTO samples (trial_id, utime, voltage_V, deflection_mm) "
        "VALUES (999, 1, 0.5, 0.5), (999, 2, 0.5, 0.5)");
    raw.Exec("INSERT INTO samples (trial_id, utime, voltage_V, deflection_mm) VALUES (" +
             std::to_string(trial) + ", 3, 1, 3)");
  }
  const std::string report = db.IntegrityCheck();
  EXPECT_NE(report.find("samples: 2 orphan row(s) referring to a missing row of trials"),
            std::string::npos)
      << report;
  EXPECT_NE(report.find("trial " + std::to_string(trial) + ": sample_count is 2 but 3"),
            std::string::npos)
      << report;
}

// --- refusals ----------------------------------------------------------------------

TEST(Database, RefusesAFileThatIsNotADatabaseAndLeavesItAlone) {
  ScratchDir dir;
  const std::string path = dir.File("notes.txt");
  std::string text;
  while (text.size() < 8192) text += "t_s,voltage_V,deflection_mm\n0,0,0\n";
  std::ofstream(path) << text;
  const std::string error = OpenError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("is not a database"), std::string::npos) << error;
  std::ifstream in(path);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), text);
}

TEST(Database, RefusesAnotherApplicationsSqliteFileAndLeavesItAlone) {
  ScratchDir dir;
  const std::string path = dir.File("other.db");
  {
    RawConnection(path).Exec("CREATE TABLE recipes (name TEXT); INSERT INTO recipes VALUES ('x')");
  }
  const std::string error = OpenError(path);
  EXPECT_NE(error.find("not a flexid database"), std::string::npos) << error;
  RawConnection raw(path);
  EXPECT_EQ(raw.Query("PRAGMA journal_mode"), "delete");  // not switched to WAL
  EXPECT_EQ(raw.Query("SELECT count(*) FROM sqlite_schema"), "1");
}

TEST(Database, RefusesANewerSchemaVersion) {
  ScratchDir dir;
  const std::string path = dir.File("future.db");
  { Database::Open(path); }
  {
    const std::string future = std::to_string(Database::kSchemaVersion + 1);
    RawConnection(path).Exec("INSERT INTO schema_version VALUES (" + future +
                             ", 0, '9.9.9', 'from the future')");
  }
  const std::string error = OpenError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("schema version " + std::to_string(Database::kSchemaVersion + 1)),
            std::string::npos)
      << error;
  EXPECT_NE(error.find("newer"), std::string::npos) << error;
}

TEST(Database, RefusesAReadOnlyFile) {
  if (::geteuid() == 0)
    GTEST_SKIP() << "running as root, which may write to a chmod 0444 file: the read-only "
                    "case cannot be produced this way";
  ScratchDir dir;
  const std::string path = dir.File("ro.db");
  { Database::Open(path).StartTrial("S1", "p", 0); }
  ASSERT_EQ(::chmod(path.c_str(), 0444), 0);
  const std::string error = OpenError(path);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("read-only"), std::string::npos) << error;
}

TEST(Database, RefusesAPathThatCannotBeCreated) {
  ScratchDir dir;
  const std::string error = OpenError(dir.File("missing/dir/x.db"));
  EXPECT_NE(error.find("cannot open"), std::string::npos) << error;
}

// --- hashing -----------------------------------------------------------------------

TEST(HashSamples, IsStableFnv1aOfTheLittleEndianBytes) {
  // Reference values from an independent implementation (Python struct + FNV-1a 64).
  EXPECT_EQ(HashSamples({}), "cbf29ce484222325");
  const Sample samples[] = {{1, 2.5, -0.125}, {2, 3.0, 1e-300}, {1'700'000'000'000'000, -5.0, 0.1}};
  EXPECT_EQ(HashSamples(samples), "7cacc992d3b04385");
  Sample changed[] = {samples[0], samples[1], samples[2]};
  changed[2].deflection_mm = std::nextafter(0.1, 1.0);
  EXPECT_NE(HashSamples(changed), HashSamples(samples));
}

// --- sample writer -----------------------------------------------------------------

TEST(SampleWriter, StoresEverythingEnqueuedFromTwoThreads) {
  ScratchDir dir;
  const std::string path = dir.File("w.db");
  const int64_t trial = Database::Open(path).StartTrial("S1", "p", 0);
  constexpr int64_t kPerThread = 50'000;
  {
    SampleWriter writer(path);
    auto produce = [&](int64_t parity) {
      for (int64_t k = 0; k < kPerThread; ++k)
        EXPECT_TRUE(writer.Enqueue(trial, SampleAt(2 * k + parity)));
    };
    std::thread even(produce, 0), odd(produce, 1);
    even.join();
    odd.join();
    EXPECT_TRUE(writer.Flush());
    EXPECT_EQ(writer.enqueued(), 2 * kPerThread);
    EXPECT_EQ(writer.stored(), writer.enqueued());
    EXPECT_EQ(writer.rejected(), 0);
    EXPECT_EQ(writer.queue_depth(), 0u);
    EXPECT_EQ(writer.last_error(), "");
    // Not flushed: the destructor commits these.
    for (int64_t k = 2 * kPerThread; k < 2 * kPerThread + 1000; ++k)
      EXPECT_TRUE(writer.Enqueue(trial, SampleAt(k)));
  }
  Database db = Database::Open(path);
  const std::vector<Sample> stored = db.Samples(trial);
  ASSERT_EQ(stored.size(), static_cast<size_t>(2 * kPerThread + 1000));
  for (size_t k = 0; k < stored.size(); ++k)
    ASSERT_TRUE(SameSample(stored[k], SampleAt(static_cast<int64_t>(k)))) << k;
  EXPECT_EQ(db.IntegrityCheck(), "ok");
}

TEST(SampleWriter, AFullQueueRefusesWithoutBlocking) {
  ScratchDir dir;
  const std::string path = dir.File("q.db");
  const int64_t trial = Database::Open(path).StartTrial("S1", "p", 0);
  {
    SampleWriter writer(path, {.commit_interval = std::chrono::hours(1), .queue_capacity = 8});
    for (int64_t k = 0; k < 8; ++k) EXPECT_TRUE(writer.Enqueue(trial, SampleAt(k)));
    const auto start = std::chrono::steady_clock::now();
    for (int64_t k = 8; k < 1000; ++k) EXPECT_FALSE(writer.Enqueue(trial, SampleAt(k)));
    EXPECT_LT(std::chrono::steady_clock::now() - start, 1s);
    EXPECT_EQ(writer.queue_depth(), 8u);
    EXPECT_EQ(writer.enqueued(), 8);
    EXPECT_TRUE(writer.Flush());  // commits now, not in an hour
    EXPECT_EQ(writer.stored(), 8);
    EXPECT_TRUE(writer.Enqueue(trial, SampleAt(8)));
  }
  EXPECT_EQ(Database::Open(path).SampleCount(trial), 9);
}

TEST(SampleWriter, CountsSamplesItCannotStoreWithoutStopping) {
  ScratchDir dir;
  const std::string path = dir.File("r.db");
  const int64_t trial = Database::Open(path).StartTrial("S1", "p", 0);
  SampleWriter writer(path);
  for (int64_t k = 0; k < 10; ++k) {
    writer.Enqueue(trial, SampleAt(k));
    writer.Enqueue(12345, SampleAt(k));                                       // no such trial
    writer.Enqueue(trial, {k, std::numeric_limits<double>::quiet_NaN(), 1});  // NaN
    writer.Enqueue(trial, SampleAt(k));                                       // duplicate
  }
  EXPECT_TRUE(writer.Flush());
  EXPECT_EQ(writer.stored(), 10);
  EXPECT_EQ(writer.rejected(), 30);
  EXPECT_EQ(writer.last_error(), "");
  EXPECT_EQ(Database::Open(path).SampleCount(trial), 10);
}

TEST(SampleWriter, RejectsInvalidOptionsAndUnusableFiles) {
  ScratchDir dir;
  EXPECT_THROW(SampleWriter(dir.File("a.db"), {.queue_capacity = 0}), std::invalid_argument);
  EXPECT_THROW(SampleWriter(dir.File("a.db"), {.commit_interval = 0ms}), std::invalid_argument);
  const std::string text = dir.File("text.db");
  std::ofstream(text) << std::string(4096, 'x');
  EXPECT_THROW(SampleWriter{text}, StorageError);
}

// A write failure (here: the file size limit, which binds root too) keeps the samples
// queued; they are committed once writing works again.
TEST(SampleWriter, KeepsSamplesQueuedWhileWritesFailAndRetries) {
  ScratchDir dir;
  const std::string path = dir.File("full.db");
  const int64_t trial = Database::Open(path).StartTrial("S1", "p", 0);
  SampleWriter writer(path, {.commit_interval = 20ms});
  ASSERT_LT(fs::file_size(path), 256u * 1024);

  struct sigaction ignore {
  }, previous{};
  ignore.sa_handler = SIG_IGN;
  ASSERT_EQ(::sigaction(SIGXFSZ, &ignore, &previous), 0);  // EFBIG instead of a signal
  rlimit original{};
  ASSERT_EQ(::getrlimit(RLIMIT_FSIZE, &original), 0);
  rlimit small = original;
  small.rlim_cur = 512 * 1024;  // files may not grow beyond 512 KiB
  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &small), 0);

  constexpr int64_t kCount = 100'000;  // ~3 MB of pages: cannot fit
  for (int64_t k = 0; k < kCount; ++k) ASSERT_TRUE(writer.Enqueue(trial, SampleAt(k)));
  const bool flushed_while_limited = writer.Flush();
  const std::string error = writer.last_error();
  const int64_t stored_while_limited = writer.stored();
  const size_t depth_while_limited = writer.queue_depth();
  std::this_thread::sleep_for(100ms);  // a few more failing retries
  const std::string error_later = writer.last_error();

  ASSERT_EQ(::setrlimit(RLIMIT_FSIZE, &original), 0);
  const bool flushed_after = writer.Flush();
  ::sigaction(SIGXFSZ, &previous, nullptr);

  std::cout << "last_error while files may not grow: " << error << "\n";
  EXPECT_FALSE(flushed_while_limited);
  EXPECT_NE(error.find(path), std::string::npos) << error;
  EXPECT_NE(error.find("100000 samples kept queued; retrying every 20 ms"), std::string::npos)
      << error;
  EXPECT_NE(error_later, "");
  EXPECT_EQ(stored_while_limited, 0);
  EXPECT_EQ(depth_while_limited, static_cast<size_t>(kCount));
  EXPECT_TRUE(flushed_after);
  EXPECT_EQ(writer.stored(), kCount);
  EXPECT_EQ(writer.last_error(), "");
  Database db = Database::Open(path);
  EXPECT_EQ(db.SampleCount(trial), kCount);
  EXPECT_EQ(db.IntegrityCheck(), "ok");
}

// The writes other than samples go in the order they were submitted, ahead of the samples
// queued after them; one the database refuses is reported and does not hold up the rest.
TEST(SampleWriter, WritesTrialsAlertsAndModelsInOrderAheadOfTheirSamples) {
  ScratchDir dir;
  const std::string path = dir.File("writes.db");
  SampleWriter writer(path, {.commit_interval = 20ms});
  std::vector<uint64_t> tickets;
  tickets.push_back(writer.Submit(TrialStart{7, "S1", "square", 100}));
  for (int64_t k = 0; k < 10; ++k) ASSERT_TRUE(writer.Enqueue(7, SampleAt(k)));
  tickets.push_back(writer.Submit(AlertRecord{0, "S1", "drift", 1, 5, 1, 5, 0.5, 0.1, "text"}));
  tickets.push_back(writer.Submit(TrialEnd{7, 9, TrialState::kComplete}));
  tickets.push_back(writer.Submit(TrialEnd{99, 9, TrialState::kComplete}));  // no such trial
  ModelRecord model;
  model.actuator_id = "S1";
  model.model_json = R"({"format": "flexid.model/1", "kind": "tf", "num": [1], "den": [1, 1]})";
  model.trial_ids = {7};
  model.active = true;
  tickets.push_back(writer.Submit(model));
  tickets.push_back(writer.Submit(ModelActivation{"S1", 1}));
  Actuator s2;
  s2.id = "S2";
  tickets.push_back(writer.Submit(s2));
  for (size_t k = 1; k < tickets.size(); ++k) EXPECT_GT(tickets[k], tickets[k - 1]);
  ASSERT_TRUE(writer.Flush()) << writer.last_error();
  EXPECT_EQ(writer.writes_queued(), 0u);

  const std::vector<WriteOutcome> outcomes = writer.TakeOutcomes();
  ASSERT_EQ(outcomes.size(), tickets.size());
  for (size_t k = 0; k < outcomes.size(); ++k) {
    EXPECT_EQ(outcomes[k].ticket, tickets[k]);
    EXPECT_EQ(outcomes[k].error.empty(), k != 3) << k << ": " << outcomes[k].error;
  }
  EXPECT_NE(outcomes[3].error.find("cannot end trial 99: no such trial"), std::string::npos);
  EXPECT_EQ(outcomes[0].trial_id, 7);
  ASSERT_TRUE(outcomes[4].model.has_value());
  EXPECT_EQ(outcomes[4].model->version, 1);
  EXPECT_TRUE(writer.TakeOutcomes().empty());

  Database db = Database::Open(path);
  const auto trial = db.FindTrial(7);
  ASSERT_TRUE(trial.has_value());
  EXPECT_EQ(trial->state, TrialState::kComplete);
  EXPECT_EQ(trial->samples, 10);
  EXPECT_EQ(db.Alerts().size(), 1u);
  EXPECT_TRUE(db.ActiveModel("S1").has_value());
  EXPECT_TRUE(db.FindActuator("S2").has_value());
  EXPECT_EQ(db.LastTrialId(), 7);
  EXPECT_EQ(db.IntegrityCheck(), "ok");
}

// Another program took the trial id the caller handed out: the trial and its samples move
// to the next free id, and the other program's trial stays as it was.
TEST(SampleWriter, ATrialIdTakenByAnotherProgramMovesTheTrialWithItsSamples) {
  ScratchDir dir;
  const std::string path = dir.File("taken.db");
  SampleWriter writer(path, {.commit_interval = 20ms});
  ASSERT_EQ(Database::Open(path).StartTrial("X", "import", 0), 1);
  writer.Submit(TrialStart{1, "S1", "square", 5});
  for (int64_t k = 0; k < 3; ++k) ASSERT_TRUE(writer.Enqueue(1, SampleAt(k)));
  writer.Submit(TrialEnd{1, 2, TrialState::kComplete});
  ASSERT_TRUE(writer.Flush()) << writer.last_error();
  const std::vector<WriteOutcome> outcomes = writer.TakeOutcomes();
  ASSERT_EQ(outcomes.size(), 2u);
  EXPECT_EQ(outcomes[0].error, "");
  EXPECT_EQ(outcomes[0].trial_id, 2);
  EXPECT_EQ(outcomes[1].error, "");
  Database db = Database::Open(path);
  EXPECT_EQ(db.FindTrial(1)->actuator_id, "X");
  EXPECT_EQ(db.FindTrial(1)->samples, 0);
  EXPECT_EQ(db.FindTrial(2)->actuator_id, "S1");
  EXPECT_EQ(db.FindTrial(2)->samples, 3);
  EXPECT_EQ(db.FindTrial(2)->state, TrialState::kComplete);
}

// A lock held beyond the busy timeout: the writes and the samples behind them stay queued,
// in order, and are written once it is released.
TEST(SampleWriter, KeepsWritesQueuedWhileTheDatabaseIsLocked) {
  ScratchDir dir;
  const std::string path = dir.File("locked.db");
  SampleWriter writer(path, {.commit_interval = 20ms});
  sqlite3* other = nullptr;
  ASSERT_EQ(sqlite3_open_v2(path.c_str(), &other, SQLITE_OPEN_READWRITE, nullptr), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(other, "BEGIN EXCLUSIVE", nullptr, nullptr, nullptr), SQLITE_OK);
  writer.Submit(TrialStart{1, "S1", "square", 0});
  ASSERT_TRUE(writer.Enqueue(1, SampleAt(0)));
  writer.Submit(AlertRecord{0, "", "storage_failing", 2, 1, 1, 1, 0.0, 0.0, "text"});
  EXPECT_FALSE(writer.Flush());  // after the 5 s busy timeout
  const std::string error = writer.last_error();
  EXPECT_NE(error.find("database is locked"), std::string::npos) << error;
  EXPECT_NE(error.find("1 samples and 2 other writes kept queued"), std::string::npos) << error;
  EXPECT_EQ(writer.writes_queued(), 2u);
  EXPECT_TRUE(writer.TakeOutcomes().empty());
  ASSERT_EQ(sqlite3_exec(other, "COMMIT", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(other);
  ASSERT_TRUE(writer.Flush()) << writer.last_error();
  EXPECT_EQ(writer.TakeOutcomes().size(), 2u);
  EXPECT_EQ(writer.last_error(), "");
  Database db = Database::Open(path);
  EXPECT_EQ(db.SampleCount(1), 1);
  EXPECT_EQ(db.Alerts().size(), 1u);
}

// Kills a child process that records continuously and checks that every sample it had
// reported as stored is in the file, intact (DESIGN.md: acknowledged samples survive
// kill -9).
TEST(SampleWriter, AcknowledgedSamplesSurviveKill9) {
  ScratchDir dir;
  const std::string path = dir.File("kill.db");
  const int64_t trial = Database::Open(path).StartTrial("S1", "kill", 0);
  int fds[2];
  ASSERT_EQ(::pipe(fds), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {  // the recorder: no gtest here, it only ever dies by SIGKILL
    ::close(fds[0]);
    try {
      SampleWriter writer(path);  // the default 100 ms commit interval
      int64_t next = 0;
      while (true) {
        for (int i = 0; i < 100; ++i)
          if (writer.Enqueue(trial, SampleAt(next))) ++next;
        const int64_t stored = writer.stored();
        if (::write(fds[1], &stored, sizeof stored) != sizeof stored) ::_exit(4);
        ::usleep(1000);  // ~100,000 samples/s, 12 times the daemon's target rate
      }
    } catch (...) {
      ::_exit(3);
    }
  }
  ::close(fds[1]);
  struct Reaper {  // never leaves the child running, whatever fails below
    pid_t pid;
    int status = 0;
    bool reaped = false;
    void Kill() {
      if (reaped) return;
      ::kill(pid, SIGKILL);
      ::waitpid(pid, &status, 0);
      reaped = true;
    }
    ~Reaper() { Kill(); }
  } reaper{child};

  int64_t acknowledged = 0;
  auto read_report = [&](int timeout_ms) {
    pollfd poll_fd{fds[0], POLLIN, 0};
    if (::poll(&poll_fd, 1, timeout_ms) <= 0) return false;
    int64_t value = 0;
    if (::read(fds[0], &value, sizeof value) != sizeof value) return false;  // EOF
    acknowledged = std::max(acknowledged, value);
    return true;
  };
  const auto start = std::chrono::steady_clock::now();
  while (acknowledged < 50'000 || std::chrono::steady_clock::now() - start < 700ms) {
    ASSERT_TRUE(read_report(10'000)) << "the child stopped reporting";
    ASSERT_LT(std::chrono::steady_clock::now() - start, 30s);
  }
  reaper.Kill();
  while (read_report(1000)) {  // reports written before the kill
  }
  ::close(fds[0]);
  ASSERT_TRUE(WIFSIGNALED(reaper.status) && WTERMSIG(reaper.status) == SIGKILL)
      << "the child ended otherwise: status " << reaper.status;

  Database db = Database::Open(path);
  EXPECT_EQ(db.IntegrityCheck(), "ok");  // includes PRAGMA integrity_check
  const std::vector<Sample> stored = db.Samples(trial);
  EXPECT_GE(static_cast<int64_t>(stored.size()), acknowledged);
  for (size_t k = 0; k < stored.size(); ++k)  // a gap-free, intact prefix
    ASSERT_TRUE(SameSample(stored[k], SampleAt(static_cast<int64_t>(k)))) << k;
  EXPECT_EQ(db.MarkRecordingTrialsInterrupted(), 1);
  EXPECT_EQ(db.FindTrial(trial)->end_utime, static_cast<int64_t>(stored.size()) - 1);
  std::cout << "acknowledged " << acknowledged << ", in the file " << stored.size() << "\n";
}

}  // namespace
}  // namespace flexid::storage
