#include "clients/cli/source.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <flexid/rpc_reply_t.hpp>
#include <iostream>
#include <map>
#include <set>
#include <thread>

#include "bus/fan_out.h"
#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "storage/database.h"
#include "storage/queries.h"
#include "storage/record_json.h"

namespace flexid::cli {

std::vector<std::string>& DbPaths() {
  static std::vector<std::string> paths;
  return paths;
}

const std::string& DbPath() {
  if (DbPaths().empty()) throw UsageError("this command reads a database file: give --db PATH");
  if (DbPaths().size() > 1)
    throw UsageError("this command works on one database file; give --db once (got " +
                     std::to_string(DbPaths().size()) + ")");
  return DbPaths().front();
}

std::vector<std::string>& DaemonIds() {
  static std::vector<std::string> ids;
  return ids;
}

double& ReplyTimeout_s() {
  static double seconds = kQueryTimeout_s;
  return seconds;
}

std::string SourceAnswer::Name() const {
  if (!database.empty()) return database;
  return announced ? daemon_id : daemon_id + " (not announced)";
}

namespace {

std::chrono::milliseconds Milliseconds(double seconds) {
  return std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000.0));
}

storage::Database OpenFile(const std::string& path) {
  try {
    if (!std::filesystem::exists(path)) throw OperationError(path + ": no such database file");
    return storage::Database::Open(path);
  } catch (const storage::StorageError& e) {
    throw OperationError(e.what());
  }
}

// Offline answers, in the daemon's shapes: the stored queries are storage/queries.h's,
// as flexidd answers them; status and actuators without the live figures.
nlohmann::json AnswerFromFile(storage::Database& db, const std::string& path,
                              const std::string& method, const nlohmann::json& args) {
  if (method == "status") {
    int64_t trials = 0, samples = 0, recording = 0, models = 0;
    const std::vector<storage::Actuator> actuators = db.Actuators();
    for (const storage::Trial& t : db.Trials({}, -1)) {
      ++trials;
      samples += t.samples;
      recording += t.state == storage::TrialState::kRecording;
    }
    for (const storage::Actuator& a : actuators)
      models += static_cast<int64_t>(db.Models(a.id).size());
    return {
        {"database", path}, {"schema_version", db.SchemaVersion()}, {"actuators", actuators.size()},
        {"trials", trials}, {"trials_recording", recording},        {"samples_stored", samples},
        {"models", models}, {"alerts", db.Alerts({}, 0, -1).size()}};
  }
  if (method == "actuators") {
    nlohmann::json list = nlohmann::json::array();
    for (const storage::Actuator& a : db.Actuators()) {
      nlohmann::json entry = storage::ActuatorJson(a);
      const auto active = db.ActiveModel(a.id);
      entry["model_version"] = active ? active->version : 0;
      int64_t recording = 0;
      for (const storage::Trial& t : db.Trials(a.id, -1))
        if (t.state == storage::TrialState::kRecording) recording = t.id;
      entry["trial"] = recording;
      list.push_back(entry);
    }
    return list;
  }
  if (storage::IsStoredQuery(method)) return storage::AnswerQuery(db, method, args);
  throw UsageError("\"" + method + "\" needs a running flexidd; it has no offline form (--db)");
}

SourceAnswer AnswerOfFile(const std::string& path, const std::string& method,
                          const nlohmann::json& args) {
  SourceAnswer answer;
  answer.database = path;
  storage::Database db = OpenFile(path);
  try {
    answer.result = AnswerFromFile(db, path, method, args);
    answer.status = flexid::rpc_reply_t::kOk;
  } catch (const storage::QueryError& e) {
    answer.status = e.kind == storage::QueryError::Kind::kNotFound
                        ? flexid::rpc_reply_t::kNotFound
                        : flexid::rpc_reply_t::kBadRequest;
    answer.error = std::string(e.what()) + " in " + path;
  } catch (const storage::StorageError& e) {
    throw OperationError(e.what());
  }
  return answer;
}

