#include "daemon/daemon.h"

#include <malloc.h>
#include <pthread.h>
#include <sched.h>
#include <spdlog/sinks/rotating_file_sink.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/signalfd.h>

#include <filesystem>

#include "bus/lcm_url.h"
#include "daemon/event_loop.h"
#include "daemon/service.h"
#include "flexid/version.h"

namespace flexid::daemon {
namespace {

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

OwnershipOptions OwnershipOptionsOf(const Config& config) {
  OwnershipOptions options;
  options.wait = std::chrono::milliseconds(static_cast<int64_t>(config.ownership_wait_s * 1000.0));
  options.accept_unknown = config.accept_unknown_actuators;
  return options;
}

}  // namespace

void KeepFreedMemory() {
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 256 << 20);
}

Service::Service(Config c, std::string path)
    : config(std::move(c)),
      channels(config.channel_prefix),
      config_path(std::move(path)),
      db(storage::Database::Open(config.database)),
      verifier(MakeVerifier(config)),
      lcm(bus::WithReceiveBuffer(config.lcm_url, kReceiveBufferBytes)),
      ownership(config.daemon_id, auth::RandomNonce(), OwnershipOptionsOf(config), started) {
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
  stored_latest_utime = db.LatestTrialUtime().value_or(kNoTime);
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
  // Configured actuators are this daemon's; those the file knows from earlier runs are
  // answered for, and adopted again when their messages come (daemon/ownership.h).
  for (const storage::Actuator& a : config.actuators) {
    Store(a);
    AddActuator(a);
    ownership.Configure(a.id);
    actuators.at(a.id).owned = true;
  }
  for (const storage::Actuator& a : db.Actuators())
    if (!actuators.count(a.id)) AddActuator(a);

  Subscribe();
  // The identification worker runs on the background CPUs with pin_threads, else on the
  // last CPU (with two or more): a fit then never holds a CPU that the loop and LCM's
  // receive thread wake on, except that one, where it yields to them (SCHED_IDLE).
  // Several daemons on one host share that CPU for their fits; their live threads are
  // not pinned. Measured in README "Benchmarks" (daemon_load and the soak).
  std::vector<int> worker_cpus = background_cpus;
  if (worker_cpus.empty() && cpus >= 2) worker_cpus = {cpus - 1};
  worker = std::make_unique<Worker>(worker_cpus, [this] { Wake(); });
}

Service::~Service() {
  worker.reset();  // its job may be flushing the writer
}

// Queues a write for the writer thread; returns its ticket (0: an alert refused).
uint64_t Service::Store(storage::Write write) {
  const uint64_t ticket = writer->Submit(std::move(write));
  last_ticket = std::max(last_ticket, ticket);
  return ticket;
}

void Service::AddActuator(const storage::Actuator& info) {
  ActuatorState& state = actuators[info.id];
  state.info = info;
  state.monitor = std::make_unique<ResidualMonitor>(info.id, config.alerts);
  const HealthConfig& h = config.health;
  state.voltage_clock = state.deflection_clock =
      ClockJumpDetector(static_cast<int64_t>(h.clock_jump_back_s * 1e6),
                        static_cast<int64_t>(h.clock_jump_forward_s * 1e6), h.clock_jump_messages);
  if (const auto record = db.ActiveModel(info.id)) LoadModel(&state, *record);
}

Daemon::Daemon(Config config, std::string config_path)
    : impl_(std::make_unique<Service>(std::move(config), std::move(config_path))) {
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
