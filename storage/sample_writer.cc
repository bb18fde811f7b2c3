#include "storage/sample_writer.h"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <exception>
#include <stdexcept>
#include <utility>

namespace flexid::storage {
namespace {

// Commit attempts the destructor makes, one per interval, after a failed final commit.
constexpr int kRetriesAtShutdown = 10;

}  // namespace

bool SampleWriterOptions::IsValid(std::string* error) const {
  std::string problem;
  if (commit_interval <= std::chrono::milliseconds::zero())
    problem = "commit_interval must be positive";
  else if (queue_capacity == 0)
    problem = "queue_capacity must be positive";
  if (error) *error = problem;
  return problem.empty();
}

namespace {

SampleWriterOptions Validated(SampleWriterOptions options) {
  std::string error;
  if (!options.IsValid(&error)) throw std::invalid_argument("SampleWriterOptions: " + error);
  return options;
}

}  // namespace

SampleWriter::SampleWriter(const std::string& db_path, SampleWriterOptions options)
    : options_(Validated(options)), path_(db_path), database_(Database::Open(db_path)) {
  // Both buffers can hold a full queue, so neither Enqueue nor the writer allocates (and
  // holds the lock meanwhile) in steady state. Untouched capacity costs no memory.
  incoming_.reserve(options_.queue_capacity);
  batch_.reserve(options_.queue_capacity);
  thread_ = std::thread([this, nice = options.thread_nice, cpus = options.thread_cpus] {
    // Linux: nice applies per thread when given the thread id.
    if (nice != 0) setpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)), nice);
    if (!cpus.empty()) {
      cpu_set_t set;
      CPU_ZERO(&set);
      for (int cpu : cpus) CPU_SET(cpu, &set);
      pthread_setaffinity_np(pthread_self(), sizeof set, &set);
    }
    Run();
  });
}

SampleWriter::~SampleWriter() {
  {
    std::lock_guard lock(mutex_);
    stop_ = true;
  }
  wake_.notify_one();
  try {
    if (thread_.joinable()) thread_.join();
  } catch (...) {  // std::system_error: nothing sensible is left to do
  }
}

bool SampleWriter::Enqueue(int64_t trial_id, const Sample& sample) {
  std::lock_guard lock(mutex_);
  if (incoming_.size() + batch_.size() >= options_.queue_capacity) return false;
  incoming_.push_back({trial_id, sample});
  enqueued_.fetch_add(1);
  return true;
}

bool SampleWriter::Flush() {
  std::unique_lock lock(mutex_);
  const int64_t target = enqueued_.load();
  auto done = [&] { return stored_.load() + rejected_.load() >= target; };
  if (done()) return true;
  const uint64_t attempts_before = attempts_;
  flush_requested_ = true;
  wake_.notify_one();
  flushed_.wait(lock, [&] {
    return done() || exited_ || (attempts_ > attempts_before && last_attempt_failed_);
  });
  return done();
}

namespace {

void Translate(std::vector<TrialSample>* samples, const std::map<int64_t, int64_t>& trial_ids) {
  for (TrialSample& s : *samples)
    if (const auto it = trial_ids.find(s.trial_id); it != trial_ids.end()) s.trial_id = it->second;
}

}  // namespace

void SampleWriter::Reopen(const std::map<int64_t, int64_t>& trial_ids) {
  {
    std::lock_guard lock(mutex_);
    Translate(&incoming_, trial_ids);
    if (!reopen_) {
      reopen_ = trial_ids;
    } else {  // a second reopen before the first was done: compose the translations
      for (auto& [from, to] : *reopen_)
        if (const auto it = trial_ids.find(to); it != trial_ids.end()) to = it->second;
      for (const auto& [from, to] : trial_ids) reopen_->emplace(from, to);
    }
    flush_requested_ = true;  // reopen now rather than at the next interval
  }
  wake_.notify_one();
}

size_t SampleWriter::queue_depth() const {
  std::lock_guard lock(mutex_);
  return incoming_.size() + batch_.size();
}

std::string SampleWriter::last_error() const {
  std::lock_guard lock(mutex_);
  return last_error_;
}

void SampleWriter::Run() noexcept {
  const auto interval = options_.commit_interval;
  std::unique_lock lock(mutex_);
  auto deadline = std::chrono::steady_clock::now() + interval;
  int failures_while_stopping = 0;
  while (true) {
    if (!stop_) wake_.wait_until(lock, deadline, [this] { return stop_ || flush_requested_; });
    const bool stopping = stop_;
    flush_requested_ = false;
    if (reopen_) {
      // Open without the lock (Enqueue and Reopen go on meanwhile; Reopen may compose
      // reopen_ further, which is read again below).
      lock.unlock();
      std::optional<Database> fresh;
      std::string error;
      try {
        fresh.emplace(Database::Open(path_));
      } catch (const std::exception& e) {
        error = e.what();
      }
      lock.lock();
      if (fresh) {
        database_ = std::move(*fresh);
        Translate(&batch_, *reopen_);
        reopen_.reset();
      } else {
        ++attempts_;
        last_attempt_failed_ = true;
        last_error_ = "cannot reopen the database: " + error + " (" +
                      std::to_string(batch_.size() + incoming_.size()) +
                      " samples kept queued; retrying every " + std::to_string(interval.count()) +
                      " ms)";
        flushed_.notify_all();
        deadline = std::max(deadline + interval, std::chrono::steady_clock::now());
        if (stopping) {
          if (++failures_while_stopping > kRetriesAtShutdown) break;
          lock.unlock();
          std::this_thread::sleep_for(interval);
          lock.lock();
        }
        continue;
      }
    }
    // Take what has queued. After a failed commit batch_ still holds its samples: the new
    // ones go behind them, keeping the order (both fit: see the constructor).
    if (batch_.empty()) {
      batch_.swap(incoming_);
    } else {
      batch_.insert(batch_.end(), incoming_.begin(), incoming_.end());
      incoming_.clear();
    }
    if (batch_.empty()) {
      if (stopping) break;
      deadline = std::max(deadline + interval, std::chrono::steady_clock::now());
      continue;
    }

    // Commit without the lock: Enqueue goes on filling incoming_ meanwhile. batch_ is not
    // modified by anyone while the lock is released.
    lock.unlock();
    AppendResult result;
    std::string error;
    try {
      result = database_.AppendSamples(std::span<const TrialSample>(batch_));
    } catch (const std::exception& e) {
      error = e.what();
    } catch (...) {
      error = "unknown error";
    }
    lock.lock();

    ++attempts_;
    last_attempt_failed_ = !error.empty();
    if (error.empty()) {
      stored_.fetch_add(result.inserted);
      rejected_.fetch_add(result.duplicates + result.invalid);
      batch_.clear();
      last_error_.clear();
    } else {
      last_error_ = error + " (" + std::to_string(batch_.size() + incoming_.size()) +
                    " samples kept queued; retrying every " + std::to_string(interval.count()) +
                    " ms)";
    }
    flushed_.notify_all();
    deadline = std::max(deadline + interval, std::chrono::steady_clock::now());

    if (stopping && !error.empty()) {
      if (++failures_while_stopping > kRetriesAtShutdown) {
        last_error_ = error + " (gave up at shutdown; " + std::to_string(batch_.size()) +
                      " samples not stored)";
        break;
      }
      lock.unlock();
      std::this_thread::sleep_for(interval);
      lock.lock();
    }
  }
  exited_ = true;
  flushed_.notify_all();
}

}  // namespace flexid::storage
