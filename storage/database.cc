// The flexid database: connection set-up, schema and migrations, typed queries.
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
#include "storage/database.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <bit>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <iterator>
#include <limits>
#include <map>
#include <string_view>
#include <utility>

#include "flexid/version.h"

namespace flexid::storage {
namespace {

// 'FLXD' as a big-endian 32-bit integer, written into the SQLite header by migration 1.
constexpr int64_t kApplicationId = 0x464C5844;
constexpr int kBusyTimeout_ms = 5000;

// Whether a failure with that result code may pass: the database was busy or locked, or
// the file system full, read-only or failing (StorageError::transient).
bool IsTransient(int result_code) {
  switch (result_code & 0xFF) {  // the primary result code
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
    case SQLITE_FULL:
    case SQLITE_READONLY:
    case SQLITE_IOERR:
    case SQLITE_CANTOPEN:
    case SQLITE_NOMEM:
    case SQLITE_PROTOCOL:
      return true;
    default:
      return false;
  }
}

[[noreturn]] void Throw(sqlite3* db, const std::string& path, std::string_view what) {
  std::string message = path + ": " + std::string(what);
  if (db == nullptr) {
    message += ": out of memory";
    throw StorageError(message, /*transient=*/true);
  }
  message += ": ";
  message += sqlite3_errmsg(db);
  switch (sqlite3_errcode(db) & 0xFF) {  // the primary result code
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
      message += " (another connection held it for more than " +
                 std::to_string(kBusyTimeout_ms / 1000) + " s)";
      break;
    case SQLITE_READONLY:
      message += " (the file or its directory is not writable)";
      break;
    default:
      break;
  }
  throw StorageError(message, IsTransient(sqlite3_errcode(db)));
}

// A prepared statement (RAII). Bind indexes are 1-based, column indexes 0-based, as in
// SQLite.
class Statement {
 public:
  Statement(sqlite3* db, const std::string& path, std::string_view sql) : db_(db), path_(path) {
    if (sqlite3_prepare_v2(db, sql.data(), static_cast<int>(sql.size()), &stmt_, nullptr) !=
        SQLITE_OK)
      Throw(db_, path_, "cannot prepare \"" + std::string(sql) + "\"");
  }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  Statement& Bind(int index, int64_t value) {
    Check(sqlite3_bind_int64(stmt_, index, value));
    return *this;
  }
  Statement& Bind(int index, double value) {  // NaN becomes NULL (SQLite's rule)
    Check(sqlite3_bind_double(stmt_, index, value));
    return *this;
  }
  Statement& Bind(int index, const std::string& value) {
    Check(sqlite3_bind_text64(stmt_, index, value.data(), value.size(), SQLITE_TRANSIENT,
                              SQLITE_UTF8));
    return *this;
  }

  // Executes one step: true if a row is available, false when done.
  bool Step() {
    const int rc = sqlite3_step(stmt_);
    if (rc == SQLITE_ROW) return true;
    if (rc == SQLITE_DONE) return false;
    sqlite3_reset(stmt_);  // makes sqlite3_errmsg() describe this statement's error
    Throw(db_, path_, "cannot execute \"" + std::string(sqlite3_sql(stmt_)) + "\"");
  }
  // Runs a statement that returns no rows.
  void Run() {
    while (Step()) {
    }
  }
  void Reset() { sqlite3_reset(stmt_); }

  bool IsNull(int column) const { return sqlite3_column_type(stmt_, column) == SQLITE_NULL; }
  int64_t Int64(int column) const { return sqlite3_column_int64(stmt_, column); }
  double Double(int column) const { return sqlite3_column_double(stmt_, column); }
  double DoubleOrNan(int column) const {
    return IsNull(column) ? std::numeric_limits<double>::quiet_NaN() : Double(column);
  }
  std::string Text(int column) const {
    const auto* text = reinterpret_cast<const char*>(sqlite3_column_text(stmt_, column));
    return text ? std::string(text, static_cast<size_t>(sqlite3_column_bytes(stmt_, column)))
                : std::string();
  }

 private:
  void Check(int rc) {
    if (rc != SQLITE_OK) Throw(db_, path_, "cannot bind a value");
  }

