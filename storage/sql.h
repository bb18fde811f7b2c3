// The SQLite plumbing of storage/ (internal: included by storage/*.cc only, never above
// storage/): a failure as a StorageError, a prepared statement and a transaction (RAII), and
// statements run once. It knows nothing of flexid's tables (database_internal.h does).
#pragma once

#include <sqlite3.h>

#include <cstdint>
#include <limits>
#include <string>
#include <string_view>

#include "storage/database.h"

namespace flexid::storage::internal {

// The busy timeout of every connection (Database::Open); a failure on a busy or locked
// database says how long it waited.
inline constexpr int kBusyTimeout_ms = 5000;

// Throws StorageError "PATH: WHAT: <SQLite's message>", with a hint for a busy or read-only
// database, transient when the same call may succeed later. db null: out of memory.
[[noreturn]] void Throw(sqlite3* db, const std::string& path, std::string_view what);

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
void Exec(sqlite3* db, const std::string& path, std::string_view sql);

// Runs a script of statements without values, one prepared statement at a time.
void ExecScript(sqlite3* db, const std::string& path, std::string_view script);

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

// The first column of the first row as an integer (0: no row, or NULL).
int64_t QueryInt(sqlite3* db, const std::string& path, std::string_view sql);

}  // namespace flexid::storage::internal
