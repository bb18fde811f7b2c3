#include "clients/cli/trial_import.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <optional>
#include <string>
#include <type_traits>
#include <vector>

#include "clients/cli/command.h"
#include "lcmtypes/wire_check.h"
#include "model/core/errors.h"

namespace flexid::cli {
namespace {

using model::InputError;

constexpr int64_t kMaxMessageBytes = 65536;  // flexidd's default max_message_bytes
// |t_s| above this (about 285 years) cannot be a recording's time and would overflow utime.
constexpr double kMaxAbsTime_s = 9e12;

// --- comments ----------------------------------------------------------------------------

std::string Escape(const std::string& text) {
  std::string out;
  for (const char c : text) {
    if (c == '\\')
      out += "\\\\";
    else if (c == '\n')
      out += "\\n";
    else if (c == '\r')
      out += "\\r";
    else
      out += c;
  }
  return out;
}

std::string Unescape(std::string_view text) {
  std::string out;
  for (size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '\\' && i + 1 < text.size()) {
      const char next = text[++i];
      out += next == 'n' ? '\n' : next == 'r' ? '\r' : next;
    } else {
      out += text[i];
    }
  }
  return out;
}

std::string_view Trim(std::string_view text) {
  while (!text.empty() && (text.front() == ' ' || text.front() == '\t')) text.remove_prefix(1);
  while (!text.empty() && (text.back() == ' ' || text.back() == '\t' || text.back() == '\r'))
    text.remove_suffix(1);
  return text;
}

std::optional<int64_t> ParseInteger(std::string_view text) {
  int64_t value = 0;
  const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (error != std::errc() || end != text.data() + text.size() || text.empty()) return std::nullopt;
  return value;
}

// The shortest text that reads back as the same double, for messages.
std::string Shortest(double value) {
  std::array<char, 32> buffer;
  return std::string(buffer.data(),
                     std::to_chars(buffer.data(), buffer.data() + buffer.size(), value).ptr);
}

// --- checked arithmetic on utimes --------------------------------------------------------

int64_t AddUtime(int64_t a, int64_t b, const std::string& source) {
  int64_t sum = 0;
  if (__builtin_add_overflow(a, b, &sum))
    throw InputError(source + ": times out of range (a utime would overflow 64 bits)");
  return sum;
}

// --- the log -----------------------------------------------------------------------------

template <typename Message>
bool DecodeEvent(const lcm::LogEvent& event, std::initializer_list<wire::Field> layout,
                 Message* message) {
  return event.datalen > 0 && event.datalen <= kMaxMessageBytes &&
         wire::WellFormed(event.data, static_cast<size_t>(event.datalen), layout) &&
         message->decode(event.data, 0, event.datalen) == event.datalen;
}

struct LogControl {
  size_t position = 0;  // index of the first message after it
  int64_t utime = 0;
  bool start = false;
  std::string protocol;
};

std::string DefaultProtocol(const std::string& path) {
  return "import " + std::filesystem::path(path).filename().string();
}

}  // namespace

// ---------------------------------------------------------------------------------------

std::string ExportCommentLines(const storage::Trial& trial, int64_t first_sample_utime) {
  std::string out = "# flexid trial export\n";
  out += "# trial: " + std::to_string(trial.id) + "\n";
  out += "# actuator: " + Escape(trial.actuator_id) + "\n";
  out += "# protocol: " + Escape(trial.protocol) + "\n";
  out += "# start_utime: " + std::to_string(trial.start_utime) + "\n";
  out += "# first_sample_utime: " + std::to_string(first_sample_utime) + "\n";
  out += "# end_utime: " + std::to_string(trial.end_utime) + "\n";
  out += std::string("# state: ") + storage::TrialStateName(trial.state) + "\n";
  out += "# samples: " + std::to_string(trial.samples) + "\n";
  return out;
}