  sqlite3* db_;
  const std::string& path_;
  sqlite3_stmt* stmt_ = nullptr;
};

// Runs one statement without values (DDL, PRAGMA, BEGIN/COMMIT).
void Exec(sqlite3* db, const std::string& path, std::string_view sql) {
  Statement(db, path, sql).Run();
}

// Runs a script of statements without values, one prepared statement at a time.
void ExecScript(sqlite3* db, const std::string& path, std::string_view script) {
  const char* next = script.data();
  const char* const end = script.data() + script.size();
  while (next < end) {
    sqlite3_stmt* stmt = nullptr;
    const char* tail = nullptr;
    if (sqlite3_prepare_v2(db, next, static_cast<int>(end - next), &stmt, &tail) != SQLITE_OK)
      Throw(db, path, "cannot prepare the schema script");
    if (stmt == nullptr) break;  // only white space or comments left
    const int rc = sqlite3_step(stmt);
    sqlite3_finalize(stmt);
    if (rc != SQLITE_DONE && rc != SQLITE_ROW) Throw(db, path, "cannot apply the schema script");
    next = tail;
  }
}

// A transaction (RAII): rolled back unless committed. Writers take the write lock at
// BEGIN (IMMEDIATE), so that a busy database makes them wait there, within the busy
// timeout, instead of failing later on a lock upgrade.
class Transaction {
 public:
  enum class Kind { kRead, kWrite };
  Transaction(sqlite3* db, const std::string& path, Kind kind) : db_(db), path_(path) {
    Exec(db_, path_, kind == Kind::kWrite ? "BEGIN IMMEDIATE" : "BEGIN");
  }
  ~Transaction() {
    if (!committed_) sqlite3_exec(db_, "ROLLBACK", nullptr, nullptr, nullptr);
  }
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;

  void Commit() {
    Exec(db_, path_, "COMMIT");
    committed_ = true;
  }

 private:
  sqlite3* db_;
  const std::string& path_;
  bool committed_ = false;
};

int64_t QueryInt(sqlite3* db, const std::string& path, std::string_view sql) {
  Statement statement(db, path, sql);
  return statement.Step() ? statement.Int64(0) : 0;
}

int64_t NowUtime() {
  return std::chrono::duration_cast<std::chrono::microseconds>(
             std::chrono::system_clock::now().time_since_epoch())
      .count();
}

// --- migrations --------------------------------------------------------------------
// Each step brings the schema from version - 1 to version and runs inside the migration
// transaction (DDL is transactional in SQLite). To add version 2: write MigrateTo2, append
// {2, "...", &MigrateTo2} to kMigrations and set Database::kSchemaVersion = 2.

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

struct Migration {
  int version;
  const char* description;
  void (*apply)(sqlite3* db, const std::string& path);
};

constexpr Migration kMigrations[] = {
    {1, "initial schema", &MigrateTo1},
};

constexpr bool MigrationsAreConsecutive() {
  int expected = 1;
  for (const Migration& migration : kMigrations)
    if (migration.version != expected++) return false;
  return expected - 1 == Database::kSchemaVersion;
}
static_assert(MigrationsAreConsecutive(),
              "kMigrations must hold versions 1..kSchemaVersion in order");

// The schema version of the file: 0 for an empty file; throws for a file that is not a
// flexid database or is from a newer flexid.
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

TrialState ParseTrialState(const std::string& text, const std::string& path) {
  for (TrialState state : {TrialState::kRecording, TrialState::kComplete, TrialState::kInterrupted})
    if (text == TrialStateName(state)) return state;
  throw StorageError(path + ": unknown trial state \"" + text + "\" in the trials table");
}

void RequireActuatorId(const std::string& id, const std::string& path) {
  if (id.empty()) throw StorageError(path + ": the actuator id is empty");
}

// Inserts the actuator with the defaults of Actuator unless it exists.
void EnsureActuator(sqlite3* db, const std::string& path, const std::string& id) {
  RequireActuatorId(id, path);
  const Actuator defaults;
  Statement(db, path,
            "INSERT OR IGNORE INTO actuators (id, length_mm, width_mm, thickness_mm, pattern, "
            "material, electrolyte, concentration_M) VALUES (?, ?, ?, ?, ?, ?, ?, ?)")
      .Bind(1, id)
      .Bind(2, defaults.length_mm)
      .Bind(3, defaults.width_mm)
      .Bind(4, defaults.thickness_mm)
      .Bind(5, defaults.pattern)
      .Bind(6, defaults.material)
      .Bind(7, defaults.electrolyte)
      .Bind(8, defaults.concentration_M)
      .Run();
}

bool TrialExists(sqlite3* db, const std::string& path, int64_t trial_id) {
  Statement statement(db, path, "SELECT 1 FROM trials WHERE id = ?");
  return statement.Bind(1, trial_id).Step();
}

// Inserts samples inside the caller's transaction, counting what happens to each, and
// then adds the inserted counts to trials.sample_count.
class SampleInserter {
 public:
  SampleInserter(sqlite3* db, const std::string& path)
      : db_(db),
        path_(path),
        insert_(db, path,
                "INSERT OR IGNORE INTO samples (trial_id, utime, voltage_V, deflection_mm) "
                "VALUES (?, ?, ?, ?)") {}

