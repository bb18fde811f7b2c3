// flexid trials list|show|export|import|start|stop: the stored trials of flexidd (online,
// --lcm URL) or of a database file (offline, --db PATH).
//
//   flexid trials list [--actuator ID] [--limit N] [--json]
//   flexid trials show ID [--json]
//   flexid trials export ID [--out FILE.csv]
//   flexid trials import FILE.csv|FILE.lcmlog --actuator ID [--protocol TEXT]
//                        [--start-utime U] [--json]
//   flexid trials start --actuator ID [--protocol TEXT] [--json]      (online only)
//   flexid trials stop --actuator ID [--json]                         (online only)
//
// Import stores the file straight into the --db file (trial_import.h), or, online, replays
// it onto the bus as the virtual rig does (bus/sample_publisher.h): signed trial_control2_t
// start on PREFIX/TRIAL, voltage_sample_t and deflection_sample_t on PREFIX/<ID>/VOLTAGE
// and /DEFLECTION, stop (PREFIX: the global --channel-prefix, default FLEXID).
// It publishes chunks of kReplayChunk deflections and lets at most kReplayWindow of them
// wait for flexidd's commit (the trial's stored count, asked over RPC) before sending
// more, so that neither the UDP socket nor flexidd's queues overflow; then it checks that
// the trial holds every sample. An lcm-logger log (detected by its magic number, not its
// name) is read as trial_import.h describes; trials are split at its trial_control_t
// messages for that actuator.
#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <optional>
#include <thread>

#include "bus/clock.h"
#include "bus/ids.h"
#include "bus/sample_publisher.h"
#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "clients/cli/trial_import.h"
#include "model/core/levels.h"
#include "storage/database.h"

