// The data commands of the flexid command line: status, actuators, trials list|show|export|
// import|start|stop, alerts list|follow. Offline on database files written here (no
// daemon), online against a real flexidd (live_daemon.h), and the bus-free importer
// (clients/cli/trial_import.h) in-process, with lcm-logger logs written by the test.
#include <gtest/gtest.h>

#include <chrono>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <lcm/lcm-cpp.hpp>
#include <nlohmann/json.hpp>
#include <sstream>
#include <thread>

#include "child_process.h"
#include "cli_process.h"
#include "clients/cli/trial_import.h"
#include "live_daemon.h"
#include "model/core/errors.h"
#include "model/core/recording.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using testing::ProcessResult;
using testing::RunCommand;
using testing::ScratchDir;
using testing::WriteFile;

const std::string kFlexid = FLEXID_BINARY;
const std::string kRig = FLEXID_RIG_BINARY;
const std::string kSquare = "square:level=2,period=220,duty=0.5,cycles=2";  // 4400 samples

// `flexid --db DB ARGS`.
ProcessResult Offline(const ScratchDir& scratch, const std::string& db, const std::string& args) {
  return RunCommand(kFlexid + " --db '" + db + "' " + args, scratch.path());
}

// A recording CSV from the rig (offline, seeded noise): 10 Hz samples of the protocol.
std::string RigCsv(const ScratchDir& scratch, const std::string& name,
                   const std::string& protocol) {
  const std::string path = scratch.File(name);
  const ProcessResult r = RunCommand(
      kRig + " --out '" + path + "' --protocol " + protocol + " --noise-mm 0.02 --seed 7",
      scratch.path());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  return path;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  text << in.rdbuf();
  return text.str();
}

// Exactly one line on stderr.
bool OneLine(const std::string& err) { return !err.empty() && err.find('\n') == err.size() - 1; }

void ExpectSameRecording(const model::Recording& a, const model::Recording& b) {
  ASSERT_EQ(a.t_s.size(), b.t_s.size());
  for (size_t k = 0; k < a.t_s.size(); ++k) {
    ASSERT_EQ(a.t_s[k], b.t_s[k]) << k;
    ASSERT_EQ(a.voltage_V[k], b.voltage_V[k]) << k;
    ASSERT_EQ(a.deflection_mm[k], b.deflection_mm[k]) << k;
  }
}

// --- lcm-logger logs -------------------------------------------------------------------

template <typename Message>
void WriteEvent(lcm::LogFile& log, const std::string& channel, const Message& m) {
  std::vector<uint8_t> bytes(static_cast<size_t>(m.getEncodedSize()));
  m.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  lcm::LogEvent event{};
  event.timestamp = m.utime;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(bytes.size());
  event.data = bytes.data();
  ASSERT_EQ(log.writeEvent(&event), 0);
}

void WriteRaw(lcm::LogFile& log, const std::string& channel, std::vector<uint8_t> bytes) {
  lcm::LogEvent event{};
  event.timestamp = 1;
  event.channel = channel;
  event.datalen = static_cast<int32_t>(bytes.size());
  event.data = bytes.data();
  ASSERT_EQ(log.writeEvent(&event), 0);
}

flexid::voltage_sample_t Voltage(int64_t utime, const std::string& id, double v) {
  flexid::voltage_sample_t m;
  m.utime = utime;
  m.actuator_id = id;
  m.voltage_V = v;
  return m;
}
flexid::deflection_sample_t Deflection(int64_t utime, const std::string& id, double mm) {
  flexid::deflection_sample_t m;
  m.utime = utime;
  m.actuator_id = id;
  m.deflection_mm = mm;
  return m;
}
flexid::trial_control_t Control(int64_t utime, const std::string& id, bool start,
                                const std::string& protocol) {
  flexid::trial_control_t m;
  m.utime = utime;
  m.actuator_id = id;
  m.action = start ? flexid::trial_control_t::kStart : flexid::trial_control_t::kStop;
  m.protocol = protocol;
  return m;
}

constexpr int64_t kLogStart = 1'700'000'000'000'000;