  void Add(int64_t trial_id, const Sample& sample) {
    if (!std::isfinite(sample.voltage_V) || !std::isfinite(sample.deflection_mm)) {
      ++result_.invalid;
      return;
    }
    TrialCount& trial = Lookup(trial_id);
    if (!trial.exists) {
      ++result_.invalid;
      return;
    }
    insert_.Bind(1, trial_id).Bind(2, sample.utime).Bind(3, sample.voltage_V);
    insert_.Bind(4, sample.deflection_mm).Run();
    insert_.Reset();
    if (sqlite3_changes(db_) > 0) {
      ++trial.inserted;
      ++result_.inserted;
    } else {
      ++result_.duplicates;
    }
  }

  AppendResult Finish() {
    Statement update(db_, path_, "UPDATE trials SET sample_count = sample_count + ? WHERE id = ?");
    for (const TrialCount& trial : trials_) {
      if (trial.inserted == 0) continue;
      update.Bind(1, trial.inserted).Bind(2, trial.trial_id).Run();
      update.Reset();
    }
    return result_;
  }

 private:
  struct TrialCount {
    int64_t trial_id;
    bool exists;
    int64_t inserted;
  };

  // A batch holds few trials (one per recording actuator): a linear search, starting with
  // the last one used, is the fastest map here.
  TrialCount& Lookup(int64_t trial_id) {
    if (last_ < trials_.size() && trials_[last_].trial_id == trial_id) return trials_[last_];
    for (last_ = 0; last_ < trials_.size(); ++last_)
      if (trials_[last_].trial_id == trial_id) return trials_[last_];
    trials_.push_back({trial_id, TrialExists(db_, path_, trial_id), 0});
    return trials_[last_];
  }

