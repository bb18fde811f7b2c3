#include "lcmtypes/message_auth.h"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <openssl/evp.h>
#include <openssl/hmac.h>
#include <sys/random.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <flexid/rpc_request_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_command_t.hpp>

namespace flexid::auth {
namespace {

constexpr char kHexDigits[] = "0123456789abcdef";

std::string Hex(const uint8_t* bytes, size_t size) {
  std::string out(2 * size, '0');
  for (size_t i = 0; i < size; ++i) {
    out[2 * i] = kHexDigits[bytes[i] >> 4];
    out[2 * i + 1] = kHexDigits[bytes[i] & 0xf];
  }
  return out;
}

int HexValue(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

void RandomBytes(uint8_t* out, size_t size) {
  size_t done = 0;
  while (done < size) {
    const ssize_t n = getrandom(out + done, size - done, 0);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw KeyError(std::string("cannot get random bytes: ") + std::strerror(errno));
    }
    done += static_cast<size_t>(n);
  }
}

// Closes a descriptor when it goes out of scope.
struct FileDescriptor {
  int fd = -1;
  ~FileDescriptor() {
    if (fd >= 0) close(fd);
  }
};

// The key in a file's text: 64 hex digits and at most one newline after them.
Key ParseKey(const std::string& text, const std::string& path) {
  std::string_view digits(text);
  if (!digits.empty() && digits.back() == '\n') digits.remove_suffix(1);
  Key key;
  bool ok = digits.size() == 2 * kKeyBytes;
  for (size_t i = 0; ok && i < kKeyBytes; ++i) {
    const int high = HexValue(digits[2 * i]), low = HexValue(digits[2 * i + 1]);
    ok = high >= 0 && low >= 0;
    key.bytes[i] = static_cast<uint8_t>(ok ? high * 16 + low : 0);
  }
  if (!ok)
    throw KeyError("key file " + path + " is malformed: expected one line of " +
                   std::to_string(2 * kKeyBytes) + " hex digits");
  return key;
}

// Reads a whole (small) file from an open descriptor.
std::string ReadAll(int fd, const std::string& path) {
  std::string text;
  char buffer[256];
  while (text.size() <= 4096) {
    const ssize_t n = read(fd, buffer, sizeof buffer);
    if (n < 0) {
      if (errno == EINTR) continue;
      throw KeyError("cannot read key file " + path + ": " + std::strerror(errno));
    }
    if (n == 0) break;
    text.append(buffer, static_cast<size_t>(n));
  }
  return text;
}

void AppendField(std::string* out, std::string_view bytes) {
  *out += std::to_string(bytes.size());
  *out += ':';
  *out += bytes;
  *out += '\n';
}
void AppendField(std::string* out, int64_t value) { AppendField(out, std::to_string(value)); }
void AppendField(std::string* out, double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  AppendField(out, std::string_view(buffer, static_cast<size_t>(result.ptr - buffer)));
}

}  // namespace

Key ReadKeyFile(const std::string& path) {
  FileDescriptor file{open(path.c_str(), O_RDONLY | O_CLOEXEC)};
  if (file.fd < 0) throw KeyError("cannot read key file " + path + ": " + std::strerror(errno));
  return ParseKey(ReadAll(file.fd, path), path);
}

Key LoadOrCreateKeyFile(const std::string& path, bool* created) {
  if (created) *created = false;
  FileDescriptor file{open(path.c_str(), O_RDONLY | O_CLOEXEC)};
  if (file.fd < 0 && errno == ENOENT) {
    std::error_code ignored;
    const auto parent = std::filesystem::path(path).parent_path();
    if (!parent.empty()) std::filesystem::create_directories(parent, ignored);
    FileDescriptor out{open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600)};
    if (out.fd >= 0) {
      Key key;
      RandomBytes(key.bytes.data(), key.bytes.size());
      const std::string text = Hex(key.bytes.data(), key.bytes.size()) + "\n";
      if (write(out.fd, text.data(), text.size()) != static_cast<ssize_t>(text.size()) ||
          fsync(out.fd) != 0) {
        const std::string why = std::strerror(errno);
        unlink(path.c_str());
        throw KeyError("cannot write key file " + path + ": " + why);
      }
      if (created) *created = true;
      return key;
    }
    if (errno != EEXIST)
      throw KeyError("cannot create key file " + path + ": " + std::strerror(errno));
    file.fd = open(path.c_str(), O_RDONLY | O_CLOEXEC);  // another process made it meanwhile
  }
  if (file.fd < 0) throw KeyError("cannot read key file " + path + ": " + std::strerror(errno));
  struct stat info {};
  if (fstat(file.fd, &info) != 0)
    throw KeyError("cannot read key file " + path + ": " + std::strerror(errno));
  if (!S_ISREG(info.st_mode)) throw KeyError("key file " + path + " is not a regular file");
  if ((info.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(info.st_mode & 07777));
    throw KeyError("key file " + path + " may be read or written by group or others (mode " + mode +
                   "); chmod 600 it");
  }
  return ParseKey(ReadAll(file.fd, path), path);
}