Gathered GatherFiles(const std::string& method, const nlohmann::json& args,
                     const std::string& only) {
  if (!DaemonIds().empty())
    throw UsageError("--daemon names a flexidd on the bus; with --db the files are read");
  Gathered out;
  out.sources = {{"databases", nlohmann::json::array()}};
  for (const std::string& path : DbPaths()) {
    if (!only.empty() && path != only) continue;
    out.answers.push_back(AnswerOfFile(path, method, args));
    out.sources["databases"].push_back({{"database", path}});
  }
  return out;
}

Gathered GatherDaemons(const std::string& method, const nlohmann::json& args,
                       const std::string& daemon) {
  const std::vector<std::string> asked = daemon.empty() ? DaemonIds() : std::vector{daemon};
  nlohmann::json addressed = args;
  if (asked.size() == 1) addressed["daemon_id"] = asked.front();  // the others stay quiet
  bus::FanOutOptions options;
  options.timeout = Milliseconds(ReplyTimeout_s());
  const std::unique_ptr<lcm::LCM> lcm = JoinBus();
  const bus::FanOutResult r = bus::FanOut(*lcm, BusChannels(), "cli-" + std::to_string(getpid()),
                                          method, addressed.dump(), asked, options);
  Gathered out;
  out.notes = r.notes;
  out.sources = {{"daemons", nlohmann::json::array()}};
  std::map<std::string, bool> announced;
  for (const bus::RollCallEntry& e : r.roll_call) {
    nlohmann::json entry = {{"daemon_id", e.daemon_id},
                            {"answered", e.answered},
                            {"announced", e.announced || e.named}};
    if (e.last_heard_s) entry["last_heard_s"] = *e.last_heard_s;
    out.sources["daemons"].push_back(entry);
    announced[e.daemon_id] = e.announced || e.named;
  }
  for (const flexid::rpc_reply_t& reply : r.replies) {
    SourceAnswer answer;
    answer.daemon_id = reply.daemon_id;
    answer.announced = announced[reply.daemon_id];
    answer.status = reply.status;
    answer.error = reply.error;
    answer.result = nlohmann::json::parse(reply.result_json, nullptr, false);
    if (reply.status == flexid::rpc_reply_t::kOk && answer.result.is_discarded()) {
      answer.status = flexid::rpc_reply_t::kFailed;
      answer.error = "its reply is not JSON";
    }
    out.answers.push_back(std::move(answer));
  }
  // By daemon, whatever order the replies came in: the same output for the same answers.
  std::stable_sort(
      out.answers.begin(), out.answers.end(),
      [](const SourceAnswer& a, const SourceAnswer& b) { return a.daemon_id < b.daemon_id; });
  return out;
}

}  // namespace

// As a usage error (bad request, not found everywhere) or an operation error.
void ThrowNoResult(const Gathered& gathered) {
  const std::string& method = gathered.method;
  if (gathered.answers.empty()) {
    std::string text =
        "no flexidd answered \"" + method + "\" on " + LcmUrl() +
        (ChannelPrefix() == bus::kDefaultPrefix ? ""
                                                : " (channel prefix " + ChannelPrefix() + ")") +
        " within " + FormatNumber(ReplyTimeout_s(), 4) + " s";
    if (!gathered.notes.empty()) text += " (" + gathered.notes.front() + ")";
    throw OperationError(text);
  }
  std::string text;
  bool usage = true;
  for (const SourceAnswer& a : gathered.answers) {
    text += (text.empty() ? "" : "; ") + (a.database.empty() ? a.daemon_id + ": " : "") + a.error;
    usage = usage && (a.status == flexid::rpc_reply_t::kBadRequest ||
                      a.status == flexid::rpc_reply_t::kNotFound);
  }
  if (usage) throw UsageError(text);
  throw OperationError(text);
}