  sqlite3* db_;
  const std::string& path_;
  Statement insert_;
  std::vector<TrialCount> trials_;
  size_t last_ = 0;
  AppendResult result_;
};

// Column list shared by the model queries: constant text (values are always bound).
constexpr const char* kModelColumns =
    "id, actuator_id, version, created_utime, model_json, fit_json, samples_hash, "
    "flexid_version, active";

ModelRecord ReadModelRow(const Statement& row) {
  ModelRecord model;
  model.id = row.Int64(0);
  model.actuator_id = row.Text(1);
  model.version = static_cast<int32_t>(row.Int64(2));
  model.created_utime = row.Int64(3);
  model.model_json = row.Text(4);
  model.fit_json = row.Text(5);
  model.samples_hash = row.Text(6);
  model.flexid_version = row.Text(7);
  model.active = row.Int64(8) != 0;
  return model;
}

// Reads the models a statement selects (columns kModelColumns) with their trial ids.
std::vector<ModelRecord> ReadModels(sqlite3* db, const std::string& path, Statement& select) {
  std::vector<ModelRecord> models;
  while (select.Step()) models.push_back(ReadModelRow(select));
  Statement trials(db, path,
                   "SELECT trial_id FROM model_trials WHERE model_id = ? ORDER BY position");
  for (ModelRecord& model : models) {
    trials.Bind(1, model.id);
    while (trials.Step()) model.trial_ids.push_back(trials.Int64(0));
    trials.Reset();
  }
  return models;
}

Trial ReadTrialRow(const Statement& row, const std::string& path) {
  Trial trial;
  trial.id = row.Int64(0);
  trial.actuator_id = row.Text(1);
  trial.protocol = row.Text(2);
  trial.start_utime = row.Int64(3);
  trial.end_utime = row.Int64(4);
  trial.state = ParseTrialState(row.Text(5), path);
  trial.samples = row.Int64(6);
  return trial;
}

Actuator ReadActuatorRow(const Statement& row) {
  Actuator actuator;
  actuator.id = row.Text(0);
  actuator.length_mm = row.Double(1);
  actuator.width_mm = row.Double(2);
  actuator.thickness_mm = row.Double(3);
  actuator.pattern = row.Text(4);
  actuator.material = row.Text(5);
  actuator.electrolyte = row.Text(6);
  actuator.concentration_M = row.Double(7);
  return actuator;
}

AlertRecord ReadAlertRow(const Statement& row) {
  AlertRecord alert;
  alert.id = row.Int64(0);
  alert.actuator_id = row.Text(1);
  alert.kind = row.Text(2);
  alert.severity = static_cast<int32_t>(row.Int64(3));
  alert.utime = row.Int64(4);
  alert.start_utime = row.Int64(5);
  alert.end_utime = row.Int64(6);
  alert.magnitude_mm = row.DoubleOrNan(7);
  alert.threshold_mm = row.DoubleOrNan(8);
  alert.text = row.Text(9);
  return alert;
}

}  // namespace

const char* TrialStateName(TrialState state) {
  switch (state) {
    case TrialState::kRecording:
      return "recording";
    case TrialState::kComplete:
      return "complete";
    case TrialState::kInterrupted:
      return "interrupted";
  }
  return "unknown";
}

void Database::Closer::operator()(sqlite3* db) const noexcept {
  sqlite3_close_v2(db);  // also finalises any statement left behind
}

Database::Database(std::unique_ptr<sqlite3, Closer> db, std::string path)
    : db_(std::move(db)), path_(std::move(path)) {}
Database::Database(Database&& other) noexcept = default;
Database& Database::operator=(Database&& other) noexcept = default;
Database::~Database() = default;

sqlite3* Database::Handle() const {
  if (!db_) throw StorageError(path_ + ": the database connection was moved away");
  return db_.get();
}

Database Database::Open(const std::string& path) {
  sqlite3* raw = nullptr;
  const int rc =
      sqlite3_open_v2(path.c_str(), &raw,
                      SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
  std::unique_ptr<sqlite3, Closer> handle(raw);
  if (rc != SQLITE_OK) Throw(raw, path, "cannot open");
  sqlite3* db = handle.get();
  sqlite3_extended_result_codes(db, 1);
  sqlite3_busy_timeout(db, kBusyTimeout_ms);

  // SQLite silently falls back to read-only when the file is not writable.
  if (sqlite3_db_readonly(db, "main") == 1)
    throw StorageError(path +
                       ": cannot open for writing: the file is read-only (check the "
                       "permissions of the file and of its directory)");

  // Identify the file before changing anything in it.
  const int version = [&] {
    try {
      return ReadSchemaVersion(db, path);
    } catch (const StorageError&) {
      if (sqlite3_errcode(db) == SQLITE_NOTADB)
        throw StorageError(path + ": cannot open: file is not a database");
      throw;
    }
  }();

  const bool in_memory = path.empty() || path == ":memory:";
  {
    Statement journal(db, path, "PRAGMA journal_mode = WAL");
    const std::string mode = journal.Step() ? journal.Text(0) : "";
    if (mode != "wal" && !in_memory)
      throw StorageError(path + ": cannot switch to WAL journal mode (it stays \"" + mode +
                         "\"); is the file on a network file system?");
  }
  // synchronous=NORMAL in WAL mode: a commit writes its pages to the -wal file but does not
  // fsync it; fsync happens at checkpoints. Every committed transaction therefore survives
  // kill -9 or a crash of this process (the OS holds the data); an OS crash or power cut
  // can lose the transactions committed since the last checkpoint (at most the
  // wal_autocheckpoint of 1000 pages, ~4 MB), without corrupting the file. FULL would
  // fsync at every commit, which DESIGN.md does not require.
  Exec(db, path, "PRAGMA synchronous = NORMAL");
  Exec(db, path, "PRAGMA foreign_keys = ON");
  // After a large import the -wal file is truncated back to at most 64 MiB at the next
  // checkpoint instead of keeping its largest size forever.
  Exec(db, path, "PRAGMA journal_size_limit = 67108864");

  if (version < kSchemaVersion) Migrate(db, path);
  return Database(std::move(handle), path);
}

int Database::SchemaVersion() const {
  return static_cast<int>(QueryInt(Handle(), path_, "SELECT max(version) FROM schema_version"));
}

// --- actuators -----------------------------------------------------------------------

void Database::UpsertActuator(const Actuator& actuator) {
  sqlite3* db = Handle();
  RequireActuatorId(actuator.id, path_);
  Statement(db, path_,
            "INSERT INTO actuators (id, length_mm, width_mm, thickness_mm, pattern, material, "
            "electrolyte, concentration_M) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8) "
            "ON CONFLICT (id) DO UPDATE SET length_mm = ?2, width_mm = ?3, thickness_mm = ?4, "
            "pattern = ?5, material = ?6, electrolyte = ?7, concentration_M = ?8")
      .Bind(1, actuator.id)
      .Bind(2, actuator.length_mm)
      .Bind(3, actuator.width_mm)
      .Bind(4, actuator.thickness_mm)
      .Bind(5, actuator.pattern)
      .Bind(6, actuator.material)
      .Bind(7, actuator.electrolyte)
      .Bind(8, actuator.concentration_M)
      .Run();
}

std::vector<Actuator> Database::Actuators() {
  Statement select(Handle(), path_,
                   "SELECT id, length_mm, width_mm, thickness_mm, pattern, material, "
                   "electrolyte, concentration_M FROM actuators ORDER BY id");
  std::vector<Actuator> actuators;
  while (select.Step()) actuators.push_back(ReadActuatorRow(select));
  return actuators;
}

std::optional<Actuator> Database::FindActuator(const std::string& id) {
  Statement select(Handle(), path_,
                   "SELECT id, length_mm, width_mm, thickness_mm, pattern, material, "
                   "electrolyte, concentration_M FROM actuators WHERE id = ?");
  if (!select.Bind(1, id).Step()) return std::nullopt;
  return ReadActuatorRow(select);
}

// --- trials --------------------------------------------------------------------------

namespace {

// Inserts a trial "recording" (with that id, or the next free one when trial_id is 0) and
// its actuator if unknown; returns the id.
int64_t InsertTrialRow(sqlite3* db, const std::string& path, int64_t trial_id,
                       const std::string& actuator_id, const std::string& protocol,
                       int64_t start_utime) {
  Transaction transaction(db, path, Transaction::Kind::kWrite);
  EnsureActuator(db, path, actuator_id);
  Statement insert(db, path,
                   "INSERT INTO trials (id, actuator_id, protocol, start_utime) "
                   "VALUES (?, ?, ?, ?)");
  if (trial_id != 0) insert.Bind(1, trial_id);  // unbound: NULL, SQLite picks the id
  insert.Bind(2, actuator_id).Bind(3, protocol).Bind(4, start_utime).Run();
  const int64_t id = sqlite3_last_insert_rowid(db);
  transaction.Commit();
  return id;
}

}  // namespace

int64_t Database::StartTrial(const std::string& actuator_id, const std::string& protocol,
                             int64_t start_utime) {
  return InsertTrialRow(Handle(), path_, 0, actuator_id, protocol, start_utime);
}

void Database::InsertTrial(int64_t trial_id, const std::string& actuator_id,
                           const std::string& protocol, int64_t start_utime) {
  if (trial_id <= 0)
    throw StorageError(path_ + ": cannot start trial " + std::to_string(trial_id) +
                       ": trial ids are positive");
  InsertTrialRow(Handle(), path_, trial_id, actuator_id, protocol, start_utime);
}

int64_t Database::LastTrialId() { return QueryInt(Handle(), path_, "SELECT max(id) FROM trials"); }

void Database::EndTrial(int64_t trial_id, int64_t end_utime, TrialState state) {
  sqlite3* db = Handle();
  if (state == TrialState::kRecording)
    throw StorageError(path_ + ": cannot end trial " + std::to_string(trial_id) +
                       " in state \"recording\"");
  Statement(db, path_, "UPDATE trials SET end_utime = ?, state = ? WHERE id = ?")
      .Bind(1, end_utime)
      .Bind(2, std::string(TrialStateName(state)))
      .Bind(3, trial_id)
      .Run();
  if (sqlite3_changes(db) == 0)
    throw StorageError(path_ + ": cannot end trial " + std::to_string(trial_id) +
                       ": no such trial");
}

int Database::MarkRecordingTrialsInterrupted() {
  sqlite3* db = Handle();
  Statement(db, path_,
            "UPDATE trials SET state = 'interrupted', end_utime = coalesce("
            "(SELECT max(utime) FROM samples WHERE samples.trial_id = trials.id), start_utime) "
            "WHERE state = 'recording'")
      .Run();
  return sqlite3_changes(db);
}

std::vector<Trial> Database::Trials(const std::optional<std::string>& actuator_id, int limit) {
  sqlite3* db = Handle();
  std::vector<Trial> trials;
  auto read = [&](Statement& select) {
    while (select.Step()) trials.push_back(ReadTrialRow(select, path_));
  };
  if (actuator_id) {
    Statement select(db, path_,
                     "SELECT id, actuator_id, protocol, start_utime, end_utime, state, "
                     "sample_count FROM trials WHERE actuator_id = ? "
                     "ORDER BY start_utime DESC, id DESC LIMIT ?");
    select.Bind(1, *actuator_id).Bind(2, int64_t{limit});
    read(select);
  } else {
    Statement select(db, path_,
                     "SELECT id, actuator_id, protocol, start_utime, end_utime, state, "
                     "sample_count FROM trials ORDER BY start_utime DESC, id DESC LIMIT ?");
    select.Bind(1, int64_t{limit});
    read(select);
  }
  return trials;
}

std::optional<Trial> Database::FindTrial(int64_t id) {
  Statement select(Handle(), path_,
                   "SELECT id, actuator_id, protocol, start_utime, end_utime, state, "
                   "sample_count FROM trials WHERE id = ?");
  if (!select.Bind(1, id).Step()) return std::nullopt;
  return ReadTrialRow(select, path_);
}

// --- samples -------------------------------------------------------------------------

AppendResult Database::AppendSamples(int64_t trial_id, std::span<const Sample> samples) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  if (!TrialExists(db, path_, trial_id))
    throw StorageError(path_ + ": cannot store samples of trial " + std::to_string(trial_id) +
                       ": no such trial");
  SampleInserter inserter(db, path_);
  for (const Sample& sample : samples) inserter.Add(trial_id, sample);
  const AppendResult result = inserter.Finish();
  transaction.Commit();
  return result;
}

AppendResult Database::AppendSamples(std::span<const TrialSample> samples) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  SampleInserter inserter(db, path_);
  for (const TrialSample& item : samples) inserter.Add(item.trial_id, item.sample);
  const AppendResult result = inserter.Finish();
  transaction.Commit();
  return result;
}

