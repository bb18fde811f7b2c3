// The flexid database's tables and their migrations (database_internal.h): what a file at
// each schema version holds, and bringing a file to Database::kSchemaVersion.
//
// Schema (migration 1), chosen for the queries of database.h:
//   schema_version  one row per applied migration; the schema version is the highest.
//   actuators       keyed by id (TEXT).
//   trials          INTEGER PRIMARY KEY id; actuator_id -> actuators. sample_count is kept
//                   by AppendSamples in the same transaction as the rows it counts, so that
//                   listing trials never counts millions of samples (IntegrityCheck
//                   verifies it against the rows).
//   samples         PRIMARY KEY (trial_id, utime) WITHOUT ROWID: the key is the table's
//                   own B-tree order, so a trial's samples are one contiguous range read in
//                   utime order with no sort and no second index, and a duplicate
//                   (trial, utime) is found by the key itself (INSERT OR IGNORE). A rowid
//                   table would store every sample twice (table plus a unique index on the
//                   same key) and write both. Rows are ~30 bytes, far below the size at
//                   which SQLite advises against WITHOUT ROWID. Samples arrive in utime
//                   order per trial, so inserts append at the right edge of each trial's
//                   range.
//   models          UNIQUE (actuator_id, version); a partial unique index on actuator_id
//                   WHERE active = 1 makes "at most one active model" a schema rule.
//   model_trials    (model_id, position) -> trial_id, keeping the caller's order.
//   alerts          indexed by utime and by (actuator_id, utime). No foreign key: an alert
//                   is a log entry and must be storable for any actuator id.
// The file carries PRAGMA application_id 'FLXD', so that Open can tell a flexid database
// from another SQLite file and refuse to touch the latter.
#include <chrono>
#include <cstdint>
#include <string>

#include "flexid/version.h"
#include "storage/database.h"
#include "storage/database_internal.h"
#include "storage/sql.h"

