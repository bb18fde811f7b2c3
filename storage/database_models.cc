// The flexid database's identified models (database.h): storing a model as its actuator's
// next version, listing and finding versions, and choosing the one active model.
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "flexid/version.h"
#include "storage/database.h"
#include "storage/database_internal.h"
#include "storage/sql.h"

namespace flexid::storage {

using namespace internal;  // NOLINT(google-build-using-namespace): storage's own parts

namespace {

// Column list shared by the model queries: constant text (values are always bound).
constexpr const char* kModelColumns =
    "id, actuator_id, version, created_utime, model_json, fit_json, samples_hash, "
    "flexid_version, active, lineage_json";

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
  model.lineage_json = row.Text(9);
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

}  // namespace

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
            "samples_hash, flexid_version, active, lineage_json) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)")
      .Bind(1, record.actuator_id)
      .Bind(2, int64_t{record.version})
      .Bind(3, record.created_utime)
      .Bind(4, record.model_json)
      .Bind(5, record.fit_json)
      .Bind(6, record.samples_hash)
      .Bind(7, record.flexid_version)
      .Bind(8, int64_t{record.active ? 1 : 0})
      .Bind(9, record.lineage_json)
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

}  // namespace flexid::storage
