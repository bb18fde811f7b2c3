// The flexid database: one SQLite file holding actuators, trials, their samples, identified
// models and alerts (DESIGN.md, "storage/"). This is the only place in flexid that speaks
// SQL; everything above it uses the typed API below. Every statement is a prepared
// statement with bound values; no SQL is ever built from values.
//
// Units: times are `utime`, integer microseconds of message time (DESIGN.md, "Bus");
// voltages in volts, deflections and geometry in millimetres, concentrations in mol/L.
//
// Durability: the file is in WAL mode with synchronous=NORMAL. A transaction is in the
// operating system (the -wal file) when its commit returns, so it survives the process
// being killed (kill -9, a crash); only an OS crash or a power cut can lose the
// transactions committed since the last checkpoint, and none of them corrupts the file.
//
// Errors: every failure throws StorageError, whose one-line message names the database
// file and the problem, e.g. "var/flexid.db: cannot open: file is not a database".
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

struct sqlite3;

namespace flexid::storage {

struct StorageError : std::runtime_error {
  explicit StorageError(const std::string& what, bool may_pass = false)
      : runtime_error(what), transient(may_pass) {}
  // True when the same write may succeed later: the database was busy or locked, full,
  // read-only or failing I/O. False when the write itself was refused (e.g. a trial that
  // does not exist, an id already taken): retrying it cannot help.
  bool transient = false;
};

// A physical actuator (the seed paper's printed strip). Defaults are the seed's geometry
// and electrolyte; StartTrial creates an actuator with these values when it is unknown.
struct Actuator {
  std::string id;  // non-empty, e.g. "S1"
  double length_mm = 40, width_mm = 8, thickness_mm = 2;
  std::string pattern, material = "chitosan", electrolyte = "NaOH";
  double concentration_M = 0.12;  // electrolyte concentration, mol/L
};

enum class TrialState { kRecording, kComplete, kInterrupted };

// "recording" | "complete" | "interrupted" (also the text stored in the database).
const char* TrialStateName(TrialState state);

struct Trial {
  int64_t id = 0;
  std::string actuator_id;
  std::string protocol;  // as given to StartTrial, e.g. "square:level=5,period=220"
  int64_t start_utime = 0, end_utime = 0;  // end_utime is 0 while recording
  TrialState state = TrialState::kRecording;
  int64_t samples = 0;  // number of samples stored
};

// A deflection sample paired with the voltage in force at its time.
struct Sample {
  int64_t utime = 0;
  double voltage_V = 0;
  double deflection_mm = 0;
};

// A sample addressed to a trial, for AppendSamples over several trials.
struct TrialSample {
  int64_t trial_id = 0;
  Sample sample;
};

// What AppendSamples did with its input. inserted + duplicates + invalid == input size.
struct AppendResult {
  int64_t inserted = 0;    // new rows
  int64_t duplicates = 0;  // (trial, utime) already stored: ignored, the stored row is kept
  int64_t invalid = 0;     // rejected: a NaN or infinite value, or (multi-trial form only)
                           // a trial that does not exist
};

struct ModelRecord {
  int64_t id = 0;
  std::string actuator_id;
  int32_t version = 0;  // 1, 2, ... per actuator
  int64_t created_utime = 0;
  std::string model_json;          // the "flexid.model/1" document
  std::string fit_json;            // fit figures
  std::vector<int64_t> trial_ids;  // trials the model was identified on, in this order
  std::string samples_hash;        // HashSamples of the samples used
  std::string flexid_version;      // of the build that identified it
  bool active = false;             // at most one active model per actuator
  // A proposed version's lineage (a JSON object: the parent version, the effects added
  // with their parameters and intervals, the held-out gain, the trials diagnosed; see
  // daemon/proposal.h); empty for a model identified from trials.
  std::string lineage_json;
};

struct AlertRecord {
  int64_t id = 0;
  std::string actuator_id, kind;  // kind: "back_relaxation", "drift", "residual", ...
  int32_t severity = 0;
  int64_t utime = 0, start_utime = 0, end_utime = 0;
  double magnitude_mm = 0, threshold_mm = 0;  // NaN is stored as SQL NULL and read as NaN
  std::string text;
};

// One connection to a flexid database file. Not thread-safe: use one Database per thread
// (SQLite serialises writers across connections; readers never wait for writers in WAL).
class Database {
 public:
  static constexpr int kSchemaVersion = 2;

  // Opens the file (creating it if absent) and migrates it to kSchemaVersion. Sets
  // journal_mode=WAL, synchronous=NORMAL (see the file comment for the loss window),
  // foreign_keys=ON and a busy timeout of 5000 ms. Throws StorageError for a file that is
  // not a SQLite database, a SQLite database that is not a flexid one (it is left
  // untouched), a database from a newer flexid (schema version > kSchemaVersion), a file
  // that cannot be written (read-only file or directory), and a database locked by
  // another connection for longer than the busy timeout.
  static Database Open(const std::string& path);

  Database(Database&& other) noexcept;
  Database& operator=(Database&& other) noexcept;
  ~Database();

  // The schema version of the open file (kSchemaVersion after Open).
  int SchemaVersion() const;
  const std::string& path() const { return path_; }

  // --- actuators -------------------------------------------------------------------
  // Inserts the actuator or replaces every field of the stored one with the same id.
  void UpsertActuator(const Actuator& actuator);
  // All actuators, by id.
  std::vector<Actuator> Actuators();
  std::optional<Actuator> FindActuator(const std::string& id);

