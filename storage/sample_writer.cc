#include "storage/sample_writer.h"

#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <exception>
#include <iterator>
#include <stdexcept>
#include <type_traits>
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
  else if (alert_capacity == 0)
    problem = "alert_capacity must be positive";
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
  const uint64_t writes_target = next_ticket_ - 1;
  auto done = [&] {
    return stored_.load() + rejected_.load() >= target && writes_done_ >= writes_target;
  };
  if (done()) return true;
  const uint64_t attempts_before = attempts_;
  flush_requested_ = true;
  wake_.notify_one();
  flushed_.wait(lock, [&] {
    return done() || exited_ || (attempts_ > attempts_before && last_attempt_failed_);
  });
  return done();
}

uint64_t SampleWriter::Submit(Write write) {
  std::lock_guard lock(mutex_);
  const bool alert = std::holds_alternative<AlertRecord>(write);
  if (alert && alerts_queued_ >= options_.alert_capacity) return 0;
  alerts_queued_ += alert;
  const uint64_t ticket = next_ticket_++;
  incoming_writes_.push_back({ticket, std::move(write)});
  return ticket;
}

std::vector<WriteOutcome> SampleWriter::TakeOutcomes() {
  std::lock_guard lock(mutex_);
  std::vector<WriteOutcome> out;
  out.swap(outcomes_);
  return out;
}

namespace {

int64_t Translated(int64_t trial_id, const std::map<int64_t, int64_t>& trial_ids) {
  const auto it = trial_ids.find(trial_id);
  return it != trial_ids.end() ? it->second : trial_id;
}

}  // namespace

void SampleWriter::Translate(std::vector<TrialSample>* samples, std::vector<Queued>* writes,
                             const std::map<int64_t, int64_t>& trial_ids) {
  for (TrialSample& s : *samples) s.trial_id = Translated(s.trial_id, trial_ids);
  if (!writes) return;
  for (Queued& q : *writes) {
    if (auto* start = std::get_if<TrialStart>(&q.write))
      start->trial_id = Translated(start->trial_id, trial_ids);
    else if (auto* end = std::get_if<TrialEnd>(&q.write))
      end->trial_id = Translated(end->trial_id, trial_ids);
  }
}

