// The flexid database's connection (database.h): opening a file (its pragmas, then the
// migration of database_schema.cc), moves, the schema version, and the maintenance of the
// whole file: online backup and the integrity check. The records' queries are in
// database_trials.cc, database_samples.cc, database_models.cc and database_alerts.cc
// (database_internal.h lists them).
#include "storage/database.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "storage/database_internal.h"
#include "storage/sql.h"

namespace flexid::storage {

using namespace internal;  // NOLINT(google-build-using-namespace): storage's own parts

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

}  // namespace flexid::storage
