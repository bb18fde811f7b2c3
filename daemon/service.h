// flexidd's shared state and its parts (docs/architecture.md, "flexidd's files"). Daemon
// owns one Service; its member functions are defined in the file of the part (DESIGN.md)
// they belong to:
//   daemon.cc       start-up (database, key, bus, writer) and the actuators
//   event_loop.cc   poll, signals, wake-ups, the status heartbeat, shutdown
//   bus_adapter.cc  subscriptions, decoding and validating messages, RPC replies
//   recorder.cc     trials (automatic and requested), samples to the writer
//   predictor.cc    the live T-S prediction and the residual monitor's alerts
//   rpc_methods.cc  requests: the signature check and the methods
//   worker.cc       identification and diagnosis on the worker thread, and their results
//   health.cc       faults other than bad messages
//   ownership_bus.cc  several daemons on one bus: announcements, held messages, conflicts
// Everything runs on the loop's thread unless it says otherwise.
#pragma once

#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <functional>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "bus/channels.h"
#include "daemon/config.h"
#include "daemon/daemon.h"
#include "daemon/health.h"
#include "daemon/ownership.h"
#include "daemon/predictor.h"
#include "daemon/rpc.h"
#include "daemon/unique_fd.h"
#include "daemon/worker.h"
#include "lcmtypes/message_auth.h"
#include "lcmtypes/wire_check.h"
#include "storage/database.h"
#include "storage/sample_writer.h"

namespace flexid::daemon {

// What the loop knows of one actuator: its inputs, its trial, its health, its prediction.
struct ActuatorState {
  storage::Actuator info;
  // This daemon records it (configured, or adopted: daemon/ownership.h). An actuator
  // known only from the file is answered for, but its messages are not recorded.
  bool owned = false;
  double voltage_V = 0.0;
  int64_t voltage_utime = kNoTime;
  int64_t deflection_utime = kNoTime;
  int64_t trial_id = 0;
  bool automatic_trial = false;
  int64_t last_active_utime = kNoTime;  // last voltage outside the rest band
  int64_t last_sample_utime = kNoTime;
  int64_t trial_start_utime = kNoTime;
  std::string trial_protocol;
  // Health (daemon/health.h): each stream's clock, and when the loop last heard from the
  // actuator (steady clock: message time stops when the source does).
  ClockJumpDetector voltage_clock, deflection_clock;
  std::chrono::steady_clock::time_point last_heard{};
  bool silent = false;  // "input_silent" raised, no message since
  Predictor predictor;
  std::unique_ptr<ResidualMonitor> monitor;
  // The on_alert policy (config.h PolicyConfig): residual and back-relaxation alerts the
  // monitor raised during the trial recording now, and when the policy last diagnosed.
  int policy_alerts = 0;
  std::optional<std::chrono::steady_clock::time_point> last_policy_diagnosis;
};

struct Service {
  Config config;
  bus::Channels channels;  // named from config.channel_prefix
  std::string config_path;
  // The loop's connection: reads only once the loop runs (RPC queries, active models; in
  // WAL mode a reader never waits for a writer). Every write goes through `writer`.
  storage::Database db;
  // Requests and trial control that change data must be signed (message_auth.h). Loaded
  // after the database opens (a database that cannot be written is the first thing to
  // say) and before the bus is joined.
  auth::Verifier verifier;
  lcm::LCM lcm;
  UniqueFd signal_fd;
  UniqueFd wake_fd;  // the worker and the writer say they have something for the loop
  // The one thread that writes (storage/sample_writer.h): declared after wake_fd, which
  // its on_outcome uses until it is gone.
  std::unique_ptr<storage::SampleWriter> writer;
  // Trial ids are handed out here, on the loop, from the highest one in the file: a trial
  // has its id before the writer has stored it.
  int64_t next_trial_id = 1;
  // The latest time the file's trials reached when flexidd started (kNoTime: none): the
  // status reply's latest_utime is never before it, so that a source that starts again
  // after a restart continues message time after what is stored.
  int64_t stored_latest_utime = kNoTime;
  // What the loop does once a write is committed or refused (replies that wait for it).
  std::multimap<uint64_t, std::function<void(const storage::WriteOutcome&)>> on_written;
  uint64_t last_ticket = 0;       // of the last write the loop queued
  uint64_t last_done_ticket = 0;  // of the last write committed or refused (in this order)
  // Updated by the loop, read by status and by other threads (counters()): relaxed atomics.
  struct LiveCounters {
    std::atomic<int64_t> messages_received{0}, samples_accepted{0}, rejected_malformed{0},
        rejected_nonfinite{0}, rejected_out_of_order{0}, rejected_unknown_actuator{0},
        dropped_queue_full{0}, predictions_published{0}, alerts_raised{0}, alerts_dropped{0},
        refused_unauthorized{0}, samples_not_owned{0}, announcements_heard{0};
  } counters;
  std::map<std::string, ActuatorState> actuators;
  std::atomic<bool> stop{false};
  std::chrono::steady_clock::time_point started = std::chrono::steady_clock::now();
  std::chrono::steady_clock::time_point next_status = started;

