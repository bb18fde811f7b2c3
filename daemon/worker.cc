#include "daemon/worker.h"

#include <pthread.h>
#include <sched.h>
#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <flexid/rpc_reply_t.hpp>

#include "bus/clock.h"
#include "daemon/proposal.h"
#include "daemon/service.h"
#include "flexid/version.h"
#include "model/core/model_file.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify_global.h"
#include "model/identify/identify_ts.h"
#include "storage/record_json.h"

namespace flexid::daemon {
namespace {

// A stored trial's samples as a recording, time from its first sample; throws if it has
// fewer than min_samples.
model::Recording RecordingOfTrial(const std::vector<storage::Sample>& samples, int64_t trial_id,
                                  size_t min_samples) {
  if (samples.size() < min_samples)
    throw std::runtime_error("trial " + std::to_string(trial_id) + " has only " +
                             std::to_string(samples.size()) + " samples; " +
                             std::to_string(min_samples) + " are needed");
  model::Recording rec;
  rec.source = "trial " + std::to_string(trial_id);
  for (const storage::Sample& s : samples) {
    rec.t_s.push_back(1e-6 * static_cast<double>(s.utime - samples.front().utime));
    rec.voltage_V.push_back(s.voltage_V);
    rec.deflection_mm.push_back(s.deflection_mm);
  }
  return rec;
}

}  // namespace

// "trial 5" or "trials 4, 5, 7".
std::string TrialWords(const std::vector<int64_t>& ids) {
  std::string text = ids.size() == 1 ? "trial " : "trials ";
  for (size_t i = 0; i < ids.size(); ++i) text += (i ? ", " : "") + std::to_string(ids[i]);
  return text;
}

DiagnosisResult RunDiagnosis(const DiagnosisJob& job, RpcContext request) {
  DiagnosisResult result;
  result.request = std::move(request);
  result.actuator_id = job.actuator_id;
  result.trial_ids = job.trial_ids;
  result.propose = !job.propose_by.empty();
  result.adopt_min_gain = job.adopt_min_gain;
  try {
    storage::Database db = storage::Database::Open(job.database);
    int64_t count = 0;
    for (int64_t id : job.trial_ids) count += db.SampleCount(id);
    if (count > job.max_samples)
      throw std::runtime_error(TrialWords(job.trial_ids) + " have " + std::to_string(count) +
                               " samples; flexidd diagnoses at most " +
                               std::to_string(job.max_samples) +
                               " (identification.max_diagnosis_samples)");
    std::vector<model::Recording> recordings;
    std::vector<storage::Sample> all;
    for (int64_t id : job.trial_ids) {
      const std::vector<storage::Sample> samples = db.Samples(id);
      recordings.push_back(RecordingOfTrial(samples, id, 200));
      result.trial_start_utimes.push_back(samples.front().utime);
      if (result.propose) all.insert(all.end(), samples.begin(), samples.end());
    }
    std::optional<model::TsModel> trusted;
    model::DiagnoseOptions options;
    std::optional<storage::ModelRecord> active;
    if (job.use_model) active = db.ActiveModel(job.actuator_id);
    if (active) {
      const std::string source = "model " + std::to_string(active->version);
      const model::ModelDocument doc = model::ParseModelJson(active->model_json, source);
      trusted = model::AsTsModel(doc);
      options.baseline_effects = model::EffectsOf(doc, source);
    }
    const model::Diagnosis diagnosis = model::Diagnose(recordings, trusted, options);
    result.diagnosis = model::DiagnosisToJson(diagnosis);
    if (job.trial_ids.size() == 1)
      result.diagnosis["trial"] = job.trial_ids.front();
    else
      result.diagnosis["trials"] = job.trial_ids;
    result.diagnosis["model_version"] = active ? active->version : 0;  // 0: identified
    if (result.propose) {
      try {
        result.proposal = ProposalOf(
            {job.actuator_id, &diagnosis, &recordings, active ? &*active : nullptr, job.trial_ids,
             storage::HashSamples(all), job.propose_by, bus::WallClockUtime()});
        const nlohmann::json lineage =
            result.proposal ? storage::LineageJson(*result.proposal) : nullptr;
        result.adopt = job.adopt_min_gain > 0 && lineage.is_object() &&
                       lineage.value("heldout_gain", 0.0) >= job.adopt_min_gain;
      } catch (const std::exception& e) {
        result.proposal_error = e.what();
      }
    }
  } catch (const std::exception& e) {
    result.error = e.what();
    result.diagnosis = nullptr;
  }
  return result;
}

IdentificationResult RunIdentification(const std::string& database, const std::string& actuator_id,
                                       std::vector<int64_t> trial_ids,
                                       const IdentificationConfig& config, RpcContext request) {
  IdentificationResult result;
  result.request = std::move(request);
  result.actuator_id = actuator_id;
  try {
    storage::Database db = storage::Database::Open(database);
    std::vector<model::Recording> recordings;
    std::vector<storage::Sample> all;
    for (int64_t id : trial_ids) {
      const std::vector<storage::Sample> samples = db.Samples(id);
      recordings.push_back(RecordingOfTrial(samples, id, 100));
      all.insert(all.end(), samples.begin(), samples.end());
    }
    model::ModelDocument doc;
    nlohmann::json fit;
    if (config.method == "global") {
      model::GlobalIdentifyOptions options;
      if (config.orders_given) {
        options.num_zeros = config.zeros;
        options.num_poles = config.poles;
      }
      options.max_delay_s = config.max_delay_s;
      const model::GlobalEstimate estimate = model::IdentifyGlobalTs(recordings, options);
      doc = model::ToModelDocument(estimate);
      fit = model::FitFiguresToJson(estimate.fit);
      fit["levels_V"] = estimate.levels_V;
    } else {
      model::TsIdentifyOptions options;
      options.local.num_zeros = config.zeros;
      options.local.num_poles = config.poles;
      options.local.max_delay_s = config.max_delay_s;
      const model::TsEstimate estimate = model::IdentifyTsModel(recordings, options);
      // The same document `flexid identify --method time` writes (identify_ts.h).
      doc = model::ToModelDocument(estimate);
      fit = model::FitFiguresToJson(estimate.fit);
      fit["levels_V"] = nlohmann::json::array();
      for (const auto& local : estimate.local) fit["levels_V"].push_back(local.level_V);
    }
    // What `flexid identify --trials` adds, so a model file reads the same online and offline.
    doc.extra["identified_from"] = nlohmann::json::array();
    for (const model::Recording& r : recordings) doc.extra["identified_from"].push_back(r.source);
    doc.extra["identified_from_trials"] = trial_ids;
    doc.extra["flexid_version"] = kVersion;
    storage::ModelRecord record;
    record.actuator_id = actuator_id;
    record.created_utime = bus::WallClockUtime();
    record.model_json = model::ModelToJson(doc).dump();
    record.fit_json = fit.dump();
    record.trial_ids = trial_ids;
    record.samples_hash = storage::HashSamples(all);
    record.flexid_version = kVersion;
    record.active = true;
    result.model = std::move(record);  // stored by the writer, on the loop's word
  } catch (const std::exception& e) {
    result.error = e.what();
  }
  return result;
}

const JobOrigin& OriginOf(const JobResult& result) {
  return std::visit([](const JobOrigin& origin) -> const JobOrigin& { return origin; }, result);
}

Worker::Worker(std::vector<int> cpus, std::function<void()> on_finished)
    : cpus_(std::move(cpus)), on_finished_(std::move(on_finished)), thread_([this] { Loop(); }) {}

Worker::~Worker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    exit_ = true;
  }
  wake_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void Worker::Loop() {
  // Identification takes a whole core for up to a second: run it under SCHED_IDLE, so
  // that it only ever uses a core nobody else wants and the loop wakes without waiting
  // for one (nice alone left a few ms of wake-up delay on two cores when a fit started).
  if (!cpus_.empty()) {
    cpu_set_t set;
    CPU_ZERO(&set);
    for (int cpu : cpus_) CPU_SET(cpu, &set);
    pthread_setaffinity_np(pthread_self(), sizeof set, &set);
  }
  sched_param idle{};
  if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &idle) != 0)
    setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), kBackgroundNice);
  while (true) {
    std::function<JobResult()> task;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      wake_.wait(lock, [this] { return exit_ || job_.has_value(); });
      if (exit_) return;
      task = std::move(*job_);
      job_.reset();
    }
    JobResult result = task();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      finished_.push_back(std::move(result));
    }
    busy_ = false;
    on_finished_();
  }
}