namespace flexid::cli {
namespace {

constexpr int64_t kReplayChunk = 2000;   // deflections published at once
constexpr int64_t kReplayWindow = 4000;  // deflections published but not yet stored
constexpr double kReplayStall_s = 10.0;  // no progress this long: flexidd is not storing
constexpr double kControlTimeout_s = 10.0;

// Actuator ids name LCM channels (bus/ids.h).
void CheckActuatorId(const std::string& id) {
  if (!bus::IsValidId(id))
    throw UsageError(std::string("--actuator must be ") + bus::kIdRule + " (got \"" + id + "\")");
}

storage::TrialState StateOf(const std::string& name) {
  if (name == "complete") return storage::TrialState::kComplete;
  if (name == "interrupted") return storage::TrialState::kInterrupted;
  return storage::TrialState::kRecording;
}

// storage::TrialJson read back.
storage::Trial TrialFromJson(const nlohmann::json& j) {
  storage::Trial t;
  t.id = j.value("id", int64_t{0});
  t.actuator_id = j.value("actuator", "");
  t.protocol = j.value("protocol", "");
  t.start_utime = j.value("start_utime", int64_t{0});
  t.end_utime = j.value("end_utime", int64_t{0});
  t.state = StateOf(j.value("state", ""));
  t.samples = j.value("samples", int64_t{0});
  return t;
}

// Seconds from start to end; none while recording (end 0).
std::optional<double> DurationOf(const storage::Trial& t) {
  if (t.end_utime == 0) return std::nullopt;
  return 1e-6 * static_cast<double>(t.end_utime - t.start_utime);
}

void PrintJson(const nlohmann::json& j) { std::cout << j.dump(2) << "\n"; }

// --- list --------------------------------------------------------------------------------

struct ListArgs {
  std::string actuator;
  std::optional<int> limit;  // none: the default (100)
  bool as_json = false;
};

void RunList(const ListArgs& args) {
  nlohmann::json query = nlohmann::json::object();
  if (!args.actuator.empty()) query["actuator"] = args.actuator;
  if (args.limit) {
    if (*args.limit < 1 || *args.limit > 10000) throw UsageError("--limit must be 1 .. 10000");
    query["limit"] = *args.limit;
  }
  const nlohmann::json list = Query("trials", query);
  if (args.as_json) return PrintJson(list);
  if (list.empty()) {
    std::cout << "no trials" << (args.actuator.empty() ? "" : " of " + args.actuator) << "\n";
    return;
  }
  Table table({"id", "actuator", "protocol", "start (UTC)", "start_utime", "duration_s", "state",
               "samples"});
  for (const nlohmann::json& item : list) {
    const storage::Trial t = TrialFromJson(item);
    const auto duration = DurationOf(t);
    table.AddRow({std::to_string(t.id), t.actuator_id, t.protocol, FormatUtcTime(t.start_utime),
                  std::to_string(t.start_utime), duration ? FormatNumber(*duration, 6) : "-",
                  storage::TrialStateName(t.state), std::to_string(t.samples)});
  }
  table.Print(std::cout, "");
}

// --- show --------------------------------------------------------------------------------

struct ShowArgs {
  int64_t trial = 0;
  bool as_json = false;
};

void CheckTrialId(int64_t id) {
  if (id < 1)
    throw UsageError("ID: a trial id is a positive integer (got " + std::to_string(id) + ")");
}

// Samples of a trial, summarised: time span, rate, voltage levels, deflection range.
nlohmann::json SampleSummary(const StoredTrial& stored) {
  const size_t n = stored.utime.size();
  nlohmann::json out = {{"samples", n}};
  if (n == 0) return out;
  const double duration_s = 1e-6 * static_cast<double>(stored.utime.back() - stored.utime.front());
  out["first_utime"] = stored.utime.front();
  out["last_utime"] = stored.utime.back();
  out["duration_s"] = duration_s;
  out["sample_rate_Hz"] =
      duration_s > 0 ? nlohmann::json(static_cast<double>(n - 1) / duration_s) : nlohmann::json();
  const auto [vmin, vmax] = std::minmax_element(stored.voltage_V.begin(), stored.voltage_V.end());
  const auto [dmin, dmax] =
      std::minmax_element(stored.deflection_mm.begin(), stored.deflection_mm.end());
  out["voltage_min_V"] = *vmin;
  out["voltage_max_V"] = *vmax;
  out["deflection_min_mm"] = *dmin;
  out["deflection_max_mm"] = *dmax;
  // Levels as identification sees them (model/core/levels.h): the voltages held on plateaus.
  nlohmann::json levels = nlohmann::json::array();
  if (n >= 2) {
    try {
      const model::Recording rec = RecordingOf(stored);
      for (const model::VoltageLevel& level : model::DetectLevels(rec.t_s, rec.voltage_V).levels)
        levels.push_back(level.level_V);
    } catch (const std::exception&) {
      // No plateau structure to report; the range above still says what was applied.
    }
  }
  out["voltage_levels_V"] = levels;
  return out;
}

void RunShow(const ShowArgs& args) {
  CheckTrialId(args.trial);
  Progress progress("load trial " + std::to_string(args.trial));
  const StoredTrial stored =
      LoadTrial(args.trial, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  progress.Finish();
  const nlohmann::json summary = SampleSummary(stored);
  if (args.as_json) return PrintJson({{"trial", stored.trial}, {"summary", summary}});
  const storage::Trial t = TrialFromJson(stored.trial);
  auto line = [](const std::string& key, const std::string& value) {
    std::cout << "  " << key << std::string(key.size() < 21 ? 21 - key.size() : 1, ' ') << value
              << "\n";
  };
  auto number = [&summary](const char* key) {
    return summary[key].is_number() ? FormatNumber(summary[key].get<double>(), 6) : "-";
  };
  std::cout << "trial " << t.id << " of " << t.actuator_id << "\n";
  line("protocol", t.protocol);
  line("state", storage::TrialStateName(t.state));
  line("start", FormatUtcTime(t.start_utime) + " (utime " + std::to_string(t.start_utime) + ")");
  line("end", t.end_utime == 0
                  ? "-"
                  : FormatUtcTime(t.end_utime) + " (utime " + std::to_string(t.end_utime) + ")");
  line("samples", std::to_string(stored.utime.size()));
  if (stored.utime.empty()) return;
  line("duration_s", number("duration_s"));
  line("sample rate_Hz", number("sample_rate_Hz"));
  std::string levels;
  for (const auto& level : summary["voltage_levels_V"])
    levels += (levels.empty() ? "" : ", ") + FormatNumber(level.get<double>(), 4);
  line("voltage levels_V", levels.empty() ? "none held" : levels);
  line("voltage range_V", number("voltage_min_V") + " .. " + number("voltage_max_V"));
  line("deflection range_mm", number("deflection_min_mm") + " .. " + number("deflection_max_mm"));
}

// --- export ------------------------------------------------------------------------------

struct ExportArgs {
  int64_t trial = 0;
  std::string out;  // empty: stdout
};

// A FILE* that is closed (and, for a file, removed unless committed) when it goes away.
class CsvOutput {
 public:
  explicit CsvOutput(const std::string& path) : path_(path) {
    if (path_.empty()) {
      file_ = stdout;
      return;
    }
    temporary_ = path_ + ".tmp";
    file_ = std::fopen(temporary_.c_str(), "wb");
    if (!file_) throw OperationError(path_ + ": cannot write (" + std::strerror(errno) + ")");
  }
  ~CsvOutput() {
    if (file_ && file_ != stdout) {
      std::fclose(file_);
      std::remove(temporary_.c_str());
    }
  }
  CsvOutput(const CsvOutput&) = delete;
  CsvOutput& operator=(const CsvOutput&) = delete;

  void Write(const std::string& text) {
    if (std::fwrite(text.data(), 1, text.size(), file_) != text.size())
      throw OperationError((path_.empty() ? "stdout" : path_) + ": cannot write (" +
                           std::strerror(errno) + ")");
  }
  void Commit() {
    if (std::fflush(file_) != 0)
      throw OperationError((path_.empty() ? "stdout" : path_) + ": cannot write (" +
                           std::strerror(errno) + ")");
    if (file_ == stdout) return;
    const bool closed = std::fclose(file_) == 0;
    file_ = nullptr;
    if (!closed || std::rename(temporary_.c_str(), path_.c_str()) != 0) {
      std::remove(temporary_.c_str());
      throw OperationError(path_ + ": cannot write (" + std::strerror(errno) + ")");
    }
  }

 private:
  std::string path_, temporary_;
  FILE* file_ = nullptr;
};

void RunExport(const ExportArgs& args) {
  CheckTrialId(args.trial);
  CsvOutput output(args.out);  // before loading: a bad --out fails at once
  Progress progress("export trial " + std::to_string(args.trial));
  const StoredTrial stored =
      LoadTrial(args.trial, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  progress.Finish();
  const size_t n = stored.utime.size();
  const int64_t first = n > 0 ? stored.utime.front() : TrialFromJson(stored.trial).start_utime;
  std::string chunk = ExportCommentLines(TrialFromJson(stored.trial), first);
  chunk += "t_s,voltage_V,deflection_mm\n";
  constexpr size_t kChunkBytes = 1 << 20;
  chunk.reserve(kChunkBytes + 128);
  for (size_t k = 0; k < n; ++k) {
    // Division is correctly rounded: 100000 us reads back as 0.1, not 0.09999999999999999.
    const double t_s = static_cast<double>(stored.utime[k] - first) / 1e6;
    AppendCsvRow(&chunk, t_s, stored.voltage_V[k], stored.deflection_mm[k]);
    if (chunk.size() >= kChunkBytes) {
      output.Write(chunk);
      chunk.clear();
    }
  }
  output.Write(chunk);
  output.Commit();
  if (!args.out.empty())
    std::cout << "exported trial " << args.trial << ": " << n << " samples to " << args.out << "\n";
}

// --- import: on the bus ------------------------------------------------------------------

// Replays one actuator's messages (bus/sample_publisher.h, as flexid-rig publishes them)
// and counts those LCM could not send. Trial control is signed, so the key is read first,
// before the bus is joined and anything is sent.
class Publisher {
 public:
  explicit Publisher(const std::string& actuator)
      : key_(SigningKey()), lcm_(LcmUrl()), publisher_(lcm_, BusChannels(), actuator, &key_) {
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
int64_t RecordingTrial(const std::string& actuator, bool* known = nullptr) {
  for (const nlohmann::json& a : Query("actuators", nlohmann::json::object()))
    if (a.value("id", "") == actuator) {
      if (known) *known = true;
      return a.value("trial", int64_t{0});
    }
  if (known) *known = false;
  return 0;
}

// The stored trial as flexidd reports it (its sample count is what it has committed).
storage::Trial DaemonTrial(int64_t id) {
  return TrialFromJson(Query("trial_samples", {{"trial", id}, {"limit", 1}}).at("trial"));
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
  Replay(const ImportPlan& plan, Progress* progress)
      : plan_(plan), progress_(progress), publisher_(plan.actuator) {}

  std::vector<StoredImport> Run() {
    bool known = false;
    const int64_t busy = RecordingTrial(plan_.actuator, &known);
    if (busy != 0)
      throw UsageError(plan_.actuator + " is recording trial " + std::to_string(busy) +
                       "; stop it first (flexid trials stop --actuator " + plan_.actuator + ")");
    if (known) CheckAfterStoredTimes();
    status_before_ = Query("status", nlohmann::json::object());
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
         Query("trials", {{"actuator", plan_.actuator}, {"limit", 10000}}))
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
      final_state = DaemonTrial(id);
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
      if (const int64_t id = RecordingTrial(plan_.actuator); id > last_trial_) {
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
    storage::Trial t = DaemonTrial(id);
    int64_t seen = t.samples;
    auto last_progress = Clock::now();
    while (t.samples < target) {
      CheckStop(id, trial);
      const double idle_s = std::chrono::duration<double>(Clock::now() - last_progress).count();
      if (idle_s > 1.0) {
        const nlohmann::json status = Query("status", nlohmann::json::object());
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
      t = DaemonTrial(id);
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
  Publisher publisher_;
  StopOnSignal stop_;
  nlohmann::json status_before_;
  int64_t last_trial_ = 0;
  int64_t done_ = 0;
};

// --- import ------------------------------------------------------------------------------

struct ImportArgs {
  std::string file;
  std::string actuator;
  std::optional<std::string> protocol;
  std::optional<int64_t> start_utime;
  bool as_json = false;
};

nlohmann::json LogCountsJson(const LogCounts& c) {
  return {{"events", c.events},
          {"voltage", c.voltage},
          {"deflection", c.deflection},
          {"trial_control", c.trial_control},
          {"malformed", c.malformed},
          {"misaddressed", c.misaddressed},
          {"nonfinite", c.nonfinite},
          {"out_of_order", c.out_of_order},
          {"outside_trial", c.outside_trial},
          {"other_channels", c.other_channels},
          {"empty_trials", c.empty_trials},
          {"truncated", c.truncated}};
}

void RunImport(const ImportArgs& args) {
  CheckActuatorId(args.actuator);
  if (args.protocol && args.protocol->size() > 1000)
    throw UsageError("--protocol: at most 1000 characters");
  PlanOptions options;
  options.actuator = args.actuator;
  options.protocol = args.protocol;
  options.start_utime = args.start_utime;
  options.now_utime = bus::WallClockUtime();
  options.channels = BusChannels();  // a log recorded under that prefix
  // The whole file is read and checked before anything is written or sent.
  const ImportPlan plan =
      IsLcmLog(args.file) ? PlanFromLcmLog(args.file, options) : PlanFromCsv(args.file, options);
  Progress progress("import " + args.file);
  std::vector<StoredImport> stored;
  if (Offline()) {
    std::optional<storage::Database> db;
    try {
      db.emplace(storage::Database::Open(DbPath()));  // may create the file
    } catch (const storage::StorageError& e) {
      throw OperationError(e.what());
    }
    stored =
        StorePlan(*db, plan, [&](int64_t done, int64_t total) { progress.Update(done, total); });
  } else {
    stored = Replay(plan, &progress).Run();
  }
  progress.Finish();

  int64_t total = 0;
  nlohmann::json trials = nlohmann::json::array();
  for (size_t i = 0; i < stored.size(); ++i) {
    total += stored[i].samples;
    trials.push_back({{"trial", stored[i].trial_id},
                      {"samples", stored[i].samples},
                      {"protocol", plan.trials[i].protocol},
                      {"start_utime", plan.trials[i].start_utime}});
    if (stored[i].samples != plan.trials[i].deflections)
      throw OperationError("trial " + std::to_string(stored[i].trial_id) + " holds " +
                           std::to_string(stored[i].samples) + " of the " +
                           std::to_string(plan.trials[i].deflections) + " samples imported");
  }
  if (args.as_json) {
    nlohmann::json out = {{"trial", stored.front().trial_id},
                          {"samples", total},
                          {"actuator", plan.actuator},
                          {"source", plan.source},
                          {"format", plan.format},
                          {"trials", trials}};
    if (plan.format == "lcmlog") out["log"] = LogCountsJson(plan.log);
    return PrintJson(out);
  }
  for (size_t i = 0; i < stored.size(); ++i)
    std::cout << "imported trial " << stored[i].trial_id << ": " << stored[i].samples
              << " samples of " << plan.actuator << " (protocol \"" << plan.trials[i].protocol
              << "\", start " << FormatUtcTime(plan.trials[i].start_utime) << ") from "
              << plan.source << "\n";
  if (plan.format == "lcmlog") {
    const LogCounts& c = plan.log;
    std::cout << "log: " << c.events << " events; used " << c.voltage << " voltage, "
              << c.deflection << " deflection, " << c.trial_control
              << " trial-control messages; skipped " << c.malformed << " malformed, "
              << c.misaddressed << " misaddressed, " << c.nonfinite << " non-finite, "
              << c.out_of_order << " out of order, " << c.outside_trial
              << " deflections outside a trial, " << c.other_channels << " on other channels; "
              << c.empty_trials << " empty trials left out"
              << (c.truncated ? "; the file ends inside an event" : "") << "\n";
  }
}

// --- start, stop -------------------------------------------------------------------------

struct ControlArgs {
  std::string actuator;
  std::optional<std::string> protocol;
  bool as_json = false;
};

void RunControl(const ControlArgs& args, bool start) {
  CheckActuatorId(args.actuator);
  nlohmann::json request = {{"actuator", args.actuator}};
  if (start && args.protocol) request["protocol"] = *args.protocol;
  const nlohmann::json reply =
      CallOnline(start ? "trial_start" : "trial_stop", request, kQueryTimeout_s);
  if (args.as_json) return PrintJson(reply);
  std::cout << "trial " << reply.value("trial", int64_t{0}) << " of "
            << reply.value("actuator", args.actuator) << (start ? " started" : " stopped") << "\n";
}

}  // namespace

void RegisterTrialsCommand(CLI::App& app) {
  CLI::App* trials =
      app.add_subcommand("trials", "List, show, export, import, start and stop trials");
  trials->require_subcommand(1);
  trials->footer(
      "Online forms ask flexidd (--lcm URL); with --db PATH they read the database file.\n"
      "Examples:\n  flexid trials list --actuator S1\n  flexid --db var/flexid.db trials export 3 "
      "--out trial3.csv");

  auto list = std::make_shared<ListArgs>();
  CLI::App* list_cmd = trials->add_subcommand("list", "Stored trials, newest first");
  list_cmd->add_option("--actuator", list->actuator, "Only this actuator's trials");
  list_cmd->add_option("--limit", list->limit, "At most this many (1 .. 10000, default 100)");
  list_cmd->add_flag("--json", list->as_json, "Print the list as JSON");
  list_cmd->footer(
      "Examples:\n  flexid trials list\n  flexid --db var/flexid.db trials list "
      "--actuator S1 --limit 5 --json");
  list_cmd->callback([list] { RunList(*list); });

  auto show = std::make_shared<ShowArgs>();
  CLI::App* show_cmd =
      trials->add_subcommand("show", "A trial's metadata and a summary of its samples");
  show_cmd->add_option("ID", show->trial, "Trial id")->required();
  show_cmd->add_flag("--json", show->as_json, "Print {\"trial\": ..., \"summary\": ...} as JSON");
  show_cmd->footer(
      "Example:\n  flexid trials show 3\n  flexid --db var/flexid.db trials show 3 --json");
  show_cmd->callback([show] { RunShow(*show); });

  auto exp = std::make_shared<ExportArgs>();
  CLI::App* export_cmd = trials->add_subcommand(
      "export", "Write a trial as a recording CSV (t_s,voltage_V,deflection_mm)");
  export_cmd->add_option("ID", exp->trial, "Trial id")->required();
  export_cmd->add_option("--out", exp->out, "Write this file (default: standard output)");
  export_cmd->footer(
      "t_s counts from the first sample; '#' lines first give the trial id, actuator, protocol\n"
      "and start_utime, which `trials import` reads back.\n"
      "Examples:\n  flexid trials export 3 --out trial3.csv\n"
      "  flexid --db var/flexid.db trials export 3 > trial3.csv");
  export_cmd->callback([exp] { RunExport(*exp); });

  auto imp = std::make_shared<ImportArgs>();
  CLI::App* import_cmd = trials->add_subcommand(
      "import",
      "Store a recording CSV or an lcm-logger log as a trial (--db), or replay it to "
      "flexidd");
  import_cmd->add_option("FILE", imp->file, "Recording CSV, or an lcm-logger log (by content)")
      ->required();
  import_cmd->add_option("--actuator", imp->actuator, "The actuator the samples belong to")
      ->required();
  import_cmd->add_option("--protocol", imp->protocol,
                         "Protocol text of the trial (default: the file's, or \"import FILE\")");
  import_cmd->add_option("--start-utime", imp->start_utime,
                         "The trial starts at this utime, us (default: the file's; a CSV "
                         "without one starts now); a log's times shift with it");
  import_cmd->add_flag("--json", imp->as_json,
                       "Print {\"trial\", \"samples\", \"actuator\", \"trials\", ...} as JSON");
  import_cmd->footer(
      "With --db the file is stored directly (the database file is created if needed);\n"
      "otherwise it is replayed over the bus to flexidd, paced so that no sample is lost.\n"
      "A log's trials are split at its trial_control_t messages for the actuator.\n"
      "Examples:\n  flexid --db var/flexid.db trials import run-5V.csv --actuator S1\n"
      "  flexid trials import lcmlog-2024-01-05.00 --actuator S1 --json");
  import_cmd->callback([imp] { RunImport(*imp); });

  auto start = std::make_shared<ControlArgs>();
  CLI::App* start_cmd = trials->add_subcommand("start", "Ask flexidd to start a trial (online)");
  start_cmd->add_option("--actuator", start->actuator, "Actuator")->required();
  start_cmd->add_option("--protocol", start->protocol, "Protocol text (default \"manual\")");
  start_cmd->add_flag("--json", start->as_json, "Print {\"actuator\", \"trial\"} as JSON");
  start_cmd->footer("Example:\n  flexid trials start --actuator S1 --protocol \"step 5 V, 600 s\"");
  start_cmd->callback([start] { RunControl(*start, true); });

  auto stop = std::make_shared<ControlArgs>();
  CLI::App* stop_cmd =
      trials->add_subcommand("stop", "Ask flexidd to end the actuator's trial (online)");
  stop_cmd->add_option("--actuator", stop->actuator, "Actuator")->required();
  stop_cmd->add_flag("--json", stop->as_json, "Print {\"actuator\", \"trial\"} as JSON");
  stop_cmd->footer("Example:\n  flexid trials stop --actuator S1");
  stop_cmd->callback([stop] { RunControl(*stop, false); });
}

}  // namespace flexid::cli
