#include "daemon/health.h"

#include <sys/stat.h>

#include <climits>
#include <flexid/alert_t.hpp>

#include "bus/clock.h"
#include "daemon/service.h"

namespace flexid::daemon {

std::string StorageProblem(const std::string& error) {
  auto has = [&](const char* text) { return error.find(text) != std::string::npos; };
  if (has("disk is full") || has("No space left")) return "disk full";
  if (has("Read-only file system") || has("readonly") || has("read-only"))
    return "file system read-only";
  if (has("locked") || has("busy")) return "database locked";
  // A write refused by the operating system (EIO, EROFS of a file system remounted
  // read-only): SQLite says "disk I/O error" and rarely keeps the errno.
  if (has("I/O error")) return "I/O error";
  return "error";
}

std::optional<FileIdentity> IdentityOf(const std::string& path) {
  struct stat info {};
  if (stat(path.c_str(), &info) != 0) return std::nullopt;
  return FileIdentity{info.st_dev, info.st_ino};
}

ClockJumpDetector::Verdict ClockJumpDetector::Check(int64_t last_utime, int64_t utime,
                                                    bool trial_open) {
  if (last_utime == INT64_MIN) {
    candidates_ = 0;
    return Verdict::kAccept;
  }
  // Differences in unsigned arithmetic: utimes from a hostile sender may be anywhere.
  const bool back = utime <= last_utime;
  const auto distance = back ? static_cast<uint64_t>(last_utime) - static_cast<uint64_t>(utime)
                             : static_cast<uint64_t>(utime) - static_cast<uint64_t>(last_utime);
  const bool far_back = back && distance >= static_cast<uint64_t>(back_us_);
  const bool far_forward = !back && trial_open && distance > static_cast<uint64_t>(forward_us_);
  if (!back && !far_forward) {
    candidates_ = 0;
    return Verdict::kAccept;
  }
  if (!far_back && !far_forward) {  // a little back: a late or repeated message
    candidates_ = 0;
    return Verdict::kReject;
  }
  // On the new time base the messages must be in order among themselves.
  if (candidates_ > 0 && utime > last_candidate_utime_)
    ++candidates_;
  else
    candidates_ = 1;
  last_candidate_utime_ = utime;
  if (candidates_ < confirm_) return Verdict::kReject;
  candidates_ = 0;
  jump_us_ = back ? -static_cast<int64_t>(distance) : static_cast<int64_t>(distance);
  return Verdict::kJumped;
}

// ---------------------------------------------------------------------------------------
// Health: faults other than bad messages (the documented behaviour is in
// tests/daemon_fault_matrix_test.cc). Checked once a second by the loop, and for clock
// jumps on every sample. What happened is logged and published as an alert on FLEXID/ALERT
// (actuator_id empty when it concerns the daemon itself).
// ---------------------------------------------------------------------------------------

// The latest sample time the daemon has seen from any actuator since it started, or
// kNoTime before any sample.
int64_t Service::LatestMessageUtime() const {
  int64_t latest = kNoTime;
  for (const auto& [id, state] : actuators)
    latest = std::max({latest, state.voltage_utime, state.deflection_utime});
  return latest;
}

// The latest message time the daemon has seen (health alerts are stamped with it), or
// the wall clock before any message.
int64_t Service::LatestUtime() const {
  const int64_t latest = LatestMessageUtime();
  return latest != kNoTime ? latest : bus::WallClockUtime();
}

// Publishes, counts and logs a health alert, and queues it for the writer (stored once
// the database takes writes).
void Service::RaiseHealth(const std::string& actuator_id, const std::string& kind, int severity,
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
void Service::Heard(ActuatorState* state) {
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
bool Service::InTimeOrder(ActuatorState* state, int64_t utime, bool voltage) {
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
void Service::OnClockJump(ActuatorState* state, int64_t jump_us, int64_t utime) {
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
  std::string text =
      fmt::format("source clock of {} jumped {} by {:.1f} s", state->info.id,
                  jump_us < 0 ? "back" : "forward", std::abs(static_cast<double>(jump_us)) * 1e-6);
  if (old_trial != 0) {
    text += fmt::format("; trial {} ended interrupted at its last sample", old_trial);
    if (!automatic) {
      StartTrial(state, protocol, utime, false);
      text += fmt::format(", trial {} continues it on the new time base", state->trial_id);
    }
  }
  RaiseHealth(state->info.id, "clock_jump", 1, previous, utime, text);
}

void Service::CheckHealth() {
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
void Service::CheckStorage() {
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
    const double failed_s = std::chrono::duration<double>(loop_now - storage_failing_since).count();
    RaiseHealth("", "storage_recovered", 0, utime, utime,
                fmt::format("storage recovered after {:.0f} s: the samples held meanwhile are "
                            "committed; {} samples were dropped (writer queue full)",
                            failed_s, dropped - drops_when_failing));
  }
}

// The database file deleted or replaced under the daemon: SQLite would go on writing to
// the old (unlinked) file, and every new sample would vanish with it. A new database is
// opened at the path; the trials recording go on there as new trials.
void Service::CheckDatabaseFile() {
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
      Store(storage::TrialStart{state.trial_id, id, state.trial_protocol, state.trial_start_utime});
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
void Service::CheckSilence() {
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

}  // namespace flexid::daemon