bool Worker::Submit(std::function<JobResult()> task) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (busy_) return false;
  busy_ = true;
  job_ = std::move(task);
  wake_.notify_one();
  return true;
}

std::deque<JobResult> Worker::TakeFinished() {
  std::deque<JobResult> done;
  std::lock_guard<std::mutex> lock(mutex_);
  done.swap(finished_);
  return done;
}

void Service::OnWorkerResult(JobResult& result) {
  if (const auto* diagnosis = std::get_if<DiagnosisResult>(&result);
      diagnosis && diagnosis->diagnosis.is_object()) {
    ReportDiagnosis(*diagnosis);
    return;
  }
  auto* identified = std::get_if<IdentificationResult>(&result);
  if (!identified || !identified->model) {
    const JobOrigin& failed = OriginOf(result);
    const auto* diagnosis = std::get_if<DiagnosisResult>(&result);
    if (auto it = actuators.find(failed.actuator_id);
        diagnosis && failed.request.request_id.empty() && it != actuators.end())
      SayPolicy(
          &it->second, 0, 0,
          "the diagnosis of " + TrialWords(diagnosis->trial_ids) + " failed: " + failed.error);
    spdlog::error("{} failed [actuator: {}, error: {}]",
                  identified ? "identification" : "diagnosis", failed.actuator_id, failed.error);
    Reply(failed.request, {flexid::rpc_reply_t::kFailed, nullptr, failed.error});
    return;
  }
  // Stored by the writer as the next version; then swapped in and answered.
  const uint64_t ticket = Store(std::move(*identified->model));
  on_written.emplace(
      ticket, [this, request = identified->request,
               actuator_id = identified->actuator_id](const storage::WriteOutcome& written) {
        if (!written.model) {
          spdlog::error("identification failed [actuator: {}, error: cannot store the model: {}]",
                        actuator_id, written.error);
          Reply(request, {flexid::rpc_reply_t::kFailed, nullptr,
                          "cannot store the model: " + written.error});
          return;
        }
        try {
          auto it = actuators.find(actuator_id);
          if (it != actuators.end()) {
            LoadModel(&it->second, *written.model);  // hot swap
            AnnounceModel(&it->second, *written.model);
          }
          nlohmann::json out = storage::ModelSummaryJson(*written.model);
          out["model"] = nlohmann::json::parse(written.model->model_json);
          Reply(request, {flexid::rpc_reply_t::kOk, out, ""});
        } catch (const std::exception& e) {
          spdlog::error("model {} stored but not put to use [actuator: {}, error: {}]",
                        written.model->version, actuator_id, e.what());
          Reply(request, {flexid::rpc_reply_t::kFailed, nullptr, e.what()});
        }
      });
}

