// Authentication of the bus messages that change stored data (DESIGN.md, "Rules for
// reliability"; README "Security"): RPC requests whose method ChangesData() and trial control
// (trial_control2_t on FLEXID/TRIAL) carry an HMAC-SHA256 under a shared key, a sender's
// wall-clock time and a nonce. flexidd refuses a message whose signature is missing or
// wrong, whose time is outside its window, or whose nonce it has already seen. Voltage
// commands (voltage_command_t on PREFIX/<actuator>/COMMAND) drive hardware and are signed
// the same way; the actuator (flexid-rig --closed-loop) checks them with a Verifier whose
// window is its command timeout.
//
// Shared by flexidd (Verifier), the command line, the virtual rig and the benchmarks (Sign):
// one small module of the bus contract, as lcmtypes/wire_check.h.
//
// Canonical form (what is signed): a tag naming the message type and version, a newline,
// then every field except `auth`, in the order of its .lcm file, each written as
//   <length in bytes, decimal> ':' <bytes> '\n'
// with integers as decimal ASCII ("-12"). The length prefixes make it unambiguous whatever
// the strings hold (newlines, colons, NULs), and the tag keeps a signature of one type from
// passing as another's.
//   rpc_request_t:    "flexid.rpc_request_t/1\n"    utime request_id client_id method
//                                                   args_json nonce
//   trial_control2_t: "flexid.trial_control2_t/1\n" utime actuator_id action protocol
//                                                   sent_utime nonce
//   voltage_command_t: "flexid.voltage_command_t/2\n" utime actuator_id voltage_V sequence
//                                                   controller_id mode reference_mm
//                                                   reference_utime sent_utime nonce
// (voltage_V and reference_mm in the shortest decimal form that reads back to the same
// double, to_chars). Version 1 had no reference; its signatures do not pass as version 2's.
// `auth` is the lowercase hex HMAC-SHA256(key, canonical form): 64 characters.
//
// The key: 32 random bytes, written as one line of 64 hex digits in a file that only the
// service user (and users who may change data) can read.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <map>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>

namespace flexid {
class rpc_request_t;
class trial_control2_t;
class voltage_command_t;
}  // namespace flexid

namespace flexid::auth {

inline constexpr size_t kKeyBytes = 32;
struct Key {
  std::array<uint8_t, kKeyBytes> bytes{};
};

// A key file that cannot be read, created or trusted: one line naming the file.
struct KeyError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Reads a key file: 64 hex digits, optionally followed by one newline. Throws KeyError.
// Clients use this; the mode bits are the daemon's concern (LoadOrCreateKeyFile).
Key ReadKeyFile(const std::string& path);

// flexidd's key: the file at `path`, created when absent (O_CREAT|O_EXCL, mode 0600, 32
// bytes from getrandom(2); the parent directory is created too). An existing file must be a
// regular file that neither group nor others may read or write, judged by its mode bits
// (not access(2), which says yes to root whatever the mode). Throws KeyError.
Key LoadOrCreateKeyFile(const std::string& path, bool* created = nullptr);

// Where a client finds the key: `flag` (--key-file) when given, else $FLEXID_KEY_FILE when
// set, else var/flexidd.key (that of flexidd running on its embedded defaults).
std::string ClientKeyFilePath(const std::string& flag);

// True for the RPC methods that change or delete stored data (they need a signature):
// identify, model_activate, trial_start, trial_stop, diagnose (it stores an alert), and
// any other name. False only for the read-only ones listed here: status, actuators, trials,
// trial_samples, models, model, alerts. Failing safe: a method added later (a delete, an
// import) is protected until someone lists it here as read-only.
bool ChangesData(std::string_view method);

// [A-Za-z0-9_-]{8,64}.
bool IsValidNonce(std::string_view nonce);
// 128 random bits as 32 hex digits (getrandom(2)).
std::string RandomNonce();

std::string CanonicalForm(const flexid::rpc_request_t& request);
std::string CanonicalForm(const flexid::trial_control2_t& control);
std::string CanonicalForm(const flexid::voltage_command_t& command);

// Lowercase hex HMAC-SHA256(key, canonical).
std::string Signature(const Key& key, std::string_view canonical);
// Compares in constant time (CRYPTO_memcmp); false for anything but 64 lowercase hex digits.
bool SignatureMatches(const Key& key, std::string_view canonical, std::string_view auth);

// Fill the nonce (a new random one when empty) and then `auth`. For a request the caller
// sets utime to its wall clock (bus::WallClockUtime()); for trial control, sent_utime (utime
// stays message time).
void Sign(const Key& key, flexid::rpc_request_t* request);
void Sign(const Key& key, flexid::trial_control2_t* control);
void Sign(const Key& key, flexid::voltage_command_t* command);

// The nonces seen within the replay window, by (scope, nonce), each remembered until the
// time after which a message carrying it is refused as stale anyway. Bounded: at most
// `capacity` entries (default 100,000, about 10 MB); when full of unexpired nonces a new
// one is refused (kFull) rather than an old one forgotten, which would let its message be
// replayed. Only messages with a valid signature get this far, so only key holders can
// fill it.
class NonceCache {
 public:
  enum class Result { kFresh, kReplayed, kFull };
  explicit NonceCache(size_t capacity = 100000) : capacity_(capacity) {}
  // Forgets entries expired at now_utime, then records the nonce until expires_utime
  // (kFresh) unless it is there already (kReplayed) or the cache is full (kFull).
  Result Insert(const std::string& scope, const std::string& nonce, int64_t expires_utime,
                int64_t now_utime);
  size_t size() const { return expiry_.size(); }

 private:
  size_t capacity_;
  std::map<std::pair<std::string, std::string>, int64_t> expiry_;  // (scope, nonce) -> until
  std::set<std::pair<int64_t, std::pair<std::string, std::string>>> by_time_;
};

struct VerifierOptions {
  int64_t window_us = 30'000'000;  // |sender's time - our wall clock| allowed
  size_t max_nonces = 100000;
};

// flexidd's side. The one place flexidd decides on the wall clock: the sender's time is
// compared with this host's, so the hosts must keep NTP time well within the window.
class Verifier {
 public:
  Verifier(const Key& key, VerifierOptions options)
      : key_(key), options_(options), nonces_(options.max_nonces) {}

  // Empty when the message is authentic, within the window and not seen before (its nonce
  // is then remembered); otherwise why not, one line: "no signature", "bad nonce", "bad
  // signature", "request time 45 s from the daemon's clock (window 30 s)", "replayed
  // nonce", "too many signed requests within the window (100000)". A command's time is
  // judged against "this host's clock", in tenths of a second under a 10 s window.
  std::string Check(const flexid::rpc_request_t& request, int64_t now_utime);
  std::string Check(const flexid::trial_control2_t& control, int64_t now_utime);
  std::string Check(const flexid::voltage_command_t& command, int64_t now_utime);

  size_t nonces_remembered() const { return nonces_.size(); }

 private:
  std::string Check(std::string_view canonical, const std::string& auth, int64_t sent_utime,
                    const std::string& scope, const std::string& nonce, int64_t now_utime,
                    const char* what = "request time", const char* whose = "the daemon's clock");
  Key key_;
  VerifierOptions options_;
  NonceCache nonces_;
};

}  // namespace flexid::auth