std::vector<Sample> Database::Samples(int64_t trial_id) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kRead);  // count and rows agree
  std::vector<Sample> samples;
  samples.reserve(static_cast<size_t>(SampleCount(trial_id)));
  Statement select(db, path_,
                   "SELECT utime, voltage_V, deflection_mm FROM samples WHERE trial_id = ? "
                   "ORDER BY utime");
  select.Bind(1, trial_id);
  while (select.Step()) samples.push_back({select.Int64(0), select.Double(1), select.Double(2)});
  transaction.Commit();
  return samples;
}

std::vector<Sample> Database::SamplesPage(int64_t trial_id, int64_t after_utime, int64_t offset,
                                          int64_t limit) {
  if (offset < 0 || limit < 0) throw StorageError(path_ + ": negative sample offset or limit");
  Statement select(Handle(), path_,
                   "SELECT utime, voltage_V, deflection_mm FROM samples WHERE trial_id = ? "
                   "AND utime > ? ORDER BY utime LIMIT ? OFFSET ?");
  select.Bind(1, trial_id).Bind(2, after_utime).Bind(3, limit).Bind(4, offset);
  std::vector<Sample> samples;
  while (select.Step()) samples.push_back({select.Int64(0), select.Double(1), select.Double(2)});
  return samples;
}

