// The flexid database's alerts (database.h): storing an alert, whatever actuator it is
// about, and listing them newest first.
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "storage/database.h"
#include "storage/sql.h"

namespace flexid::storage {

using namespace internal;  // NOLINT(google-build-using-namespace): storage's own parts

namespace {

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

}  // namespace flexid::storage
