// Replaying an import plan to flexidd over the bus, paced by what flexidd has stored
// (trials_replay.h).
#include "clients/cli/trials_replay.h"

#include <algorithm>
#include <chrono>
#include <cstdint>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>
#include <vector>

#include "bus/sample_publisher.h"
#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "clients/cli/trial_import.h"
#include "clients/cli/trials_common.h"
#include "storage/database.h"

namespace flexid::cli::trials {
namespace {

constexpr int64_t kReplayChunk = 2000;   // deflections published at once
constexpr int64_t kReplayWindow = 4000;  // deflections published but not yet stored
constexpr double kReplayStall_s = 10.0;  // no progress this long: flexidd is not storing
constexpr double kControlTimeout_s = 10.0;

// Replays one actuator's messages (bus/sample_publisher.h, as flexid-rig publishes them)
// and counts those LCM could not send. Trial control is signed, so the key is read first,
// before the bus is joined and anything is sent.
class Publisher {
 public:
  // `daemon`: the one that will record the actuator, whose key signs the trial control.
  Publisher(const std::string& actuator, const std::string& daemon)
      : key_(SigningKey(daemon)), lcm_(LcmUrl()), publisher_(lcm_, BusChannels(), actuator, &key_) {
    if (!lcm_.good()) throw OperationError("cannot join the LCM bus at " + LcmUrl());
  }
  void Sample(const BusSample& m) {
    const bool sent = m.is_voltage ? publisher_.PublishVoltage(m.utime, m.value)
                                   : publisher_.PublishDeflection(m.utime, m.value);
    if (!sent) ++failed_;
  }
  // utime is the recording's message time.
  void Control(int64_t utime, bool start, const std::string& protocol) {
    if (!publisher_.PublishTrialControl(
            utime, start ? bus::TrialAction::kStart : bus::TrialAction::kStop, protocol))
      ++failed_;
  }
  int64_t failed() const { return failed_; }

 private:
  const auth::Key& key_;
  lcm::LCM lcm_;
  bus::SamplePublisher publisher_;
  int64_t failed_ = 0;
};

// The trial flexidd is recording for the actuator (0: none); *known says whether flexidd
// lists the actuator at all.
int64_t RecordingTrial(const std::string& actuator, const std::string& daemon,
                       bool* known = nullptr) {
  for (const nlohmann::json& a : Query("actuators", nlohmann::json::object(), daemon))
    if (a.value("id", "") == actuator) {
      if (known) *known = true;
      return a.value("trial", int64_t{0});
    }
  if (known) *known = false;
  return 0;
}

// The stored trial as flexidd reports it (its sample count is what it has committed).
storage::Trial DaemonTrial(int64_t id, const std::string& daemon) {
  return TrialFromJson(Query("trial_samples", {{"trial", id}, {"limit", 1}}, daemon).at("trial"));
}

constexpr const char* kRejectionCounters[] = {"rejected_out_of_order", "rejected_malformed",
                                              "rejected_nonfinite", "rejected_unknown_actuator",
                                              "dropped_queue_full"};

std::string CounterDeltas(const nlohmann::json& before, const nlohmann::json& after) {
  std::string out;
  for (const char* name : kRejectionCounters) {
    const int64_t delta = after.value(name, int64_t{0}) - before.value(name, int64_t{0});
    if (delta > 0)
      out += std::string(out.empty() ? "" : ", ") + name + " +" + std::to_string(delta);
  }
  return out.empty() ? "no rejections counted" : out;
}

class Replay {
 public:
  // The daemon that records the actuator (its owner; with several daemons and no owner,
  // name one with --daemon) is the one whose storing is watched.
  Replay(const ImportPlan& plan, Progress* progress)
      : plan_(plan),
        progress_(progress),
        daemon_(TargetDaemon("trials import", plan.actuator)),
        publisher_(plan.actuator, daemon_) {}