int64_t Database::SampleCount(int64_t trial_id) {
  Statement select(Handle(), path_, "SELECT sample_count FROM trials WHERE id = ?");
  return select.Bind(1, trial_id).Step() ? select.Int64(0) : 0;
}

// --- models --------------------------------------------------------------------------

ModelRecord Database::StoreModel(ModelRecord record) {
  sqlite3* db = Handle();
  if (record.flexid_version.empty()) record.flexid_version = kVersion;
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  EnsureActuator(db, path_, record.actuator_id);
  {
    Statement select(db, path_, "SELECT max(version) FROM models WHERE actuator_id = ?");
    select.Bind(1, record.actuator_id).Step();
    record.version = static_cast<int32_t>(select.Int64(0) + 1);  // NULL reads as 0
  }
  if (record.active)
    Statement(db, path_, "UPDATE models SET active = 0 WHERE actuator_id = ? AND active = 1")
        .Bind(1, record.actuator_id)
        .Run();
  Statement(db, path_,
            "INSERT INTO models (actuator_id, version, created_utime, model_json, fit_json, "
            "samples_hash, flexid_version, active) VALUES (?, ?, ?, ?, ?, ?, ?, ?)")
      .Bind(1, record.actuator_id)
      .Bind(2, int64_t{record.version})
      .Bind(3, record.created_utime)
      .Bind(4, record.model_json)
      .Bind(5, record.fit_json)
      .Bind(6, record.samples_hash)
      .Bind(7, record.flexid_version)
      .Bind(8, int64_t{record.active ? 1 : 0})
      .Run();
  record.id = sqlite3_last_insert_rowid(db);
  Statement insert(db, path_,
                   "INSERT INTO model_trials (model_id, position, trial_id) VALUES (?, ?, ?)");
  for (size_t position = 0; position < record.trial_ids.size(); ++position) {
    if (!TrialExists(db, path_, record.trial_ids[position]))
      throw StorageError(path_ + ": cannot store a model of actuator " + record.actuator_id +
                         ": trial " + std::to_string(record.trial_ids[position]) +
                         " does not exist");
    insert.Bind(1, record.id).Bind(2, static_cast<int64_t>(position));
    insert.Bind(3, record.trial_ids[position]).Run();
    insert.Reset();
  }
  transaction.Commit();
  return record;
}