// A diagnosis that names an effect is an alert of that effect's kind (the catalogue of
// model/diagnose/diagnose.h), spanning the trial, with the explanation as its text.
void Service::ReportDiagnosis(const DiagnosisResult& result) {
  const nlohmann::json& d = result.diagnosis;
  auto it = actuators.find(result.actuator_id);
  const std::string verdict = d.value("verdict", "none");
  const auto findings = d.find("findings");
  if (it != actuators.end() && verdict != "none" && findings != d.end() && findings->is_array() &&
      !findings->empty() && findings->front().is_object()) {
    const nlohmann::json& f = findings->front();
    Alert alert;
    alert.kind = verdict;
    alert.severity = 1;
    // Where it acts, from the start of the first span to the end of the last, each on the
    // times of its trial (a span's "recording" indexes the diagnosed trials).
    auto at_utime = [&result](const nlohmann::json& span, const char* key) {
      const int64_t index = span.value("recording", int64_t{0});
      const size_t trial =
          index >= 0 && static_cast<size_t>(index) < result.trial_start_utimes.size()
              ? static_cast<size_t>(index)
              : 0;
      return result.trial_start_utimes.at(trial) + static_cast<int64_t>(span.value(key, 0.0) * 1e6);
    };
    alert.start_utime = alert.end_utime = result.trial_start_utimes.front();
    const auto where = f.find("where");
    if (where != f.end() && where->is_array() && !where->empty() && where->front().is_object() &&
        where->back().is_object()) {
      alert.start_utime = at_utime(where->front(), "t_start_s");
      alert.end_utime = at_utime(where->back(), "t_end_s");
    }
    // Magnitude: the held-out RMSE the model leaves; threshold: what is left with the
    // effect added.
    alert.magnitude_mm = f.value("heldout_rmse_before_mm", 0.0);
    alert.threshold_mm = f.value("heldout_rmse_after_mm", 0.0);
    alert.text = TrialWords(result.trial_ids) + ": " + f.value("explanation", "");
    // The other effects the data hold too (Finding::rivals), by name: the verdict may be a
    // narrow choice.
    std::string rivals;
    if (const auto r = f.find("rivals"); r != f.end() && r->is_array())
      for (const nlohmann::json& rival : *r)
        if (rival.is_object() && rival.contains("effect") && rival["effect"].is_string())
          rivals += (rivals.empty() ? "" : ", ") + rival["effect"].get<std::string>();
    if (!rivals.empty()) alert.text += " (also claimed on its own: " + rivals + ")";
    Raise(&it->second, {alert});
  }
  // A diagnosis the policy asked for: nobody to answer; what came of it is an alert.
  const bool by_policy = result.request.request_id.empty();
  if (by_policy && it != actuators.end()) {
    const int64_t start = result.trial_start_utimes.front();
    if (verdict == "none")
      SayPolicy(&it->second, start, start,
                TrialWords(result.trial_ids) + " diagnosed: no effect named");
    else if (!result.proposal_error.empty())
      SayPolicy(&it->second, start, start,
                TrialWords(result.trial_ids) +
                    " diagnosed; its augmented model is not proposed: " + result.proposal_error);
  }
  if (!result.propose) {
    Reply(result.request, {flexid::rpc_reply_t::kOk, d, "", false});
  } else if (!result.proposal_error.empty()) {
    spdlog::error("cannot propose the augmented model [actuator: {}, error: {}]",
                  result.actuator_id, result.proposal_error);
    Reply(result.request, {flexid::rpc_reply_t::kFailed, nullptr,
                           "cannot propose the augmented model: " + result.proposal_error});
  } else if (!result.proposal) {
    nlohmann::json out = d;
    out["proposed_version"] = nullptr;  // no effect named: nothing to propose
    Reply(result.request, {flexid::rpc_reply_t::kOk, out, "", false});
  } else {
    StoreProposal(result);
  }
}