void SampleWriter::Reopen(const std::map<int64_t, int64_t>& trial_ids) {
  {
    std::lock_guard lock(mutex_);
    Translate(&incoming_, &incoming_writes_, trial_ids);
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

size_t SampleWriter::writes_queued() const {
  std::lock_guard lock(mutex_);
  return incoming_writes_.size() + writes_.size();
}

std::string SampleWriter::last_error() const {
  std::lock_guard lock(mutex_);
  return last_error_;
}

std::string SampleWriter::Held() const {
  std::string held = std::to_string(batch_.size() + incoming_.size()) + " samples";
  if (const size_t writes = writes_.size() + incoming_writes_.size(); writes > 0)
    held += " and " + std::to_string(writes) + " other writes";
  return held;
}

WriteOutcome SampleWriter::CommitWrite(Queued& queued) {
  WriteOutcome outcome;
  outcome.ticket = queued.ticket;
  Database& db = database_;
  std::visit(
      [&](auto& write) {
        using T = std::decay_t<decltype(write)>;
        if constexpr (std::is_same_v<T, TrialStart>) {
          outcome.trial_id = write.trial_id;
          try {
            db.InsertTrial(write.trial_id, write.actuator_id, write.protocol, write.start_utime);
          } catch (const StorageError& e) {
            if (e.transient) throw;
            const std::optional<Trial> there = db.FindTrial(write.trial_id);
            if (!there) throw;
            // Written already (a start submitted again after Reopen), or the id taken by
            // another program writing the file: the trial moves to the next free id.
            if (there->actuator_id == write.actuator_id && there->protocol == write.protocol &&
                there->start_utime == write.start_utime)
              return;
            outcome.trial_id = db.LastTrialId() + 1;
            db.InsertTrial(outcome.trial_id, write.actuator_id, write.protocol, write.start_utime);
            moved_trials_[write.trial_id] = outcome.trial_id;
          }
        } else if constexpr (std::is_same_v<T, TrialEnd>) {
          db.EndTrial(Translated(write.trial_id, moved_trials_), write.end_utime, write.state);
        } else if constexpr (std::is_same_v<T, Actuator>) {
          db.UpsertActuator(write);
        } else if constexpr (std::is_same_v<T, AlertRecord>) {
          db.StoreAlert(write);
        } else if constexpr (std::is_same_v<T, ModelRecord>) {
          outcome.model = db.StoreModel(write);
        } else {
          static_assert(std::is_same_v<T, ModelActivation>);
          db.ActivateModel(write.actuator_id, write.version);
        }
      },
      queued.write);
  return outcome;
}

size_t SampleWriter::CommitWrites(std::vector<WriteOutcome>* outcomes, std::string* error) {
  size_t done = 0;
  for (; done < writes_.size(); ++done) {
    try {
      outcomes->push_back(CommitWrite(writes_[done]));
    } catch (const StorageError& e) {
      if (e.transient) {
        *error = e.what();
        break;
      }
      outcomes->push_back({writes_[done].ticket, e.what(), std::nullopt, 0});
    } catch (const std::exception& e) {  // e.g. out of memory: may pass
      *error = e.what();
      break;
    }
  }
  return done;
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
        Translate(&batch_, &writes_, *reopen_);
        reopen_.reset();
      } else {
        ++attempts_;
        last_attempt_failed_ = true;
        last_error_ = "cannot reopen the database: " + error + " (" + Held() +
                      " kept queued; retrying every " + std::to_string(interval.count()) + " ms)";
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
    // Take what has queued. After a failed commit batch_ and writes_ still hold theirs: the
    // new ones go behind them, keeping the order (samples fit: see the constructor).
    if (batch_.empty()) {
      batch_.swap(incoming_);
    } else {
      batch_.insert(batch_.end(), incoming_.begin(), incoming_.end());
      incoming_.clear();
    }
    std::move(incoming_writes_.begin(), incoming_writes_.end(), std::back_inserter(writes_));
    incoming_writes_.clear();
    if (batch_.empty() && writes_.empty()) {
      if (stopping) break;
      deadline = std::max(deadline + interval, std::chrono::steady_clock::now());
      continue;
    }

    // Commit without the lock: Enqueue and Submit go on filling incoming_ and
    // incoming_writes_ meanwhile. batch_ and writes_ are modified by nobody else.
    lock.unlock();
    std::vector<WriteOutcome> outcomes;
    std::string error;
    const size_t writes_done = CommitWrites(&outcomes, &error);
    AppendResult result;
    // Samples only behind every write before them: a trial's row comes first.
    if (error.empty() && !batch_.empty()) {
      if (!moved_trials_.empty()) Translate(&batch_, nullptr, moved_trials_);
      try {
        result = database_.AppendSamples(std::span<const TrialSample>(batch_));
      } catch (const std::exception& e) {
        error = e.what();
      } catch (...) {
        error = "unknown error";
      }
    }
    lock.lock();

    ++attempts_;
    last_attempt_failed_ = !error.empty();
    for (size_t k = 0; k < writes_done; ++k)
      alerts_queued_ -= std::holds_alternative<AlertRecord>(writes_[k].write);
    writes_.erase(writes_.begin(), writes_.begin() + static_cast<std::ptrdiff_t>(writes_done));
    writes_done_ += writes_done;
    std::move(outcomes.begin(), outcomes.end(), std::back_inserter(outcomes_));
    if (error.empty()) {
      stored_.fetch_add(result.inserted);
      rejected_.fetch_add(result.duplicates + result.invalid);
      batch_.clear();
      last_error_.clear();
    } else {
      last_error_ = error + " (" + Held() + " kept queued; retrying every " +
                    std::to_string(interval.count()) + " ms)";
    }
    flushed_.notify_all();
    deadline = std::max(deadline + interval, std::chrono::steady_clock::now());
    if (writes_done > 0 && options_.on_outcome) {
      lock.unlock();
      options_.on_outcome();
      lock.lock();
    }

    if (stopping && !error.empty()) {
      if (++failures_while_stopping > kRetriesAtShutdown) {
        last_error_ = error + " (gave up at shutdown; " + Held() + " not stored)";
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