namespace {

// The reply's result, or the error it carries as a usage error (bad request, not found) or
// an operation error.
nlohmann::json ResultOf(const RpcResult& r) {
  if (r.status == flexid::rpc_reply_t::kOk) return r.result;
  if (r.status == flexid::rpc_reply_t::kBadRequest || r.status == flexid::rpc_reply_t::kNotFound)
    throw UsageError(r.daemon_id + ": " + r.error);
  throw OperationError(r.daemon_id + ": " + r.error);
}

// The names of the answers in order, "lab-a and lab-b" or "A.db, B.db and C.db".
std::string NamesOf(const std::vector<const SourceAnswer*>& answers) {
  std::vector<std::string> names;
  for (const SourceAnswer* a : answers) names.push_back(a->Name());
  std::sort(names.begin(), names.end());
  std::string text;
  for (size_t i = 0; i < names.size(); ++i)
    text += (i == 0 ? "" : i + 1 == names.size() ? " and " : ", ") + names[i];
  return text;
}

}  // namespace

storage::Database OpenDbFile() { return OpenFile(DbPath()); }

Gathered Gather(const std::string& method, const nlohmann::json& args, const std::string& daemon) {
  Gathered out =
      Offline() ? GatherFiles(method, args, daemon) : GatherDaemons(method, args, daemon);
  out.method = method;
  return out;
}

nlohmann::json MergedRows(const Gathered& gathered) {
  nlohmann::json rows = nlohmann::json::array();
  bool any = false;
  for (const SourceAnswer& a : gathered.answers) {
    if (a.status != flexid::rpc_reply_t::kOk || !a.result.is_array()) continue;
    any = true;
    for (nlohmann::json row : a.result) {
      if (!row.is_object()) continue;
      if (a.database.empty())
        row["daemon_id"] = a.daemon_id;
      else
        row["database"] = a.database;
      rows.push_back(std::move(row));
    }
  }
  if (!any) ThrowNoResult(gathered);  // e.g. an actuator no source knows
  return rows;
}

nlohmann::json MergedDocument(const Gathered& gathered, const std::string& key,
                              nlohmann::json rows) {
  nlohmann::json out = gathered.sources;
  out[key] = std::move(rows);
  out["notes"] = gathered.notes;
  for (const SourceAnswer& a : gathered.answers)
    if (a.status != flexid::rpc_reply_t::kOk && a.status != flexid::rpc_reply_t::kNotFound)
      out["notes"].push_back(a.Name() + ": " + a.error);
  return out;
}

nlohmann::json NewestFirst(nlohmann::json rows, const char* utime_key, int limit) {
  std::stable_sort(rows.begin(), rows.end(),
                   [utime_key](const nlohmann::json& a, const nlohmann::json& b) {
                     return a.value(utime_key, int64_t{0}) > b.value(utime_key, int64_t{0});
                   });
  if (limit >= 0 && rows.size() > static_cast<size_t>(limit))
    rows.erase(rows.begin() + limit, rows.end());
  return rows;
}

std::string SourceHeader() { return Offline() ? "database" : "daemon"; }

std::string SourceCell(const Gathered& gathered, const nlohmann::json& row) {
  if (row.contains("database")) return row.value("database", "");
  const std::string id = row.value("daemon_id", "");
  for (const SourceAnswer& a : gathered.answers)
    if (a.daemon_id == id) return a.Name();
  return id;
}

void PrintNotes(const Gathered& gathered) {
  static std::set<std::string> printed;
  for (const std::string& note : gathered.notes)
    if (printed.insert(note).second) std::cerr << "flexid: note: " << note << "\n";
  for (const SourceAnswer& a : gathered.answers)
    if (a.status != flexid::rpc_reply_t::kOk && a.status != flexid::rpc_reply_t::kNotFound) {
      const std::string note = a.Name() + ": " + a.error;
      if (printed.insert(note).second) std::cerr << "flexid: note: " << note << "\n";
    }
}

