// Where the data of a flexid command comes from (DESIGN.md, "Command lines"): the flexidd
// on the bus by default (global --lcm URL), or, with the global --db PATH, database files
// read directly with no daemon running. Both give the same JSON documents
// (storage/record_json.h), so a command formats one shape whichever way its data came.
//
// Several sources (docs/architecture.md, "Several daemons"): a read-only request goes to
// every flexidd on the bus (bus/fan_out.h), or to each --db file given, and each answers
// for itself. The --daemon ids given narrow it to those daemons. A request that changes
// data goes to one daemon: the one --daemon names, else the owner of its actuator, found
// by asking every daemon for its actuators first.
//
// Read-only requests use flexidd's RPC method names and arguments (daemon/rpc.h):
//   status, actuators, trials {actuator?, limit?}, trial_samples {trial, after_utime?,
//   offset?, limit?}, models {actuator}, model {actuator, version?}, alerts {actuator?,
//   since_utime?, limit?}.
// Offline, `status` describes the file instead of a running daemon.
#pragma once

#include <cstdint>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "storage/database.h"

namespace flexid::cli {

// The --db files given (in order); empty when commands talk to flexidd.
std::vector<std::string>& DbPaths();
inline bool Offline() { return !DbPaths().empty(); }
// The one --db file of a command that works on one file. Throws UsageError without --db
// or with several.
const std::string& DbPath();
// The --daemon ids given (empty: every daemon on the bus).
std::vector<std::string>& DaemonIds();
// Seconds a read-only request waits for every daemon heard of (--reply-timeout).
double& ReplyTimeout_s();

// Seconds to wait for flexidd's reply to a read-only request (the default of --reply-timeout).
inline constexpr double kQueryTimeout_s = 10.0;

// The --db file, opened for an offline command. Throws UsageError without --db (or with
// several) and OperationError when the file is missing or is not a flexid database.
storage::Database OpenDbFile();

// One source's answer to a read-only request: a daemon's reply, or a database file's.
struct SourceAnswer {
  std::string daemon_id;  // online
  std::string database;   // offline
  bool announced = true;  // online: heard of on the bus (false: kept, but marked)
  int8_t status = 0;      // rpc_reply_t::kOk, kNotFound, ...
  nlohmann::json result;
  std::string error;
  // "lab-a", "lab-x (not announced)" or the file's path.
  std::string Name() const;
};

// Every source's answer, who was asked and did not answer, and what else to tell.
struct Gathered {
  std::string method;
  std::vector<SourceAnswer> answers;
  // Online {"daemons": [{"daemon_id", "answered", "announced", "last_heard_s"?}]};
  // offline {"databases": [{"database"}]}.
  nlohmann::json sources;
  std::vector<std::string> notes;  // one line each (bus/fan_out.h)
};

// A read-only request to every source (online: to `daemon` alone when given, else to the
// --daemon ids or every daemon). Throws OperationError when the bus cannot be joined or a
// file cannot be read; an answer that is an error is returned as such.
Gathered Gather(const std::string& method, const nlohmann::json& args,
                const std::string& daemon = "");

// The rows of every answer that has a result (a list), each naming its source with
// "daemon_id" (online) or "database" (offline); a source that holds nothing asked for
// ("not found") adds none. Throws as Query does when none has a result.
nlohmann::json MergedRows(const Gathered& gathered);

// The error of a request no source answered with a result: a UsageError when each said
// bad request or not found, an OperationError otherwise or when nobody answered.
[[noreturn]] void ThrowNoResult(const Gathered& gathered);

// The --json document of a read-only command over several sources:
//   {"<key>": rows, "daemons": [...] (online) or "databases": [...] (offline), "notes": [...]}
// where "daemons" names every daemon asked or heard of, answered or not (Gathered::sources).
nlohmann::json MergedDocument(const Gathered& gathered, const std::string& key,
                              nlohmann::json rows);
// The header of the table column naming each row's source ("daemon" or "database"), and a
// row's cell ("lab-x (not announced)" for a daemon not heard of on the bus).
std::string SourceHeader();
std::string SourceCell(const Gathered& gathered, const nlohmann::json& row);

// Merged rows newest first by their member `utime_key` (a stable sort: each source's own
// order among equal times stays), at most `limit` of them.
nlohmann::json NewestFirst(nlohmann::json rows, const char* utime_key, int limit);

// The sources' notes, on stderr, one line each ("flexid: note: ..."); each at most once
// per run.
void PrintNotes(const Gathered& gathered);

// A read-only request answered by one source (`source`: a daemon id or a file path; empty:
// any). Throws UsageError for a bad request, something that does not exist, or an answer
// that several sources give (name one with --daemon, or give one --db) unless each is a
// list (then the rows are merged as MergedRows does); OperationError when no daemon
// answers or the file cannot be read. Notes go to stderr.
nlohmann::json Query(const std::string& method, const nlohmann::json& args,
                     const std::string& source = "");
// The same, with the source that answered.
SourceAnswer QueryOne(const std::string& method, const nlohmann::json& args,
                      const std::string& source = "");

// The daemon a request about `actuator` goes to: the one --daemon names; else the
// daemon that owns the actuator; else, when one daemon answers alone, that one. Throws
// UsageError when several claim it or none does among several daemons.
std::string TargetDaemon(const std::string& method, const std::string& actuator);

// A request only flexidd can carry out (identify, diagnose, model_activate, trial_start,
// trial_stop): refused with a UsageError naming the method when --db is given; otherwise
// sent to `daemon`, or when empty to TargetDaemon (signed with that daemon's key), and its
// reply's result returned.
nlohmann::json CallOnline(const std::string& method, const nlohmann::json& args, double timeout_s,
                          const std::string& daemon = "");

// The samples of a stored trial, in utime order.
struct StoredTrial {
  nlohmann::json trial;  // storage::TrialJson
  std::vector<int64_t> utime;
  std::vector<double> voltage_V, deflection_mm;
};

// Reads a trial page by page; progress(done, total) after each page. `source`: the daemon
// or file that holds it (empty: the one source that has a trial of that id).
StoredTrial LoadTrial(int64_t trial_id,
                      const std::function<void(int64_t done, int64_t total)>& progress = {},
                      const std::string& source = "");

// The trial as a recording, t_s from its first sample; source "trial ID". Throws UsageError
// when it has fewer than min_samples samples.
model::Recording RecordingOf(const StoredTrial& trial, size_t min_samples = 2);

// A stored model of an actuator (version 0: the active one) as a model document; its
// source name is "S1 model v3". Throws UsageError when there is no such model.
model::ModelDocument StoredModel(const std::string& actuator, int32_t version = 0);

}  // namespace flexid::cli
