// The flexid database's samples (database.h): appending a trial's samples with the trial's
// sample count in the same transaction, reading them whole or a page at a time, and
// HashSamples, the digest a model keeps of the samples it was identified on.
#include <bit>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "storage/database.h"
#include "storage/database_internal.h"
#include "storage/sql.h"

namespace flexid::storage {

using namespace internal;  // NOLINT(google-build-using-namespace): storage's own parts

namespace {

// Inserts samples inside the caller's transaction, counting what happens to each, and
// then adds the inserted counts to trials.sample_count.
class SampleInserter {
 public:
  SampleInserter(sqlite3* db, const std::string& path)
      : db_(db),
        path_(path),
        insert_(db, path,
                "INSERT OR IGNORE INTO samples (trial_id, utime, voltage_V, deflection_mm) "
                "VALUES (?, ?, ?, ?)") {}

  void Add(int64_t trial_id, const Sample& sample) {
    if (!std::isfinite(sample.voltage_V) || !std::isfinite(sample.deflection_mm)) {
      ++result_.invalid;
      return;
    }
    TrialCount& trial = Lookup(trial_id);
    if (!trial.exists) {
      ++result_.invalid;
      return;
    }
    insert_.Bind(1, trial_id).Bind(2, sample.utime).Bind(3, sample.voltage_V);
    insert_.Bind(4, sample.deflection_mm).Run();
    insert_.Reset();
    if (sqlite3_changes(db_) > 0) {
      ++trial.inserted;
      ++result_.inserted;
    } else {
      ++result_.duplicates;
    }
  }

  AppendResult Finish() {
    Statement update(db_, path_, "UPDATE trials SET sample_count = sample_count + ? WHERE id = ?");
    for (const TrialCount& trial : trials_) {
      if (trial.inserted == 0) continue;
      update.Bind(1, trial.inserted).Bind(2, trial.trial_id).Run();
      update.Reset();
    }
    return result_;
  }

 private:
  struct TrialCount {
    int64_t trial_id;
    bool exists;
    int64_t inserted;
  };

  // A batch holds few trials (one per recording actuator): a linear search, starting with
  // the last one used, is the fastest map here.
  TrialCount& Lookup(int64_t trial_id) {
    if (last_ < trials_.size() && trials_[last_].trial_id == trial_id) return trials_[last_];
    for (last_ = 0; last_ < trials_.size(); ++last_)
      if (trials_[last_].trial_id == trial_id) return trials_[last_];
    trials_.push_back({trial_id, TrialExists(db_, path_, trial_id), 0});
    return trials_[last_];
  }

  sqlite3* db_;
  const std::string& path_;
  Statement insert_;
  std::vector<TrialCount> trials_;
  size_t last_ = 0;
  AppendResult result_;
};

}  // namespace

// --- samples -------------------------------------------------------------------------

AppendResult Database::AppendSamples(int64_t trial_id, std::span<const Sample> samples) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  if (!TrialExists(db, path_, trial_id))
    throw StorageError(path_ + ": cannot store samples of trial " + std::to_string(trial_id) +
                       ": no such trial");
  SampleInserter inserter(db, path_);
  for (const Sample& sample : samples) inserter.Add(trial_id, sample);
  const AppendResult result = inserter.Finish();
  transaction.Commit();
  return result;
}

AppendResult Database::AppendSamples(std::span<const TrialSample> samples) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kWrite);
  SampleInserter inserter(db, path_);
  for (const TrialSample& item : samples) inserter.Add(item.trial_id, item.sample);
  const AppendResult result = inserter.Finish();
  transaction.Commit();
  return result;
}

std::vector<Sample> Database::Samples(int64_t trial_id) {
  sqlite3* db = Handle();
  Transaction transaction(db, path_, Transaction::Kind::kRead);  // count and rows agree
  std::vector<Sample> samples;
  samples.reserve(static_cast<size_t>(SampleCount(trial_id)));
  Statement select(db, path_,
                   "SELECT utime, voltage_V, deflection_mm FROM samples WHERE trial_id = ? "
                   "ORDER BY utime");
  select.Bind(1, trial_id);
  while (select.Step()) samples.push_back({select.Int64(0), select.Double(1), select.Double(2)});
  transaction.Commit();
  return samples;
}

std::vector<Sample> Database::SamplesPage(int64_t trial_id, int64_t after_utime, int64_t offset,
                                          int64_t limit) {
  if (offset < 0 || limit < 0) throw StorageError(path_ + ": negative sample offset or limit");
  Statement select(Handle(), path_,
                   "SELECT utime, voltage_V, deflection_mm FROM samples WHERE trial_id = ? "
                   "AND utime > ? ORDER BY utime LIMIT ? OFFSET ?");
  select.Bind(1, trial_id).Bind(2, after_utime).Bind(3, limit).Bind(4, offset);
  std::vector<Sample> samples;
  while (select.Step()) samples.push_back({select.Int64(0), select.Double(1), select.Double(2)});
  return samples;
}

int64_t Database::SampleCount(int64_t trial_id) {
  Statement select(Handle(), path_, "SELECT sample_count FROM trials WHERE id = ?");
  return select.Bind(1, trial_id).Step() ? select.Int64(0) : 0;
}

// --- hashing -------------------------------------------------------------------------

std::string HashSamples(std::span<const Sample> samples) {
  constexpr uint64_t kOffsetBasis = 14695981039346656037ULL;  // FNV-1a 64-bit parameters
  constexpr uint64_t kPrime = 1099511628211ULL;
  uint64_t hash = kOffsetBasis;
  auto feed = [&hash](uint64_t value) {
    for (int byte = 0; byte < 8; ++byte) {  // little-endian, whatever the host
      hash ^= (value >> (8 * byte)) & 0xFF;
      hash *= kPrime;
    }
  };
  auto bits = [](double value) { return std::bit_cast<uint64_t>(value == 0.0 ? 0.0 : value); };
  for (const Sample& sample : samples) {
    feed(static_cast<uint64_t>(sample.utime));
    feed(bits(sample.voltage_V));
    feed(bits(sample.deflection_mm));
  }
  static constexpr char kDigits[] = "0123456789abcdef";
  std::string hex(16, '0');
  for (int digit = 15; digit >= 0; --digit, hash >>= 4)
    hex[static_cast<size_t>(digit)] = kDigits[hash & 0xF];
  return hex;
}

}  // namespace flexid::storage
