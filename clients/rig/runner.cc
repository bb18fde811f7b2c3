#include "clients/rig/runner.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <thread>

namespace flexid::rig {
namespace {

using Clock = std::chrono::steady_clock;

bool Stopped(const std::atomic<bool>* stop) { return stop && stop->load(); }

// Sleeps until `when` in slices of at most 100 ms; false if *stop became true.
bool WaitUntil(Clock::time_point when, const std::atomic<bool>* stop) {
  constexpr auto kSlice = std::chrono::milliseconds(100);
  while (true) {
    if (Stopped(stop)) return false;
    const auto now = Clock::now();
    if (now >= when) return true;
    std::this_thread::sleep_until(std::min(when, now + kSlice));
  }
}

}  // namespace

int64_t ContinuedStartUtime(int64_t wall_utime, std::optional<int64_t> latest_utime,
                            double rate_Hz) {
  if (!latest_utime) return wall_utime;
  const auto gap_us = static_cast<int64_t>(std::ceil(std::max(kRestartGap_s, 1.0 / rate_Hz) * 1e6));
  const int64_t after_us = *latest_utime > std::numeric_limits<int64_t>::max() - gap_us
                               ? std::numeric_limits<int64_t>::max()
                               : *latest_utime + gap_us;
  return std::max(wall_utime, after_us);
}

RunSummary RunRig(Rig& rig, BusSink& sink, const RunOptions& options,
                  const std::atomic<bool>* stop) {
  return RunRigs({{.rig = &rig, .sink = &sink}}, options, stop);
}

RunSummary RunRigs(const std::vector<ActuatorOnBus>& actuators, const RunOptions& options,
                   const std::atomic<bool>* stop) {
  if (actuators.empty()) throw std::invalid_argument("RunRigs: no actuators");
  const Rig& first = *actuators.front().rig;
  for (const ActuatorOnBus& actuator : actuators) {
    const Rig& rig = *actuator.rig;
    if (rig.sample_count() != first.sample_count() ||
        rig.options().rate_Hz != first.options().rate_Hz ||
        rig.options().start_utime != first.options().start_utime)
      throw std::invalid_argument("RunRigs: the rigs differ in samples, rate or start utime");
  }
  RunSummary summary;
  summary.actuators = static_cast<int64_t>(actuators.size());
  const auto count = [&summary](bool sent, int64_t* counter) {
    ++(sent ? *counter : summary.failed_messages);
  };
  const Clock::time_point wall_start = Clock::now();
  if (options.trial_control)
    for (const ActuatorOnBus& actuator : actuators)
      count(actuator.sink->PublishTrialControl(first.UtimeOf(0), TrialAction::kStart,
                                               actuator.rig->protocol().text),
            &summary.trial_messages);
  RigSample sample;
  for (int64_t k = 0; k < first.sample_count() && !Stopped(stop); ++k) {
    if (options.speed > 0.0) {
      const double t_s = static_cast<double>(k) / first.options().rate_Hz;
      const std::chrono::duration<double> offset(t_s / options.speed);
      if (!WaitUntil(wall_start + std::chrono::duration_cast<Clock::duration>(offset), stop)) break;
    }
    for (const ActuatorOnBus& actuator : actuators) {
      actuator.rig->Next(&sample);
      if (sample.publish_voltage)
        count(actuator.sink->PublishVoltage(sample.utime, sample.voltage_V),
              &summary.voltage_messages);
      count(actuator.sink->PublishDeflection(sample.utime, sample.deflection_mm),
            &summary.deflection_messages);
    }
    ++summary.samples;
    summary.final_utime = sample.utime;
  }
  summary.interrupted = summary.samples < first.sample_count();
  if (options.trial_control)
    for (const ActuatorOnBus& actuator : actuators)
      count(actuator.sink->PublishTrialControl(first.UtimeOf(summary.samples), TrialAction::kStop,
                                               actuator.rig->protocol().text),
            &summary.trial_messages);
  summary.duration_s = static_cast<double>(summary.samples) / first.options().rate_Hz;
  summary.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
  return summary;
}

std::string SummaryLine(const RunSummary& summary) {
  std::ostringstream line;
  line << "published " << summary.samples << " samples";
  if (summary.actuators > 1) line << " for each of " << summary.actuators << " actuators";
  line << " (" << summary.deflection_messages << " deflection, " << summary.voltage_messages
       << " voltage, " << summary.trial_messages << " trial-control messages) covering "
       << summary.duration_s << " s of message time in " << summary.wall_s << " s, final utime "
       << summary.final_utime;
  if (summary.failed_messages > 0) line << ", " << summary.failed_messages << " failed to send";
  if (summary.interrupted) line << " (interrupted)";
  return line.str();
}

}  // namespace flexid::rig