std::string ClientKeyFilePath(const std::string& flag) {
  if (!flag.empty()) return flag;
  if (const char* env = std::getenv("FLEXID_KEY_FILE"); env != nullptr && *env != '\0') return env;
  return "var/flexidd.key";
}

bool ChangesData(std::string_view method) {
  for (const std::string_view read_only :
       {"status", "actuators", "trials", "trial_samples", "models", "model", "alerts"})
    if (method == read_only) return false;
  return true;
}

bool IsValidNonce(std::string_view nonce) {
  if (nonce.size() < 8 || nonce.size() > 64) return false;
  for (const char c : nonce) {
    const bool ok = (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') ||
                    c == '_' || c == '-';
    if (!ok) return false;
  }
  return true;
}

std::string RandomNonce() {
  uint8_t bytes[16];
  RandomBytes(bytes, sizeof bytes);
  return Hex(bytes, sizeof bytes);
}

std::string CanonicalForm(const flexid::rpc_request_t& request) {
  std::string out = "flexid.rpc_request_t/1\n";
  AppendField(&out, request.utime);
  AppendField(&out, request.request_id);
  AppendField(&out, request.client_id);
  AppendField(&out, request.method);
  AppendField(&out, request.args_json);
  AppendField(&out, request.nonce);
  return out;
}

std::string CanonicalForm(const flexid::trial_control2_t& control) {
  std::string out = "flexid.trial_control2_t/1\n";
  AppendField(&out, control.utime);
  AppendField(&out, control.actuator_id);
  AppendField(&out, static_cast<int64_t>(control.action));
  AppendField(&out, control.protocol);
  AppendField(&out, control.sent_utime);
  AppendField(&out, control.nonce);
  return out;
}

std::string CanonicalForm(const flexid::voltage_command_t& command) {
  std::string out = "flexid.voltage_command_t/2\n";
  AppendField(&out, command.utime);
  AppendField(&out, command.actuator_id);
  AppendField(&out, command.voltage_V);
  AppendField(&out, command.sequence);
  AppendField(&out, command.controller_id);
  AppendField(&out, static_cast<int64_t>(command.mode));
  AppendField(&out, command.reference_mm);
  AppendField(&out, command.reference_utime);
  AppendField(&out, command.sent_utime);
  AppendField(&out, command.nonce);
  return out;
}

std::string Signature(const Key& key, std::string_view canonical) {
  uint8_t mac[EVP_MAX_MD_SIZE];
  unsigned int size = 0;
  if (HMAC(EVP_sha256(), key.bytes.data(), static_cast<int>(key.bytes.size()),
           reinterpret_cast<const unsigned char*>(canonical.data()), canonical.size(), mac,
           &size) == nullptr)
    throw std::runtime_error("HMAC-SHA256 failed");
  return Hex(mac, size);
}

bool SignatureMatches(const Key& key, std::string_view canonical, std::string_view auth) {
  const std::string expected = Signature(key, canonical);
  return auth.size() == expected.size() &&
         CRYPTO_memcmp(auth.data(), expected.data(), expected.size()) == 0;
}

void Sign(const Key& key, flexid::rpc_request_t* request) {
  if (request->nonce.empty()) request->nonce = RandomNonce();
  request->auth = Signature(key, CanonicalForm(*request));
}

void Sign(const Key& key, flexid::trial_control2_t* control) {
  if (control->nonce.empty()) control->nonce = RandomNonce();
  control->auth = Signature(key, CanonicalForm(*control));
}

void Sign(const Key& key, flexid::voltage_command_t* command) {
  if (command->nonce.empty()) command->nonce = RandomNonce();
  command->auth = Signature(key, CanonicalForm(*command));
}

NonceCache::Result NonceCache::Insert(const std::string& scope, const std::string& nonce,
                                      int64_t expires_utime, int64_t now_utime) {
  while (!by_time_.empty() && by_time_.begin()->first < now_utime) {
    expiry_.erase(by_time_.begin()->second);
    by_time_.erase(by_time_.begin());
  }
  auto key = std::make_pair(scope, nonce);
  if (expiry_.count(key)) return Result::kReplayed;
  if (expiry_.size() >= capacity_) return Result::kFull;
  expiry_.emplace(key, expires_utime);
  by_time_.emplace(expires_utime, std::move(key));
  return Result::kFresh;
}

std::string Verifier::Check(const flexid::rpc_request_t& request, int64_t now_utime) {
  return Check(CanonicalForm(request), request.auth, request.utime, "rpc/" + request.client_id,
               request.nonce, now_utime);
}

std::string Verifier::Check(const flexid::trial_control2_t& control, int64_t now_utime) {
  return Check(CanonicalForm(control), control.auth, control.sent_utime, "trial", control.nonce,
               now_utime);
}

std::string Verifier::Check(const flexid::voltage_command_t& command, int64_t now_utime) {
  return Check(CanonicalForm(command), command.auth, command.sent_utime,
               "command/" + command.controller_id, command.nonce, now_utime, "command time",
               "this host's clock");
}

std::string Verifier::Check(std::string_view canonical, const std::string& auth, int64_t sent_utime,
                            const std::string& scope, const std::string& nonce, int64_t now_utime,
                            const char* what, const char* whose) {
  if (auth.empty()) return "no signature";
  if (!IsValidNonce(nonce)) return "bad nonce (expected [A-Za-z0-9_-]{8,64})";
  if (!SignatureMatches(key_, canonical, auth)) return "bad signature";
  // In doubles: a signed but absurd time must not overflow a subtraction.
  const double off_s = 1e-6 * (static_cast<double>(sent_utime) - static_cast<double>(now_utime));
  if (std::abs(off_s) * 1e6 > static_cast<double>(options_.window_us)) {
    char text[200];
    const double window_s = 1e-6 * static_cast<double>(options_.window_us);
    // Whole seconds for the daemon's 30 s window; tenths under 10 s (a rig's commands).
    const int digits = window_s < 10.0 ? 1 : 0;
    std::snprintf(text, sizeof text, "%s %.*f s %s %s (window %.*f s)", what, digits,
                  std::abs(off_s), off_s < 0 ? "behind" : "ahead of", whose, digits, window_s);
    return text;
  }
  switch (nonces_.Insert(scope, nonce, sent_utime + options_.window_us, now_utime)) {
    case NonceCache::Result::kFresh:
      return "";
    case NonceCache::Result::kReplayed:
      return "replayed nonce";
    case NonceCache::Result::kFull:
      return "too many signed requests within the window (" + std::to_string(options_.max_nonces) +
             "); try again shortly";
  }
  return "refused";
}

}  // namespace flexid::auth
