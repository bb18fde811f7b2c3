// The SQLite plumbing of storage/ (sql.h): errors, one-off statements and scripts.
#include "storage/sql.h"

#include <sqlite3.h>

#include <string>
#include <string_view>

namespace flexid::storage::internal {
namespace {

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

}  // namespace

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

void Exec(sqlite3* db, const std::string& path, std::string_view sql) {
  Statement(db, path, sql).Run();
}

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

int64_t QueryInt(sqlite3* db, const std::string& path, std::string_view sql) {
  Statement statement(db, path, sql);
  return statement.Step() ? statement.Int64(0) : 0;
}

}  // namespace flexid::storage::internal
