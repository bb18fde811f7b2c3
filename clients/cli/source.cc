#include "clients/cli/source.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <flexid/rpc_reply_t.hpp>
#include <thread>

#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "storage/database.h"
#include "storage/queries.h"
#include "storage/record_json.h"

namespace flexid::cli {

std::string& DbPath() {
  static std::string path;
  return path;
}

namespace {

std::chrono::milliseconds Milliseconds(double seconds) {
  return std::chrono::milliseconds(static_cast<int64_t>(seconds * 1000.0));
}

// Offline answers, in the daemon's shapes: the stored queries are storage/queries.h's,
// as flexidd answers them; status and actuators without the live figures.
nlohmann::json QueryFile(const std::string& method, const nlohmann::json& args) {
  storage::Database db = OpenDbFile();
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
    return {{"database", DbPath()},
            {"schema_version", db.SchemaVersion()},
            {"actuators", actuators.size()},
            {"trials", trials},
            {"trials_recording", recording},
            {"samples_stored", samples},
            {"models", models},
            {"alerts", db.Alerts({}, 0, -1).size()}};
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
  if (storage::IsStoredQuery(method)) {
    try {
      return storage::AnswerQuery(db, method, args);
    } catch (const storage::QueryError& e) {
      throw UsageError(std::string(e.what()) + " in " + DbPath());
    }
  }
  throw UsageError("\"" + method + "\" needs a running flexidd; it has no offline form (--db)");
}

// The reply's result, or the error it carries as a usage error (bad request, not found) or
// an operation error.
nlohmann::json ResultOf(const RpcResult& r) {
  if (r.status == flexid::rpc_reply_t::kOk) return r.result;
  if (r.status == flexid::rpc_reply_t::kBadRequest || r.status == flexid::rpc_reply_t::kNotFound)
    throw UsageError(r.daemon_id + ": " + r.error);
  throw OperationError(r.daemon_id + ": " + r.error);
}

nlohmann::json QueryDaemon(const std::string& method, const nlohmann::json& args,
                           double timeout_s) {
  return ResultOf(CallDaemon(method, args, Milliseconds(timeout_s)));
}

}  // namespace

storage::Database OpenDbFile() {
  if (!Offline()) throw UsageError("this command reads a database file: give --db PATH");
  try {
    if (!std::filesystem::exists(DbPath()))
      throw OperationError(DbPath() + ": no such database file");
    return storage::Database::Open(DbPath());
  } catch (const storage::StorageError& e) {
    throw OperationError(e.what());
  }
}

nlohmann::json Query(const std::string& method, const nlohmann::json& args, double timeout_s) {
  if (!Offline()) return QueryDaemon(method, args, timeout_s);
  try {
    return QueryFile(method, args);
  } catch (const storage::StorageError& e) {
    throw OperationError(e.what());
  }
}

nlohmann::json CallOnline(const std::string& method, const nlohmann::json& args, double timeout_s) {
  if (Offline())
    throw UsageError("\"" + method + "\" asks flexidd to act; it cannot run on a --db file");
  // flexidd runs one identification or diagnosis at a time, its own too (policy.on_alert
  // diagnoses a trial that raised alerts when it ends): a busy worker is waited for, within
  // the timeout, each try a new signed request.
  const auto end = std::chrono::steady_clock::now() + Milliseconds(timeout_s);
  constexpr auto kRetry = std::chrono::milliseconds(500);
  while (true) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        end - std::chrono::steady_clock::now());
    const RpcResult r = CallDaemon(method, args, std::max(left, std::chrono::milliseconds(1)));
    if (r.status != flexid::rpc_reply_t::kBusy || std::chrono::steady_clock::now() + kRetry >= end)
      return ResultOf(r);
    std::this_thread::sleep_for(kRetry);
  }
}

StoredTrial LoadTrial(int64_t trial_id,
                      const std::function<void(int64_t done, int64_t total)>& progress) {
  constexpr int64_t kPage = 20000;  // the daemon's largest page
  StoredTrial out;
  if (Offline()) {  // straight from the file, without a JSON round trip per page
    try {
      storage::Database db = OpenDbFile();
      const auto trial = db.FindTrial(trial_id);
      if (!trial) throw UsageError("no trial " + std::to_string(trial_id) + " in " + DbPath());
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
  int64_t after = INT64_MIN;
  while (true) {
    const nlohmann::json page =
        Query("trial_samples", {{"trial", trial_id}, {"after_utime", after}, {"limit", kPage}});
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