  std::vector<StoredImport> Run() {
    bool known = false;
    const int64_t busy = RecordingTrial(plan_.actuator, daemon_, &known);
    if (busy != 0)
      throw UsageError(plan_.actuator + " is recording trial " + std::to_string(busy) +
                       "; stop it first (flexid trials stop --actuator " + plan_.actuator + ")");
    if (known) CheckAfterStoredTimes();
    status_before_ = Query("status", nlohmann::json::object(), daemon_);
    std::vector<StoredImport> out;
    for (const ImportTrial& trial : plan_.trials) out.push_back(PlayTrial(trial));
    return out;
  }

 private:
  // flexidd takes a stream's messages in time order only: older ones are rejected, and a
  // run of them reads as the source's clock jumping back (the trial then ends interrupted).
  // So the file's times must come after everything stored for the actuator.
  void CheckAfterStoredTimes() {
    int64_t latest = std::numeric_limits<int64_t>::min();
    for (const nlohmann::json& t :
         Query("trials", {{"actuator", plan_.actuator}, {"limit", 10000}}, daemon_))
      latest = std::max({latest, t.value("start_utime", latest), t.value("end_utime", latest)});
    int64_t first = plan_.trials.front().start_utime;
    if (!plan_.trials.front().messages.empty())
      first = std::min(first, plan_.trials.front().messages.front().utime);
    if (first <= latest)
      throw UsageError(plan_.source + ": its times (from utime " + std::to_string(first) +
                       ") are not after " + plan_.actuator + "'s latest stored time (utime " +
                       std::to_string(latest) +
                       "), so flexidd would not take them in order; shift them with "
                       "--start-utime U (e.g. a time after " +
                       std::to_string(latest) + ")");
  }

  StoredImport PlayTrial(const ImportTrial& trial) {
    publisher_.Control(trial.start_utime, true, trial.protocol);
    const int64_t id = AwaitNewTrial(trial);
    // The voltage in force at the first deflection must be the file's, not whatever flexidd
    // last saw for this actuator.
    std::vector<BusSample> lead;
    if (!trial.messages.empty() && !trial.messages.front().is_voltage) {
      int64_t first_voltage = trial.messages.front().utime;
      for (const BusSample& m : trial.messages)
        if (m.is_voltage) {
          first_voltage = std::min(first_voltage, m.utime);
          break;
        }
      lead.push_back({first_voltage - 1, trial.initial_voltage_V, true});
    }
    for (const BusSample& m : lead) publisher_.Sample(m);
    int64_t sent = 0;
    for (size_t k = 0; k < trial.messages.size();) {
      int64_t in_chunk = 0;
      for (; k < trial.messages.size() && in_chunk < kReplayChunk; ++k) {
        publisher_.Sample(trial.messages[k]);
        in_chunk += trial.messages[k].is_voltage ? 0 : 1;
      }
      sent += in_chunk;
      AwaitStored(id, trial, sent - kReplayWindow);
    }
    publisher_.Control(trial.end_utime, false, trial.protocol);
    const storage::Trial stored = AwaitStored(id, trial, trial.deflections, true);
    // flexidd ends the trial on the stop message; its state says it took it.
    const auto end = Clock::now() + Seconds(kControlTimeout_s);
    storage::Trial final_state = stored;
    while (final_state.state == storage::TrialState::kRecording && Clock::now() < end) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      final_state = DaemonTrial(id, daemon_);
    }
    if (final_state.state == storage::TrialState::kRecording)
      throw OperationError("flexidd did not end trial " + std::to_string(id) + " within " +
                           FormatNumber(kControlTimeout_s) + " s of the stop message");
    if (publisher_.failed() > 0)
      throw OperationError(std::to_string(publisher_.failed()) + " messages could not be sent on " +
                           LcmUrl());
    done_ += trial.deflections;
    return {id, final_state.samples};
  }

  using Clock = std::chrono::steady_clock;
  static Clock::duration Seconds(double s) {
    return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(s));
  }

