#include "clients/rig/closed_loop.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <flexid/voltage_command_t.hpp>
#include <sstream>
#include <stdexcept>

#include "bus/clock.h"
#include "lcmtypes/command_check.h"
#include "model/core/errors.h"

namespace flexid::rig {

ClosedLoopPlant::ClosedLoopPlant(const model::TsModel& model,
                                 std::vector<std::unique_ptr<Effect>> effects,
                                 const RigOptions& options)
    : model_(model), effects_(std::move(effects)), options_(options), noise_(options.seed) {
  std::string why;
  if (!options_.IsValid(&why)) throw model::InputError(why);
}

int64_t ClosedLoopPlant::UtimeOf(int64_t k) const {
  return options_.start_utime + std::llround(static_cast<double>(k) * 1e6 / options_.rate_Hz);
}

void ClosedLoopPlant::SetStartUtime(int64_t start_utime) {
  if (next_ > 0) throw std::logic_error("ClosedLoopPlant::SetStartUtime after the first sample");
  if (start_utime < 0) throw model::InputError("the start utime must be >= 0");
  options_.start_utime = start_utime;
}

RigSample ClosedLoopPlant::Next(double voltage_V) {
  const int64_t k = next_++;
  RigSample sample;
  sample.index = k;
  sample.utime = UtimeOf(k);
  sample.t_s = static_cast<double>(k) / options_.rate_Hz;
  sample.voltage_V = voltage_V;
  sample.voltage_changed = k == 0 || voltage_V != last_voltage_V_;
  last_voltage_V_ = voltage_V;
  const auto repeat_us = static_cast<int64_t>(std::llround(options_.voltage_repeat_s * 1e6));
  sample.publish_voltage =
      sample.voltage_changed || sample.utime - last_voltage_utime_ >= repeat_us;
  if (sample.publish_voltage) last_voltage_utime_ = sample.utime;
  double drive_V = voltage_V;
  for (const auto& effect : effects_) drive_V = effect->DriveVoltage(sample.t_s, drive_V);
  double deflection_mm = model_.Step(sample.t_s, drive_V);
  if (!std::isfinite(deflection_mm)) {
    std::ostringstream text;
    text << "the model's output diverges at t = " << sample.t_s << " s (is the model stable?)";
    throw std::runtime_error(text.str());
  }
  for (const auto& effect : effects_)
    deflection_mm = effect->Deflection(sample.t_s, voltage_V, deflection_mm);
  clean_mm_ = deflection_mm;
  if (options_.noise_mm > 0.0) deflection_mm += options_.noise_mm * noise_.StandardNormal();
  sample.deflection_mm = deflection_mm;
  return sample;
}

CommandInbox::CommandInbox(const auth::Key& key, std::string actuator_id, double command_timeout_s,
                           std::function<void(const std::string&)> log)
    : verifier_(key, {.window_us = std::llround(command_timeout_s * 1e6), .max_nonces = 100000}),
      actuator_id_(std::move(actuator_id)),
      timeout_us_(std::llround(command_timeout_s * 1e6)),
      log_(std::move(log)) {}

void CommandInbox::Log(const std::string& kind, const std::string& line, int64_t now_utime) {
  auto [it, first] = last_logged_.emplace(kind, now_utime);
  if (!first && now_utime - it->second < 1'000'000) return;
  it->second = now_utime;
  if (log_) log_(line);
}

std::string CommandInbox::Receive(const flexid::voltage_command_t& command, int64_t now_utime) {
  std::string why;
  int64_t* counter = &counts_.refused_other;
  if (command.actuator_id != actuator_id_) {
    why = "for actuator \"" + command.actuator_id + "\"";
  } else if (const std::string problem = wire::VoltageCommandProblem(command); !problem.empty()) {
    why = "invalid: " + problem;
  } else {
    why = verifier_.Check(command, now_utime);
    if (why == "no signature")
      counter = &counts_.refused_unsigned;
    else if (why.starts_with("bad"))
      counter = &counts_.refused_bad_signature;
    else if (why.starts_with("command time") || why == "replayed nonce")
      counter = &counts_.refused_stale;
    if (why.empty()) {
      const auto last = last_sequence_.find(command.controller_id);
      counter = &counts_.refused_stale;
      if (command.utime <= played_utime_)
        why = "stale: for message time " + std::to_string(command.utime) +
              ", a sample already played (" + std::to_string(played_utime_) + ")";
      else if (last != last_sequence_.end() && command.sequence <= last->second)
        why = "stale: sequence " + std::to_string(command.sequence) + " after " +
              std::to_string(last->second);
    }
  }
  if (!why.empty()) {
    ++*counter;
    Log(why.substr(0, why.find(' ')),
        "flexid-rig: refused a voltage command [reason: " + why +
            ", refused so far: " + std::to_string(counts_.Refused()) + "]",
        now_utime);
    return why;
  }
  ++counts_.accepted;
  last_sequence_[command.controller_id] = command.sequence;
  while (!pending_.empty() && pending_.back().first >= command.utime) pending_.pop_back();
  pending_.emplace_back(command.utime, command.voltage_V);
  last_accepted_wall_ = now_utime;
  return "";
}

bool CommandInbox::Attached(int64_t now_utime) const {
  return last_accepted_wall_ >= 0 && now_utime - last_accepted_wall_ <= timeout_us_;
}

bool CommandInbox::Answered(int64_t sample_utime) const {
  return !pending_.empty() && pending_.back().first >= sample_utime;
}

double CommandInbox::VoltageFor(int64_t sample_utime, int64_t now_utime) {
  while (!pending_.empty() && pending_.front().first <= sample_utime) {
    voltage_V_ = pending_.front().second;
    pending_.pop_front();
  }
  played_utime_ = sample_utime;
  if (!Attached(now_utime)) {
    if (!timed_out_ && last_accepted_wall_ >= 0) {
      ++counts_.timeouts;
      Log("timeout",
          "flexid-rig: no voltage command for " + std::to_string(timeout_us_ / 1000) +
              " ms: the voltage goes to 0 V",
          now_utime);
    }
    timed_out_ = true;
    voltage_V_ = 0.0;
    return 0.0;
  }
  timed_out_ = false;
  return voltage_V_;
}

RunSummary RunClosedLoop(ClosedLoopPlant& plant, int64_t samples, CommandInbox& inbox,
                         BusSink& sink, const std::function<void(int)>& pump,
                         const ClosedLoopRunOptions& options, const std::atomic<bool>* stop) {
  using Clock = std::chrono::steady_clock;
  RunSummary summary;
  const auto count = [&summary](bool sent, int64_t* counter) {
    ++(sent ? *counter : summary.failed_messages);
  };
  const Clock::time_point wall_start = Clock::now();
  // Half the timeout: a sample whose deflection the controller never got (a lost message)
  // goes on with the voltage in force well before the controller's own stale timeout.
  const auto grace = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(0.5 * options.command_timeout_s));
  if (options.trial_control)
    count(sink.PublishTrialControl(plant.UtimeOf(0), TrialAction::kStart, options.protocol),
          &summary.trial_messages);
  for (int64_t k = 0; k < samples && !(stop && stop->load()); ++k) {
    const int64_t utime = plant.UtimeOf(k);
    const double t_s = static_cast<double>(k) / plant.options().rate_Hz;
    const Clock::time_point due =
        options.speed > 0.0 ? wall_start + std::chrono::duration_cast<Clock::duration>(
                                               std::chrono::duration<double>(t_s / options.speed))
                            : Clock::now();
    // Until the sample is due, and while a controller is attached, until it answered.
    while (!(stop && stop->load())) {
      const Clock::time_point now = Clock::now();
      const bool waiting_for_command = k > 0 && inbox.Attached(bus::WallClockUtime()) &&
                                       !inbox.Answered(utime) && now < due + grace;
      if (now >= due && !waiting_for_command) break;
      const auto left = now < due ? due - now : due + grace - now;
      pump(static_cast<int>(std::clamp<int64_t>(
          std::chrono::duration_cast<std::chrono::milliseconds>(left).count(), 0, 20)));
    }
    pump(0);
    const RigSample sample = plant.Next(inbox.VoltageFor(utime, bus::WallClockUtime()));
    if (sample.publish_voltage)
      count(sink.PublishVoltage(sample.utime, sample.voltage_V), &summary.voltage_messages);
    count(sink.PublishDeflection(sample.utime, sample.deflection_mm), &summary.deflection_messages);
    ++summary.samples;
    summary.final_utime = sample.utime;
  }
  summary.interrupted = summary.samples < samples;
  if (options.trial_control)
    count(sink.PublishTrialControl(plant.UtimeOf(summary.samples), TrialAction::kStop,
                                   options.protocol),
          &summary.trial_messages);
  summary.duration_s = static_cast<double>(summary.samples) / plant.options().rate_Hz;
  summary.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
  return summary;
}

}  // namespace flexid::rig
