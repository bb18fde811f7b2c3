#include "daemon/health.h"

#include <sys/stat.h>

#include <climits>

namespace flexid::daemon {

std::string StorageProblem(const std::string& error) {
  auto has = [&](const char* text) { return error.find(text) != std::string::npos; };
  if (has("disk is full") || has("No space left")) return "disk full";
  if (has("Read-only file system") || has("readonly") || has("read-only"))
    return "file system read-only";
  if (has("locked") || has("busy")) return "database locked";
  // A write refused by the operating system (EIO, EROFS of a file system remounted
  // read-only): SQLite says "disk I/O error" and rarely keeps the errno.
  if (has("I/O error")) return "I/O error";
  return "error";
}

std::optional<FileIdentity> IdentityOf(const std::string& path) {
  struct stat info {};
  if (stat(path.c_str(), &info) != 0) return std::nullopt;
  return FileIdentity{info.st_dev, info.st_ino};
}

ClockJumpDetector::Verdict ClockJumpDetector::Check(int64_t last_utime, int64_t utime,
                                                    bool trial_open) {
  if (last_utime == INT64_MIN) {
    candidates_ = 0;
    return Verdict::kAccept;
  }
  // Differences in unsigned arithmetic: utimes from a hostile sender may be anywhere.
  const bool back = utime <= last_utime;
  const auto distance = back ? static_cast<uint64_t>(last_utime) - static_cast<uint64_t>(utime)
                             : static_cast<uint64_t>(utime) - static_cast<uint64_t>(last_utime);
  const bool far_back = back && distance >= static_cast<uint64_t>(back_us_);
  const bool far_forward = !back && trial_open && distance > static_cast<uint64_t>(forward_us_);
  if (!back && !far_forward) {
    candidates_ = 0;
    return Verdict::kAccept;
  }
  if (!far_back && !far_forward) {  // a little back: a late or repeated message
    candidates_ = 0;
    return Verdict::kReject;
  }
  // On the new time base the messages must be in order among themselves.
  if (candidates_ > 0 && utime > last_candidate_utime_)
    ++candidates_;
  else
    candidates_ = 1;
  last_candidate_utime_ = utime;
  if (candidates_ < confirm_) return Verdict::kReject;
  candidates_ = 0;
  jump_us_ = back ? -static_cast<int64_t>(distance) : static_cast<int64_t>(distance);
  return Verdict::kJumped;
}

}  // namespace flexid::daemon
