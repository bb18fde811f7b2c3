// What the implementation files of the flexid database share (internal to
// storage/database*.cc): migrating a file, which Database::Open runs, and the checks and
// rows that more than one kind of record needs. The Database member functions are defined
// in the file of the records they handle:
//   database.cc          the connection: Open, moves, SchemaVersion, Backup, IntegrityCheck
//   database_schema.cc   the tables (migration 1) and migrating a file to kSchemaVersion
//   database_trials.cc   actuators and trials
//   database_samples.cc  samples, and HashSamples
//   database_models.cc   identified models
//   database_alerts.cc   alerts
// The SQLite plumbing they all use (Statement, Transaction, Throw) is sql.h.
#pragma once

#include <cstdint>
#include <string>

struct sqlite3;

namespace flexid::storage::internal {

// --- database_schema.cc ----------------------------------------------------------------

// The schema version of the file: 0 for an empty file; throws for a file that is not a
// flexid database or is from a newer flexid.
int ReadSchemaVersion(sqlite3* db, const std::string& path);

// Brings the file to Database::kSchemaVersion in one write transaction, applying the
// migrations it lacks (none if another connection migrated it meanwhile).
void Migrate(sqlite3* db, const std::string& path);

// --- database_trials.cc ----------------------------------------------------------------

// Throws StorageError for an empty actuator id.
void RequireActuatorId(const std::string& id, const std::string& path);

// Inserts the actuator with the defaults of Actuator unless it exists.
void EnsureActuator(sqlite3* db, const std::string& path, const std::string& id);

bool TrialExists(sqlite3* db, const std::string& path, int64_t trial_id);

}  // namespace flexid::storage::internal