SourceAnswer QueryOne(const std::string& method, const nlohmann::json& args,
                      const std::string& source) {
  const Gathered gathered = Gather(method, args, source);
  PrintNotes(gathered);
  std::vector<const SourceAnswer*> ok;
  for (const SourceAnswer& a : gathered.answers)
    if (a.status == flexid::rpc_reply_t::kOk) ok.push_back(&a);
  if (ok.empty()) ThrowNoResult(gathered);
  if (ok.size() == 1) return *ok.front();
  bool lists = true;
  for (const SourceAnswer* a : ok) lists = lists && a->result.is_array();
  if (!lists)
    throw UsageError(
        "\"" + method + "\" " + args.dump() + " is answered by " + NamesOf(ok) +
        (Offline() ? ": give one of the files alone with --db" : ": name one with --daemon ID"));
  SourceAnswer merged = *ok.front();
  merged.result = MergedRows(gathered);
  return merged;
}

nlohmann::json Query(const std::string& method, const nlohmann::json& args,
                     const std::string& source) {
  return QueryOne(method, args, source).result;
}

std::string TargetDaemon(const std::string& method, const std::string& actuator) {
  if (DaemonIds().size() == 1) return DaemonIds().front();
  if (DaemonIds().size() > 1)
    throw UsageError("\"" + method + "\" goes to one daemon: give --daemon once");
  if (actuator.empty()) return "";
  const Gathered gathered = Gather("actuators", nlohmann::json::object());
  std::vector<const SourceAnswer*> owners, answered;
  for (const SourceAnswer& a : gathered.answers) {
    if (a.status != flexid::rpc_reply_t::kOk || !a.result.is_array()) continue;
    answered.push_back(&a);
    for (const nlohmann::json& row : a.result)
      if (row.is_object() && row.value("id", "") == actuator &&
          (!row.contains("claim") || row.value("claim", "") == "configured" ||
           row.value("claim", "") == "adopted"))
        owners.push_back(&a);
  }
  if (owners.size() == 1) return owners.front()->daemon_id;
  if (owners.size() > 1)
    throw UsageError("actuator " + actuator + " is claimed by " + NamesOf(owners) +
                     " (an ownership conflict): name one with --daemon ID");
  if (answered.size() == 1) return answered.front()->daemon_id;  // it says why, if it cannot
  if (answered.empty()) ThrowNoResult(gathered);
  throw UsageError("no daemon owns actuator " + actuator + " (asked " + NamesOf(answered) +
                   "): name the one to ask with --daemon ID");
}

nlohmann::json CallOnline(const std::string& method, const nlohmann::json& args, double timeout_s,
                          const std::string& daemon) {
  if (Offline())
    throw UsageError("\"" + method + "\" asks flexidd to act; it cannot run on a --db file");
  const auto actuator = args.find("actuator");
  const std::string target =
      !daemon.empty() ? daemon
                      : TargetDaemon(method, actuator != args.end() && actuator->is_string()
                                                 ? actuator->get<std::string>()
                                                 : "");
  // flexidd runs one identification or diagnosis at a time, its own too (policy.on_alert
  // diagnoses a trial that raised alerts when it ends): a busy worker is waited for, within
  // the timeout, each try a new signed request.
  const auto end = std::chrono::steady_clock::now() + Milliseconds(timeout_s);
  constexpr auto kRetry = std::chrono::milliseconds(500);
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        end - std::chrono::steady_clock::now());
    const RpcResult r =
        CallDaemon(method, args, std::max(left, std::chrono::milliseconds(1)), target);
    if (r.status != flexid::rpc_reply_t::kBusy || std::chrono::steady_clock::now() + kRetry >= end)
      return ResultOf(r);
    std::this_thread::sleep_for(kRetry);
  }
}

