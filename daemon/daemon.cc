#include "daemon/daemon.h"

#include <poll.h>
#include <pthread.h>
#include <sched.h>
#include <signal.h>
#include <spdlog/sinks/rotating_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/resource.h>
#include <sys/signalfd.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <deque>
#include <filesystem>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/status_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <functional>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "bus/lcm_url.h"
#include "daemon/health.h"
#include "daemon/rpc.h"
#include "daemon/unique_fd.h"
#include "flexid/version.h"
#include "lcmtypes/message_auth.h"
#include "lcmtypes/wire_check.h"
#include "model/diagnose.h"
#include "model/identify_global.h"
#include "model/identify_ts.h"
#include "model/model_file.h"
#include "model/simulate.h"
#include "storage/record_json.h"
#include "storage/sample_writer.h"

namespace flexid::daemon {
namespace {

constexpr int64_t kNoTime = INT64_MIN;

// SIGTERM and SIGINT stop the loop, SIGHUP reloads.
sigset_t HandledSignals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  return signals;
}
constexpr int kQueueCapacity = 1 << 17;  // messages per sample subscription
// The sample writer and the identification worker run at this nice value, so that their
// bursts (a commit every 100 ms, a fit taking a core for a second) yield the cores to the
// loop and LCM's receive thread: on two cores, commits otherwise showed up as a cluster
// of >1 ms prediction latencies once per commit interval (bench/daemon_load).
constexpr int kBackgroundNice = 10;

// The kernel receive buffer of this daemon's socket when the URL gives none: 16 actuators
// at 500 Hz (plus the daemon's own predictions, which udpm loops back) overflow the
// default ~200 kB within ~10 ms of a stalled receive thread.
constexpr int64_t kReceiveBufferBytes = 8388608;

// The verifier of signed requests, with the key from the configured file (created when
// absent). Throws auth::KeyError naming the file.
auth::Verifier MakeVerifier(const Config& config) {
  const std::string path = KeyFilePath(config);
  bool created = false;
  const auth::Key key = auth::LoadOrCreateKeyFile(path, &created);
  spdlog::info("{} [file: {}]", created ? "key created" : "key loaded", path);
  auth::VerifierOptions options;
  options.window_us = static_cast<int64_t>(config.auth_window_s * 1e6);
  return auth::Verifier(key, options);
}

// A request's arguments for the log: at most 200 bytes, control characters as '?'.
std::string ArgumentSummary(const std::string& args_json) {
  std::string out = args_json.substr(0, 200);
  for (char& c : out)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  if (args_json.size() > 200) out += "...";
  return out;
}

// The active model of one actuator, run on the live voltage in message time.
struct Predictor {
  int32_t version = 0;  // 0: no model
  std::optional<model::StreamingSimulator> simulator;
  int64_t base_utime = kNoTime;  // time origin of the simulator (keeps doubles precise)
  int64_t last_utime = kNoTime;
  double last_output_mm = NAN;
  std::vector<double> memberships;

  bool ready() const { return simulator.has_value(); }

  // Feeds the voltage in force from utime on; returns the prediction at utime.
  double Step(int64_t utime, double voltage_V) {
    if (!simulator) return NAN;
    if (base_utime == kNoTime) base_utime = utime;
    if (last_utime != kNoTime && utime <= last_utime) utime = last_utime + 1;  // same instant
    last_output_mm = simulator->Step(1e-6 * static_cast<double>(utime - base_utime), voltage_V);
    memberships = simulator->memberships();
    last_utime = utime;
    return last_output_mm;
  }
};

struct ActuatorState {
  storage::Actuator info;
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
};

// A finished identification, handed from the worker to the loop.
// A finished diagnosis carries its result instead (diagnosis is an object).
// "trial 5" or "trials 4, 5, 7".
std::string TrialWords(const std::vector<int64_t>& ids) {
  std::string text = ids.size() == 1 ? "trial " : "trials ";
  for (size_t i = 0; i < ids.size(); ++i) text += (i ? ", " : "") + std::to_string(ids[i]);
  return text;
}

struct IdentifyResult {
  RpcContext request;
  std::string actuator_id;
  std::optional<storage::ModelRecord> model;  // identified, to be stored (the writer) as active
  std::string error;
  nlohmann::json diagnosis = nullptr;  // the diagnose method's result
  // The diagnosed trials and their first samples' times (empty: an identification).
  std::vector<int64_t> trial_ids = {};
  std::vector<int64_t> trial_start_utimes = {};
};

}  // namespace

struct Daemon::Impl {
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
  // What the loop does once a write is committed or refused (replies that wait for it).
  std::multimap<uint64_t, std::function<void(const storage::WriteOutcome&)>> on_written;
  uint64_t last_ticket = 0;       // of the last write the loop queued
  uint64_t last_done_ticket = 0;  // of the last write committed or refused (in this order)
  // Updated by the loop, read by status and by other threads (counters()): relaxed atomics.
  struct LiveCounters {
    std::atomic<int64_t> messages_received{0}, samples_accepted{0}, rejected_malformed{0},
        rejected_nonfinite{0}, rejected_out_of_order{0}, rejected_unknown_actuator{0},
        dropped_queue_full{0}, predictions_published{0}, alerts_raised{0}, alerts_dropped{0},
        refused_unauthorized{0};
  } counters;
  std::map<std::string, ActuatorState> actuators;
  std::atomic<bool> stop{false};
  std::chrono::steady_clock::time_point started = std::chrono::steady_clock::now();
  std::chrono::steady_clock::time_point next_status = started;

  // Identification worker: one job at a time; a second request while one runs is "busy".
  std::thread worker;
  std::mutex worker_mutex;
  std::condition_variable worker_wake;
  std::optional<std::function<IdentifyResult()>> job;
  std::deque<IdentifyResult> finished;
  std::atomic<bool> identifying{false};
  bool worker_exit = false;
  std::vector<int> background_cpus;  // pin_threads: the writer's and the worker's CPUs

  // Health (see "Health" below): the time of this loop pass, the database file's identity,
  // the storage failure in progress.
  std::chrono::steady_clock::time_point loop_now = started;
  std::optional<FileIdentity> database_identity;
  bool storage_failing = false;
  std::chrono::steady_clock::time_point storage_failing_since{};
  int64_t drops_when_failing = 0, drops_reported = 0, alert_drops_reported = 0;

  Impl(Config c, std::string path)
      : config(std::move(c)),
        channels(config.channel_prefix),
        config_path(std::move(path)),
        db(storage::Database::Open(config.database)),
        verifier(MakeVerifier(config)),
        lcm(bus::WithReceiveBuffer(config.lcm_url, kReceiveBufferBytes)) {
    database_identity = IdentityOf(config.database);  // none in memory: nothing to watch
    if (!lcm.good()) throw std::runtime_error("cannot join the LCM bus at " + config.lcm_url);
    // Signals are taken through signalfd in the loop. They are blocked here, before any
    // thread starts, so that every thread inherits the mask: a SIGTERM delivered to the
    // writer or the worker would otherwise end the process without flushing.
    BlockHandledSignals();
    const sigset_t signals = HandledSignals();
    signal_fd = UniqueFd(signalfd(-1, &signals, SFD_NONBLOCK | SFD_CLOEXEC));
    wake_fd = UniqueFd(eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC));
    if (!signal_fd.valid() || !wake_fd.valid())
      throw std::runtime_error("cannot create signal or wake descriptors");

    // The one write of start-up on this connection, before the writer and the loop run:
    // trials are ended before new ones get ids.
    const int interrupted = db.MarkRecordingTrialsInterrupted();
    if (interrupted > 0)
      spdlog::warn("trials left recording by an earlier run marked interrupted [count: {}]",
                   interrupted);
    next_trial_id = db.LastTrialId() + 1;
    storage::SampleWriterOptions options;
    options.commit_interval = std::chrono::milliseconds(config.commit_interval_ms);
    options.thread_nice = kBackgroundNice;
    options.queue_capacity = static_cast<size_t>(config.health.writer_queue_samples);
    const int cpus = static_cast<int>(std::thread::hardware_concurrency());
    if (config.pin_threads && cpus >= 2) {
      for (int cpu = 1; cpu < cpus; ++cpu) background_cpus.push_back(cpu);
      options.thread_cpus = background_cpus;
      // This thread runs the loop; LCM's receive thread, created at the first
      // subscription below, inherits CPU 0 from it.
      cpu_set_t set;
      CPU_ZERO(&set);
      CPU_SET(0, &set);
      pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    }
    options.on_outcome = [this] { Wake(); };
    writer = std::make_unique<storage::SampleWriter>(config.database, options);
    for (const storage::Actuator& a : config.actuators) {
      Store(a);
      AddActuator(a);
    }
    for (const storage::Actuator& a : db.Actuators())
      if (!actuators.count(a.id)) AddActuator(a);