void Service::StoreProposal(const DiagnosisResult& result) {
  on_written.emplace(Store(*result.proposal), [this, result](const storage::WriteOutcome& written) {
    if (!written.model) {
      spdlog::error("cannot store the proposal [actuator: {}, error: {}]", result.actuator_id,
                    written.error);
      Reply(result.request, {flexid::rpc_reply_t::kFailed, nullptr,
                             "cannot store the proposed model: " + written.error});
      return;
    }
    const storage::ModelRecord proposal = *written.model;
    Alert alert;
    alert.kind = "model_proposed";
    alert.severity = 0;
    alert.start_utime = result.trial_start_utimes.front();
    alert.end_utime = result.trial_start_utimes.back();
    alert.text = result.actuator_id + ": " + ProposalWords(proposal);
    if (result.adopt)
      alert.text += "; adopted (policy.on_alert adopt)";
    else if (result.adopt_min_gain > 0)
      alert.text += "; not adopted: the gain is below policy.adopt_min_gain " +
                    std::to_string(result.adopt_min_gain).substr(0, 4);
    if (auto it = actuators.find(result.actuator_id); it != actuators.end())
      Raise(&it->second, {alert});
    nlohmann::json out = result.diagnosis;
    out["proposed_version"] = proposal.version;
    out["adopted"] = result.adopt;
    if (!result.adopt) {
      Reply(result.request, {flexid::rpc_reply_t::kOk, out, ""});
      return;
    }
    // Adopted: activated once the writer has stored the activation, then swapped in.
    on_written.emplace(
        Store(storage::ModelActivation{result.actuator_id, proposal.version}),
        [this, result, proposal, out](const storage::WriteOutcome& activated) {
          if (!activated.error.empty()) {
            spdlog::error("cannot adopt the proposal [actuator: {}, version: {}, error: {}]",
                          result.actuator_id, proposal.version, activated.error);
            Reply(result.request, {flexid::rpc_reply_t::kFailed, nullptr,
                                   "proposed as version " + std::to_string(proposal.version) +
                                       " but not adopted: " + activated.error});
            return;
          }
          if (auto it = actuators.find(result.actuator_id); it != actuators.end()) {
            LoadModel(&it->second, proposal);
            AnnounceModel(&it->second, proposal);
          }
          Reply(result.request, {flexid::rpc_reply_t::kOk, out, ""});
        });
  });
}

}  // namespace flexid::daemon
