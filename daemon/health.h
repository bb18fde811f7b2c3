// The faults flexidd watches for besides bad messages (README, "Reliability so far";
// tests/daemon_fault_matrix_test.cc states the behaviour for each one):
//  - storage failing (disk full, file system read-only, database locked): StorageProblem
//    names it from the writer's error;
//  - the database file deleted or replaced under the daemon: FileIdentity tells;
//  - a source's clock jumping back or forward: ClockJumpDetector, per stream, in message
//    time (the host's wall clock plays no part in recording).
// Small pure pieces; the daemon's loop acts on what they say (health.cc, below them).
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <optional>
#include <string>

namespace flexid::daemon {

// A few words for a storage error message (storage::StorageError, SQLite's text): "disk
// full", "file system read-only", "database locked", "I/O error" or "error".
std::string StorageProblem(const std::string& error);

// Which file a path names: device and inode. Nothing when the path does not exist.
struct FileIdentity {
  dev_t device = 0;
  ino_t inode = 0;
  bool operator==(const FileIdentity& other) const {
    return device == other.device && inode == other.inode;
  }
};
std::optional<FileIdentity> IdentityOf(const std::string& path);

// Tells a source whose clock jumped from stray or repeated messages, on one stream of
// utimes. A message at or before the stream's last accepted utime is out of order and
// rejected, as is (while a trial records) one more than forward_us after it; but when
// `confirm` consecutive such messages lie at least back_us behind (or forward_us ahead)
// and are in order among themselves, the source's clock has jumped: the last of them is
// reported as kJumped and starts the new time base. So a jump costs confirm - 1 rejected
// messages per stream, and one stray message costs nothing but itself.
class ClockJumpDetector {
 public:
  enum class Verdict { kAccept, kReject, kJumped };
  ClockJumpDetector() = default;
  ClockJumpDetector(int64_t back_us, int64_t forward_us, int confirm)
      : back_us_(back_us), forward_us_(forward_us), confirm_(confirm) {}

  // last_utime: the stream's last accepted utime (INT64_MIN: none yet). trial_open: a
  // forward gap only counts as a jump while a trial records (between trials a source may
  // rest for days).
  Verdict Check(int64_t last_utime, int64_t utime, bool trial_open);
  // After kJumped: utime minus the stream's last accepted utime (negative: back).
  int64_t jump_us() const { return jump_us_; }
  void Reset() { candidates_ = 0; }

 private:
  int64_t back_us_ = 5'000'000, forward_us_ = 3'600'000'000;
  int confirm_ = 10;
  int candidates_ = 0;  // consecutive messages on a new time base so far
  int64_t last_candidate_utime_ = 0;
  int64_t jump_us_ = 0;
};

}  // namespace flexid::daemon