std::vector<ModelRecord> Database::Models(const std::string& actuator_id) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kRead);
  Statement select(db, path_,
                   std::string("SELECT ") + kModelColumns +
                       " FROM models WHERE actuator_id = ? ORDER BY version DESC");
  select.Bind(1, actuator_id);
  std::vector<ModelRecord> models = ReadModels(db, path_, select);
  transaction.Commit();
  return models;
}

std::optional<ModelRecord> Database::FindModel(const std::string& actuator_id, int32_t version) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kRead);
  Statement select(db, path_,
                   std::string("SELECT ") + kModelColumns +
                       " FROM models WHERE actuator_id = ? AND version = ?");
  select.Bind(1, actuator_id).Bind(2, int64_t{version});
  std::vector<ModelRecord> models = ReadModels(db, path_, select);
  transaction.Commit();
  if (models.empty()) return std::nullopt;
  return std::move(models.front());
}

std::optional<ModelRecord> Database::ActiveModel(const std::string& actuator_id) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kRead);
  Statement select(
      db, path_,
      std::string("SELECT ") + kModelColumns + " FROM models WHERE actuator_id = ? AND active = 1");
  select.Bind(1, actuator_id);
  std::vector<ModelRecord> models = ReadModels(db, path_, select);
  transaction.Commit();
  if (models.empty()) return std::nullopt;
  return std::move(models.front());
}

void Database::ActivateModel(const std::string& actuator_id, int32_t version) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  {
    Statement select(db, path_, "SELECT 1 FROM models WHERE actuator_id = ? AND version = ?");
    if (!select.Bind(1, actuator_id).Bind(2, int64_t{version}).Step())
      throw StorageError(path_ + ": cannot activate model version " + std::to_string(version) +
                         " of actuator " + actuator_id + ": no such model");
  }
  Statement(db, path_, "UPDATE models SET active = 0 WHERE actuator_id = ? AND active = 1")
      .Bind(1, actuator_id)
      .Run();
  Statement(db, path_, "UPDATE models SET active = 1 WHERE actuator_id = ? AND version = ?")
      .Bind(1, actuator_id)
      .Bind(2, int64_t{version})
      .Run();
  transaction.Commit();
}

// --- alerts --------------------------------------------------------------------------

int64_t Database::StoreAlert(const AlertRecord& alert) {
  sqlite3* db = Handle();
  Statement(db, path_,
            "INSERT INTO alerts (actuator_id, kind, severity, utime, start_utime, end_utime, "
            "magnitude_mm, threshold_mm, text) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)")
      .Bind(1, alert.actuator_id)
      .Bind(2, alert.kind)
      .Bind(3, int64_t{alert.severity})
      .Bind(4, alert.utime)
      .Bind(5, alert.start_utime)
      .Bind(6, alert.end_utime)
      .Bind(7, alert.magnitude_mm)
      .Bind(8, alert.threshold_mm)
      .Bind(9, alert.text)
      .Run();
  return sqlite3_last_insert_rowid(db);
}

std::vector<AlertRecord> Database::Alerts(const std::optional<std::string>& actuator_id,
                                          int64_t since_utime, int limit) {
  sqlite3* db = Handle();
  std::vector<AlertRecord> alerts;
  auto read = [&](Statement& select) {
    while (select.Step()) alerts.push_back(ReadAlertRow(select));
  };
  if (actuator_id) {
    Statement select(db, path_,
                     "SELECT id, actuator_id, kind, severity, utime, start_utime, end_utime, "
                     "magnitude_mm, threshold_mm, text FROM alerts "
                     "WHERE actuator_id = ? AND utime >= ? ORDER BY utime DESC, id DESC LIMIT ?");
    select.Bind(1, *actuator_id).Bind(2, since_utime).Bind(3, int64_t{limit});
    read(select);
  } else {
    Statement select(db, path_,
                     "SELECT id, actuator_id, kind, severity, utime, start_utime, end_utime, "
                     "magnitude_mm, threshold_mm, text FROM alerts "
                     "WHERE utime >= ? ORDER BY utime DESC, id DESC LIMIT ?");
    select.Bind(1, since_utime).Bind(2, int64_t{limit});
    read(select);
  }
  return alerts;
}

// --- maintenance ---------------------------------------------------------------------

