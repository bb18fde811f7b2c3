// The batched sample writer: the recorder's only path to disk (DESIGN.md, "Rules for
// reliability"; STYLE.md: handlers never block, drops are counted).
//
// Enqueue only copies a sample into a bounded in-memory queue under a short lock; a writer
// thread with its own Database connection commits what has queued, in one transaction,
// every commit_interval. A sample counts as stored (stored(), the STATUS figure) once its
// transaction has committed, and then survives kill -9 (database.h, "Durability").
//
// Loss window: a sample that Enqueue accepted but that is not yet committed is lost if
// the process dies. It waits at most commit_interval for its batch to be taken, plus the
// time the commit takes (about 1 ms for the 800 samples of 16 actuators x 500 Hz over
// 100 ms), so the window is commit_interval + a few ms: ~100 ms by default, within
// DESIGN.md's 200 ms.
//
// Failures: if a commit fails (disk full, file made read-only, a lock held too long), the
// batch stays queued and is retried every commit_interval; last_error() says what
// happened until a commit succeeds again. Meanwhile the queue fills up and Enqueue returns
// false for the samples that do not fit; the caller counts those drops.
//
// A database file deleted or replaced under the process (the caller notices: it owns the
// path's identity): Reopen makes the writer commit to a fresh connection on the path from
// its next commit on, with the trial ids of the queued samples translated to the trials
// that continue them in the new file. Samples committed to the old file before that are
// gone with it; they were counted in stored() and stay counted.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "storage/database.h"

namespace flexid::storage {

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
  // it gives up after 10 more intervals, and the samples still queued are lost (they
  // were never counted as stored).
  ~SampleWriter();
  SampleWriter(const SampleWriter&) = delete;
  SampleWriter& operator=(const SampleWriter&) = delete;

  // Queues one sample of a trial (which must exist by the time it is committed; samples
  // of an unknown trial, duplicates and non-finite values are counted in rejected()).
  // Thread-safe; never waits for the disk. Returns false, queueing nothing, when the
  // queue holds queue_capacity samples.
  bool Enqueue(int64_t trial_id, const Sample& sample);

  // Blocks until every sample accepted before the call is committed (true), or until a
  // commit attempt fails (false: the samples stay queued; see last_error()).
  // (Returns bool rather than void so that a failing disk cannot block the caller forever.)
  bool Flush();

  // Commits to a new connection on the same path from the next commit on (see the file
  // comment): queued samples of trial `from` become samples of trial `to` for each entry
  // of trial_ids; samples of other trials stay as they are (and are counted in rejected()
  // if their trial is not in the new file). Thread-safe, never waits for the disk. If the
  // path cannot be opened, last_error() says so and the writer retries every interval,
  // committing nothing meanwhile.
  void Reopen(const std::map<int64_t, int64_t>& trial_ids);

  int64_t stored() const { return stored_.load(); }      // committed as new rows
  int64_t rejected() const { return rejected_.load(); }  // committed as duplicates/invalid
  int64_t enqueued() const { return enqueued_.load(); }  // accepted by Enqueue
  // Samples accepted but not yet committed. stored() + rejected() + queue_depth() ==
  // enqueued() whenever no commit is finishing.
  size_t queue_depth() const;
  // Empty while healthy; otherwise the last commit failure, with how many samples are
  // waiting and that they are being retried.
  std::string last_error() const;

 private:
  void Run() noexcept;

  const SampleWriterOptions options_;
  const std::string path_;
  Database database_;  // used only by the writer thread once it runs

  mutable std::mutex mutex_;
  std::condition_variable wake_;       // writer: stop or flush requested
  std::condition_variable flushed_;    // Flush: an attempt finished
  std::vector<TrialSample> incoming_;  // filled by Enqueue
  std::vector<TrialSample> batch_;     // being committed (or kept for retry) by the writer
  bool stop_ = false;
  bool flush_requested_ = false;
  bool exited_ = false;
  // Reopen requested: translation for the samples in batch_ (incoming_ is translated at once).
  std::optional<std::map<int64_t, int64_t>> reopen_;
  uint64_t attempts_ = 0;  // commit attempts finished
  bool last_attempt_failed_ = false;
  std::string last_error_;
  std::atomic<int64_t> stored_{0}, rejected_{0}, enqueued_{0};

  std::thread thread_;  // last: starts after everything above is initialised
};

}  // namespace flexid::storage