    // LCM keeps at most 30 undispatched messages per subscription by default and drops
    // the rest silently; 16 actuators at 500 Hz need far more between two loop passes.
    lcm.subscribeFunction(channels.AllVoltages(), &Impl::OnVoltageThunk, this)
        ->setQueueCapacity(kQueueCapacity);
    lcm.subscribeFunction(channels.AllDeflections(), &Impl::OnDeflectionThunk, this)
        ->setQueueCapacity(kQueueCapacity);
    lcm.subscribeFunction(bus::Exactly(channels.RpcRequest()), &Impl::OnRequestThunk, this)
        ->setQueueCapacity(1000);
    lcm.subscribeFunction(bus::Exactly(channels.TrialControl()), &Impl::OnTrialControlThunk, this)
        ->setQueueCapacity(1000);
    worker = std::thread([this] { WorkerLoop(); });
  }

  ~Impl() {
    {
      std::lock_guard<std::mutex> lock(worker_mutex);
      worker_exit = true;
    }
    worker_wake.notify_all();
    if (worker.joinable()) worker.join();
  }

  // Queues a write for the writer thread; returns its ticket (0: an alert refused).
  uint64_t Store(storage::Write write) {
    const uint64_t ticket = writer->Submit(std::move(write));
    last_ticket = std::max(last_ticket, ticket);
    return ticket;
  }

  // Makes the loop's next poll return for DrainFinished (any thread).
  void Wake() {
    const uint64_t one = 1;
    if (write(wake_fd.get(), &one, sizeof one) < 0) spdlog::error("cannot wake the loop");
  }

  void AddActuator(const storage::Actuator& info) {
    ActuatorState& state = actuators[info.id];
    state.info = info;
    state.monitor = std::make_unique<ResidualMonitor>(info.id, config.alerts);
    const HealthConfig& h = config.health;
    state.voltage_clock = state.deflection_clock = ClockJumpDetector(
        static_cast<int64_t>(h.clock_jump_back_s * 1e6),
        static_cast<int64_t>(h.clock_jump_forward_s * 1e6), h.clock_jump_messages);
    if (const auto record = db.ActiveModel(info.id)) LoadModel(&state, *record);
  }

  void LoadModel(ActuatorState* state, const storage::ModelRecord& record) {
    const model::ModelDocument doc =
        model::ParseModelJson(record.model_json, "model " + std::to_string(record.version));
    Predictor predictor;
    predictor.version = record.version;
    // Start at rest, or in steady state under the voltage in force: a model swapped in
    // during a hold starts where the actuator is assumed to be.
    model::SimulationOptions options;
    options.start_in_steady_state = std::abs(state->voltage_V) > config.alerts.rest_band_V;
    predictor.simulator.emplace(model::AsTsModel(doc), options);
    state->predictor = std::move(predictor);
    // Alert thresholds are calibrated on the residual this model showed when it was
    // fitted (its RMSE), unless the configuration fixes the noise scale.
    MonitorOptions monitor_options = config.alerts;
    const nlohmann::json fit = nlohmann::json::parse(record.fit_json, nullptr, false);
    if (monitor_options.noise_mm <= 0.0 && fit.is_object() && fit.contains("rmse_mm") &&
        fit["rmse_mm"].is_number())
      monitor_options.noise_mm = fit["rmse_mm"].get<double>();
    state->monitor = std::make_unique<ResidualMonitor>(state->info.id, monitor_options);
    spdlog::info("model active [actuator: {}, version: {}]", state->info.id, record.version);
  }

  // ---------------------------------------------------------------------------------------
  // Bus handlers. Nothing may throw through LCM's C callback: every handler catches at the
  // edge, logs, counts and goes on.
  // ---------------------------------------------------------------------------------------

  static void OnVoltageThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Impl* self) {
    self->Guarded(channel, [&] { self->OnVoltage(*rbuf, channel); });
  }
  static void OnDeflectionThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                Impl* self) {
    self->Guarded(channel, [&] { self->OnDeflection(*rbuf, channel); });
  }
  static void OnRequestThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                             Impl* self) {
    self->Guarded(channel, [&] { self->OnRequest(*rbuf); });
  }
  static void OnTrialControlThunk(const lcm::ReceiveBuffer* rbuf, const std::string& channel,
                                  Impl* self) {
    self->Guarded(channel, [&] { self->OnTrialControl(*rbuf); });
  }

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

  // The actuator a sample channel names (PREFIX/<id>/KIND), if the message agrees with it
  // and the actuator is known or may be added.
  ActuatorState* SampleActuator(const std::string& channel, const std::string& message_id) {
    const size_t first = config.channel_prefix.size() + 1;
    const size_t second = channel.find('/', first);
    if (second == std::string::npos || channel.find('/', second + 1) != std::string::npos ||
        channel.compare(first, second - first, message_id) != 0) {
      ++counters.rejected_malformed;  // misaddressed: the channel names another actuator
      return nullptr;
    }
    return KnownOrNewActuator(message_id);
  }

  // The actuator of that id, added (and stored) when unknown actuators are accepted.
  ActuatorState* KnownOrNewActuator(const std::string& message_id) {
    auto it = actuators.find(message_id);
    if (it != actuators.end()) return &it->second;
    if (!config.accept_unknown_actuators || !bus::IsValidId(message_id)) {
      ++counters.rejected_unknown_actuator;
      return nullptr;
    }
    storage::Actuator info;
    info.id = message_id;
    Store(info);
    AddActuator(info);
    spdlog::info("new actuator [id: {}]", message_id);
    return &actuators.at(message_id);
  }

  void OnVoltage(const lcm::ReceiveBuffer& rbuf, const std::string& channel) {
    flexid::voltage_sample_t message;
    if (!Decode(rbuf, &message, wire::kVoltageSample)) return;
    ActuatorState* state = SampleActuator(channel, message.actuator_id);
    if (!state) return;
    if (!std::isfinite(message.voltage_V)) {
      ++counters.rejected_nonfinite;
      return;
    }
    if (!InTimeOrder(state, message.utime, /*voltage=*/true)) return;
    ++counters.samples_accepted;
    state->voltage_utime = message.utime;
    state->voltage_V = message.voltage_V;
    // Automatic trials: one ends after trial_idle_stop_s without voltage (checked on every
    // voltage message, also the first after a long gap); one starts when an idle actuator
    // gets a voltage.
    const bool active = std::abs(message.voltage_V) > config.alerts.rest_band_V;
    if (state->automatic_trial && state->last_active_utime != kNoTime &&
        message.utime - state->last_active_utime >
            static_cast<int64_t>(config.trial_idle_stop_s * 1e6))
      StopTrial(state, message.utime, storage::TrialState::kComplete);
    if (active) state->last_active_utime = message.utime;
    if (config.auto_trials && active && state->trial_id == 0)
      StartTrial(state, "automatic", message.utime, true);
    if (state->predictor.ready()) state->predictor.Step(message.utime, message.voltage_V);
    Raise(state, state->monitor->OnVoltage(message.utime, message.voltage_V));
  }

  void OnDeflection(const lcm::ReceiveBuffer& rbuf, const std::string& channel) {
    flexid::deflection_sample_t message;
    if (!Decode(rbuf, &message, wire::kDeflectionSample)) return;
    ActuatorState* state = SampleActuator(channel, message.actuator_id);
    if (!state) return;
    if (!std::isfinite(message.deflection_mm)) {
      ++counters.rejected_nonfinite;
      return;
    }
    if (!InTimeOrder(state, message.utime, /*voltage=*/false)) return;
    ++counters.samples_accepted;
    state->deflection_utime = message.utime;
    // Paired with the voltage in force at its time (held since its last message).
    if (state->trial_id != 0) {
      if (writer->Enqueue(state->trial_id,
                          {message.utime, state->voltage_V, message.deflection_mm}))
        state->last_sample_utime = message.utime;
      else
        ++counters.dropped_queue_full;
    }
    const double predicted = state->predictor.Step(message.utime, state->voltage_V);
    const double residual = message.deflection_mm - predicted;
    flexid::prediction_t out;
    out.utime = message.utime;
    out.actuator_id = message.actuator_id;
    out.voltage_V = state->voltage_V;
    out.measured_mm = message.deflection_mm;
    out.predicted_mm = predicted;
    out.residual_mm = residual;
    out.model_version = state->predictor.version;
    out.trial_id = static_cast<int32_t>(state->trial_id);
    out.memberships = state->predictor.memberships;
    out.num_memberships = static_cast<int16_t>(out.memberships.size());
    lcm.publish(channels.Prediction(message.actuator_id), &out);
    ++counters.predictions_published;
    Raise(state, state->monitor->OnDeflection(message.utime, state->voltage_V, residual));
  }

  // Trial control changes stored data, so it is signed: trial_control2_t with a valid
  // signature, within the window of its sent_utime (wall clock; utime is message time and
  // may be accelerated or replayed), with a nonce not seen before. The unsigned
  // trial_control_t of earlier versions is refused (and counted) like a bad signature.
  void OnTrialControl(const lcm::ReceiveBuffer& rbuf) {
    if (rbuf.data_size >= 8 && FingerprintOf(rbuf) == flexid::trial_control_t::getHash()) {
      flexid::trial_control_t old;
      const bool decoded = Decode(rbuf, &old, wire::kTrialControl);
      ++counters.refused_unauthorized;
      spdlog::warn(
          "trial control refused [actuator: {}, action: {}] not authorised: unsigned "
          "trial_control_t (send a signed trial_control2_t)",
          decoded ? old.actuator_id : "?", decoded ? old.action : 0);
      return;
    }
    flexid::trial_control2_t message;
    if (!Decode(rbuf, &message, wire::kTrialControl2)) return;
    const std::string refusal = verifier.Check(message, bus::WallClockUtime());
    if (!refusal.empty()) {
      ++counters.refused_unauthorized;
      spdlog::warn(
          "trial control refused [actuator: {}, action: {}, protocol: {}] not "
          "authorised: {}",
          message.actuator_id, message.action, ArgumentSummary(message.protocol), refusal);
      return;
    }
    if (message.action != flexid::trial_control2_t::kStart &&
        message.action != flexid::trial_control2_t::kStop) {
      ++counters.rejected_malformed;
      spdlog::warn("trial control rejected [actuator: {}, action: {}] unknown action",
                   message.actuator_id, message.action);
      return;
    }
    spdlog::info("trial control accepted [actuator: {}, action: {}, protocol: {}]",
                 message.actuator_id,
                 message.action == flexid::trial_control2_t::kStart ? "start" : "stop",
                 ArgumentSummary(message.protocol));
    ActuatorState* state = KnownOrNewActuator(message.actuator_id);
    if (!state) return;
    if (state->trial_id != 0) StopTrial(state, message.utime, storage::TrialState::kComplete);
    if (message.action == flexid::trial_control2_t::kStart)
      StartTrial(state, message.protocol, message.utime, false);
  }

  // The type fingerprint an encoded LCM message starts with (8 bytes, big-endian).
  static int64_t FingerprintOf(const lcm::ReceiveBuffer& rbuf) {
    const auto* bytes = static_cast<const uint8_t*>(rbuf.data);
    uint64_t value = 0;
    for (int i = 0; i < 8; ++i) value = (value << 8) | bytes[i];
    return static_cast<int64_t>(value);
  }

  // Starts a trial under the next id; returns the ticket of its write. Never waits for the
  // disk, never throws for it: the writer stores the trial, or retries.
  uint64_t StartTrial(ActuatorState* state, const std::string& protocol, int64_t utime,
                      bool automatic) {
    state->trial_id = next_trial_id++;
    const uint64_t ticket =
        Store(storage::TrialStart{state->trial_id, state->info.id, protocol, utime});
    on_written.emplace(ticket, [id = state->trial_id,
                                actuator = state->info.id](const storage::WriteOutcome& written) {
      if (written.error.empty() && written.trial_id != id)
        spdlog::warn(
            "trial stored under another id: another program took its id [actuator: {}, "
            "trial: {}, stored as: {}]",
            actuator, id, written.trial_id);
    });
    state->trial_start_utime = utime;
    state->trial_protocol = protocol;
    state->last_heard = loop_now;  // input silence counts from the start of a trial
    state->automatic_trial = automatic;
    state->last_sample_utime = kNoTime;
    spdlog::info("trial started [actuator: {}, trial: {}, protocol: {}]", state->info.id,
                 state->trial_id, protocol);
    return ticket;
  }

  // Ends the trial recording; returns the ticket of its write (as StartTrial).
  uint64_t StopTrial(ActuatorState* state, int64_t utime, storage::TrialState how) {
    // A trial ends at its last sample; one without samples ends where it started (message
    // time; 0 would read as "still recording").
    const int64_t end = state->last_sample_utime != kNoTime ? state->last_sample_utime
                        : utime > state->trial_start_utime  ? utime
                                                            : state->trial_start_utime;
    const uint64_t ticket = Store(storage::TrialEnd{state->trial_id, end, how});
    spdlog::info("trial ended [actuator: {}, trial: {}, state: {}]", state->info.id,
                 state->trial_id, storage::TrialStateName(how));
    state->trial_id = 0;
    state->automatic_trial = false;
    return ticket;
  }

  // Queues an alert for the writer; counts it when the writer's alert queue is full.
  void StoreAlert(storage::AlertRecord record) {
    if (Store(std::move(record)) == 0) ++counters.alerts_dropped;
  }

  void Raise(ActuatorState* state, const std::vector<Alert>& alerts) {
    for (const Alert& alert : alerts) {
      flexid::alert_t out;
      out.utime =
          state->deflection_utime != kNoTime ? state->deflection_utime : state->voltage_utime;
      out.actuator_id = state->info.id;
      out.kind = alert.kind;
      out.severity = static_cast<int8_t>(alert.severity);
      out.start_utime = alert.start_utime;
      out.end_utime = alert.end_utime;
      out.magnitude_mm = alert.magnitude_mm;
      out.threshold_mm = alert.threshold_mm;
      out.text = alert.text;
      lcm.publish(channels.Alert(), &out);
      ++counters.alerts_raised;
      storage::AlertRecord record{0,
                                  out.actuator_id,
                                  out.kind,
                                  out.severity,
                                  out.utime,
                                  out.start_utime,
                                  out.end_utime,
                                  out.magnitude_mm,
                                  out.threshold_mm,
                                  out.text};
      StoreAlert(std::move(record));
      spdlog::log(alert.severity == 0 ? spdlog::level::info : spdlog::level::warn,
                  "alert [actuator: {}, kind: {}, magnitude_mm: {:.3f}] {}", out.actuator_id,
                  out.kind, out.magnitude_mm, out.text);
    }
  }

  // A diagnosis that names an effect is an alert of that effect's kind (the catalogue of
  // model/diagnose.h), spanning the trial, with the explanation as its text.
  void ReportDiagnosis(const IdentifyResult& result) {
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
        return result.trial_start_utimes.at(trial) +
               static_cast<int64_t>(span.value(key, 0.0) * 1e6);
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
      Raise(&it->second, {alert});
    }
    Reply(result.request, {flexid::rpc_reply_t::kOk, d, "", false});
  }

  // Tells the bus that a new model is active: an info alert of kind "model_changed".
  void AnnounceModel(ActuatorState* state, const storage::ModelRecord& record) {
    const nlohmann::json fit = nlohmann::json::parse(record.fit_json, nullptr, false);
    Alert alert;
    alert.kind = "model_changed";
    alert.severity = 0;
    alert.start_utime = alert.end_utime =
        state->deflection_utime != kNoTime ? state->deflection_utime : 0;
    alert.text =
        state->info.id + ": model version " + std::to_string(record.version) + " is active";
    if (fit.is_object() && fit.contains("fit_percent") && fit["fit_percent"].is_number()) {
      char figures[96];
      std::snprintf(figures, sizeof figures,
                    " (fit %.1f %%, RMSE %.3g mm on trials it was identified from)",
                    fit["fit_percent"].get<double>(), fit.value("rmse_mm", 0.0));
      alert.text += figures;
    }
    Raise(state, {alert});
  }

  // ---------------------------------------------------------------------------------------
  // RPC
  // ---------------------------------------------------------------------------------------

  void OnRequest(const lcm::ReceiveBuffer& rbuf) {
    flexid::rpc_request_t request;
    if (!Decode(rbuf, &request, wire::kRpcRequest)) return;
    const RpcContext context{request.request_id, request.client_id};
    // Methods that change data need a valid signature, a fresh time and a new nonce; every
    // one is logged with its outcome. Read-only methods need none (an `auth` is ignored).
    const bool changes_data = ChangesData(request.method);
    if (changes_data) {
      const std::string refusal = verifier.Check(request, bus::WallClockUtime());
      if (!refusal.empty()) {
        ++counters.refused_unauthorized;
        spdlog::warn(
            "request refused [method: {}, client: {}, request: {}, args: {}] not authorised: {}",
            ArgumentSummary(request.method), ArgumentSummary(request.client_id),
            ArgumentSummary(request.request_id), ArgumentSummary(request.args_json), refusal);
        Reply(context,
              {flexid::rpc_reply_t::kUnauthorized, nullptr, "not authorised: " + refusal, false});
        return;
      }
    }
    // A request that reads the file sees every write queued before it (a trial stopped
    // on the bus, then "identify"), as when the loop wrote itself: it waits for them,
    // unless storage is failing (then it is answered from what the file holds).
    if (ReadsTheFile(request.method) && last_done_ticket < last_ticket &&
        writer->last_error().empty()) {
      on_written.emplace(last_ticket,
                         [this, request](const storage::WriteOutcome&) { Answer(request); });
      return;
    }
    Answer(request);
  }

  static bool ReadsTheFile(const std::string& method) {
    return method != "status" && method != "actuators";
  }

  void Answer(const flexid::rpc_request_t& request) {
    const RpcContext context{request.request_id, request.client_id};
    const bool changes_data = ChangesData(request.method);
    RpcOutcome outcome = HandleRequest(request);
    if (outcome.deferred && outcome.written != 0) return;  // see ReplyWhenWritten
    if (changes_data)
      LogAccepted(request, outcome.deferred ? "running on the worker"
                           : outcome.status == flexid::rpc_reply_t::kOk
                               ? "done"
                               : "failed: " + ArgumentSummary(outcome.error));
    if (outcome.deferred) return;  // identify: answered when the worker finishes
    Reply(context, outcome);
  }

  static void LogAccepted(const flexid::rpc_request_t& request, const std::string& how) {
    spdlog::info("request accepted [method: {}, client: {}, request: {}, args: {}] {}",
                 ArgumentSummary(request.method), ArgumentSummary(request.client_id),
                 ArgumentSummary(request.request_id), ArgumentSummary(request.args_json), how);
  }

  // A request that changed data is answered once the writer has committed its last write
  // (then "ok" means stored, and `then` runs first), or refused it (then the reply says
  // why). While storage fails the reply waits: the write is retried. Returns the deferred
  // outcome for HandleRequest to return.
  RpcOutcome ReplyWhenWritten(uint64_t ticket, const flexid::rpc_request_t& request,
                              RpcOutcome reply, std::function<void()> then = {}) {
    on_written.emplace(ticket, [this, request, reply = std::move(reply),
                                then = std::move(then)](const storage::WriteOutcome& written) {
      RpcOutcome outcome = written.error.empty()
                               ? reply
                               : RpcOutcome{flexid::rpc_reply_t::kFailed, nullptr, written.error};
      try {
        if (written.error.empty() && then) then();
      } catch (const std::exception& e) {
        outcome = {flexid::rpc_reply_t::kFailed, nullptr, e.what()};
      }
      LogAccepted(request, outcome.status == flexid::rpc_reply_t::kOk
                               ? "done"
                               : "failed: " + ArgumentSummary(outcome.error));
      Reply({request.request_id, request.client_id}, outcome);
    });
    return {flexid::rpc_reply_t::kOk, nullptr, "", true, ticket};
  }

  void Reply(const RpcContext& context, const RpcOutcome& outcome) {
    if (!bus::IsValidId(context.client_id)) return;  // nowhere to reply to
    flexid::rpc_reply_t reply;
    reply.utime = bus::WallClockUtime();
    reply.request_id = context.request_id;
    reply.daemon_id = config.daemon_id;
    reply.status = outcome.status;
    reply.result_json = outcome.result.dump();
    reply.error = outcome.error;
    lcm.publish(channels.RpcReply(context.client_id), &reply);
  }

  RpcOutcome HandleRequest(const flexid::rpc_request_t& request);

  // ---------------------------------------------------------------------------------------
  // Identification worker
  // ---------------------------------------------------------------------------------------

  void WorkerLoop() {
    // Identification takes a whole core for up to a second: run it under SCHED_IDLE, so
    // that it only ever uses a core nobody else wants and the loop wakes without waiting
    // for one (nice alone left a few ms of wake-up delay on two cores when a fit started).
    if (!background_cpus.empty()) {
      cpu_set_t set;
      CPU_ZERO(&set);
      for (int cpu : background_cpus) CPU_SET(cpu, &set);
      pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    }
    sched_param idle{};
    if (pthread_setschedparam(pthread_self(), SCHED_IDLE, &idle) != 0)
      setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), kBackgroundNice);
    while (true) {
      std::function<IdentifyResult()> task;
      {
        std::unique_lock<std::mutex> lock(worker_mutex);
        worker_wake.wait(lock, [this] { return worker_exit || job.has_value(); });
        if (worker_exit) return;
        task = std::move(*job);
        job.reset();
      }
      IdentifyResult result = task();
      {
        std::lock_guard<std::mutex> lock(worker_mutex);
        finished.push_back(std::move(result));
      }
      identifying = false;
      Wake();
    }
  }

  bool Submit(std::function<IdentifyResult()> task) {
    std::lock_guard<std::mutex> lock(worker_mutex);
    if (identifying) return false;
    identifying = true;
    job = std::move(task);
    worker_wake.notify_one();
    return true;
  }

  // Takes what the worker and the writer have finished. Each result is handled on its own:
  // one that fails is logged (and its request answered) and the others go on.
  void DrainFinished() {
    uint64_t count = 0;
    if (read(wake_fd.get(), &count, sizeof count) < 0 && errno != EAGAIN)
      spdlog::error("wake read failed");
    for (const storage::WriteOutcome& outcome : writer->TakeOutcomes()) {
      try {
        OnWritten(outcome);
      } catch (const std::exception& e) {
        spdlog::error("write outcome not handled [error: {}]", e.what());
      }
    }
    std::deque<IdentifyResult> done;
    {
      std::lock_guard<std::mutex> lock(worker_mutex);
      done.swap(finished);
    }
    for (IdentifyResult& result : done) {
      try {
        OnWorkerResult(result);
      } catch (const std::exception& e) {
        spdlog::error("worker result failed [actuator: {}, error: {}]", result.actuator_id,
                      e.what());
        Reply(result.request, {flexid::rpc_reply_t::kFailed, nullptr, e.what()});
      }
    }
  }

  void OnWritten(const storage::WriteOutcome& outcome) {
    last_done_ticket = std::max(last_done_ticket, outcome.ticket);
    if (!outcome.error.empty())
      spdlog::error("write refused by the database, not retried [error: {}]", outcome.error);
    auto [first, last] = on_written.equal_range(outcome.ticket);
    std::vector<std::function<void(const storage::WriteOutcome&)>> then;
    for (auto it = first; it != last; ++it) then.push_back(std::move(it->second));
    on_written.erase(first, last);
    for (const auto& run : then) run(outcome);
  }

  void OnWorkerResult(IdentifyResult& result) {
    if (result.diagnosis.is_object()) {
      ReportDiagnosis(result);
      return;
    }
    if (!result.model) {
      spdlog::error("{} failed [actuator: {}, error: {}]",
                    !result.trial_ids.empty() ? "diagnosis" : "identification", result.actuator_id,
                    result.error);
      Reply(result.request, {flexid::rpc_reply_t::kFailed, nullptr, result.error});
      return;
    }
    // Stored by the writer as the next version; then swapped in and answered.
    const uint64_t ticket = Store(std::move(*result.model));
    on_written.emplace(ticket, [this, request = result.request, actuator_id = result.actuator_id](
                                   const storage::WriteOutcome& written) {
      if (!written.model) {
        spdlog::error("identification failed [actuator: {}, error: cannot store the model: {}]",
                      actuator_id, written.error);
        Reply(request,
              {flexid::rpc_reply_t::kFailed, nullptr, "cannot store the model: " + written.error});
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

  // ---------------------------------------------------------------------------------------
  // Health: faults other than bad messages (daemon/health.h; the documented behaviour is in
  // tests/daemon_fault_matrix_test.cc). Checked once a second by the loop, and for clock
  // jumps on every sample. What happened is logged and published as an alert on
  // FLEXID/ALERT (actuator_id empty when it concerns the daemon itself).
  // ---------------------------------------------------------------------------------------

  // The latest message time the daemon has seen (health alerts are stamped with it), or
  // the wall clock before any message.
  int64_t LatestUtime() const {
    int64_t latest = kNoTime;
    for (const auto& [id, state] : actuators)
      latest = std::max({latest, state.voltage_utime, state.deflection_utime});
    return latest != kNoTime ? latest : bus::WallClockUtime();
  }

  // Publishes, counts and logs a health alert, and queues it for the writer (stored once
  // the database takes writes).
  void RaiseHealth(const std::string& actuator_id, const std::string& kind, int severity,
                   int64_t start_utime, int64_t utime, const std::string& text) {
    flexid::alert_t out;
    out.utime = utime;
    out.actuator_id = actuator_id;
    out.kind = kind;
    out.severity = static_cast<int8_t>(severity);
    out.start_utime = start_utime;
    out.end_utime = utime;
    out.magnitude_mm = 0.0;
    out.threshold_mm = 0.0;
    out.text = text;
    lcm.publish(channels.Alert(), &out);
    ++counters.alerts_raised;
    spdlog::log(severity == 0   ? spdlog::level::info
                : severity == 1 ? spdlog::level::warn
                                : spdlog::level::err,
                "{} [kind: {}, actuator: {}]", text, kind, actuator_id);
    StoreAlert({0, actuator_id, kind, severity, utime, start_utime, utime, 0.0, 0.0, text});
  }

  // Records that a message of the actuator arrived; says so if it had fallen silent.
  void Heard(ActuatorState* state) {
    if (state->silent) {
      state->silent = false;
      const double quiet_s = std::chrono::duration<double>(loop_now - state->last_heard).count();
      RaiseHealth(
          state->info.id, "input_resumed", 0, LatestUtime(), LatestUtime(),
          fmt::format("input from {} resumed after {:.1f} s of silence", state->info.id, quiet_s));
    }
    state->last_heard = loop_now;
  }

  // A sample's time against its stream: in order (true), out of order (false, counted), or
  // the first on a new time base after the source's clock jumped (true, see OnClockJump).
  bool InTimeOrder(ActuatorState* state, int64_t utime, bool voltage) {
    Heard(state);
    const int64_t last = voltage ? state->voltage_utime : state->deflection_utime;
    ClockJumpDetector& clock = voltage ? state->voltage_clock : state->deflection_clock;
    switch (clock.Check(last, utime, state->trial_id != 0)) {
      case ClockJumpDetector::Verdict::kAccept:
        return true;
      case ClockJumpDetector::Verdict::kReject:
        ++counters.rejected_out_of_order;
        return false;
      case ClockJumpDetector::Verdict::kJumped:
        OnClockJump(state, clock.jump_us(), utime);
        return true;
    }
    return false;
  }

  // The source's clock jumped: the trial in progress ends "interrupted" at its last sample,
  // a manual trial continues as a new trial from `utime` (an automatic one restarts by the
  // usual rule), both streams and the prediction start over on the new time base.
  void OnClockJump(ActuatorState* state, int64_t jump_us, int64_t utime) {
    const int64_t old_trial = state->trial_id;
    const bool automatic = state->automatic_trial;
    const std::string protocol = state->trial_protocol;
    if (old_trial != 0)
      StopTrial(state, std::max(state->voltage_utime, state->deflection_utime),
                storage::TrialState::kInterrupted);
    const int64_t previous = std::max(state->voltage_utime, state->deflection_utime);
    state->voltage_utime = state->deflection_utime = kNoTime;
    state->voltage_clock.Reset();
    state->deflection_clock.Reset();
    state->last_active_utime = kNoTime;
    state->last_sample_utime = kNoTime;
    // The predictor and the monitor run in message time: start them again.
    std::optional<storage::ModelRecord> record;
    try {
      if (state->predictor.ready()) record = db.ActiveModel(state->info.id);
    } catch (const std::exception& e) {
      spdlog::warn("cannot reload the model [actuator: {}, error: {}]", state->info.id, e.what());
    }
    if (record) {
      LoadModel(state, *record);
    } else {
      state->predictor = Predictor{};
      state->monitor = std::make_unique<ResidualMonitor>(state->info.id, config.alerts);
    }
    std::string text = fmt::format("source clock of {} jumped {} by {:.1f} s", state->info.id,
                                   jump_us < 0 ? "back" : "forward",
                                   std::abs(static_cast<double>(jump_us)) * 1e-6);
    if (old_trial != 0) {
      text += fmt::format("; trial {} ended interrupted at its last sample", old_trial);
      if (!automatic) {
        StartTrial(state, protocol, utime, false);
        text += fmt::format(", trial {} continues it on the new time base", state->trial_id);
      }
    }
    RaiseHealth(state->info.id, "clock_jump", 1, previous, utime, text);
  }

  void CheckHealth() {
    try {
      CheckStorage();
      CheckDatabaseFile();
      CheckSilence();
    } catch (const std::exception& e) {  // e.g. a trial that cannot be ended: next second
      spdlog::error("health check failed [error: {}]", e.what());
    }
  }

  // The writer's commits failing (disk full, read-only file system, a lock held too long):
  // said once when it starts, drops said as they happen (at most once a second), and the
  // recovery said with what it cost.
  void CheckStorage() {
    const std::string error = writer->last_error();
    if (const int64_t alert_drops = counters.alerts_dropped.load(std::memory_order_relaxed);
        alert_drops > alert_drops_reported) {
      spdlog::error("alerts not stored: the writer holds as many as it may [dropped: {}]",
                    alert_drops - alert_drops_reported);
      alert_drops_reported = alert_drops;
    }
    const int64_t dropped = counters.dropped_queue_full.load(std::memory_order_relaxed);
    const int64_t utime = LatestUtime();
    if (!error.empty() && !storage_failing) {
      storage_failing = true;
      storage_failing_since = loop_now;
      drops_when_failing = drops_reported = dropped;
      RaiseHealth("", "storage_failing", 2, utime, utime,
                  fmt::format("storage failing: {}: {}; samples (at most {}), trials, alerts and "
                              "models are held in memory and retried, and none counts as stored "
                              "until it is committed",
                              StorageProblem(error), error, config.health.writer_queue_samples));
    } else if (storage_failing && !error.empty() && dropped > drops_reported) {
      if (drops_reported == drops_when_failing)
        RaiseHealth("", "samples_dropped", 2, utime, utime,
                    fmt::format("storage failing: {}: the {} samples held in memory fill the "
                                "writer queue; new samples are dropped and counted until storage "
                                "recovers",
                                StorageProblem(error), config.health.writer_queue_samples));
      spdlog::error("samples dropped while storage fails [dropped: {}, since it failed: {}]",
                    dropped - drops_reported, dropped - drops_when_failing);
      drops_reported = dropped;
    } else if (storage_failing && error.empty()) {
      storage_failing = false;
      const double failed_s =
          std::chrono::duration<double>(loop_now - storage_failing_since).count();
      RaiseHealth("", "storage_recovered", 0, utime, utime,
                  fmt::format("storage recovered after {:.0f} s: the samples held meanwhile are "
                              "committed; {} samples were dropped (writer queue full)",
                              failed_s, dropped - drops_when_failing));
    }
  }

  // The database file deleted or replaced under the daemon: SQLite would go on writing to
  // the old (unlinked) file, and every new sample would vanish with it. A new database is
  // opened at the path; the trials recording go on there as new trials.
  void CheckDatabaseFile() {
    if (!database_identity) return;
    const std::optional<FileIdentity> current = IdentityOf(config.database);
    if (current && *current == *database_identity) return;
    const char* what = current ? "replaced" : "deleted";
    if (!current) {
      // The old file's -wal and -shm are the old connections'; a new database must not
      // start from them.
      for (const char* suffix : {"-wal", "-shm"}) unlink((config.database + suffix).c_str());
    }
    try {
      db = storage::Database::Open(config.database);
    } catch (const std::exception& e) {
      spdlog::error(
          "database file {} under the daemon and no new one can be opened; retrying "
          "every second [path: {}, error: {}]",
          what, config.database, e.what());
      return;
    }
    database_identity = IdentityOf(config.database);
    // Ids go on from the highest of both files: a replaced file may hold trials already.
    next_trial_id = std::max(next_trial_id, db.LastTrialId() + 1);
    std::map<int64_t, int64_t> trial_ids;
    std::string continued;
    for (auto& [id, state] : actuators) {
      if (state.trial_id == 0) continue;
      const int64_t old_trial = state.trial_id;
      state.trial_id = next_trial_id++;
      trial_ids[old_trial] = state.trial_id;
      continued +=
          fmt::format("{}{} -> {}", continued.empty() ? "" : ", ", old_trial, state.trial_id);
    }
    // Then, in the writer's order: the new file, the actuators, the trials that go on.
    writer->Reopen(trial_ids);
    for (auto& [id, state] : actuators) {
      Store(state.info);
      if (state.trial_id != 0)
        Store(
            storage::TrialStart{state.trial_id, id, state.trial_protocol, state.trial_start_utime});
    }
    const int64_t utime = LatestUtime();
    RaiseHealth("", "database_replaced", 2, utime, utime,
                fmt::format("database file {} was {} under the daemon: a new database is open "
                            "there; what the old file held is gone with it (including {} "
                            "samples stored since this daemon started); recording goes on{}",
                            config.database, what, writer->stored(),
                            continued.empty() ? "" : " [trials: " + continued + "]"));
  }

  // An actuator with a trial recording that has fallen silent: said after input_silence_s,
  // and its trial ends "interrupted" after input_silence_stop_s.
  void CheckSilence() {
    const HealthConfig& h = config.health;
    for (auto& [id, state] : actuators) {
      if (state.trial_id == 0 || state.last_heard == std::chrono::steady_clock::time_point{})
        continue;
      const double quiet_s = std::chrono::duration<double>(loop_now - state.last_heard).count();
      if (!state.silent && quiet_s >= h.input_silence_s) {
        state.silent = true;
        RaiseHealth(id, "input_silent", 1, LatestUtime(), LatestUtime(),
                    fmt::format("no input from {} for {:.0f} s while trial {} records", id, quiet_s,
                                state.trial_id));
      }
      if (state.silent && h.input_silence_stop_s > 0.0 && quiet_s >= h.input_silence_stop_s) {
        const int64_t trial = state.trial_id;
        StopTrial(&state, state.last_sample_utime, storage::TrialState::kInterrupted);
        RaiseHealth(id, "input_silent", 1, LatestUtime(), LatestUtime(),
                    fmt::format("no input from {} for {:.0f} s: trial {} ended interrupted at "
                                "its last sample",
                                id, quiet_s, trial));
      }
    }
  }

  // ---------------------------------------------------------------------------------------
  // Loop
  // ---------------------------------------------------------------------------------------

  void PublishStatus() {
    flexid::status_t status;
    status.utime = bus::WallClockUtime();
    status.daemon_id = config.daemon_id;
    status.version = kVersion;
    status.uptime_s =
        std::chrono::duration_cast<std::chrono::seconds>(std::chrono::steady_clock::now() - started)
            .count();
    const Counters c = Snapshot();
    status.messages_received = c.messages_received;
    status.samples_accepted = c.samples_accepted;
    status.samples_stored = c.samples_stored;
    status.rejected_malformed = c.rejected_malformed;
    status.rejected_nonfinite = c.rejected_nonfinite;
    status.rejected_out_of_order = c.rejected_out_of_order;
    status.rejected_unknown_actuator = c.rejected_unknown_actuator;
    status.dropped_queue_full = c.dropped_queue_full;
    status.predictions_published = c.predictions_published;
    status.alerts_raised = c.alerts_raised;
    status.writer_queue_depth = static_cast<int32_t>(writer->queue_depth());
    int32_t recording = 0;
    for (const auto& [id, state] : actuators) recording += state.trial_id != 0;
    status.trials_recording = recording;
    status.identification_running = identifying ? 1 : 0;
    lcm.publish(channels.Status(), &status);
    if (!writer->last_error().empty())
      spdlog::error("sample writer [error: {}]", writer->last_error());
  }

  Counters Snapshot() const {
    Counters c;
    c.messages_received = counters.messages_received.load(std::memory_order_relaxed);
    c.samples_accepted = counters.samples_accepted.load(std::memory_order_relaxed);
    c.rejected_malformed = counters.rejected_malformed.load(std::memory_order_relaxed);
    c.rejected_nonfinite = counters.rejected_nonfinite.load(std::memory_order_relaxed);
    c.rejected_out_of_order = counters.rejected_out_of_order.load(std::memory_order_relaxed);
    c.rejected_unknown_actuator =
        counters.rejected_unknown_actuator.load(std::memory_order_relaxed);
    c.dropped_queue_full = counters.dropped_queue_full.load(std::memory_order_relaxed);
    c.predictions_published = counters.predictions_published.load(std::memory_order_relaxed);
    c.alerts_raised = counters.alerts_raised.load(std::memory_order_relaxed);
    c.alerts_dropped = counters.alerts_dropped.load(std::memory_order_relaxed);
    c.refused_unauthorized = counters.refused_unauthorized.load(std::memory_order_relaxed);
    c.samples_stored = writer->stored();
    return c;
  }

  void HandleSignals() {
    signalfd_siginfo info;
    while (read(signal_fd.get(), &info, sizeof info) == static_cast<ssize_t>(sizeof info)) {
      if (info.ssi_signo == SIGHUP) {
        Reload();
      } else {
        spdlog::info("stopping [signal: {}]", info.ssi_signo);
        stop = true;
      }
    }
  }

  void Reload() {
    spdlog::info("SIGHUP: reopening the log and reloading the configuration");
    if (!config_path.empty()) {
      try {
        Config next = LoadConfigFile(config_path);
        Validate(next);
        // What can change while running: alert thresholds, trial rules, log settings.
        config.alerts = next.alerts;
        config.auto_trials = next.auto_trials;
        config.trial_idle_stop_s = next.trial_idle_stop_s;
        config.log_level = next.log_level;
        config.log_file = next.log_file;
        for (auto& [id, state] : actuators)
          state.monitor = std::make_unique<ResidualMonitor>(id, config.alerts);
      } catch (const std::exception& e) {
        spdlog::error("reload refused, keeping the running configuration [error: {}]", e.what());
      }
    }
    SetUpLogging(config);
    for (const std::string& line : Describe(config)) spdlog::info("config {}", line);
  }

  // One pass of the loop. No exception leaves it: each part that fails is logged and the
  // loop goes on (handlers already catch at LCM's edge).
  void RunOnce(int timeout_ms) {
    pollfd fds[3] = {
        {lcm.getFileno(), POLLIN, 0}, {signal_fd.get(), POLLIN, 0}, {wake_fd.get(), POLLIN, 0}};
    const auto now = std::chrono::steady_clock::now();
    const int until_status = static_cast<int>(std::max<int64_t>(
        0, std::chrono::duration_cast<std::chrono::milliseconds>(next_status - now).count()));
    const int ready = poll(fds, 3, std::min(timeout_ms, until_status));
    loop_now = std::chrono::steady_clock::now();
    if (ready > 0) {
      // Drain what LCM has, bounded so that signals and the timer are served.
      if (fds[0].revents & POLLIN)
        LoopPart("bus", [this] {
          for (int i = 0; i < 10000 && lcm.handleTimeout(0) > 0; ++i) {
          }
        });
      if (fds[1].revents & POLLIN) LoopPart("signals", [this] { HandleSignals(); });
      if (fds[2].revents & POLLIN) LoopPart("results", [this] { DrainFinished(); });
    }
    if (std::chrono::steady_clock::now() >= next_status) {
      loop_now = std::chrono::steady_clock::now();
      LoopPart("health", [this] { CheckHealth(); });
      LoopPart("status", [this] { PublishStatus(); });
      next_status += std::chrono::seconds(1);
      if (next_status < std::chrono::steady_clock::now())
        next_status = std::chrono::steady_clock::now() + std::chrono::seconds(1);
    }
  }

  template <typename F>
  static void LoopPart(const char* part, F&& run) {
    Contained("loop pass", "part", part, std::forward<F>(run));
  }

  void Shutdown() {
    for (auto& [id, state] : actuators)
      if (state.trial_id != 0)
        StopTrial(&state, state.last_sample_utime != kNoTime ? state.last_sample_utime : 0,
                  storage::TrialState::kInterrupted);
    if (!writer->Flush())
      spdlog::error("samples and writes left unwritten at shutdown [error: {}]",
                    writer->last_error());
    const Counters c = Snapshot();
    spdlog::info("stopped [received: {}, accepted: {}, stored: {}, dropped: {}]",
                 c.messages_received, c.samples_accepted, c.samples_stored, c.dropped_queue_full);
  }
};

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

// Diagnosis of stored trials of one actuator (one diagnosis from all of them, oldest
// first) against the actuator's active model (or, without one or when asked, against the
// seed's structure identified on the trials), on the worker thread with its own connection
// (reads only).
IdentifyResult RunDiagnosis(const std::string& database, const std::string& actuator_id,
                            const std::vector<int64_t>& trial_ids, bool use_model,
                            int64_t max_samples, RpcContext request) {
  IdentifyResult result{std::move(request), actuator_id, std::nullopt, "", nullptr, trial_ids, {}};
  try {
    storage::Database db = storage::Database::Open(database);
    int64_t count = 0;
    for (int64_t id : trial_ids) count += db.SampleCount(id);
    if (count > max_samples)
      throw std::runtime_error(TrialWords(trial_ids) + " have " + std::to_string(count) +
                               " samples; flexidd diagnoses at most " +
                               std::to_string(max_samples) +
                               " (identification.max_diagnosis_samples)");
    std::vector<model::Recording> recordings;
    for (int64_t id : trial_ids) {
      const std::vector<storage::Sample> samples = db.Samples(id);
      recordings.push_back(RecordingOfTrial(samples, id, 200));
      result.trial_start_utimes.push_back(samples.front().utime);
    }
    std::optional<model::TsModel> trusted;
    model::DiagnoseOptions options;
    int32_t version = 0;
    if (use_model) {
      if (const auto active = db.ActiveModel(actuator_id)) {
        const model::ModelDocument doc =
            model::ParseModelJson(active->model_json, "model " + std::to_string(active->version));
        trusted = model::AsTsModel(doc);
        options.baseline_effects =
            model::EffectsOf(doc, "model " + std::to_string(active->version));
        version = active->version;
      }
    }
    result.diagnosis = model::DiagnosisToJson(model::Diagnose(recordings, trusted, options));
    if (trial_ids.size() == 1)
      result.diagnosis["trial"] = trial_ids.front();
    else
      result.diagnosis["trials"] = trial_ids;
    result.diagnosis["model_version"] = version;  // 0: identified on the trials
  } catch (const std::exception& e) {
    result.error = e.what();
    result.diagnosis = nullptr;
  }
  return result;
}

// Identification of one actuator on stored trials, on the worker thread with its own
// connection (reads only): samples -> recordings -> T-S model -> the record of a new active
// model version, which the loop hands to the writer.
IdentifyResult RunIdentification(const std::string& database, const std::string& actuator_id,
                                 std::vector<int64_t> trial_ids, const IdentificationConfig& config,
                                 RpcContext request) {
  IdentifyResult result{std::move(request), actuator_id, std::nullopt, ""};
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

}  // namespace

RpcOutcome Daemon::Impl::HandleRequest(const flexid::rpc_request_t& request) {
  using Reply = flexid::rpc_reply_t;
  if (!bus::IsValidId(request.client_id) || request.request_id.empty() ||
      request.request_id.size() > 128)
    return {Reply::kBadRequest, nullptr,
            "client_id must be [A-Za-z0-9_-]{1,64} and request_id 1-128 characters", false};
  try {
    const nlohmann::json args = ParseArguments(request.args_json);
    const std::string& method = request.method;
    auto actuator_of = [&](bool required) -> ActuatorState* {
      const std::string empty;
      const std::string id = StringArgument(args, "actuator", required ? nullptr : &empty);
      if (id.empty()) return nullptr;
      auto it = actuators.find(id);
      if (it == actuators.end()) throw ArgumentError("unknown actuator \"" + id + "\"");
      return &it->second;
    };
    if (method == "status") {
      const Counters c = Snapshot();
      return {Reply::kOk,
              {{"daemon_id", config.daemon_id},
               {"version", kVersion},
               {"database", config.database},
               {"messages_received", c.messages_received},
               {"samples_accepted", c.samples_accepted},
               {"samples_stored", c.samples_stored},
               {"rejected_malformed", c.rejected_malformed},
               {"rejected_nonfinite", c.rejected_nonfinite},
               {"rejected_out_of_order", c.rejected_out_of_order},
               {"rejected_unknown_actuator", c.rejected_unknown_actuator},
               {"dropped_queue_full", c.dropped_queue_full},
               {"predictions_published", c.predictions_published},
               {"alerts_raised", c.alerts_raised},
               {"alerts_dropped", c.alerts_dropped},
               {"writes_queued", writer->writes_queued()},
               {"requests_refused_unauthorized", c.refused_unauthorized},
               {"identification_running", identifying.load()}},
              "",
              false};
    }
    if (method == "actuators") {
      nlohmann::json list = nlohmann::json::array();
      for (const auto& [id, state] : actuators)
        list.push_back({{"id", id},
                        {"length_mm", state.info.length_mm},
                        {"width_mm", state.info.width_mm},
                        {"thickness_mm", state.info.thickness_mm},
                        {"material", state.info.material},
                        {"electrolyte", state.info.electrolyte},
                        {"concentration_M", state.info.concentration_M},
                        {"model_version", state.predictor.version},
                        {"trial", state.trial_id},
                        {"voltage_V", state.voltage_V}});
      return {Reply::kOk, list, "", false};
    }
    if (method == "trials") {
      const ActuatorState* state = actuator_of(false);
      std::optional<std::string> filter;
      if (state) filter = state->info.id;
      nlohmann::json list = nlohmann::json::array();
      for (const storage::Trial& t :
           db.Trials(filter, static_cast<int>(IntegerArgument(args, "limit", 100, 1, 10000))))
        list.push_back(storage::TrialJson(t));
      return {Reply::kOk, list, "", false};
    }
    if (method == "trial_samples") {
      const int64_t id = RequiredIntegerArgument(args, "trial", 1, INT64_MAX);
      const auto trial = db.FindTrial(id);
      if (!trial) return {Reply::kNotFound, nullptr, "no trial " + std::to_string(id), false};
      // Pages by offset, or (cheaper for long trials) by the last utime of the previous page.
      const int64_t offset = IntegerArgument(args, "offset", 0, 0, INT64_MAX);
      const int64_t after = IntegerArgument(args, "after_utime", INT64_MIN, INT64_MIN, INT64_MAX);
      const int64_t limit = IntegerArgument(args, "limit", 5000, 1, 20000);
      const std::vector<storage::Sample> page = db.SamplesPage(id, after, offset, limit);
      return {Reply::kOk, storage::SamplesPageJson(*trial, offset, page), "", false};
    }
    if (method == "models") {
      ActuatorState* state = actuator_of(true);
      nlohmann::json list = nlohmann::json::array();
      for (const storage::ModelRecord& m : db.Models(state->info.id))
        list.push_back(storage::ModelSummaryJson(m));
      return {Reply::kOk, list, "", false};
    }
    if (method == "model") {
      ActuatorState* state = actuator_of(true);
      const auto version = static_cast<int32_t>(IntegerArgument(args, "version", 0, 0, INT32_MAX));
      const auto m =
          version == 0 ? db.ActiveModel(state->info.id) : db.FindModel(state->info.id, version);
      if (!m) return {Reply::kNotFound, nullptr, "no such model of " + state->info.id, false};
      nlohmann::json out = storage::ModelSummaryJson(*m);
      out["model"] = nlohmann::json::parse(m->model_json);
      return {Reply::kOk, out, "", false};
    }
    if (method == "model_activate") {
      ActuatorState* state = actuator_of(true);
      const auto version =
          static_cast<int32_t>(RequiredIntegerArgument(args, "version", 1, INT32_MAX));
      const auto record = db.FindModel(state->info.id, version);
      if (!record) return {Reply::kNotFound, nullptr, "no such model version", false};
      // Swapped in once the writer has made it the active one.
      return ReplyWhenWritten(
          Store(storage::ModelActivation{state->info.id, version}), request,
          {Reply::kOk, {{"actuator", state->info.id}, {"version", version}}, ""},
          [this, actuator = state->info.id, record = *record] {
            LoadModel(&actuators.at(actuator), record);
          });
    }
    if (method == "alerts") {
      const ActuatorState* state = actuator_of(false);
      std::optional<std::string> filter;
      if (state) filter = state->info.id;
      nlohmann::json list = nlohmann::json::array();
      for (const storage::AlertRecord& a :
           db.Alerts(filter, IntegerArgument(args, "since_utime", 0, 0, INT64_MAX),
                     static_cast<int>(IntegerArgument(args, "limit", 100, 1, 10000))))
        list.push_back(storage::AlertJson(a));
      return {Reply::kOk, list, "", false};
    }
    if (method == "trial_start" || method == "trial_stop") {
      ActuatorState* state = actuator_of(true);
      const int64_t now =
          state->voltage_utime != kNoTime ? state->voltage_utime : bus::WallClockUtime();
      if (method == "trial_start") {
        const std::string fallback = "manual";
        const std::string protocol = StringArgument(args, "protocol", &fallback);
        if (state->trial_id != 0) StopTrial(state, now, storage::TrialState::kComplete);
        const uint64_t ticket = StartTrial(state, protocol, now, false);
        return ReplyWhenWritten(
            ticket, request,
            {Reply::kOk, {{"actuator", state->info.id}, {"trial", state->trial_id}}, ""});
      }
      if (state->trial_id == 0)
        return {Reply::kNotFound, nullptr, state->info.id + " has no trial recording", false};
      // Answered once the end is written; the trial's samples are committed within one
      // commit interval, under its id (waiting for them would block the loop).
      const int64_t id = state->trial_id;
      const uint64_t ticket = StopTrial(state, now, storage::TrialState::kComplete);
      return ReplyWhenWritten(ticket, request,
                              {Reply::kOk, {{"actuator", state->info.id}, {"trial", id}}, ""});
    }
    if (method == "identify") {
      ActuatorState* state = actuator_of(true);
      std::vector<int64_t> trials;
      if (args.contains("trials")) {
        for (int64_t id : TrialIdsArgument(args, "trials", 100)) {
          const auto trial = db.FindTrial(id);
          if (!trial || trial->actuator_id != state->info.id)
            return {Reply::kNotFound, nullptr,
                    "no trial " + std::to_string(id) + " of " + state->info.id, false};
          trials.push_back(trial->id);
        }
      } else {
        const auto latest =
            IntegerArgument(args, "latest", config.identification.latest_trials, 1, 100);
        // Only trials long enough to identify from (model::MinimumSamplesToIdentify, at the
        // trial's own sample period).
        const IdentificationConfig& ic = config.identification;
        auto long_enough = [&ic](const storage::Trial& t) {
          if (t.samples < 2 || t.end_utime <= t.start_utime) return false;
          const double dt_s = 1e-6 * static_cast<double>(t.end_utime - t.start_utime) /
                              static_cast<double>(t.samples - 1);
          return static_cast<size_t>(t.samples) >=
                 model::MinimumSamplesToIdentify(ic.zeros + ic.poles + 2, ic.max_delay_s, dt_s);
        };
        for (const storage::Trial& t : db.Trials(state->info.id, 1000)) {
          if (t.state == storage::TrialState::kRecording || !long_enough(t)) continue;
          trials.push_back(t.id);
          if (static_cast<int64_t>(trials.size()) == latest) break;
        }
        if (trials.empty())
          return {Reply::kNotFound, nullptr,
                  state->info.id + " has no finished trial long enough to identify from", false};
      }
      storage::SampleWriter* samples = writer.get();  // flushed on the worker: Flush() blocks
      const std::string database = config.database, id = state->info.id;
      const IdentificationConfig options = config.identification;
      const RpcContext context{request.request_id, request.client_id};
      if (!Submit([database, id, trials, options, context, samples] {
            if (!samples->Flush())  // the worker reads what is committed
              return IdentifyResult{context, id, std::nullopt,
                                    "cannot commit samples: " + samples->last_error()};
            return RunIdentification(database, id, trials, options, context);
          }))
        return {Reply::kBusy, nullptr,
                "an identification is already running; try again when it ends", false};
      spdlog::info("identification started [actuator: {}, trials: {}]", id,
                   nlohmann::json(trials).dump());
      return {Reply::kOk, nullptr, "", true};
    }
    if (method == "diagnose") {
      ActuatorState* state = actuator_of(true);
      // "trial": one; "trials": several, in the order given; "recent": the latest K
      // finished ones, oldest first; none: the latest finished one.
      if (args.contains("trial") + args.contains("trials") + args.contains("recent") > 1)
        throw ArgumentError("give one of \"trial\", \"trials\" and \"recent\"");
      std::vector<int64_t> trial_ids;
      if (args.contains("trial"))
        trial_ids = {
            RequiredIntegerArgument(args, "trial", 1, std::numeric_limits<int64_t>::max())};
      else if (args.contains("trials"))
        trial_ids = TrialIdsArgument(args, "trials", model::kMaxDiagnosedRecordings);
      for (int64_t trial_id : trial_ids) {
        const auto trial = db.FindTrial(trial_id);
        if (!trial || trial->actuator_id != state->info.id)
          return {Reply::kNotFound, nullptr,
                  "no trial " + std::to_string(trial_id) + " of " + state->info.id, false};
      }
      if (trial_ids.empty()) {
        const int64_t recent =
            IntegerArgument(args, "recent", 1, 1, model::kMaxDiagnosedRecordings);
        for (const storage::Trial& t : db.Trials(state->info.id, 1000))
          if (t.state != storage::TrialState::kRecording && t.samples >= 200 &&
              static_cast<int64_t>(trial_ids.size()) < recent)
            trial_ids.insert(trial_ids.begin(), t.id);
        if (trial_ids.empty())
          return {Reply::kNotFound, nullptr, state->info.id + " has no finished trial to diagnose",
                  false};
      }
      bool use_model = true;
      if (const auto it = args.find("use_model"); it != args.end()) {
        if (!it->is_boolean()) throw ArgumentError("argument \"use_model\" must be true or false");
        use_model = it->get<bool>();
      }
      storage::SampleWriter* samples = writer.get();
      const std::string database = config.database, id = state->info.id;
      const RpcContext context{request.request_id, request.client_id};
      const int64_t max_samples = config.identification.max_diagnosis_samples;
      if (!Submit([database, id, trial_ids, use_model, max_samples, context, samples] {
            if (!samples->Flush())
              return IdentifyResult{context,
                                    id,
                                    std::nullopt,
                                    "cannot commit samples: " + samples->last_error(),
                                    nullptr,
                                    trial_ids,
                                    {}};
            return RunDiagnosis(database, id, trial_ids, use_model, max_samples, context);
          }))
        return {Reply::kBusy, nullptr,
                "an identification or diagnosis is already running; try again when it ends", false};
      spdlog::info("diagnosis started [actuator: {}, trials: {}]", id,
                   nlohmann::json(trial_ids).dump());
      return {Reply::kOk, nullptr, "", true};
    }
    return {Reply::kBadRequest, nullptr, "unknown method \"" + method + "\"", false};
  } catch (const ArgumentError& e) {
    return {Reply::kBadRequest, nullptr, e.what(), false};
  } catch (const std::exception& e) {
    return {Reply::kFailed, nullptr, e.what(), false};
  }
}

Daemon::Daemon(Config config, std::string config_path)
    : impl_(std::make_unique<Impl>(std::move(config), std::move(config_path))) {
  for (const std::string& line : Describe(impl_->config)) spdlog::info("config {}", line);
}

Daemon::~Daemon() = default;

int Daemon::Run() {
  spdlog::info("flexidd {} running [daemon_id: {}]", kVersion, impl_->config.daemon_id);
  while (!impl_->stop) impl_->RunOnce(1000);
  impl_->Shutdown();
  return 0;
}

void Daemon::RunOnce(int timeout_ms) { impl_->RunOnce(timeout_ms); }
void Daemon::Stop() { impl_->stop = true; }
Counters Daemon::counters() const { return impl_->Snapshot(); }

void BlockHandledSignals() {
  const sigset_t signals = HandledSignals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
}

void SetUpLogging(const Config& config) {
  std::vector<spdlog::sink_ptr> sinks = {std::make_shared<spdlog::sinks::stderr_color_sink_mt>()};
  if (!config.log_file.empty()) {
    std::error_code ignored;
    const auto parent = std::filesystem::path(config.log_file).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent, ignored);
    try {
      sinks.push_back(
          std::make_shared<spdlog::sinks::rotating_file_sink_mt>(config.log_file, 5 << 20, 3));
    } catch (const spdlog::spdlog_ex& e) {
      std::fprintf(stderr, "flexidd: cannot open log file %s: %s\n", config.log_file.c_str(),
                   e.what());
    }
  }
  auto logger = std::make_shared<spdlog::logger>("flexidd", sinks.begin(), sinks.end());
  logger->set_level(spdlog::level::from_str(config.log_level));
  logger->flush_on(spdlog::level::warn);
  spdlog::set_default_logger(logger);
}

}  // namespace flexid::daemon