  // --- trials ----------------------------------------------------------------------
  // Creates a trial in state "recording" and returns its id; creates the actuator with
  // the defaults of Actuator if it is unknown.
  int64_t StartTrial(const std::string& actuator_id, const std::string& protocol,
                     int64_t start_utime);
  // The same with the id given (flexidd hands out trial ids on its loop: SampleWriter).
  // Throws if a trial with that id exists.
  void InsertTrial(int64_t trial_id, const std::string& actuator_id, const std::string& protocol,
                   int64_t start_utime);
  // The highest trial id stored (0: none).
  int64_t LastTrialId();
  // The latest time any trial stored reaches (its end, or its start while it records);
  // nullopt without trials.
  std::optional<int64_t> LatestTrialUtime();
  // Sets the end time and the final state (kComplete or kInterrupted). Throws if the
  // trial does not exist or state is kRecording.
  void EndTrial(int64_t trial_id, int64_t end_utime, TrialState state);
  // For daemon start-up: every trial still "recording" (its recorder died) becomes
  // "interrupted", ending at the utime of its last stored sample, or at its own start when
  // it has none (message time throughout: no wall clock). Returns how many trials changed.
  int MarkRecordingTrialsInterrupted();
  // Trials, newest first (by start_utime, then id), optionally of one actuator, at most
  // `limit` of them (negative: no limit). Each carries its sample count.
  std::vector<Trial> Trials(const std::optional<std::string>& actuator_id = {}, int limit = 1000);
  std::optional<Trial> FindTrial(int64_t id);

  // --- samples ---------------------------------------------------------------------
  // Stores the samples of one trial in one transaction. A sample whose (trial, utime) is
  // already stored is ignored (the first one written wins, whatever its values), and so
  // is one with a NaN or infinite value; neither aborts the batch, both are counted in
  // the result. Throws if the trial does not exist. Samples may come in any order.
  AppendResult AppendSamples(int64_t trial_id, std::span<const Sample> samples);
  // The same for samples of several trials, in one transaction (the SampleWriter's
  // batch). A sample of a trial that does not exist is counted as invalid, not thrown.
  AppendResult AppendSamples(std::span<const TrialSample> samples);
  // The samples of a trial in utime order (empty for an unknown trial). Doubles read back
  // bit for bit as written, except that -0.0 reads back as 0.0.
  std::vector<Sample> Samples(int64_t trial_id);
  // One page of them: the samples with utime > after_utime, in utime order, skipping the
  // first `offset` of those and returning at most `limit` (>= 0). Paging by after_utime
  // (the last utime of the previous page) costs the same for every page.
  std::vector<Sample> SamplesPage(int64_t trial_id, int64_t after_utime, int64_t offset,
                                  int64_t limit);
  // Number of samples stored for the trial (0 for an unknown trial).
  int64_t SampleCount(int64_t trial_id);

  // --- models ----------------------------------------------------------------------
  // Stores a model as the next version of its actuator (1 + the highest stored version)
  // and returns it with id and version assigned; record.id and record.version are
  // ignored. An empty flexid_version becomes this build's version. If record.active,
  // every other model of the actuator is deactivated in the same transaction. Creates
  // the actuator with defaults if it is unknown; throws if a trial id does not exist.
  ModelRecord StoreModel(ModelRecord record);
  // Models of an actuator, newest version first.
  std::vector<ModelRecord> Models(const std::string& actuator_id);
  std::optional<ModelRecord> FindModel(const std::string& actuator_id, int32_t version);
  std::optional<ModelRecord> ActiveModel(const std::string& actuator_id);
  // Makes that version the only active model of the actuator. Throws if it does not exist.
  void ActivateModel(const std::string& actuator_id, int32_t version);

  // --- alerts ----------------------------------------------------------------------
  // Stores an alert (record.id is ignored) and returns its id. The actuator need not be
  // known: an alert is a log entry and must be storable whatever it is about.
  int64_t StoreAlert(const AlertRecord& alert);
  // Alerts with utime >= since_utime, optionally of one actuator, newest first (by utime,
  // then id), at most `limit` of them (negative: no limit).
  std::vector<AlertRecord> Alerts(const std::optional<std::string>& actuator_id = {},
                                  int64_t since_utime = 0, int limit = 1000);

  // --- maintenance -----------------------------------------------------------------
  // Online backup (sqlite3_backup) of a consistent snapshot to a new file; writers may
  // go on meanwhile. Refuses an existing destination; removes a partial copy on failure.
  void Backup(const std::string& destination_path);
  // "ok", or one line per problem: PRAGMA integrity_check, PRAGMA foreign_key_check
  // (orphan rows, e.g. a sample of a trial that does not exist) and trial sample counts
  // that disagree with the stored samples.
  std::string IntegrityCheck();

 private:
  struct Closer {
    void operator()(sqlite3* db) const noexcept;
  };
  Database(std::unique_ptr<sqlite3, Closer> db, std::string path);
  sqlite3* Handle() const;

  std::unique_ptr<sqlite3, Closer> db_;
  std::string path_;
};

// A stable hex digest (16 digits) of the exact sample values, for telling whether a
// model was identified on these very samples: 64-bit FNV-1a over utime, voltage_V and
// deflection_mm of each sample in order, each as its 8 little-endian bytes (doubles as
// IEEE 754 bit patterns, -0.0 taken as 0.0 so that equal values hash equally). The same
// on every platform. An identity check, not a security measure: it is easy to forge.
std::string HashSamples(std::span<const Sample> samples);

}  // namespace flexid::storage