ExportComments ReadExportComments(const std::string& path) {
  ExportComments out;
  std::ifstream in(path, std::ios::binary);
  std::string line;
  bool first = true;
  while (std::getline(in, line)) {
    std::string_view text = line;
    if (first && text.substr(0, 3) == "\xEF\xBB\xBF") text.remove_prefix(3);
    first = false;
    text = Trim(text);
    if (text.empty()) continue;
    if (text.front() != '#') break;  // the header: our comments come before it
    text.remove_prefix(1);
    const size_t colon = text.find(':');
    if (colon == std::string_view::npos) continue;
    const std::string_view key = Trim(text.substr(0, colon));
    const std::string_view value = Trim(text.substr(colon + 1));
    if (key == "trial")
      out.trial = ParseInteger(value);
    else if (key == "actuator")
      out.actuator = Unescape(value);
    else if (key == "protocol")
      out.protocol = Unescape(value);
    else if (key == "start_utime")
      out.start_utime = ParseInteger(value);
    else if (key == "first_sample_utime")
      out.first_sample_utime = ParseInteger(value);
  }
  return out;
}

void AppendCsvRow(std::string* out, double t_s, double voltage_V, double deflection_mm) {
  std::array<char, 96> buffer;
  char* p = buffer.data();
  char* const end = buffer.data() + buffer.size();
  p = std::to_chars(p, end, t_s).ptr;
  *p++ = ',';
  p = std::to_chars(p, end, voltage_V).ptr;
  *p++ = ',';
  p = std::to_chars(p, end, deflection_mm).ptr;
  *p++ = '\n';
  out->append(buffer.data(), p);
}

int64_t ImportPlan::samples() const {
  int64_t total = 0;
  for (const ImportTrial& trial : trials) total += trial.deflections;
  return total;
}

bool IsLcmLog(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::array<unsigned char, 4> magic{};
  if (!in.read(reinterpret_cast<char*>(magic.data()), magic.size())) return false;
  return magic == std::array<unsigned char, 4>{0xED, 0xA1, 0xDA, 0x01};
}

ImportPlan PlanFromCsv(const std::string& path, const PlanOptions& options) {
  const ExportComments comments = ReadExportComments(path);
  const model::Recording recording = model::ReadRecordingCsv(path);  // validates everything

  // Where t_s = 0 is, and where the trial starts (trial_import.h, "Times").
  const int64_t file_start =
      comments.start_utime.value_or(comments.first_sample_utime.value_or(options.now_utime));
  const int64_t file_base = comments.first_sample_utime.value_or(file_start);
  int64_t shift = 0;
  if (options.start_utime) {
    if (__builtin_sub_overflow(*options.start_utime, file_start, &shift))
      throw InputError(path + ": --start-utime is too far from the file's start_utime");
  }
  ImportTrial trial;
  trial.protocol = options.protocol.value_or(comments.protocol.value_or(DefaultProtocol(path)));
  trial.start_utime = AddUtime(file_start, shift, path);
  const int64_t base = AddUtime(file_base, shift, path);

  const size_t n = recording.t_s.size();
  trial.messages.reserve(2 * n);
  int64_t previous = 0;
  for (size_t k = 0; k < n; ++k) {
    const double t_s = recording.t_s[k];
    if (!(std::abs(t_s) <= kMaxAbsTime_s))
      throw InputError(path + ": t_s " + Shortest(t_s) + " is out of range");
    const int64_t utime = AddUtime(base, std::llround(t_s * 1e6), path);
    if (k > 0 && utime <= previous)
      throw InputError(path + ": samples " + std::to_string(k) + " and " + std::to_string(k + 1) +
                       " (t_s " + Shortest(recording.t_s[k - 1]) + " and " + Shortest(t_s) +
                       ") are less than 1 us apart; samples are stored in whole microseconds");
    previous = utime;
    const double voltage_V = recording.voltage_V[k];
    if (k == 0 || voltage_V != recording.voltage_V[k - 1])
      trial.messages.push_back({utime, voltage_V, true});
    trial.messages.push_back({utime, recording.deflection_mm[k], false});
  }
  trial.deflections = static_cast<int64_t>(n);
  trial.end_utime = previous;

  ImportPlan plan;
  plan.actuator = options.actuator;
  plan.source = path;
  plan.format = "csv";
  plan.trials.push_back(std::move(trial));
  return plan;
}

