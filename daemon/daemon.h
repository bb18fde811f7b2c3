// flexidd: the lab service. One event loop owns LCM's file descriptor, a signal
// descriptor, a wake-up descriptor for the workers and a 1 s timer; handlers never block
// on disk or on identification:
//
//   FLEXID/<id>/VOLTAGE, /DEFLECTION --> validate, count --> pair each deflection sample
//        with the voltage in force --> SampleWriter (bounded queues, own thread, commits at
//        least every commit_interval) --> SQLite
//                                     --> T-S prediction (StreamingSimulator, message time)
//                                          --> FLEXID/<id>/PREDICTION
//                                          --> ResidualMonitor --> FLEXID/ALERT (+ writer)
//   FLEXID/RPC/REQUEST --> signature check for methods that change data (message_auth.h)
//        --> methods (rpc_methods.h); "identify" runs on the identification worker, the writer
//        stores a new model version, then the loop hot-swaps the predictor and replies.
//   FLEXID/STATUS <-- counters, once a second.
//   FLEXID/OWNERSHIP <--> the actuators this daemon owns and the daemons it heard, once a
//        second and when they change (several daemons on one bus: daemon/ownership.h).
//
// The daemon works in message time (utime), never wall-clock time (one exception: the
// replay window of signed requests, lcmtypes/message_auth.h), so an accelerated rig
// or a replayed log behaves like a real-time run.
//
// One thread writes: the SampleWriter's. The loop hands it samples, trial starts and ends
// (trial ids are handed out on the loop, from the highest in the file at start-up),
// actuators, alerts, models and model activations, and never waits for the disk: a
// locked or full database delays the rows, not predictions. A write that fails stays
// queued and is retried, and the failure is a "storage_failing" health alert. A request
// that changes data is answered once its write is committed; one that reads the file
// first waits for the writes queued before it (unless storage is failing). The loop's own
// connection only reads, except for marking an earlier run's trials interrupted at
// start-up. No exception leaves a pass of the loop (RunOnce).
#pragma once

#include <cstdint>
#include <memory>
#include <string>

#include "daemon/config.h"

namespace flexid::daemon {

struct Counters {
  int64_t messages_received = 0;
  int64_t samples_accepted = 0;
  int64_t rejected_malformed = 0;
  int64_t rejected_nonfinite = 0;
  int64_t rejected_out_of_order = 0;
  int64_t rejected_unknown_actuator = 0;
  int64_t dropped_queue_full = 0;
  int64_t predictions_published = 0;
  int64_t alerts_raised = 0;
  // Alerts published but not stored: the writer held as many as it may (storage failing
  // for long; SampleWriterOptions::alert_capacity).
  int64_t alerts_dropped = 0;
  int64_t samples_stored = 0;  // acknowledged: committed
  // RPC requests and trial control that would change data, refused as unsigned, badly
  // signed, stale or replayed (README "Security").
  int64_t refused_unauthorized = 0;
  // Samples and trial control of actuators another daemon owns (daemon/ownership.h):
  // seen, not recorded.
  int64_t samples_not_owned = 0;
};

struct Service;

class Daemon {
 public:
  // Opens the database (marking trials left 'recording' by a crash as interrupted), loads
  // the active models, joins the bus. Throws ConfigError, storage::StorageError or
  // std::runtime_error (the bus) with one line saying what failed.
  explicit Daemon(Config config, std::string config_path = "");
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  // Runs until Stop(), SIGTERM or SIGINT (SIGHUP reloads the configuration file and
  // reopens the log). Flushes every queued sample before returning. Returns 0.
  int Run();
  // One pass of the loop: handles whatever is ready within timeout_ms. Never throws.
  void RunOnce(int timeout_ms);
  void Stop();

  Counters counters() const;

 private:
  std::unique_ptr<Service> impl_;  // the state and the parts (daemon/service.h)
};

// Blocks SIGTERM, SIGINT and SIGHUP in the calling thread (and so in every thread it
// starts afterwards): the loop takes them through signalfd. Call it first in main(), so
// that a signal during start-up waits for the loop.
void BlockHandledSignals();

// Memory freed by identification and diagnosis stays with the process for the next job
// instead of going back to the kernel. Otherwise glibc maps each large block afresh and
// unmaps it when freed, and trims its heaps: a fit then takes about 12,000 page faults a
// second, and every unmap interrupts the other threads of the process (the loop and LCM's
// receive thread) to flush their address translations. Kept: up to 32 MiB per block on
// the heap (larger ones are still mapped), up to 256 MiB free at the top of a heap. It
// sets glibc's thresholds for the whole process, so main() calls it (flexidd, and
// bench/daemon_load, which measures the daemon as flexidd runs it).
void KeepFreedMemory();

// Sets up spdlog (console + rotating file) once per process; safe to call again (SIGHUP).
void SetUpLogging(const Config& config);

}  // namespace flexid::daemon
