// The identification worker (DESIGN.md: "identification worker"): identification and
// diagnosis of stored trials, one job at a time on a thread of its own with its own
// database connection (reads only). The loop takes the results (worker.cc).
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "daemon/config.h"
#include "daemon/rpc.h"
#include "storage/database.h"

namespace flexid::daemon {

// The sample writer and the identification worker run at this nice value, so that their
// bursts (a commit every 100 ms, a fit taking a core for a second) yield the cores to the
// loop and LCM's receive thread: on two cores, commits otherwise showed up as a cluster
// of >1 ms prediction latencies once per commit interval (bench/daemon_load).
constexpr int kBackgroundNice = 10;

// What every finished job carries back to the loop: the request to answer, the actuator,
// and what went wrong (empty: nothing).
struct JobOrigin {
  RpcContext request = {};
  std::string actuator_id = {};
  std::string error = {};
};

// A finished identification: the record of a new model version, to be stored (by the
// writer) as the active one; nothing when it failed.
struct IdentificationResult : JobOrigin {
  std::optional<storage::ModelRecord> model = std::nullopt;
};

// A finished diagnosis: the diagnose method's result (null when it failed), the diagnosed
// trials and their first samples' times (the alert it raises is placed on them).
struct DiagnosisResult : JobOrigin {
  nlohmann::json diagnosis = nullptr;
  std::vector<int64_t> trial_ids = {};
  std::vector<int64_t> trial_start_utimes = {};
  // Asked to propose (DiagnosisJob::propose_by): the augmented model as a new inactive
  // version (proposal.h), to be stored by the writer; nothing when no effect was named.
  // proposal_error: why it could not be built (the diagnosis stands).
  bool propose = false;
  bool adopt = false;  // activate the proposal once stored (on_alert = adopt, gain passed)
  std::optional<storage::ModelRecord> proposal = std::nullopt;
  std::string proposal_error = {};
};

// What a diagnosis job is asked: which trials of which actuator, against its active model
// (use_model) or a baseline identified on them; and whether to propose the augmented model
// (propose_by "diagnose" or "policy"; empty: no) and to adopt it when its held-out gain
// reaches adopt_min_gain (0: never adopt).
struct DiagnosisJob {
  std::string database = {};
  std::string actuator_id = {};
  std::vector<int64_t> trial_ids = {};
  bool use_model = true;
  int64_t max_samples = 0;
  std::string propose_by = {};
  double adopt_min_gain = 0.0;
};

using JobResult = std::variant<IdentificationResult, DiagnosisResult>;
const JobOrigin& OriginOf(const JobResult& result);

// One job at a time on a thread of its own, pinned to `cpus` (none: any) and run under
// SCHED_IDLE. A second job while one runs is refused (the RPC answers "busy").
class Worker {
 public:
  // on_finished runs on the worker's thread after each job (it wakes the loop).
  Worker(std::vector<int> cpus, std::function<void()> on_finished);
  // Waits for the job in progress, if any.
  ~Worker();
  Worker(const Worker&) = delete;
  Worker& operator=(const Worker&) = delete;

  // False when a job is already running (or waiting to).
  bool Submit(std::function<JobResult()> job);
  // The results finished since the last call, oldest first (any thread).
  std::deque<JobResult> TakeFinished();
  bool busy() const { return busy_; }

 private:
  void Loop();

  const std::vector<int> cpus_;
  const std::function<void()> on_finished_;
  std::mutex mutex_;
  std::condition_variable wake_;
  std::optional<std::function<JobResult()>> job_;
  std::deque<JobResult> finished_;
  std::atomic<bool> busy_{false};
  bool exit_ = false;
  std::thread thread_;  // last: it starts once the rest is ready
};

// "trial 5" or "trials 4, 5, 7".
std::string TrialWords(const std::vector<int64_t>& ids);

// Diagnosis of stored trials of one actuator (one diagnosis from all of them, oldest
// first) against the actuator's active model (or, without one or when asked, against the
// seed's structure identified on the trials), on the worker thread with its own connection
// (reads only).
DiagnosisResult RunDiagnosis(const DiagnosisJob& job, RpcContext request);

// Identification of one actuator on stored trials, on the worker thread with its own
// connection (reads only): samples -> recordings -> T-S model -> the record of a new active
// model version, which the loop hands to the writer.
IdentificationResult RunIdentification(const std::string& database, const std::string& actuator_id,
                                       std::vector<int64_t> trial_ids,
                                       const IdentificationConfig& config, RpcContext request);

}  // namespace flexid::daemon
