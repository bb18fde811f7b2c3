// flexid db check|backup: recovery tools for a flexid database file (--db PATH).
//   check   integrity (SQLite's integrity and foreign-key checks: orphan rows), stored
//           sample counts against the trials' counts, and the trials a restart ended
//           ("interrupted") or that are still "recording"; exit 1 when a problem is found
//   backup  a consistent copy through SQLite's online backup, safe while flexidd writes;
//           the copy is checked before the command reports success
// Both read the file directly, with or without a running flexidd.
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "storage/record_json.h"

namespace flexid::cli {
namespace {

std::vector<std::string> Lines(const std::string& text) {
  std::vector<std::string> lines;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = text.find('\n', start);
    lines.push_back(text.substr(start, end == std::string::npos ? std::string::npos : end - start));
    if (end == std::string::npos) break;
    start = end + 1;
  }
  return lines;
}

void RunCheck(bool json) {
  storage::Database db = OpenDbFile();
  const std::string report = db.IntegrityCheck();
  const std::vector<std::string> problems =
      report == "ok" ? std::vector<std::string>{} : Lines(report);
  nlohmann::json interrupted = nlohmann::json::array(), recording = nlohmann::json::array();
  int64_t trials = 0, samples = 0;
  for (const storage::Trial& t : db.Trials({}, -1)) {
    ++trials;
    samples += t.samples;
    if (t.state == storage::TrialState::kInterrupted) interrupted.push_back(storage::TrialJson(t));
    if (t.state == storage::TrialState::kRecording) recording.push_back(storage::TrialJson(t));
  }
  if (json) {
    std::cout << nlohmann::json{{"database", DbPath()},         {"ok", problems.empty()},
                                {"problems", problems},         {"trials", trials},
                                {"samples", samples},           {"interrupted_trials", interrupted},
                                {"recording_trials", recording}}
                     .dump(2)
              << "\n";
  } else {
    std::cout << DbPath() << ": schema " << db.SchemaVersion() << ", " << trials << " trials, "
              << samples << " samples\n";
    std::cout << "integrity: " << (problems.empty() ? "ok" : "PROBLEMS") << "\n";
    for (const std::string& p : problems) std::cout << "  " << p << "\n";
    std::cout << "interrupted trials: " << interrupted.size()
              << (interrupted.empty() ? "" : " (ended by a restart of flexidd; samples kept)")
              << "\n";
    for (const auto& t : interrupted)
      std::cout << "  trial " << t["id"] << " of " << t["actuator"].get<std::string>() << ", "
                << t["samples"] << " samples\n";
    std::cout << "recording trials: " << recording.size()
              << (recording.empty()
                      ? ""
                      : " (a running flexidd records them; if none runs, its next start marks "
                        "them interrupted)")
              << "\n";
    for (const auto& t : recording)
      std::cout << "  trial " << t["id"] << " of " << t["actuator"].get<std::string>() << ", "
                << t["samples"] << " samples so far\n";
  }
  if (!problems.empty())
    throw OperationError(DbPath() + ": " + std::to_string(problems.size()) +
                         " problem(s) found; restore a backup (flexid db backup) or export the "
                         "trials that read back");
}

void RunBackup(const std::string& destination, bool json) {
  if (destination.empty()) throw UsageError("backup: give the destination file");
  if (std::filesystem::exists(destination))
    throw UsageError(destination + ": the file exists (a backup never overwrites a file)");
  storage::Database db = OpenDbFile();
  Progress progress("backup");
  progress.Note("copying " + DbPath() + " to " + destination);
  try {
    db.Backup(destination);
  } catch (const storage::StorageError& e) {
    throw OperationError(e.what());
  }
  progress.Finish();
  std::string check;
  try {
    check = storage::Database::Open(destination).IntegrityCheck();
  } catch (const storage::StorageError& e) {
    check = e.what();
  }
  if (check != "ok") throw OperationError(destination + ": the copy does not check: " + check);
  const auto bytes = std::filesystem::file_size(destination);
  if (json)
    std::cout << nlohmann::json{{"database", DbPath()},
                                {"backup", destination},
                                {"bytes", bytes},
                                {"check", check}}
                     .dump(2)
              << "\n";
  else
    std::cout << "backed up " << DbPath() << " to " << destination << " (" << bytes
              << " bytes); the copy checks ok\n";
}

}  // namespace

void RegisterDbCommand(CLI::App& app) {
  CLI::App* db = app.add_subcommand("db", "Check or back up a flexid database file (--db PATH)");
  db->require_subcommand(1);
  db->footer(
      "Examples:\n  flexid --db var/flexid.db db check\n  flexid --db var/flexid.db db backup "
      "var/flexid-2026-11-21.db");

  auto check_json = std::make_shared<bool>(false);
  CLI::App* check = db->add_subcommand(
      "check", "Integrity, orphan rows, sample counts, interrupted and recording trials");
  check->add_flag("--json", *check_json, "Print one JSON document");
  check->footer("Example:\n  flexid --db var/flexid.db db check --json");
  check->callback([check_json] { RunCheck(*check_json); });

  struct BackupArgs {
    std::string destination;
    bool json = false;
  };
  auto backup_args = std::make_shared<BackupArgs>();
  CLI::App* backup = db->add_subcommand(
      "backup", "Copy the database with SQLite's online backup (safe while flexidd runs)");
  backup->add_option("DEST", backup_args->destination, "New file to write (never overwritten)")
      ->required();
  backup->add_flag("--json", backup_args->json, "Print one JSON document");
  backup->footer("Example:\n  flexid --db var/flexid.db db backup /media/backup/flexid.db");
  backup->callback([backup_args] { RunBackup(backup_args->destination, backup_args->json); });
}

}  // namespace flexid::cli