  std::vector<int> background_cpus;  // pin_threads: the writer's and the worker's CPUs
  // Identification and diagnosis (worker.h): after the writer, which its jobs flush.
  std::unique_ptr<Worker> worker;

  // Several daemons on one bus (ownership_bus.cc): the claims, and the messages and
  // requests about actuators whose owner is being decided, in arrival order.
  Ownership ownership;
  std::map<std::string, std::vector<std::function<void()>>> held;
  size_t held_count = 0;
  std::chrono::steady_clock::time_point last_announced{};

  // Health (health.cc): the time of this loop pass, the database file's identity,
  // the storage failure in progress.
  std::chrono::steady_clock::time_point loop_now = started;
  std::optional<FileIdentity> database_identity;
  bool storage_failing = false;
  std::chrono::steady_clock::time_point storage_failing_since{};
  int64_t drops_when_failing = 0, drops_reported = 0, alert_drops_reported = 0;

  Service(Config c, std::string path);
  ~Service();
  Service(const Service&) = delete;
  Service& operator=(const Service&) = delete;

  // daemon.cc: the actuators and the writes.
  uint64_t Store(storage::Write write);
  void AddActuator(const storage::Actuator& info);

  // event_loop.cc
  void Wake();
  void DrainFinished();
  void OnWritten(const storage::WriteOutcome& outcome);
  void PublishStatus();
  Counters Snapshot() const;
  void HandleSignals();
  void Reload();
  void RunOnce(int timeout_ms);
  void Shutdown();
  template <typename F>
  static void LoopPart(const char* part, F&& run) {
    Contained("loop pass", "part", part, std::forward<F>(run));
  }

