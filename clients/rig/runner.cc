#include "clients/rig/runner.h"

#include <algorithm>
#include <chrono>
#include <sstream>
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

RunSummary RunRig(Rig& rig, BusSink& sink, const RunOptions& options,
                  const std::atomic<bool>* stop) {
  RunSummary summary;
  const auto count = [&summary](bool sent, int64_t* counter) {
    ++(sent ? *counter : summary.failed_messages);
  };
  const Clock::time_point wall_start = Clock::now();
  if (options.trial_control)
    count(sink.PublishTrialControl(rig.UtimeOf(0), TrialAction::kStart, rig.protocol().text),
          &summary.trial_messages);
  RigSample sample;
  while (!Stopped(stop) && rig.Next(&sample)) {
    if (options.speed > 0.0) {
      const std::chrono::duration<double> offset(sample.t_s / options.speed);
      if (!WaitUntil(wall_start + std::chrono::duration_cast<Clock::duration>(offset), stop)) break;
    }
    if (sample.publish_voltage)
      count(sink.PublishVoltage(sample.utime, sample.voltage_V), &summary.voltage_messages);
    count(sink.PublishDeflection(sample.utime, sample.deflection_mm), &summary.deflection_messages);
    ++summary.samples;
    summary.final_utime = sample.utime;
  }
  summary.interrupted = summary.samples < rig.sample_count();
  if (options.trial_control)
    count(sink.PublishTrialControl(rig.UtimeOf(summary.samples), TrialAction::kStop,
                                   rig.protocol().text),
          &summary.trial_messages);
  summary.duration_s = static_cast<double>(summary.samples) / rig.options().rate_Hz;
  summary.wall_s = std::chrono::duration<double>(Clock::now() - wall_start).count();
  return summary;
}

std::string SummaryLine(const RunSummary& summary) {
  std::ostringstream line;
  line << "published " << summary.samples << " samples (" << summary.deflection_messages
       << " deflection, " << summary.voltage_messages << " voltage, " << summary.trial_messages
       << " trial-control messages) covering " << summary.duration_s << " s of message time in "
       << summary.wall_s << " s, final utime " << summary.final_utime;
  if (summary.failed_messages > 0) line << ", " << summary.failed_messages << " failed to send";
  if (summary.interrupted) line << " (interrupted)";
  return line.str();
}

}  // namespace flexid::rig
