// The flexid database's actuators and trials (database.h): storing and finding actuators,
// starting, ending and listing trials, and the actuator and trial checks the other records
// share (database_internal.h).
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "storage/database.h"
#include "storage/database_internal.h"
#include "storage/sql.h"

namespace flexid::storage {
namespace internal {

void RequireActuatorId(const std::string& id, const std::string& path) {
  if (id.empty()) throw StorageError(path + ": the actuator id is empty");
}

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

}  // namespace internal

using namespace internal;  // NOLINT(google-build-using-namespace): storage's own parts

namespace {

TrialState ParseTrialState(const std::string& text, const std::string& path) {
  for (TrialState state : {TrialState::kRecording, TrialState::kComplete, TrialState::kInterrupted})
    if (text == TrialStateName(state)) return state;
  throw StorageError(path + ": unknown trial state \"" + text + "\" in the trials table");
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

std::optional<int64_t> Database::LatestTrialUtime() {
  Statement select(Handle(), path_, "SELECT max(max(start_utime, end_utime)) FROM trials");
  if (!select.Step() || select.IsNull(0)) return std::nullopt;
  return select.Int64(0);
}

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

}  // namespace flexid::storage