  // bus_adapter.cc. Nothing may throw through LCM's C callback: every handler catches at
  // the edge, logs, counts and goes on.
  void Subscribe();
  static void OnVoltageThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Service* self);
  static void OnDeflectionThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                Service* self);
  static void OnRequestThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Service* self);
  static void OnTrialControlThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                  Service* self);
  template <typename F>
  void Guarded(const std::string& channel, F&& handler) {
    ++counters.messages_received;
    Contained("handler", "channel", channel, std::forward<F>(handler));
  }
  // Runs `run`; an exception it throws is logged as "<what> failed [<key>: <name>, error:
  // ...]" and goes no further.
  template <typename F>
  static void Contained(const char* what, const char* key, const std::string& name, F&& run) {
    try {
      run();
    } catch (const std::exception& e) {
      spdlog::error("{} failed [{}: {}, error: {}]", what, key, name, e.what());
    } catch (...) {
      spdlog::error("{} failed [{}: {}]", what, key, name);
    }
  }
  // Decodes a message, rejecting oversized, ill-formed and undecodable ones (counted). The
  // structure is checked before lcm-gen's decoder runs (lcmtypes/wire_check.h).
  template <typename Message>
  bool Decode(const lcm::ReceiveBuffer& rbuf, Message* message,
              std::initializer_list<wire::Field> layout) {
    if (static_cast<int64_t>(rbuf.data_size) > config.max_message_bytes ||
        !wire::WellFormed(rbuf.data, rbuf.data_size, layout) ||
        message->decode(rbuf.data, 0, static_cast<int>(rbuf.data_size)) !=
            static_cast<int>(rbuf.data_size)) {
      ++counters.rejected_malformed;
      return false;
    }
    return true;
  }
  bool ChannelNames(const std::string& channel, const std::string& message_id);
  void OnVoltage(const lcm::ReceiveBuffer& rbuf, const std::string& channel);
  void OnDeflection(const lcm::ReceiveBuffer& rbuf, const std::string& channel);
  void AcceptVoltage(const flexid::voltage_sample_t& message);
  void AcceptDeflection(const flexid::deflection_sample_t& message);
  void OnTrialControl(const lcm::ReceiveBuffer& rbuf);
  void ApplyTrialControl(const flexid::trial_control2_t& message);
  static int64_t FingerprintOf(const lcm::ReceiveBuffer& rbuf);
  void Reply(const RpcContext& context, const RpcOutcome& outcome);

  // recorder.cc
  void FollowVoltage(ActuatorState* state, int64_t utime, double voltage_V);
  void RecordSample(ActuatorState* state, int64_t utime, double deflection_mm);
  uint64_t StartTrial(ActuatorState* state, const std::string& protocol, int64_t utime,
                      bool automatic);
  uint64_t StopTrial(ActuatorState* state, int64_t utime, storage::TrialState how);

  // predictor.cc
  void LoadModel(ActuatorState* state, const storage::ModelRecord& record);
  void PredictVoltage(ActuatorState* state, int64_t utime, double voltage_V);
  void PublishPrediction(ActuatorState* state, const flexid::deflection_sample_t& message);
  void StoreAlert(storage::AlertRecord record);
  void Raise(ActuatorState* state, const std::vector<Alert>& alerts);
  void AnnounceModel(ActuatorState* state, const storage::ModelRecord& record);

  // rpc_methods.cc
  void OnRequest(const lcm::ReceiveBuffer& rbuf);
  void Dispatch(const flexid::rpc_request_t& request);
  static bool ReadsTheFile(const std::string& method);
  void Answer(const flexid::rpc_request_t& request);
  static void LogAccepted(const flexid::rpc_request_t& request, const std::string& how);
  RpcOutcome ReplyWhenWritten(uint64_t ticket, const flexid::rpc_request_t& request,
                              RpcOutcome reply, std::function<void()> then = {});
  RpcOutcome HandleRequest(const flexid::rpc_request_t& request);
  ActuatorState* ActuatorArgument(const nlohmann::json& args, bool required);
  // The actuator of a request that changes data: one this daemon owns, else ArgumentError
  // naming the owner.
  ActuatorState* OwnedActuatorArgument(const nlohmann::json& args);
  // The methods (rpc_methods.cc: kRpcMethods).
  RpcOutcome RpcStatus(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcActuators(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcStoredQuery(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcModelActivate(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcTrialControl(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcIdentify(const flexid::rpc_request_t& request, const nlohmann::json& args);
  RpcOutcome RpcDiagnose(const flexid::rpc_request_t& request, const nlohmann::json& args);

  // worker.cc
  void OnWorkerResult(JobResult& result);
  void ReportDiagnosis(const DiagnosisResult& result);
  // Monitor alerts: raised, and counted for the policy when they are about a trial.
  void RaiseMonitorAlerts(ActuatorState* state, const std::vector<Alert>& alerts);
  // A trial that raised monitor alerts has ended: diagnose it as config.policy says.
  void ApplyPolicy(ActuatorState* state, int64_t trial_id, int64_t start_utime, int64_t end_utime);
  // One step of the policy: an info alert of kind "policy" (and its log line).
  void SayPolicy(ActuatorState* state, int64_t start_utime, int64_t end_utime,
                 const std::string& text);
  // Runs a diagnosis on the worker (false: it is busy); its result comes back to
  // OnWorkerResult, which answers `context` (empty request id: nobody to answer).
  bool SubmitDiagnosis(const DiagnosisJob& job, const RpcContext& context);
  // Stores a diagnosis's proposal (then a model_proposed alert), activates it when
  // asked (adopt), and answers the request with the diagnosis and the new version.
  void StoreProposal(const DiagnosisResult& result);

  // ownership_bus.cc
  static void OnOwnershipThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                               Service* self);
  void OnOwnership(const lcm::ReceiveBuffer& rbuf);
  void Announce();
  void DecideOwnership(bool periodic);
  void ApplyOwnershipEvents();
  void OnOwnershipEvent(const OwnershipEvent& event);
  // The actuator a message names when this daemon records it; otherwise nullptr, with
  // *hold set while its owner is being decided (the caller holds the message) and the
  // message counted when it is refused (another daemon's, or unknown).
  ActuatorState* OwnedActuator(const std::string& actuator_id, bool* hold);
  Ownership::Verdict RouteTo(const std::string& actuator_id);
  void Hold(const std::string& actuator_id, std::function<void()> replay);
  // "lab-b does not own actuator S3: lab-a does (configured there) ..." for a refusal.
  std::string NotOwnerText(const std::string& actuator_id) const;

  // health.cc
  int64_t LatestMessageUtime() const;
  int64_t LatestUtime() const;
  void RaiseHealth(const std::string& actuator_id, const std::string& kind, int severity,
                   int64_t start_utime, int64_t utime, const std::string& text);
  void Heard(ActuatorState* state);
  bool InTimeOrder(ActuatorState* state, int64_t utime, bool voltage);
  void OnClockJump(ActuatorState* state, int64_t jump_us, int64_t utime);
  void CheckHealth();
  void CheckStorage();
  void CheckDatabaseFile();
  void CheckSilence();
};

}  // namespace flexid::daemon
