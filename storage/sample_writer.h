// The database writer: the one path to disk of a running flexidd (DESIGN.md, "Rules for
// reliability"; STYLE.md: handlers never block, drops are counted). Named for its first
// job; it writes every row the daemon adds after start-up: samples, and the other writes
// below (trial starts and ends, actuators, alerts, models and model activations).
//
// Enqueue and Submit only copy into bounded in-memory queues under a short lock; a writer
// thread with its own Database connection commits what has queued every commit_interval:
// first the other writes, in the order they were submitted, each in its own transaction,
// then the samples, in one transaction. So a trial's row is written before its samples and
// its end after its start. A sample counts as stored (stored(), the STATUS figure) once its
// transaction has committed, and then survives kill -9 (database.h, "Durability").
//
// Loss window: a sample that Enqueue accepted but that is not yet committed is lost if
// the process dies. It waits at most commit_interval for its batch to be taken, plus the
// time the commit takes (about 1 ms for the 800 samples of 16 actuators x 500 Hz over
// 100 ms), so the window is commit_interval + a few ms: ~100 ms by default, within
// DESIGN.md's 200 ms. The same holds for the other writes.
//
// Failures: if a commit fails for a reason that may pass (disk full, file made read-only,
// a lock held too long: StorageError::transient), the write and everything behind it stay
// queued and are retried every commit_interval; last_error() says what happened until a
// commit succeeds again. Meanwhile the queues fill up: Enqueue returns false for the
// samples that do not fit, and Submit returns 0 for the alerts that do not fit (see
// SampleWriterOptions); the caller counts those drops. A write the database refuses for
// good (a trial that does not exist, ...) is not retried: its outcome says why.
//
// Outcomes: each submitted write gets a ticket; once it is committed or refused, its
// outcome (with the model's version for a stored model) waits in TakeOutcomes(), and
// options.on_outcome is called from the writer thread to say so.
//
// A database file deleted or replaced under the process (the caller notices: it owns the
// path's identity): Reopen makes the writer commit to a fresh connection on the path from
// its next commit on, with the trial ids of the queued samples and writes translated to
// the trials that continue them in the new file. Samples committed to the old file before
// that are gone with it; they were counted in stored() and stay counted.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <variant>
#include <vector>

#include "storage/database.h"

namespace flexid::storage {

// The writes other than samples. An Actuator is upserted, an AlertRecord stored, a
// ModelRecord stored as the next version of its actuator (Database::StoreModel).
struct TrialStart {
  int64_t trial_id = 0;  // handed out by the caller (Database::InsertTrial)
  std::string actuator_id, protocol;
  int64_t start_utime = 0;
};
struct TrialEnd {
  int64_t trial_id = 0;
  int64_t end_utime = 0;
  TrialState state = TrialState::kComplete;
};
struct ModelActivation {
  std::string actuator_id;
  int32_t version = 0;
};
using Write =
    std::variant<TrialStart, TrialEnd, Actuator, AlertRecord, ModelRecord, ModelActivation>;

// What became of a submitted write.
struct WriteOutcome {
  uint64_t ticket = 0;
  std::string error;  // empty: committed; else why the database refused it (not retried)
  std::optional<ModelRecord> model;  // a stored model, with its id and version
  // A trial start: the id the trial has in the file. It differs from the one submitted
  // when another program had taken that id meanwhile; the trial's samples and end follow.
  int64_t trial_id = 0;
};

struct SampleWriterOptions {
  // How often queued samples are committed; bounds the loss window (see above).
  std::chrono::milliseconds commit_interval{100};
  // Samples held in memory at most (queued plus being committed): 2^18 is 32 s of
  // 16 actuators x 500 Hz, 8 MiB.
  size_t queue_capacity = 1 << 18;
  // Run the writer thread at this nice value (Linux, per thread; 0 leaves it alone). A
  // service that answers in real time gives its writer a lower priority (e.g. 10) so that
  // commits yield the cores to the threads that handle messages.
  int thread_nice = 0;
  // Run the writer thread on these CPUs only (empty: wherever the scheduler likes).
  std::vector<int> thread_cpus = {};
  // Alerts held in memory at most (queued and not yet stored); beyond it Submit refuses
  // an alert. Trial, actuator and model writes are always taken: each follows a deliberate
  // event (a trial starting or ending, a request), so they cannot come in floods.
  size_t alert_capacity = 10000;
  // Called on the writer thread after outcomes were added (see TakeOutcomes); must not
  // block. Empty: nobody is told.
  std::function<void()> on_outcome = {};