namespace {

// Where the well-framed events of an lcm-logger file end: LCM's reader allocates whatever
// length an event header claims (up to 2 GB) before it finds the file too short, so the
// framing is checked first. An event is: magic 0xEDA1DA01, event number (8 bytes), time
// (8), channel length (4), data length (4), all big-endian, then the channel and the
// data. Returns the offset after the last event that fits in the file.
int64_t WellFramedLogBytes(const std::string& path, uint64_t file_size) {
  std::ifstream in(path, std::ios::binary);
  uint64_t offset = 0;
  std::array<unsigned char, 28> header{};
  while (offset + header.size() <= file_size &&
         in.read(reinterpret_cast<char*>(header.data()), header.size())) {
    if (header[0] != 0xED || header[1] != 0xA1 || header[2] != 0xDA || header[3] != 0x01) break;
    auto u32 = [&header](size_t at) {
      return (uint64_t{header[at]} << 24) | (uint64_t{header[at + 1]} << 16) |
             (uint64_t{header[at + 2]} << 8) | uint64_t{header[at + 3]};
    };
    const uint64_t end = offset + header.size() + u32(20) + u32(24);
    if (end > file_size) break;
    offset = end;
    in.seekg(static_cast<std::streamoff>(offset));
  }
  return static_cast<int64_t>(offset);
}

constexpr int64_t kNoUtime = std::numeric_limits<int64_t>::min();

// A voltage_sample_t or deflection_sample_t of the log, checked as flexidd checks one from
// the bus: decoded, for this actuator, finite, and later than the channel's last accepted
// one. Appended to messages and counted when accepted; what it refuses is counted too.
template <typename Message>
void AcceptSample(const lcm::LogEvent& event, const std::string& actuator, int64_t* last_utime,
                  std::vector<BusSample>* messages, LogCounts* counts) {
  constexpr bool kVoltage = std::is_same_v<Message, flexid::voltage_sample_t>;
  Message m;
  if (!DecodeEvent(event, kVoltage ? wire::kVoltageSample : wire::kDeflectionSample, &m)) {
    ++counts->malformed;
    return;
  }
  double value = 0.0;
  if constexpr (kVoltage)
    value = m.voltage_V;
  else
    value = m.deflection_mm;
  if (m.actuator_id != actuator) {
    ++counts->misaddressed;
  } else if (!std::isfinite(value)) {
    ++counts->nonfinite;
  } else if (*last_utime != kNoUtime && m.utime <= *last_utime) {
    ++counts->out_of_order;
  } else {
    *last_utime = m.utime;
    messages->push_back({m.utime, value, kVoltage});
    ++(kVoltage ? counts->voltage : counts->deflection);
  }
}

// A trial control of the log for this actuator, or nullopt (counted). Logs hold the
// signed trial_control2_t, or trial_control_t from before flexid signed trial control; a
// log is a file, not a request, so either marks a trial.
std::optional<LogControl> ReadControl(const lcm::LogEvent& event, const std::string& actuator,
                                      size_t position, LogCounts* counts) {
  flexid::trial_control_t m;
  flexid::trial_control2_t signed_control;
  bool decoded = DecodeEvent(event, wire::kTrialControl, &m);
  if (!decoded && DecodeEvent(event, wire::kTrialControl2, &signed_control)) {
    decoded = true;
    m.utime = signed_control.utime;
    m.actuator_id = signed_control.actuator_id;
    m.action = signed_control.action;
    m.protocol = signed_control.protocol;
  }
  if (!decoded) {
    ++counts->malformed;
  } else if (m.actuator_id != actuator) {
    ++counts->other_channels;  // another actuator's trial
  } else if (m.action != flexid::trial_control_t::kStart &&
             m.action != flexid::trial_control_t::kStop) {
    ++counts->malformed;
  } else {
    ++counts->trial_control;
    return LogControl{position, m.utime, m.action == flexid::trial_control_t::kStart, m.protocol};
  }
  return std::nullopt;
}

// Pass 1: the accepted messages in log order, and the trial controls between them.
struct LogContents {
  std::vector<BusSample> messages;
  std::vector<LogControl> controls;
};

LogContents ReadLog(const std::string& path, const PlanOptions& options, LogCounts* counts) {
  std::error_code size_error;
  const auto file_size = std::filesystem::file_size(path, size_error);
  if (size_error) throw InputError(path + ": cannot open: " + size_error.message());
  const int64_t framed_bytes = WellFramedLogBytes(path, file_size);
  lcm::LogFile log(path, "r");
  if (!log.good()) throw InputError(path + ": cannot open: " + std::strerror(errno));
  const std::string voltage_channel = options.channels.Voltage(options.actuator);
  const std::string deflection_channel = options.channels.Deflection(options.actuator);
  const std::string trial_channel = options.channels.TrialControl();

  LogContents contents;
  int64_t last_voltage_utime = kNoUtime, last_deflection_utime = kNoUtime;
  int64_t end_of_last_event = 0;
  const lcm::LogEvent* event = nullptr;
  while (static_cast<int64_t>(ftello(log.getFilePtr())) < framed_bytes &&
         (event = log.readNextEvent()) != nullptr) {
    ++counts->events;
    end_of_last_event = static_cast<int64_t>(ftello(log.getFilePtr()));
    if (event->channel == voltage_channel) {
      AcceptSample<flexid::voltage_sample_t>(*event, options.actuator, &last_voltage_utime,
                                             &contents.messages, counts);
    } else if (event->channel == deflection_channel) {
      AcceptSample<flexid::deflection_sample_t>(*event, options.actuator, &last_deflection_utime,
                                                &contents.messages, counts);
    } else if (event->channel == trial_channel) {
      if (std::optional<LogControl> control =
              ReadControl(*event, options.actuator, contents.messages.size(), counts))
        contents.controls.push_back(std::move(*control));
    } else {
      ++counts->other_channels;
    }
  }
  counts->truncated = end_of_last_event < static_cast<int64_t>(file_size);
  if (counts->deflection == 0)
    throw InputError(path + ": no deflection messages of actuator " + options.actuator + " on " +
                     deflection_channel + " (" + std::to_string(counts->events) + " events read, " +
                     std::to_string(counts->malformed) + " malformed)");
  return contents;
}

// Pass 2: trials, pairing state as flexidd keeps it.
void GroupIntoTrials(const LogContents& contents, const std::string& path,
                     const PlanOptions& options, ImportPlan* plan) {
  LogCounts& counts = plan->log;
  const std::vector<BusSample>& messages = contents.messages;
  const std::vector<LogControl>& controls = contents.controls;
  double voltage_V = 0;  // in force
  ImportTrial open;
  bool is_open = false;
  auto close = [&](int64_t end_utime) {
    if (!is_open) return;
    open.end_utime =
        std::max(end_utime, open.messages.empty() ? open.start_utime : open.messages.back().utime);
    if (open.deflections > 0)
      plan->trials.push_back(std::move(open));
    else
      ++counts.empty_trials;
    open = ImportTrial{};
    is_open = false;
  };
  auto begin = [&](int64_t utime, const std::string& protocol) {
    open.protocol = options.protocol.value_or(protocol);
    open.start_utime = utime;
    open.initial_voltage_V = voltage_V;
    is_open = true;
  };
  if (controls.empty()) begin(messages.front().utime, DefaultProtocol(path));
  size_t next_control = 0;
  for (size_t k = 0; k <= messages.size(); ++k) {
    for (; next_control < controls.size() && controls[next_control].position == k; ++next_control) {
      const LogControl& control = controls[next_control];
      close(control.utime);  // a start while a trial is open ends it first, as in flexidd
      if (control.start) begin(control.utime, control.protocol);
    }
    if (k == messages.size()) break;
    const BusSample& m = messages[k];
    if (m.is_voltage) voltage_V = m.value;
    if (!is_open) {
      if (!m.is_voltage) ++counts.outside_trial;
      continue;
    }
    open.messages.push_back(m);
    if (!m.is_voltage) ++open.deflections;
  }
  close(kNoUtime);  // the log ended inside a trial: end at its last message
  if (plan->trials.empty())
    throw InputError(path + ": no deflection of actuator " + options.actuator +
                     " inside a trial (" + std::to_string(counts.trial_control) +
                     " trial-control messages, " + std::to_string(counts.outside_trial) +
                     " deflections outside trials)");
}

// --start-utime: every time shifted so that the first trial starts there.
void ShiftToStart(int64_t start_utime, const std::string& path, ImportPlan* plan) {
  int64_t shift = 0;
  if (__builtin_sub_overflow(start_utime, plan->trials.front().start_utime, &shift))
    throw InputError(path + ": --start-utime is too far from the log's times");
  for (ImportTrial& trial : plan->trials) {
    trial.start_utime = AddUtime(trial.start_utime, shift, path);
    trial.end_utime = AddUtime(trial.end_utime, shift, path);
    for (BusSample& m : trial.messages) m.utime = AddUtime(m.utime, shift, path);
  }
}

}  // namespace