StoredTrial LoadTrial(int64_t trial_id,
                      const std::function<void(int64_t done, int64_t total)>& progress,
                      const std::string& source) {
  constexpr int64_t kPage = 20000;  // the daemon's largest page
  StoredTrial out;
  if (Offline()) {  // straight from the file, without a JSON round trip per page
    std::vector<std::string> holders;
    for (const std::string& path : DbPaths()) {
      if (!source.empty() && path != source) continue;
      try {
        if (OpenFile(path).FindTrial(trial_id)) holders.push_back(path);
      } catch (const storage::StorageError& e) {
        throw OperationError(e.what());
      }
    }
    if (holders.empty())
      throw UsageError("no trial " + std::to_string(trial_id) + " in " +
                       (source.empty() ? DbPaths().front() : source) +
                       (source.empty() && DbPaths().size() > 1 ? " or the other --db files" : ""));
    if (holders.size() > 1)
      throw UsageError("trial " + std::to_string(trial_id) + " is in " + holders[0] + " and " +
                       holders[1] + ": give the one to read alone with --db");
    try {
      storage::Database db = OpenFile(holders.front());
      const auto trial = db.FindTrial(trial_id);
      out.trial = storage::TrialJson(*trial);
      int64_t after = INT64_MIN;
      while (true) {
        const std::vector<storage::Sample> page = db.SamplesPage(trial_id, after, 0, kPage);
        for (const storage::Sample& s : page) {
          out.utime.push_back(s.utime);
          out.voltage_V.push_back(s.voltage_V);
          out.deflection_mm.push_back(s.deflection_mm);
        }
        if (progress) progress(static_cast<int64_t>(out.utime.size()), trial->samples);
        if (static_cast<int64_t>(page.size()) < kPage) break;
        after = out.utime.back();
      }
      return out;
    } catch (const storage::StorageError& e) {
      throw OperationError(e.what());
    }
  }
  // The first page finds the daemon holding the trial; the others are asked of it alone.
  std::string holder = source;
  int64_t after = INT64_MIN;
  while (true) {
    const SourceAnswer answer = QueryOne(
        "trial_samples", {{"trial", trial_id}, {"after_utime", after}, {"limit", kPage}}, holder);
    holder = answer.daemon_id;
    const nlohmann::json& page = answer.result;
    if (out.trial.is_null()) out.trial = page.at("trial");
    const auto& utime = page.at("utime");
    const auto& volts = page.at("voltage_V");
    const auto& mm = page.at("deflection_mm");
    if (volts.size() != utime.size() || mm.size() != utime.size())
      throw OperationError("trial " + std::to_string(trial_id) +
                           ": reply columns differ in length");
    for (size_t k = 0; k < utime.size(); ++k) {
      out.utime.push_back(utime[k].get<int64_t>());
      // null: a non-finite value (JSON has none); stored samples are always finite.
      out.voltage_V.push_back(volts[k].is_number() ? volts[k].get<double>() : NAN);
      out.deflection_mm.push_back(mm[k].is_number() ? mm[k].get<double>() : NAN);
    }
    if (progress) progress(static_cast<int64_t>(out.utime.size()), page.at("total").get<int64_t>());
    if (static_cast<int64_t>(utime.size()) < kPage) break;
    after = out.utime.back();
  }
  return out;
}

model::Recording RecordingOf(const StoredTrial& trial, size_t min_samples) {
  const int64_t id = trial.trial.value("id", int64_t{0});
  if (trial.utime.size() < min_samples)
    throw UsageError("trial " + std::to_string(id) + " has " + std::to_string(trial.utime.size()) +
                     " samples; at least " + std::to_string(min_samples) + " are needed");
  model::Recording rec;
  rec.source = "trial " + std::to_string(id);
  for (size_t k = 0; k < trial.utime.size(); ++k) {
    rec.t_s.push_back(1e-6 * static_cast<double>(trial.utime[k] - trial.utime.front()));
    rec.voltage_V.push_back(trial.voltage_V[k]);
    rec.deflection_mm.push_back(trial.deflection_mm[k]);
  }
  return rec;
}

model::ModelDocument StoredModel(const std::string& actuator, int32_t version) {
  nlohmann::json args = {{"actuator", actuator}};
  if (version != 0) args["version"] = version;
  const nlohmann::json reply = Query("model", args);
  const std::string name = actuator + " model v" + std::to_string(reply.value("version", version));
  return model::ParseModelJson(reply.at("model").dump(), name);
}

}  // namespace flexid::cli