  int64_t AwaitNewTrial(const ImportTrial& trial) {
    const auto end = Clock::now() + Seconds(kControlTimeout_s);
    while (Clock::now() < end) {
      CheckStop(0, trial);
      if (const int64_t id = RecordingTrial(plan_.actuator, daemon_); id > last_trial_) {
        last_trial_ = id;
        return id;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    throw OperationError("flexidd did not start a trial for " + plan_.actuator + " within " +
                         FormatNumber(kControlTimeout_s) +
                         " s of the trial-control message (does it accept this actuator?)");
  }

  // Waits until flexidd holds at least `target` samples of the trial. Fails when its count
  // stops growing for kReplayStall_s, or sooner (after 1 s without progress) when flexidd
  // has counted at least as many rejected messages as samples are missing: those will never
  // be stored (e.g. out of order: the actuator already had newer messages).
  storage::Trial AwaitStored(int64_t id, const ImportTrial& trial, int64_t target,
                             bool stop_sent = false) {
    storage::Trial t = DaemonTrial(id, daemon_);
    int64_t seen = t.samples;
    auto last_progress = Clock::now();
    while (t.samples < target) {
      CheckStop(id, trial);
      const double idle_s = std::chrono::duration<double>(Clock::now() - last_progress).count();
      if (idle_s > 1.0) {
        const nlohmann::json status = Query("status", nlohmann::json::object(), daemon_);
        if (idle_s > kReplayStall_s || Rejections(status) >= target - t.samples) {
          publisher_.Control(trial.end_utime, false, trial.protocol);
          throw OperationError("flexidd stored " + std::to_string(t.samples) + " of " +
                               std::to_string(trial.deflections) + " samples of trial " +
                               std::to_string(id) + " and took no more (" +
                               CounterDeltas(status_before_, status) +
                               "; out of order means the actuator already has newer "
                               "messages: try --start-utime)");
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
      t = DaemonTrial(id, daemon_);
      if (!stop_sent && t.state != storage::TrialState::kRecording) {
        // Ended before its stop message: flexidd saw a clock jump, or someone stopped it.
        publisher_.Control(trial.end_utime, false, trial.protocol);
        throw OperationError(
            "flexidd ended trial " + std::to_string(id) + " (" + storage::TrialStateName(t.state) +
            ") after " + std::to_string(t.samples) + " of " + std::to_string(trial.deflections) +
            " samples, before the import sent its stop (see flexidd's alerts)");
      }
      if (t.samples > seen) {
        seen = t.samples;
        last_progress = Clock::now();
      }
      if (progress_) progress_->Update(done_ + t.samples, plan_.samples());
    }
    if (progress_) progress_->Update(done_ + t.samples, plan_.samples());
    return t;
  }

  // Messages flexidd rejected or dropped since the replay began.
  int64_t Rejections(const nlohmann::json& status) const {
    int64_t total = 0;
    for (const char* name : kRejectionCounters)
      total += status.value(name, int64_t{0}) - status_before_.value(name, int64_t{0});
    return total;
  }

  // On SIGINT/SIGTERM: ends the trial being played (if flexidd opened it) and fails.
  void CheckStop(int64_t id, const ImportTrial& trial) {
    if (!stop_.requested()) return;
    publisher_.Control(trial.end_utime, false, trial.protocol);
    throw OperationError(
        "interrupted: the import stopped" +
        (id != 0 ? "; trial " + std::to_string(id) + " holds what was sent" : std::string()));
  }

  const ImportPlan& plan_;
  Progress* progress_;
  std::string daemon_;
  Publisher publisher_;
  StopOnSignal stop_;
  nlohmann::json status_before_;
  int64_t last_trial_ = 0;
  int64_t done_ = 0;
};

}  // namespace

std::vector<StoredImport> ReplayOnBus(const ImportPlan& plan, Progress* progress) {
  return Replay(plan, progress).Run();
}

}  // namespace flexid::cli::trials
