#include "daemon/event_loop.h"

#include <poll.h>
#include <pthread.h>
#include <spdlog/spdlog.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include <flexid/rpc_reply_t.hpp>
#include <flexid/status_t.hpp>

#include "bus/clock.h"
#include "daemon/service.h"
#include "flexid/version.h"

namespace flexid::daemon {

sigset_t HandledSignals() {
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  return signals;
}

void BlockHandledSignals() {
  const sigset_t signals = HandledSignals();
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
}

// Makes the loop's next poll return for DrainFinished (any thread).
void Service::Wake() {
  const uint64_t one = 1;
  if (write(wake_fd.get(), &one, sizeof one) < 0) spdlog::error("cannot wake the loop");
}

// Takes what the worker and the writer have finished. Each result is handled on its own:
// one that fails is logged (and its request answered) and the others go on.
void Service::DrainFinished() {
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
  for (JobResult& result : worker->TakeFinished()) {
    try {
      OnWorkerResult(result);
    } catch (const std::exception& e) {
      spdlog::error("worker result failed [actuator: {}, error: {}]", OriginOf(result).actuator_id,
                    e.what());
      Reply(OriginOf(result).request, {flexid::rpc_reply_t::kFailed, nullptr, e.what()});
    }
  }
}

void Service::OnWritten(const storage::WriteOutcome& outcome) {
  last_done_ticket = std::max(last_done_ticket, outcome.ticket);
  if (!outcome.error.empty())
    spdlog::error("write refused by the database, not retried [error: {}]", outcome.error);
  auto [first, last] = on_written.equal_range(outcome.ticket);
  std::vector<std::function<void(const storage::WriteOutcome&)>> then;
  for (auto it = first; it != last; ++it) then.push_back(std::move(it->second));
  on_written.erase(first, last);
  for (const auto& run : then) run(outcome);
}

void Service::PublishStatus() {
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
  status.identification_running = worker->busy() ? 1 : 0;
  lcm.publish(channels.Status(), &status);
  if (!writer->last_error().empty())
    spdlog::error("sample writer [error: {}]", writer->last_error());
}

Counters Service::Snapshot() const {
  Counters c;
  c.messages_received = counters.messages_received.load(std::memory_order_relaxed);
  c.samples_accepted = counters.samples_accepted.load(std::memory_order_relaxed);
  c.rejected_malformed = counters.rejected_malformed.load(std::memory_order_relaxed);
  c.rejected_nonfinite = counters.rejected_nonfinite.load(std::memory_order_relaxed);
  c.rejected_out_of_order = counters.rejected_out_of_order.load(std::memory_order_relaxed);
  c.rejected_unknown_actuator = counters.rejected_unknown_actuator.load(std::memory_order_relaxed);
  c.dropped_queue_full = counters.dropped_queue_full.load(std::memory_order_relaxed);
  c.predictions_published = counters.predictions_published.load(std::memory_order_relaxed);
  c.alerts_raised = counters.alerts_raised.load(std::memory_order_relaxed);
  c.alerts_dropped = counters.alerts_dropped.load(std::memory_order_relaxed);
  c.refused_unauthorized = counters.refused_unauthorized.load(std::memory_order_relaxed);
  c.samples_not_owned = counters.samples_not_owned.load(std::memory_order_relaxed);
  c.samples_stored = writer->stored();
  return c;
}

void Service::HandleSignals() {
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

void Service::Reload() {
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
void Service::RunOnce(int timeout_ms) {
  pollfd fds[3] = {
      {lcm.getFileno(), POLLIN, 0}, {signal_fd.get(), POLLIN, 0}, {wake_fd.get(), POLLIN, 0}};
  const auto now = std::chrono::steady_clock::now();
  // The next status, or the next ownership decision if sooner.
  auto next_timer = next_status;
  if (const auto decide = ownership.NextDeadline()) next_timer = std::min(next_timer, *decide);
  const int until_timer = static_cast<int>(
      std::max<int64_t>(0, std::chrono::ceil<std::chrono::milliseconds>(next_timer - now).count()));
  const int ready = poll(fds, 3, std::min(timeout_ms, until_timer));
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
  LoopPart("ownership", [this] { DecideOwnership(false); });
  if (std::chrono::steady_clock::now() >= next_status) {
    loop_now = std::chrono::steady_clock::now();
    LoopPart("health", [this] { CheckHealth(); });
    LoopPart("ownership", [this] { DecideOwnership(true); });
    LoopPart("status", [this] {
      PublishStatus();
      Announce();
    });
    next_status += std::chrono::seconds(1);
    if (next_status < std::chrono::steady_clock::now())
      next_status = std::chrono::steady_clock::now() + std::chrono::seconds(1);
  }
}

void Service::Shutdown() {
  for (auto& [id, state] : actuators)
    if (state.trial_id != 0)
      StopTrial(&state, state.last_sample_utime != kNoTime ? state.last_sample_utime : 0,
                storage::TrialState::kInterrupted);
  if (!writer->Flush())
    spdlog::error("samples and writes left unwritten at shutdown [error: {}]",
                  writer->last_error());
  const Counters c = Snapshot();
  spdlog::info("stopped [received: {}, accepted: {}, stored: {}, dropped: {}]", c.messages_received,
               c.samples_accepted, c.samples_stored, c.dropped_queue_full);
}

}  // namespace flexid::daemon