ImportPlan PlanFromLcmLog(const std::string& path, const PlanOptions& options) {
  ImportPlan plan;
  plan.actuator = options.actuator;
  plan.source = path;
  plan.format = "lcmlog";
  const LogContents contents = ReadLog(path, options, &plan.log);
  GroupIntoTrials(contents, path, options, &plan);
  if (options.start_utime) ShiftToStart(*options.start_utime, path, &plan);
  return plan;
}

std::vector<storage::Sample> PairSamples(const ImportTrial& trial) {
  std::vector<storage::Sample> samples;
  samples.reserve(static_cast<size_t>(trial.deflections));
  double voltage_V = trial.initial_voltage_V;
  for (const BusSample& m : trial.messages) {
    if (m.is_voltage)
      voltage_V = m.value;
    else
      samples.push_back({m.utime, voltage_V, m.value});
  }
  return samples;
}

std::vector<StoredImport> StorePlan(storage::Database& db, const ImportPlan& plan,
                                    const std::function<void(int64_t, int64_t)>& progress,
                                    size_t batch_size) {
  batch_size = std::max<size_t>(batch_size, 1);
  const int64_t total = plan.samples();
  int64_t done = 0;
  std::vector<StoredImport> out;
  for (const ImportTrial& trial : plan.trials) {
    const std::vector<storage::Sample> samples = PairSamples(trial);
    StoredImport stored;
    try {
      stored.trial_id = db.StartTrial(plan.actuator, trial.protocol, trial.start_utime);
    } catch (const storage::StorageError& e) {
      throw OperationError(std::string(e.what()) + " (nothing was imported from " + plan.source +
                           ")");
    }
    int64_t last_utime = trial.start_utime;
    try {
      for (size_t begin = 0; begin < samples.size(); begin += batch_size) {
        const size_t count = std::min(batch_size, samples.size() - begin);
        const storage::AppendResult r =
            db.AppendSamples(stored.trial_id, std::span(samples).subspan(begin, count));
        stored.samples += r.inserted;
        last_utime = samples[begin + count - 1].utime;
        done += static_cast<int64_t>(count);
        if (progress) progress(done, total);
      }
      // As flexidd: a trial ends at its last sample.
      db.EndTrial(stored.trial_id, std::max(last_utime, trial.start_utime),
                  storage::TrialState::kComplete);
    } catch (const storage::StorageError& e) {
      std::string marked = "it is marked interrupted";
      try {
        db.EndTrial(stored.trial_id, std::max(last_utime, trial.start_utime),
                    storage::TrialState::kInterrupted);
      } catch (const std::exception&) {
        marked = "it could not be marked interrupted (flexidd does so when it next starts)";
      }
      throw OperationError(plan.source + ": import stopped after " +
                           std::to_string(stored.samples) + " of " +
                           std::to_string(samples.size()) + " samples of trial " +
                           std::to_string(stored.trial_id) + "; " + marked + ": " + e.what());
    }
    out.push_back(stored);
  }
  return out;
}

}  // namespace flexid::cli
