// The bus-free half of `flexid trials export|import`: the trial CSV with its comment lines,
// turning a recording CSV or an lcm-logger log into the voltage and deflection messages one
// actuator would have sent (an ImportPlan), pairing those messages into stored samples the
// way flexidd does, and storing a plan's trials in a database file. The command lines are
// trials_export_command.cc and trials_import_command.cc; the bus replay and its daemon
// queries are trials_replay.h.
//
// Export format (DESIGN.md, "Recording CSV", plus comments that import reads back):
//   # flexid trial export
//   # trial: 3
//   # actuator: S1
//   # protocol: square:level=2,period=220,duty=0.5,cycles=2
//   # start_utime: 1700000000000000
//   # first_sample_utime: 1700000000000000
//   # end_utime: 1700000439900000
//   # state: complete
//   # samples: 4400
//   t_s,voltage_V,deflection_mm
//   0,0,0.0123
// t_s in seconds from the first sample, numbers in the shortest form that reads back to
// the same double (std::to_chars), so export -> import -> export is exact. Protocol text
// has '\', CR and LF escaped as \\, \r, \n.
//
// Times: a utime is integer microseconds of message time (DESIGN.md, "Bus"). A CSV's sample
// k is stored at first_sample_utime + round(t_s[k] * 1e6).
//
// Pairing (daemon/daemon.cc, OnVoltage/OnDeflection): messages are taken in the order they
// came (log order); a voltage holds from its message until the next one; each deflection is
// stored with the voltage in force when it arrives (0 V before the first voltage). A voltage
// or deflection whose utime is not after the previous one of the same stream is rejected as
// out of order, as are non-finite values; flexidd does the same.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "bus/channels.h"
#include "model/core/recording.h"
#include "storage/database.h"

namespace flexid::cli {

// ---------------------------------------------------------------------------------------
// CSV comments

// What an export's leading comment lines say (each field only when present and valid).
struct ExportComments {
  std::optional<int64_t> trial;
  std::optional<std::string> actuator, protocol;
  std::optional<int64_t> start_utime, first_sample_utime;
};

// The "# key: value" lines an export writes before its header, ending with '\n'.
std::string ExportCommentLines(const storage::Trial& trial, int64_t first_sample_utime);

// Reads the '#' lines before the first other line of the file at path (our own export's
// comments; any other comment is ignored). Unreadable files give no comments: the CSV
// reader reports them.
ExportComments ReadExportComments(const std::string& path);

// Appends "t,v,d\n" with each number in its shortest round-trip form.
void AppendCsvRow(std::string* out, double t_s, double voltage_V, double deflection_mm);

// ---------------------------------------------------------------------------------------
// Import plans

// One voltage or deflection message of the actuator, as it goes on the bus.
struct BusSample {
  int64_t utime = 0;
  double value = 0;  // voltage_V or deflection_mm
  bool is_voltage = false;
};

// One trial to import: its trial control (start and stop times, protocol) and the messages
// between them, in order.
struct ImportTrial {
  std::string protocol;
  int64_t start_utime = 0;       // trial start (trial_control_t or the CSV's start)
  int64_t end_utime = 0;         // trial stop: the last message's utime unless the log says later
  double initial_voltage_V = 0;  // voltage in force before the first message (pairing)
  std::vector<BusSample> messages;
  int64_t deflections = 0;  // deflection messages among them: the samples it will hold
};

// What a log held, message by message.
struct LogCounts {
  int64_t events = 0;          // every event in the file
  int64_t voltage = 0;         // accepted voltage messages of the actuator
  int64_t deflection = 0;      // accepted deflection messages of the actuator
  int64_t trial_control = 0;   // trial_control_t start/stop of the actuator
  int64_t malformed = 0;       // failed wire::WellFormed or decode, oversized, bad action
  int64_t misaddressed = 0;    // the channel names the actuator, the message another
  int64_t nonfinite = 0;       // NaN or Inf value
  int64_t out_of_order = 0;    // utime not after the previous message of its stream
  int64_t outside_trial = 0;   // deflections between a trial stop and the next start
  int64_t other_channels = 0;  // events on channels of other actuators or other kinds
  int64_t empty_trials = 0;    // trials in the log without a deflection: not imported
  bool truncated = false;      // the file ends inside an event (or has garbage at its end)
};

struct ImportPlan {
  std::string actuator;
  std::string source;  // the file
  std::string format;  // "csv" or "lcmlog"
  std::vector<ImportTrial> trials;
  LogCounts log;  // lcmlog only
  int64_t samples() const;
};

// Options of a plan; unset ones come from the file (CSV comments, log messages) or defaults.
struct PlanOptions {
  std::string actuator;                 // required
  std::optional<std::string> protocol;  // overrides the file's
  std::optional<int64_t> start_utime;   // the (first) trial starts here; everything shifts
  int64_t now_utime = 0;                // CSV without start: the trial starts now
  bus::Channels channels;               // lcmlog: the channels it was recorded on
};

// True if the file starts with the LCM log magic 0xEDA1DA01 (big-endian), whatever its name.
bool IsLcmLog(const std::string& path);

// A recording CSV as one trial. Throws model::InputError for a bad file (model::
// ReadRecordingCsv's messages) or for samples closer than 1 us or times out of range.
ImportPlan PlanFromCsv(const std::string& path, const PlanOptions& options);

// The voltage and deflection messages of one actuator in an lcm-logger log, on the
// channels options.channels names (PREFIX/<actuator>/VOLTAGE, ...), validated
// (wire::WellFormed, then decode) and split into trials at that actuator's trial_control2_t
// (or, in older logs, trial_control_t) messages; without any, the whole log is one trial from its
// first to its last message. Deflections outside a trial are dropped, as flexidd drops them; trials
// without a deflection are left out. Throws model::InputError when the file cannot be read or holds
// no deflection of the actuator.
ImportPlan PlanFromLcmLog(const std::string& path, const PlanOptions& options);

// The stored samples of a trial: each deflection with the voltage in force (see the top).
std::vector<storage::Sample> PairSamples(const ImportTrial& trial);

// ---------------------------------------------------------------------------------------
// Storing

struct StoredImport {
  int64_t trial_id = 0;
  int64_t samples = 0;  // inserted
};

// Stores each trial of the plan: StartTrial, AppendSamples in batches of batch_size,
// EndTrial complete. progress(done, total) after each batch, over all trials. If a write
// fails, the trial being written is marked interrupted (what was committed stays) and
// OperationError says how far it got. Nothing is written before this call, so a bad file
// never touches the database.
std::vector<StoredImport> StorePlan(storage::Database& db, const ImportPlan& plan,
                                    const std::function<void(int64_t, int64_t)>& progress = {},
                                    size_t batch_size = 50000);

}  // namespace flexid::cli