void Database::Backup(const std::string& destination_path) {
  sqlite3* db = Handle();
  const std::string what = "cannot back up to " + destination_path;
  // Creating the file with O_EXCL makes the refusal to overwrite race-free; an empty file
  // is a valid empty SQLite database.
  const int fd = ::open(destination_path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) {
    const int error = errno;
    throw StorageError(path_ + ": " + what + ": " +
                       (error == EEXIST ? "the file exists (a backup never overwrites a file)"
                                        : std::strerror(error)));
  }
  ::close(fd);

  // Removes the partial copy unless the backup completes.
  struct RemoveUnlessKept {
    const std::string& path;
    bool keep = false;
    ~RemoveUnlessKept() {
      if (keep) return;
      std::error_code ignored;
      std::filesystem::remove(path, ignored);
      std::filesystem::remove(path + "-journal", ignored);
    }
  } cleanup{destination_path};

  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(destination_path.c_str(), &raw, SQLITE_OPEN_READWRITE, nullptr);
  std::unique_ptr<sqlite3, Closer> destination(raw);
  if (rc != SQLITE_OK) Throw(raw, destination_path, what);
  sqlite3_backup* backup = sqlite3_backup_init(destination.get(), "main", db, "main");
  if (backup == nullptr) Throw(destination.get(), destination_path, what);
  // One step copies every page within one read transaction: a consistent snapshot.
  const int step = sqlite3_backup_step(backup, -1);
  const int finish = sqlite3_backup_finish(backup);
  if (step != SQLITE_DONE || finish != SQLITE_OK)
    Throw(destination.get(), destination_path, what + " (from " + path_ + ")");
  if (sqlite3_close(destination.release()) != SQLITE_OK)
    throw StorageError(path_ + ": " + what + ": cannot close the copy");
  cleanup.keep = true;
}

std::string Database::IntegrityCheck() {
  sqlite3* db = Handle();
  std::vector<std::string> problems;
  Transaction transaction(db, path_, Transaction::Kind::kRead);
  {
    Statement check(db, path_, "PRAGMA integrity_check");
    while (check.Step())
      if (const std::string line = check.Text(0); line != "ok") problems.push_back(line);
  }
  {
    // Rows: table, rowid (NULL in a WITHOUT ROWID table), parent table, foreign key
    // index. Reported as one line per (table, parent) with a count.
    struct Orphans {
      int64_t count = 0;
      std::optional<int64_t> first_rowid;
    };
    std::map<std::pair<std::string, std::string>, Orphans> orphans;
    Statement check(db, path_, "PRAGMA foreign_key_check");
    while (check.Step()) {
      Orphans& entry = orphans[{check.Text(0), check.Text(2)}];
      ++entry.count;
      if (!entry.first_rowid && !check.IsNull(1)) entry.first_rowid = check.Int64(1);
    }
    for (const auto& [tables, entry] : orphans) {
      std::string line = tables.first + ": " + std::to_string(entry.count) +
                         " orphan row(s) referring to a missing row of " + tables.second;
      if (entry.first_rowid) line += " (first rowid " + std::to_string(*entry.first_rowid) + ")";
      problems.push_back(line);
    }
  }
  {
    Statement check(db, path_,
                    "SELECT id, sample_count, (SELECT count(*) FROM samples "
                    "WHERE samples.trial_id = trials.id) AS stored FROM trials "
                    "WHERE stored <> sample_count ORDER BY id");
    while (check.Step())
      problems.push_back("trial " + std::to_string(check.Int64(0)) + ": sample_count is " +
                         std::to_string(check.Int64(1)) + " but " + std::to_string(check.Int64(2)) +
                         " samples are stored");
  }
  transaction.Commit();
  if (problems.empty()) return "ok";
  std::string report;
  for (const std::string& problem : problems) report += (report.empty() ? "" : "\n") + problem;
  return report;
}

// --- hashing -------------------------------------------------------------------------

std::string HashSamples(std::span<const Sample> samples) {
  constexpr uint64_t kOffsetBasis = 14695981039346656037ULL;  // FNV-1a 64-bit parameters
  constexpr uint64_t kPrime = 1099511628211ULL;
  uint64_t hash = kOffsetBasis;
  auto feed = [&hash](uint64_t value) {
    for (int byte = 0; byte < 8; ++byte) {  // little-endian, whatever the host
      hash ^= (value >> (8 * byte)) & 0xFF;
      hash *= kPrime;
    }
  };
  auto bits = [](double value) { return std::bit_cast<uint64_t>(value == 0.0 ? 0.0 : value); };
  for (const Sample& sample : samples) {
    feed(static_cast<uint64_t>(sample.utime));
    feed(bits(sample.voltage_V));
    feed(bits(sample.deflection_mm));
  }
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string hex(16, '0');
  for (int digit = 15; digit >= 0; --digit, hash >>= 4)
    hex[static_cast<size_t>(digit)] = kDigits[hash & 0xF];
  return hex;
}

}  // namespace flexid::storage