// 50 deflections of S1 at 10 Hz; 2 V until just before sample 25, 0 V after; plus one of
// each kind of bad or foreign event. The stored samples are (base + k*0.1 s, v_k, 0.01 k).
void WriteMixedLog(const std::string& path) {
  lcm::LogFile log(path, "w");
  ASSERT_TRUE(log.good());
  WriteEvent(log, "FLEXID/S1/VOLTAGE", Voltage(kLogStart - 1, "S1", 2.0));
  for (int k = 0; k < 50; ++k) {
    const int64_t utime = kLogStart + k * 100'000;
    if (k == 25) WriteEvent(log, "FLEXID/S1/VOLTAGE", Voltage(utime - 50'000, "S1", 0.0));
    WriteEvent(log, "FLEXID/S1/DEFLECTION", Deflection(utime, "S1", 0.01 * k));
    WriteEvent(log, "FLEXID/S2/DEFLECTION", Deflection(utime, "S2", 5.0));  // other actuator
  }
  WriteRaw(log, "FLEXID/S1/DEFLECTION", {1, 2, 3, 4, 5});  // malformed
  WriteEvent(log, "FLEXID/S1/DEFLECTION",
             Deflection(kLogStart + 9'000'000, "S3", 1));  // misaddressed
  WriteEvent(log, "FLEXID/S1/DEFLECTION",
             Deflection(kLogStart + 9'000'000, "S1", NAN));                 // non-finite
  WriteEvent(log, "FLEXID/S1/DEFLECTION", Deflection(kLogStart, "S1", 7));  // out of order
  // A string length of INT32_MIN: wire::WellFormed must catch it before decode().
  flexid::deflection_sample_t probe = Deflection(kLogStart + 9'000'000, "S1", 1);
  std::vector<uint8_t> bytes(static_cast<size_t>(probe.getEncodedSize()));
  probe.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  bytes[16] = 0x80, bytes[17] = 0, bytes[18] = 0, bytes[19] = 0;
  WriteRaw(log, "FLEXID/S1/DEFLECTION", bytes);
}

// ========================================================================================
// The importer, in-process

TEST(TrialImport, LogMessagesArePairedAsFlexiddPairsThem) {
  const ScratchDir scratch;
  const std::string path = scratch.File("mixed.lcmlog");
  WriteMixedLog(path);
  EXPECT_TRUE(cli::IsLcmLog(path));
  cli::PlanOptions options;
  options.actuator = "S1";
  const cli::ImportPlan plan = cli::PlanFromLcmLog(path, options);
  EXPECT_EQ(plan.log.deflection, 50);
  EXPECT_EQ(plan.log.voltage, 2);
  EXPECT_EQ(plan.log.malformed, 2);
  EXPECT_EQ(plan.log.misaddressed, 1);
  EXPECT_EQ(plan.log.nonfinite, 1);
  EXPECT_EQ(plan.log.out_of_order, 1);
  EXPECT_EQ(plan.log.other_channels, 50);
  EXPECT_FALSE(plan.log.truncated);
  ASSERT_EQ(plan.trials.size(), 1u);
  EXPECT_EQ(plan.trials[0].start_utime, kLogStart - 1);  // the first message
  EXPECT_EQ(plan.trials[0].protocol, "import mixed.lcmlog");
  const std::vector<storage::Sample> samples = cli::PairSamples(plan.trials[0]);
  ASSERT_EQ(samples.size(), 50u);
  for (int k = 0; k < 50; ++k) {
    EXPECT_EQ(samples[k].utime, kLogStart + k * 100'000);
    EXPECT_EQ(samples[k].voltage_V, k < 25 ? 2.0 : 0.0) << k;
    EXPECT_EQ(samples[k].deflection_mm, 0.01 * k);
  }
}

TEST(TrialImport, LogTrialControlSplitsTrials) {
  const ScratchDir scratch;
  const std::string path = scratch.File("split.log");
  {
    lcm::LogFile log(path, "w");
    int64_t t = kLogStart;
    WriteEvent(log, "FLEXID/TRIAL", Control(t, "S1", true, "first"));
    WriteEvent(log, "FLEXID/TRIAL", Control(t, "S9", true, "someone else's"));
    WriteEvent(log, "FLEXID/S1/VOLTAGE", Voltage(t, "S1", 3.0));
    for (int k = 0; k < 10; ++k)
      WriteEvent(log, "FLEXID/S1/DEFLECTION", Deflection(t += 1000, "S1", k));
    WriteEvent(log, "FLEXID/TRIAL", Control(t + 1, "S1", false, "first"));
    for (int k = 0; k < 3; ++k)
      WriteEvent(log, "FLEXID/S1/DEFLECTION", Deflection(t += 1000, "S1", k));
    WriteEvent(log, "FLEXID/TRIAL", Control(t + 1, "S1", true, "second"));
    for (int k = 0; k < 10; ++k)
      WriteEvent(log, "FLEXID/S1/DEFLECTION", Deflection(t += 1000, "S1", k));
    WriteEvent(log, "FLEXID/TRIAL", Control(t + 1, "S1", true, "third, empty"));
  }
  cli::PlanOptions options;
  options.actuator = "S1";
  const cli::ImportPlan plan = cli::PlanFromLcmLog(path, options);
  ASSERT_EQ(plan.trials.size(), 2u);
  EXPECT_EQ(plan.trials[0].protocol, "first");
  EXPECT_EQ(plan.trials[1].protocol, "second");
  EXPECT_EQ(plan.trials[0].deflections, 10);
  EXPECT_EQ(plan.trials[1].deflections, 10);
  EXPECT_EQ(plan.trials[0].start_utime, kLogStart);
  EXPECT_EQ(plan.log.outside_trial, 3);
  EXPECT_EQ(plan.log.empty_trials, 1);
  EXPECT_EQ(plan.log.trial_control, 4);
  // The voltage in force carries over into the second trial, as in flexidd.
  EXPECT_EQ(cli::PairSamples(plan.trials[1]).front().voltage_V, 3.0);

  // --start-utime shifts every time; --protocol names every trial.
  options.start_utime = 5'000'000;
  options.protocol = "replayed";
  const cli::ImportPlan shifted = cli::PlanFromLcmLog(path, options);
  EXPECT_EQ(shifted.trials[0].start_utime, 5'000'000);
  EXPECT_EQ(shifted.trials[1].protocol, "replayed");
  EXPECT_EQ(cli::PairSamples(shifted.trials[0]).front().utime, 5'000'000 + 1000);
}

TEST(TrialImport, TruncatedLogIsReportedAndNoDeflectionsIsAnError) {
  const ScratchDir scratch;
  const std::string path = scratch.File("cut.lcmlog");
  WriteMixedLog(path);
  const std::string whole = ReadText(path);
  WriteFile(path, whole.substr(0, whole.size() - 7));
  cli::PlanOptions options;
  options.actuator = "S1";
  EXPECT_TRUE(cli::PlanFromLcmLog(path, options).log.truncated);
  options.actuator = "S7";
  EXPECT_THROW(cli::PlanFromLcmLog(path, options), model::InputError);
}

TEST(TrialImport, CsvTimesAndCommentsRoundTrip) {
  const ScratchDir scratch;
  storage::Trial trial;
  trial.id = 4;
  trial.actuator_id = "S1";
  trial.protocol = "odd\\text\nwith a newline";
  trial.start_utime = 1'000'000;
  const std::string path = scratch.File("t.csv");
  WriteFile(path, cli::ExportCommentLines(trial, 1'500'000) +
                      "t_s,voltage_V,deflection_mm\n0,1,2\n0.1,1,3\n0.2,0,4\n");
  const cli::ExportComments comments = cli::ReadExportComments(path);
  EXPECT_EQ(comments.protocol, trial.protocol);
  EXPECT_EQ(comments.start_utime, 1'000'000);
  EXPECT_EQ(comments.first_sample_utime, 1'500'000);
  cli::PlanOptions options;
  options.actuator = "S2";
  const cli::ImportPlan plan = cli::PlanFromCsv(path, options);
  EXPECT_EQ(plan.trials[0].start_utime, 1'000'000);
  const auto samples = cli::PairSamples(plan.trials[0]);
  ASSERT_EQ(samples.size(), 3u);
  EXPECT_EQ(samples[1].utime, 1'600'000);
  EXPECT_EQ(samples[2].voltage_V, 0.0);
  EXPECT_EQ(plan.trials[0].messages.size(), 5u);  // a voltage message only when it changes

  // Two rows within a microsecond cannot be stored apart.
  WriteFile(path, "t_s,voltage_V,deflection_mm\n0,1,2\n0.0000001,1,3\n");
  EXPECT_THROW(cli::PlanFromCsv(path, options), model::InputError);
}

// ========================================================================================
// Offline: --db

TEST(CliDataOffline, ImportExportImportIsExact) {
  const ScratchDir scratch;
  const std::string db = scratch.File("new.db");  // does not exist yet: import creates it
  const std::string csv = RigCsv(scratch, "square.csv", kSquare);
  const ProcessResult imported =
      Offline(scratch, db, "trials import '" + csv + "' --actuator S1 --protocol sq --json");
  ASSERT_EQ(imported.exit_code, 0) << imported.err;
  const auto doc = nlohmann::json::parse(imported.out);
  EXPECT_EQ(doc["samples"], 4400);
  EXPECT_EQ(doc["actuator"], "S1");
  const int64_t id = doc["trial"].get<int64_t>();

  const std::string exported = scratch.File("export.csv");
  const ProcessResult ex =
      Offline(scratch, db, "trials export " + std::to_string(id) + " --out '" + exported + "'");
  ASSERT_EQ(ex.exit_code, 0) << ex.err;
  ExpectSameRecording(model::ReadRecordingCsv(csv), model::ReadRecordingCsv(exported));
  const std::string text = ReadText(exported);
  EXPECT_NE(text.find("# protocol: sq\n"), std::string::npos) << text.substr(0, 300);
  EXPECT_NE(text.find("# actuator: S1\n"), std::string::npos);

  // Import of our own export restores protocol and times; export to stdout is the same file
  // apart from the trial id and actuator.
  const ProcessResult again =
      Offline(scratch, db, "trials import '" + exported + "' --actuator S2 --json");
  ASSERT_EQ(again.exit_code, 0) << again.err;
  const int64_t id2 = nlohmann::json::parse(again.out)["trial"].get<int64_t>();
  const ProcessResult list = Offline(scratch, db, "trials list --json");
  ASSERT_EQ(list.exit_code, 0) << list.err;
  const auto trials = nlohmann::json::parse(list.out)["trials"];
  ASSERT_EQ(trials.size(), 2u);
  EXPECT_EQ(trials[0]["start_utime"], trials[1]["start_utime"]);
  EXPECT_EQ(trials[0]["protocol"], "sq");
  EXPECT_EQ(trials[1]["protocol"], "sq");
  const ProcessResult stdout_export = Offline(scratch, db, "trials export " + std::to_string(id2));
  ASSERT_EQ(stdout_export.exit_code, 0) << stdout_export.err;
  auto strip = [](std::string s) {
    std::string out, line;
    std::istringstream in(s);
    while (std::getline(in, line))
      if (line.rfind("# trial:", 0) != 0 && line.rfind("# actuator:", 0) != 0) out += line + "\n";
    return out;
  };
  EXPECT_EQ(strip(stdout_export.out), strip(text));

  // --start-utime overrides the file's start; the spacing stays.
  const ProcessResult moved = Offline(
      scratch, db, "trials import '" + exported + "' --actuator S3 --start-utime 1000000 --json");
  ASSERT_EQ(moved.exit_code, 0) << moved.err;
  const ProcessResult shown = Offline(
      scratch, db,
      "trials show " + std::to_string(nlohmann::json::parse(moved.out)["trial"].get<int64_t>()) +
          " --json");
  ASSERT_EQ(shown.exit_code, 0) << shown.err;
  const auto show = nlohmann::json::parse(shown.out);
  EXPECT_EQ(show["trial"]["start_utime"], 1000000);
  EXPECT_EQ(show["summary"]["first_utime"], 1000000);
  EXPECT_NEAR(show["summary"]["duration_s"].get<double>(), 439.9, 1e-9);
  EXPECT_NEAR(show["summary"]["sample_rate_Hz"].get<double>(), 10.0, 1e-9);
  ASSERT_EQ(show["summary"]["voltage_levels_V"].size(), 1u);
  EXPECT_NEAR(show["summary"]["voltage_levels_V"][0].get<double>(), 2.0, 1e-9);
  EXPECT_GT(show["summary"]["deflection_max_mm"].get<double>(), 1.0);
}

TEST(CliDataOffline, BadInputIsRejectedBeforeAnythingIsWritten) {
  const ScratchDir scratch;
  const std::string db = scratch.File("f.db");
  const std::string csv = RigCsv(scratch, "ok.csv", "step:level=2,duration=60");
  ASSERT_EQ(Offline(scratch, db, "trials import '" + csv + "' --actuator S1").exit_code, 0);

  // A time going backwards deep in the file: exit 2, one line naming file and line.
  std::string text = ReadText(csv);
  const size_t cut = text.find("\n50,");
  ASSERT_NE(cut, std::string::npos);
  text.insert(cut + 1, "49.95,1,1\n1,1,1\n");
  const std::string bad = scratch.File("bad.csv");
  WriteFile(bad, text);
  const std::vector<std::string> bad_usage = {"trials import '" + bad + "' --actuator S1",
                                              "trials import missing.csv --actuator S1",
                                              "trials import '" + csv + "' --actuator 'S 1'",
                                              "trials show 0",
                                              "trials show 99",
                                              "trials list --limit 0",
                                              "alerts list --since-utime -1",
                                              "trials start --actuator S1",
                                              "alerts follow"};
  for (const std::string& args : bad_usage) {
    const ProcessResult r = Offline(scratch, db, args);
    EXPECT_EQ(r.exit_code, 2) << args << "\n" << r.err;
    EXPECT_TRUE(OneLine(r.err)) << args << "\n" << r.err;
  }
  EXPECT_EQ(Offline(scratch, db, "trials import '" + csv + "'").exit_code, 2);  // no --actuator
  const ProcessResult r = Offline(scratch, db, "trials import '" + bad + "' --actuator S1");
  EXPECT_NE(r.err.find("bad.csv:"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("strictly increasing"), std::string::npos) << r.err;

  storage::Database file = storage::Database::Open(db);
  EXPECT_EQ(file.Trials().size(), 1u);
  EXPECT_EQ(file.IntegrityCheck(), "ok");

  // Commands other than import refuse a database file that does not exist.
  const ProcessResult missing = Offline(scratch, scratch.File("none.db"), "status");
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_TRUE(OneLine(missing.err)) << missing.err;
}

TEST(CliDataOffline, LogImportStoresPairedSamplesAndReportsBadEvents) {
  const ScratchDir scratch;
  const std::string db = scratch.File("f.db");
  const std::string log = scratch.File("lcmlog-2024-01-05.00");  // no extension: by content
  WriteMixedLog(log);
  const ProcessResult r = Offline(scratch, db, "trials import '" + log + "' --actuator S1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_EQ(doc["format"], "lcmlog");
  EXPECT_EQ(doc["samples"], 50);
  EXPECT_EQ(doc["log"]["malformed"], 2);
  EXPECT_EQ(doc["log"]["misaddressed"], 1);
  EXPECT_EQ(doc["log"]["nonfinite"], 1);
  EXPECT_EQ(doc["log"]["out_of_order"], 1);

  storage::Database file = storage::Database::Open(db);
  const auto samples = file.Samples(doc["trial"].get<int64_t>());
  ASSERT_EQ(samples.size(), 50u);
  EXPECT_EQ(samples[24].voltage_V, 2.0);
  EXPECT_EQ(samples[25].voltage_V, 0.0);
  EXPECT_EQ(samples[49].utime, kLogStart + 49 * 100'000);

  const ProcessResult human = Offline(scratch, db, "trials import '" + log + "' --actuator S1");
  ASSERT_EQ(human.exit_code, 0) << human.err;
  EXPECT_NE(human.out.find("2 malformed"), std::string::npos) << human.out;
  EXPECT_NE(human.out.find("imported trial 2: 50 samples of S1"), std::string::npos) << human.out;
}

TEST(CliDataOffline, StatusActuatorsAlertsTables) {
  const ScratchDir scratch;
  const std::string db = scratch.File("f.db");
  {
    storage::Database file = storage::Database::Open(db);
    const int64_t trial = file.StartTrial("S1", "step", 1'700'000'000'000'000);
    file.AppendSamples(trial, std::vector<storage::Sample>{{1'700'000'000'000'000, 2, 0.5},
                                                           {1'700'000'000'100'000, 2, 0.6}});
    file.EndTrial(trial, 1'700'000'000'100'000, storage::TrialState::kComplete);
    file.StartTrial("S2", "open", 1'700'000'100'000'000);
    storage::AlertRecord alert{
        0,     "S1", "back_relaxation",        1, 1'700'000'000'500'000, 0, 0,
        -0.42, 0.1,  "Deflection creeps back."};
    file.StoreAlert(alert);
    alert.actuator_id = "S2";
    alert.kind = "drift";
    alert.utime = 1'700'000'200'000'000;
    alert.magnitude_mm = NAN;
    file.StoreAlert(alert);
  }
  const ProcessResult status = Offline(scratch, db, "status --json");
  ASSERT_EQ(status.exit_code, 0) << status.err;
  const auto s = nlohmann::json::parse(status.out)["status"][0];
  EXPECT_EQ(s["trials"], 2);
  EXPECT_EQ(s["samples_stored"], 2);
  EXPECT_EQ(s["alerts"], 2);
  const ProcessResult status_table = Offline(scratch, db, "status");
  EXPECT_NE(status_table.out.find("trials_recording"), std::string::npos) << status_table.out;

  const ProcessResult actuators = Offline(scratch, db, "actuators");
  ASSERT_EQ(actuators.exit_code, 0) << actuators.err;
  EXPECT_NE(actuators.out.find("40 x 8 x 2"), std::string::npos) << actuators.out;
  EXPECT_NE(actuators.out.find("trial 2"), std::string::npos) << actuators.out;  // S2 recording

  const ProcessResult list = Offline(scratch, db, "trials list --actuator S1");
  ASSERT_EQ(list.exit_code, 0) << list.err;
  EXPECT_NE(list.out.find("2023-11-14T22:13:20Z"), std::string::npos) << list.out;
  EXPECT_NE(list.out.find("duration_s"), std::string::npos) << list.out;
  EXPECT_EQ(list.out.find("open"), std::string::npos) << list.out;  // S2's trial

  const ProcessResult alerts = Offline(scratch, db, "alerts list --json");
  ASSERT_EQ(alerts.exit_code, 0) << alerts.err;
  const auto a = nlohmann::json::parse(alerts.out)["alerts"];
  ASSERT_EQ(a.size(), 2u);
  EXPECT_EQ(a[0]["kind"], "drift");  // newest first
  EXPECT_TRUE(a[0]["magnitude_mm"].is_null());
  const ProcessResult since =
      Offline(scratch, db, "alerts list --actuator S1 --since-utime 1700000000000000");
  ASSERT_EQ(since.exit_code, 0) << since.err;
  EXPECT_NE(since.out.find("back_relaxation  warning"), std::string::npos) << since.out;
  EXPECT_NE(since.out.find("-0.42"), std::string::npos) << since.out;
  EXPECT_EQ(since.out.find("drift"), std::string::npos) << since.out;
}

// ========================================================================================
// Online: a real flexidd

TEST(CliDataOnline, ReadsAgreeWithTheFileAndStartStopWork) {
  const ScratchDir scratch;
  testing::LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  const int64_t id = daemon.RecordTrial("step:level=2,duration=60");

  const ProcessResult status = daemon.Flexid("status");
  ASSERT_EQ(status.exit_code, 0) << status.err;
  EXPECT_NE(status.out.find("samples_stored"), std::string::npos) << status.out;
  const ProcessResult actuators = daemon.Flexid("actuators --json");
  ASSERT_EQ(actuators.exit_code, 0) << actuators.err;
  EXPECT_EQ(nlohmann::json::parse(actuators.out)["actuators"][0]["id"], "S1");

  const std::string db = daemon.db().string();
  const ProcessResult online = daemon.Flexid("trials list --json");
  const ProcessResult offline = Offline(scratch, db, "trials list --json");
  ASSERT_EQ(online.exit_code, 0) << online.err;
  ASSERT_EQ(offline.exit_code, 0) << offline.err;
  EXPECT_EQ(testing::RowsWithoutSource(online.out, "trials"),
            testing::RowsWithoutSource(offline.out, "trials"));
  const std::string show = "trials show " + std::to_string(id) + " --json";
  EXPECT_EQ(nlohmann::json::parse(daemon.Flexid(show).out),
            nlohmann::json::parse(Offline(scratch, db, show).out));
  const std::string ex = "trials export " + std::to_string(id);
  const ProcessResult online_csv = daemon.Flexid(ex);
  ASSERT_EQ(online_csv.exit_code, 0) << online_csv.err;
  EXPECT_EQ(online_csv.out, Offline(scratch, db, ex).out);
  EXPECT_GT(std::count(online_csv.out.begin(), online_csv.out.end(), '\n'), 500);

  const ProcessResult start =
      daemon.Flexid("trials start --actuator S1 --protocol manual-test --json");
  ASSERT_EQ(start.exit_code, 0) << start.err;
  const int64_t manual = nlohmann::json::parse(start.out)["trial"].get<int64_t>();
  EXPECT_GT(manual, id);
  EXPECT_NE(daemon.Flexid("actuators").out.find("trial " + std::to_string(manual)),
            std::string::npos);
  const ProcessResult stop = daemon.Flexid("trials stop --actuator S1");
  ASSERT_EQ(stop.exit_code, 0) << stop.err;
  EXPECT_EQ(stop.out, "trial " + std::to_string(manual) + " of S1 stopped\n");
  const ProcessResult again = daemon.Flexid("trials stop --actuator S1");
  EXPECT_EQ(again.exit_code, 2) << again.err;  // nothing recording
  EXPECT_TRUE(OneLine(again.err)) << again.err;
}

TEST(CliDataOnline, ImportReplaysCsvAndLogWithoutLosingSamples) {
  const ScratchDir scratch;
  testing::LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  const std::string csv = RigCsv(scratch, "square.csv", kSquare);
  const ProcessResult r =
      daemon.Flexid("trials import '" + csv + "' --actuator S2 --protocol replay --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_EQ(doc["samples"], 4400);
  const int64_t id = doc["trial"].get<int64_t>();

  // flexidd paired every deflection with the voltage the file gives it.
  const std::string exported = scratch.File("back.csv");
  const ProcessResult ex =
      Offline(scratch, daemon.db().string(),
              "trials export " + std::to_string(id) + " --out '" + exported + "'");
  ASSERT_EQ(ex.exit_code, 0) << ex.err;
  ExpectSameRecording(model::ReadRecordingCsv(csv), model::ReadRecordingCsv(exported));
  const auto list =
      nlohmann::json::parse(daemon.Flexid("trials list --actuator S2 --json").out)["trials"];
  EXPECT_EQ(list[0]["protocol"], "replay");
  EXPECT_EQ(list[0]["state"], "complete");

  // A log with two trials, replayed with its own trial control.
  const std::string log = scratch.File("two.lcmlog");
  {
    lcm::LogFile out(log, "w");
    int64_t t = kLogStart;
    for (const char* protocol : {"log-a", "log-b"}) {
      WriteEvent(out, "FLEXID/TRIAL", Control(t, "S3", true, protocol));
      WriteEvent(out, "FLEXID/S3/VOLTAGE", Voltage(t, "S3", 4.0));
      for (int k = 0; k < 300; ++k)
        WriteEvent(out, "FLEXID/S3/DEFLECTION", Deflection(t += 100'000, "S3", 0.001 * k));
      WriteEvent(out, "FLEXID/TRIAL", Control(t += 100'000, "S3", false, protocol));
    }
  }
  const ProcessResult replay = daemon.Flexid("trials import '" + log + "' --actuator S3 --json");
  ASSERT_EQ(replay.exit_code, 0) << replay.err;
  const auto replayed = nlohmann::json::parse(replay.out);
  ASSERT_EQ(replayed["trials"].size(), 2u);
  EXPECT_EQ(replayed["samples"], 600);
  const auto s3 =
      nlohmann::json::parse(daemon.Flexid("trials list --actuator S3 --json").out)["trials"];
  ASSERT_EQ(s3.size(), 2u);
  EXPECT_EQ(s3[0]["protocol"], "log-b");
  EXPECT_EQ(s3[0]["samples"], 300);
  EXPECT_EQ(s3[0]["start_utime"], kLogStart + 301 * 100'000);

  // Replaying the same times again: flexidd would not take them in order; the import says
  // so before sending anything, and --start-utime shifts them.
  const ProcessResult stale = daemon.Flexid("trials import '" + log + "' --actuator S3");
  EXPECT_EQ(stale.exit_code, 2);
  EXPECT_NE(stale.err.find("--start-utime"), std::string::npos) << stale.err;
  EXPECT_TRUE(OneLine(stale.err)) << stale.err;
  EXPECT_EQ(
      nlohmann::json::parse(daemon.Flexid("trials list --actuator S3 --json").out)["trials"].size(),
      2u);
  const ProcessResult shifted =
      daemon.Flexid("trials import '" + log + "' --actuator S3 --start-utime " +
                    std::to_string(kLogStart + 1'000'000'000) + " --json");
  ASSERT_EQ(shifted.exit_code, 0) << shifted.err;
  EXPECT_EQ(nlohmann::json::parse(shifted.out)["samples"], 600);

  // An actuator that is recording is not replayed into.
  ASSERT_EQ(daemon.Flexid("trials start --actuator S2").exit_code, 0);
  const ProcessResult busy = daemon.Flexid("trials import '" + csv + "' --actuator S2");
  EXPECT_EQ(busy.exit_code, 2);
  EXPECT_NE(busy.err.find("is recording trial"), std::string::npos) << busy.err;
}

// alerts follow needs only the bus: the test publishes the alerts itself.
TEST(CliDataOnline, AlertsFollowPrintsJsonLinesAndEndsCleanlyOnSigterm) {
  const ScratchDir scratch;
  const std::string url = testing::RandomUrl();
  const std::string out = scratch.File("follow.out");
  testing::ChildProcess follow(
      {kFlexid, "--lcm", url, "alerts", "follow", "--actuator", "S1", "--json"}, out,
      scratch.File("follow.err"));
  lcm::LCM lcm(url);
  ASSERT_TRUE(lcm.good());
  flexid::alert_t alert;
  alert.utime = 1'700'000'000'000'000;
  alert.actuator_id = "S1";
  alert.kind = "back_relaxation";
  alert.severity = flexid::alert_t::kWarning;
  alert.magnitude_mm = -0.5;
  alert.threshold_mm = 0.1;
  alert.text = "Deflection creeps back.";
  flexid::alert_t other = alert;
  other.actuator_id = "S2";
  // Publish until the follower has subscribed and printed one (it starts asynchronously).
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(10);
  while (ReadText(out).empty() && std::chrono::steady_clock::now() < end) {
    lcm.publish("FLEXID/ALERT", &other);
    lcm.publish("FLEXID/ALERT", &alert);
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  ASSERT_TRUE(follow.Signal(SIGTERM));
  const auto status = follow.Wait(std::chrono::seconds(5));
  ASSERT_TRUE(status.has_value());
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 0) << testing::DescribeStatus(*status);
  std::istringstream lines(ReadText(out));
  std::string line;
  int count = 0;
  while (std::getline(lines, line)) {
    const auto j = nlohmann::json::parse(line);  // every line a JSON document
    EXPECT_EQ(j["actuator"], "S1");
    EXPECT_EQ(j["kind"], "back_relaxation");
    EXPECT_EQ(j["magnitude_mm"], -0.5);
    EXPECT_FALSE(j.contains("id"));
    ++count;
  }
  EXPECT_GE(count, 1);

  // --seconds ends by itself; the human form is one line per alert.
  const ProcessResult timed =
      RunCommand(kFlexid + " --lcm '" + url + "' alerts follow --seconds 0.5", scratch.path());
  EXPECT_EQ(timed.exit_code, 0) << timed.err;
  const ProcessResult bad =
      RunCommand(kFlexid + " --lcm '" + url + "' alerts follow --seconds -1", scratch.path());
  EXPECT_EQ(bad.exit_code, 2);
}

}  // namespace
}  // namespace flexid