namespace flexid::storage::internal {
namespace {

// 'FLXD' as a big-endian 32-bit integer, written into the SQLite header by migration 1.
constexpr int64_t kApplicationId = 0x464C5844;

int64_t NowUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// --- migrations --------------------------------------------------------------------
// Each step brings the schema from version - 1 to version and runs inside the migration
// transaction (DDL is transactional in SQLite). To add version N: write MigrateToN, append
// {N, "...", &MigrateToN} to kMigrations and set Database::kSchemaVersion = N.

void MigrateTo1(sqlite3* db, const std::string& path) {
  static_assert(kApplicationId == 1179408452, "the PRAGMA below spells kApplicationId");
  ExecScript(db, path, R"sql(
    PRAGMA application_id = 1179408452;
    CREATE TABLE schema_version (
      version        INTEGER PRIMARY KEY,
      applied_utime  INTEGER NOT NULL,  -- wall clock, microseconds since 1970
      flexid_version TEXT    NOT NULL,
      description    TEXT    NOT NULL
    );
    CREATE TABLE actuators (
      id              TEXT PRIMARY KEY NOT NULL CHECK (id <> ''),
      length_mm       REAL NOT NULL,
      width_mm        REAL NOT NULL,
      thickness_mm    REAL NOT NULL,
      pattern         TEXT NOT NULL,
      material        TEXT NOT NULL,
      electrolyte     TEXT NOT NULL,
      concentration_M REAL NOT NULL
    );
    CREATE TABLE trials (
      id           INTEGER PRIMARY KEY,
      actuator_id  TEXT    NOT NULL REFERENCES actuators (id),
      protocol     TEXT    NOT NULL,
      start_utime  INTEGER NOT NULL,
      end_utime    INTEGER NOT NULL DEFAULT 0,
      state        TEXT    NOT NULL DEFAULT 'recording'
                   CHECK (state IN ('recording', 'complete', 'interrupted')),
      sample_count INTEGER NOT NULL DEFAULT 0
    );
    CREATE INDEX trials_by_actuator ON trials (actuator_id, start_utime);
    CREATE INDEX trials_by_start ON trials (start_utime);
    CREATE INDEX trials_recording ON trials (id) WHERE state = 'recording';
    CREATE TABLE samples (
      trial_id      INTEGER NOT NULL REFERENCES trials (id),
      utime         INTEGER NOT NULL,
      voltage_V     REAL    NOT NULL,
      deflection_mm REAL    NOT NULL,
      PRIMARY KEY (trial_id, utime)
    ) WITHOUT ROWID;
    CREATE TABLE models (
      id             INTEGER PRIMARY KEY,
      actuator_id    TEXT    NOT NULL REFERENCES actuators (id),
      version        INTEGER NOT NULL CHECK (version >= 1),
      created_utime  INTEGER NOT NULL,
      model_json     TEXT    NOT NULL,
      fit_json       TEXT    NOT NULL,
      samples_hash   TEXT    NOT NULL,
      flexid_version TEXT    NOT NULL,
      active         INTEGER NOT NULL DEFAULT 0 CHECK (active IN (0, 1)),
      UNIQUE (actuator_id, version)
    );
    CREATE UNIQUE INDEX models_one_active ON models (actuator_id) WHERE active = 1;
    CREATE TABLE model_trials (
      model_id INTEGER NOT NULL REFERENCES models (id),
      position INTEGER NOT NULL,
      trial_id INTEGER NOT NULL REFERENCES trials (id),
      PRIMARY KEY (model_id, position)
    ) WITHOUT ROWID;
    CREATE INDEX model_trials_by_trial ON model_trials (trial_id);
    CREATE TABLE alerts (
      id           INTEGER PRIMARY KEY,
      actuator_id  TEXT    NOT NULL,
      kind         TEXT    NOT NULL,
      severity     INTEGER NOT NULL,
      utime        INTEGER NOT NULL,
      start_utime  INTEGER NOT NULL,
      end_utime    INTEGER NOT NULL,
      magnitude_mm REAL,  -- NULL: not a number
      threshold_mm REAL,
      text         TEXT    NOT NULL
    );
    CREATE INDEX alerts_by_utime ON alerts (utime);
    CREATE INDEX alerts_by_actuator ON alerts (actuator_id, utime);
  )sql");
}

// Version 2: a model's lineage (ModelRecord::lineage_json), for versions proposed by a
// diagnosis. Existing models were identified from trials: no lineage.
void MigrateTo2(sqlite3* db, const std::string& path) {
  ExecScript(db, path, "ALTER TABLE models ADD COLUMN lineage_json TEXT NOT NULL DEFAULT '';");
}

struct Migration {
  int version;
  const char* description;
  void (*apply)(sqlite3* db, const std::string& path);
};

constexpr Migration kMigrations[] = {
    {1, "initial schema", &MigrateTo1},
    {2, "model lineage", &MigrateTo2},
};

constexpr bool MigrationsAreConsecutive() {
  int expected = 1;
  for (const Migration& migration : kMigrations)
    if (migration.version != expected++) return false;
  return expected - 1 == Database::kSchemaVersion;
}
static_assert(MigrationsAreConsecutive(),
              "kMigrations must hold versions 1..kSchemaVersion in order");

}  // namespace

int ReadSchemaVersion(sqlite3* db, const std::string& path) {
  // The first read of the file: a file that is not a database fails here.
  int64_t application_id = 0;
  {
    Statement statement(db, path, "PRAGMA application_id");
    if (statement.Step()) application_id = statement.Int64(0);
  }
  const int64_t objects = QueryInt(db, path, "SELECT count(*) FROM sqlite_schema");
  if (application_id != kApplicationId) {
    if (application_id == 0 && objects == 0) return 0;
    throw StorageError(path + ": not a flexid database (a SQLite file with " +
                       std::to_string(objects) + " schema objects and application_id " +
                       std::to_string(application_id) + "); it was left untouched");
  }
  if (QueryInt(db, path,
               "SELECT count(*) FROM sqlite_schema WHERE type = 'table' AND "
               "name = 'schema_version'") == 0)
    throw StorageError(path + ": damaged flexid database: it has no schema_version table");
  const int64_t version = QueryInt(db, path, "SELECT max(version) FROM schema_version");
  if (version < 1)
    throw StorageError(path + ": damaged flexid database: its schema_version table is empty");
  if (version > Database::kSchemaVersion)
    throw StorageError(path + ": the database has schema version " + std::to_string(version) +
                       ", newer than this flexid (" + kVersion + ") supports (" +
                       std::to_string(Database::kSchemaVersion) + "); use a newer flexid");
  return static_cast<int>(version);
}

void Migrate(sqlite3* db, const std::string& path) {
  Transaction transaction(db, path, Transaction::Kind::kWrite);
  const int from = ReadSchemaVersion(db, path);  // again: another process may have migrated
  for (const Migration& migration : kMigrations) {
    if (migration.version <= from) continue;
    migration.apply(db, path);
    Statement(db, path,
              "INSERT INTO schema_version (version, applied_utime, flexid_version, description) "
              "VALUES (?, ?, ?, ?)")
        .Bind(1, int64_t{migration.version})
        .Bind(2, NowUtime())
        .Bind(3, std::string(kVersion))
        .Bind(4, std::string(migration.description))
        .Run();
  }
  transaction.Commit();
}

}  // namespace flexid::storage::internal