  // True if usable; otherwise false with the reason in *error (if error is not null).
  bool IsValid(std::string* error = nullptr) const;
};

class SampleWriter {
 public:
  // Opens its own connection to db_path (Database::Open: creates and migrates the file if
  // needed) and starts the writer thread. Throws StorageError if the database cannot be
  // opened, std::invalid_argument if the options are not valid.
  explicit SampleWriter(const std::string& db_path, SampleWriterOptions options = {});
  // Commits everything queued and joins the thread; never throws. If commits keep failing
  // it gives up after 10 more intervals, and the samples and writes still queued are lost
  // (they were never counted as stored).
  ~SampleWriter();
  SampleWriter(const SampleWriter&) = delete;
  SampleWriter& operator=(const SampleWriter&) = delete;

  // Queues one sample of a trial (which must exist by the time it is committed; samples
  // of an unknown trial, duplicates and non-finite values are counted in rejected()).
  // Thread-safe; never waits for the disk. Returns false, queueing nothing, when the
  // queue holds queue_capacity samples.
  bool Enqueue(int64_t trial_id, const Sample& sample);

  // Queues a write, behind every write submitted before it. Thread-safe; never waits for
  // the disk. Returns its ticket (> 0), or 0, queueing nothing, for an alert when
  // alert_capacity alerts are queued.
  uint64_t Submit(Write write);
  // The outcomes of the writes committed or refused since the last call, in submission
  // order. Thread-safe.
  std::vector<WriteOutcome> TakeOutcomes();

  // Blocks until every sample and write accepted before the call is committed or refused
  // (true), or until a commit attempt fails (false: they stay queued; see last_error()).
  // (Returns bool rather than void so that a failing disk cannot block the caller forever.)
  bool Flush();

  // Commits to a new connection on the same path from the next commit on (see the file
  // comment): queued samples, starts and ends of trial `from` become those of trial `to`
  // for each entry of trial_ids; samples of other trials stay as they are (and are counted
  // in rejected() if their trial is not in the new file). A start then found in the new
  // file as the caller wrote it again (same id, actuator, protocol and start) is done.
  // Thread-safe, never waits for the disk. If the path cannot be opened, last_error() says
  // so and the writer retries every interval, committing nothing meanwhile.
  void Reopen(const std::map<int64_t, int64_t>& trial_ids);

  int64_t stored() const { return stored_.load(); }      // committed as new rows
  int64_t rejected() const { return rejected_.load(); }  // committed as duplicates/invalid
  int64_t enqueued() const { return enqueued_.load(); }  // accepted by Enqueue
  // Samples accepted but not yet committed. stored() + rejected() + queue_depth() ==
  // enqueued() whenever no commit is finishing.
  size_t queue_depth() const;
  // Writes submitted and not yet committed or refused.
  size_t writes_queued() const;
  // Empty while healthy; otherwise the last commit failure, with how many samples and
  // writes are waiting and that they are being retried.
  std::string last_error() const;

 private:
  struct Queued {
    uint64_t ticket = 0;
    Write write;
  };
  void Run() noexcept;
  // Commits writes_ from the front on, without the lock; stops at the first failure that
  // may pass (its message is returned) and leaves the rest. Returns how many are done.
  size_t CommitWrites(std::vector<WriteOutcome>* outcomes, std::string* error);
  WriteOutcome CommitWrite(Queued& queued);
  // Translates queued samples and writes (if not null) to the trials that continue them.
  static void Translate(std::vector<TrialSample>* samples, std::vector<Queued>* writes,
                        const std::map<int64_t, int64_t>& trial_ids);
  std::string Held() const;  // "N samples" or "N samples and M writes", under the lock

  const SampleWriterOptions options_;
  const std::string path_;
  Database database_;  // used only by the writer thread once it runs

  mutable std::mutex mutex_;
  std::condition_variable wake_;         // writer: stop or flush requested
  std::condition_variable flushed_;      // Flush: an attempt finished
  std::vector<TrialSample> incoming_;    // filled by Enqueue
  std::vector<TrialSample> batch_;       // being committed (or kept for retry) by the writer
  std::vector<Queued> incoming_writes_;  // filled by Submit
  std::vector<Queued> writes_;           // being committed (or kept for retry) by the writer
  std::vector<WriteOutcome> outcomes_;   // waiting for TakeOutcomes
  uint64_t next_ticket_ = 1;
  uint64_t writes_done_ = 0;  // committed or refused
  size_t alerts_queued_ = 0;
  // Trials the writer started under another id than submitted (WriteOutcome::trial_id):
  // their samples and ends follow them. Writer thread only.
  std::map<int64_t, int64_t> moved_trials_;
  bool stop_ = false;
  bool flush_requested_ = false;
  bool exited_ = false;
  // Reopen requested: translation for batch_ and writes_ (the incoming ones are translated
  // at once).
  std::optional<std::map<int64_t, int64_t>> reopen_;
  uint64_t attempts_ = 0;  // commit attempts finished
  bool last_attempt_failed_ = false;
  std::string last_error_;
  std::atomic<int64_t> stored_{0}, rejected_{0}, enqueued_{0};

  std::thread thread_;  // last: starts after everything above is initialised
};

}  // namespace flexid::storage
