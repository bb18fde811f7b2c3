// Authentication of requests that change data (lcmtypes/message_auth.h, README "Security"):
// the canonical form, signatures, the nonce cache, which methods need a key and the key
// files; then flexidd itself, in-process on a real bus and database, refusing unsigned,
// badly signed, stale and replayed requests and trial control (and logging each), and the
// command line and flexidd's start-up as programs.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "bus/clock.h"
#include "child_process.h"
#include "daemon/daemon.h"
#include "daemon/rpc.h"
#include "fault_harness.h"
#include "lcmtypes/message_auth.h"
#include "live_daemon.h"
#include "scratch_dir.h"
#include "storage/database.h"

namespace flexid {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;
using testing::Bus;
using testing::Bytes;
using testing::Encode;
using testing::RandomUrl;
using testing::ReadFile;

constexpr int64_t kNow = 1'750'000'000'000'000;  // a wall-clock time, us

auth::Key TestKey(uint8_t first = 0) {
  auth::Key key;
  for (size_t i = 0; i < key.bytes.size(); ++i) key.bytes[i] = static_cast<uint8_t>(first + i);
  return key;
}

flexid::rpc_request_t Request(const std::string& method, const std::string& args_json,
                              int64_t utime = kNow) {
  flexid::rpc_request_t r;
  r.utime = utime;
  r.request_id = "r1";
  r.client_id = "auth_test";
  r.method = method;
  r.args_json = args_json;
  return r;
}

// ---------------------------------------------------------------------------------------
// The pieces
// ---------------------------------------------------------------------------------------

TEST(MessageAuth, CanonicalFormIsLengthPrefixedAndUnambiguous) {
  flexid::rpc_request_t r = Request("identify", R"({"actuator": "S1"})", -12);
  r.nonce = "abcdefgh";
  r.auth = "not part of it";
  EXPECT_EQ(auth::CanonicalForm(r),
            "flexid.rpc_request_t/1\n3:-12\n2:r1\n9:auth_test\n8:identify\n"
            "18:{\"actuator\": \"S1\"}\n8:abcdefgh\n");
  // Moving bytes between neighbouring fields changes the form (and so the signature).
  flexid::rpc_request_t a = r, b = r;
  a.method = "identify\n8:x";
  a.args_json = "";
  b.method = "identify";
  b.args_json = "8:x";
  EXPECT_NE(auth::CanonicalForm(a), auth::CanonicalForm(b));

  flexid::trial_control2_t c;
  c.utime = 5;
  c.actuator_id = "S1";
  c.action = flexid::trial_control2_t::kStart;
  c.protocol = "p";
  c.sent_utime = 7;
  c.nonce = "n0000000";
  EXPECT_EQ(auth::CanonicalForm(c),
            "flexid.trial_control2_t/1\n1:5\n2:S1\n1:1\n1:p\n1:7\n8:n0000000\n");
}

TEST(MessageAuth, SignatureIsHmacSha256InLowercaseHex) {
  // Python: hmac.new(bytes(range(32)), b"abc", hashlib.sha256).hexdigest()
  EXPECT_EQ(auth::Signature(TestKey(), "abc"),
            "f0133729c4163dede81e21cd47839256da58171238c8a0d874397c73b14e1e47");
  const std::string good = auth::Signature(TestKey(), "abc");
  EXPECT_TRUE(auth::SignatureMatches(TestKey(), "abc", good));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(1), "abc", good));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(), "abd", good));
  std::string upper = good;
  for (char& ch : upper) ch = static_cast<char>(std::toupper(ch));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(), "abc", upper));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(), "abc", good.substr(0, 63)));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(), "abc", good + "0"));
  EXPECT_FALSE(auth::SignatureMatches(TestKey(), "abc", ""));
}

TEST(MessageAuth, VerifierAcceptsOnceAndRefusesWhatIsNotAuthentic) {
  auth::Verifier verifier(TestKey(), {});
  flexid::rpc_request_t r = Request("identify", R"({"actuator": "S1"})");
  auth::Sign(TestKey(), &r);
  EXPECT_TRUE(auth::IsValidNonce(r.nonce)) << r.nonce;
  EXPECT_EQ(r.auth.size(), 64u);
  EXPECT_EQ(verifier.Check(r, kNow + 1'000'000), "");
  EXPECT_EQ(verifier.Check(r, kNow + 2'000'000), "replayed nonce");
  // The same nonce from another client is another request.
  flexid::rpc_request_t other = r;
  other.client_id = "auth_test2";
  auth::Sign(TestKey(), &other);
  EXPECT_EQ(verifier.Check(other, kNow), "");

  flexid::rpc_request_t unsigned_request = Request("identify", "{}");
  unsigned_request.nonce = auth::RandomNonce();
  EXPECT_EQ(verifier.Check(unsigned_request, kNow), "no signature");
  flexid::rpc_request_t wrong_key = Request("identify", "{}");
  auth::Sign(TestKey(7), &wrong_key);
  EXPECT_EQ(verifier.Check(wrong_key, kNow), "bad signature");
  flexid::rpc_request_t tampered = Request("model_activate", R"({"version": 1})");
  auth::Sign(TestKey(), &tampered);
  tampered.args_json = R"({"version": 2})";
  EXPECT_EQ(verifier.Check(tampered, kNow), "bad signature");
  flexid::rpc_request_t bad_nonce = Request("identify", "{}");
  bad_nonce.nonce = "short";
  auth::Sign(TestKey(), &bad_nonce);
  EXPECT_EQ(verifier.Check(bad_nonce, kNow).rfind("bad nonce", 0), 0u);

  // The window: 30 s either way by default.
  flexid::rpc_request_t old = Request("identify", "{}", kNow - 45'000'000);
  auth::Sign(TestKey(), &old);
  EXPECT_EQ(verifier.Check(old, kNow), "request time 45 s behind the daemon's clock (window 30 s)");
  flexid::rpc_request_t future = Request("identify", "{}", kNow + 31'000'000);
  auth::Sign(TestKey(), &future);
  EXPECT_EQ(verifier.Check(future, kNow),
            "request time 31 s ahead of the daemon's clock (window 30 s)");
  flexid::rpc_request_t edge = Request("identify", "{}", kNow - 29'000'000);
  auth::Sign(TestKey(), &edge);
  EXPECT_EQ(verifier.Check(edge, kNow), "");
  flexid::rpc_request_t absurd = Request("identify", "{}", INT64_MIN);
  auth::Sign(TestKey(), &absurd);
  EXPECT_NE(verifier.Check(absurd, kNow).find("behind the daemon's clock"), std::string::npos);
  // An exact replay after the window is stale, whatever the cache forgot meanwhile.
  EXPECT_NE(verifier.Check(r, kNow + 31'000'000).find("behind"), std::string::npos);
}

TEST(MessageAuth, TrialControlIsJudgedOnItsSentTimeNotItsMessageTime) {
  auth::Verifier verifier(TestKey(), {});
  flexid::trial_control2_t c;
  c.utime = 1'000'000;  // an accelerated rig's message time, far from the wall clock
  c.actuator_id = "S1";
  c.action = flexid::trial_control2_t::kStart;
  c.protocol = "square:level=5";
  c.sent_utime = kNow;
  auth::Sign(TestKey(), &c);
  EXPECT_EQ(verifier.Check(c, kNow + 500'000), "");
  EXPECT_EQ(verifier.Check(c, kNow + 600'000), "replayed nonce");
  flexid::trial_control2_t moved = c;  // signed for one actuator, sent for another
  moved.actuator_id = "S2";
  moved.nonce = auth::RandomNonce();
  EXPECT_EQ(verifier.Check(moved, kNow), "bad signature");
  flexid::trial_control2_t stale = c;
  stale.sent_utime = kNow - 60'000'000;
  stale.nonce.clear();
  auth::Sign(TestKey(), &stale);
  EXPECT_NE(verifier.Check(stale, kNow).find("60 s behind"), std::string::npos);
  // An RPC signature does not pass as trial control's (the tag differs).
  flexid::trial_control2_t unsigned_control = c;
  unsigned_control.auth.clear();
  EXPECT_EQ(verifier.Check(unsigned_control, kNow), "no signature");
}

TEST(MessageAuth, NonceCacheExpiresAndIsBounded) {
  auth::NonceCache cache(3);
  using R = auth::NonceCache::Result;
  EXPECT_EQ(cache.Insert("a", "n1", 100, 0), R::kFresh);
  EXPECT_EQ(cache.Insert("a", "n1", 100, 50), R::kReplayed);
  EXPECT_EQ(cache.Insert("b", "n1", 100, 50), R::kFresh);  // scopes are apart
  EXPECT_EQ(cache.Insert("a", "n2", 200, 50), R::kFresh);
  // Full of unexpired nonces: a new one is refused, none is forgotten.
  EXPECT_EQ(cache.Insert("a", "n3", 200, 60), R::kFull);
  EXPECT_EQ(cache.Insert("a", "n1", 100, 60), R::kReplayed);
  EXPECT_EQ(cache.size(), 3u);
  // After n1's expiry (100) its entries go, making room.
  EXPECT_EQ(cache.Insert("a", "n3", 200, 101), R::kFresh);
  EXPECT_EQ(cache.size(), 2u);
  EXPECT_EQ(cache.Insert("a", "n1", 300, 102), R::kFresh);

  // Through the verifier: the bound is a refusal with a reason.
  auth::VerifierOptions options;
  options.max_nonces = 2;
  auth::Verifier verifier(TestKey(), options);
  for (int i = 0; i < 3; ++i) {
    flexid::rpc_request_t r = Request("identify", "{}");
    auth::Sign(TestKey(), &r);
    const std::string verdict = verifier.Check(r, kNow);
    if (i < 2)
      EXPECT_EQ(verdict, "");
    else
      EXPECT_EQ(verdict.rfind("too many signed requests within the window (2)", 0), 0u) << verdict;
  }
  flexid::rpc_request_t later = Request("identify", "{}", kNow + 31'000'000);
  auth::Sign(TestKey(), &later);
  EXPECT_EQ(verifier.Check(later, kNow + 31'000'000), "");  // the first two expired
}

TEST(MessageAuth, OnlyTheListedReadOnlyMethodsNeedNoKey) {
  for (const char* m :
       {"status", "actuators", "trials", "trial_samples", "models", "model", "alerts"})
    EXPECT_FALSE(daemon::ChangesData(m)) << m;
  for (const char* m : {"identify", "model_activate", "trial_start", "trial_stop", "diagnose",
                        "trials_delete", "import", "", "STATUS", "status ", "frobnicate"})
    EXPECT_TRUE(daemon::ChangesData(m)) << m;
}

TEST(MessageAuth, KeyFileIsCreatedPrivateAndRefusedWhenOthersMayReadIt) {
  const testing::ScratchDir scratch;
  const std::string path = scratch.File("sub/flexidd.key");
  bool created = false;
  const auth::Key key = auth::LoadOrCreateKeyFile(path, &created);
  EXPECT_TRUE(created);
  struct stat info {};
  ASSERT_EQ(stat(path.c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 07777, 0600u);
  const std::string text = ReadFile(path);
  ASSERT_EQ(text.size(), 65u);
  EXPECT_EQ(text.find_first_not_of("0123456789abcdef"), 64u);
  EXPECT_EQ(text.back(), '\n');
  const auth::Key again = auth::LoadOrCreateKeyFile(path, &created);
  EXPECT_FALSE(created);
  EXPECT_EQ(again.bytes, key.bytes);
  EXPECT_EQ(auth::ReadKeyFile(path).bytes, key.bytes);
  EXPECT_NE(auth::LoadOrCreateKeyFile(scratch.File("other.key")).bytes, key.bytes);

  // Mode bits, not access(2): the tests run as root, who may read anything.
  for (const mode_t mode : {0640, 0604, 0620, 0660, 0602}) {
    ASSERT_EQ(chmod(path.c_str(), mode), 0);
    try {
      auth::LoadOrCreateKeyFile(path);
      ADD_FAILURE() << "mode " << std::oct << mode << " accepted";
    } catch (const auth::KeyError& e) {
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("group or others"), std::string::npos) << e.what();
    }
    EXPECT_EQ(auth::ReadKeyFile(path).bytes, key.bytes);  // clients do not judge the mode
  }
  ASSERT_EQ(chmod(path.c_str(), 0400), 0);
  EXPECT_EQ(auth::LoadOrCreateKeyFile(path).bytes, key.bytes);

  for (const std::string& bad :
       {std::string(""), std::string(63, 'a'), std::string(65, 'a'), std::string(63, 'a') + "g",
        std::string(64, 'a') + "\n\n", " " + std::string(64, 'a')}) {
    const std::string bad_path = scratch.File("bad.key");
    std::filesystem::remove(bad_path);
    {
      std::ofstream out(bad_path);
      out << bad;
    }
    chmod(bad_path.c_str(), 0600);
    EXPECT_THROW(auth::LoadOrCreateKeyFile(bad_path), auth::KeyError) << "[" << bad << "]";
    EXPECT_THROW(auth::ReadKeyFile(bad_path), auth::KeyError) << "[" << bad << "]";
  }
  try {
    auth::ReadKeyFile(scratch.File("absent.key"));
    ADD_FAILURE() << "no error for a missing key file";
  } catch (const auth::KeyError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("cannot read key file " + scratch.File("absent.key"), 0),
              0u)
        << e.what();
  }
}

TEST(MessageAuth, ClientsFindTheKeyByFlagThenEnvironmentThenDefault) {
  const char* saved = std::getenv("FLEXID_KEY_FILE");
  const std::optional<std::string> previous =
      saved ? std::optional<std::string>(saved) : std::nullopt;
  unsetenv("FLEXID_KEY_FILE");
  EXPECT_EQ(auth::ClientKeyFilePath(""), "var/flexidd.key");
  setenv("FLEXID_KEY_FILE", "/etc/flexid/key", 1);
  EXPECT_EQ(auth::ClientKeyFilePath(""), "/etc/flexid/key");
  EXPECT_EQ(auth::ClientKeyFilePath("mine.key"), "mine.key");
  if (previous)
    setenv("FLEXID_KEY_FILE", previous->c_str(), 1);
  else
    unsetenv("FLEXID_KEY_FILE");

  daemon::Config config;
  EXPECT_EQ(daemon::KeyFilePath(config), "var/flexidd.key");  // what the clients default to
  config.database = "/srv/flexid/flexid.db";
  EXPECT_EQ(daemon::KeyFilePath(config), "/srv/flexid/flexidd.key");
  config.auth_key_file = "/etc/flexid/key";
  EXPECT_EQ(daemon::KeyFilePath(config), "/etc/flexid/key");
}

// ---------------------------------------------------------------------------------------
// flexidd in-process: refusals on the bus, in the database and in the log
// ---------------------------------------------------------------------------------------

class AuthenticatedDaemon : public testing::InProcessDaemonTest {
 protected:
  void SetUp() override {
    InProcessDaemonTest::SetUp();
    if (IsSkipped()) return;
    config_.daemon_id = "auth";
    config_.log_level = "info";
    config_.auto_trials = false;
    StartDaemon();
  }

  bool Drive(const std::function<bool()>& done, std::chrono::milliseconds timeout) {
    return testing::DriveInProcess(*daemon_, *bus_, done, timeout);
  }
  void Send(const std::string& channel, const Bytes& bytes) {
    const int64_t before = daemon_->counters().messages_received;
    ASSERT_EQ(bus_->PublishRaw(channel, bytes), 0);
    ASSERT_TRUE(Drive([&] { return daemon_->counters().messages_received > before; }, 3s))
        << "a message on " << channel << " never reached the daemon";
  }
  // Publishes the encoded request and returns the n-th reply (from 1) to its request id.
  std::optional<flexid::rpc_reply_t> Call(const Bytes& bytes, const std::string& request_id,
                                          size_t n = 1) {
    Send("FLEXID/RPC/REQUEST", bytes);
    Drive([&] { return bus_->RepliesTo(request_id).size() >= n; }, 3s);
    const auto replies = bus_->RepliesTo(request_id);
    if (replies.size() < n) return std::nullopt;
    return replies[n - 1].second;
  }
  flexid::rpc_request_t Make(const std::string& method, const std::string& args_json) {
    flexid::rpc_request_t r;
    r.utime = bus::WallClockUtime();
    r.request_id = "a" + std::to_string(++requests_);
    r.client_id = "auth_test";
    r.method = method;
    r.args_json = args_json;
    return r;
  }
  flexid::trial_control2_t Control(int8_t action, int64_t utime) {
    flexid::trial_control2_t c;
    c.utime = utime;
    c.actuator_id = "S1";
    c.action = action;
    c.protocol = "auth test";
    c.sent_utime = bus::WallClockUtime();
    return c;
  }
  size_t StoredTrials() {
    return storage::Database::Open(config_.database).Trials(std::nullopt, 1000).size();
  }
  size_t StoredModels() { return storage::Database::Open(config_.database).Models("S1").size(); }
  // The log file; flexidd flushes it at every warning, and each test ends with a refusal.
  std::string Log() { return ReadFile(config_.log_file); }

  int requests_ = 0;
};

TEST_F(AuthenticatedDaemon, RefusesUnsignedBadlySignedStaleAndReplayedRequestsAndLogsThem) {
  struct stat info {};
  ASSERT_EQ(stat(daemon::KeyFilePath(config_).c_str(), &info), 0);
  EXPECT_EQ(info.st_mode & 07777, 0600u) << "flexidd created its key readable by others";

  auto expect_refused = [&](const flexid::rpc_request_t& r, const std::string& why) {
    SCOPED_TRACE(why);
    const auto reply = Call(Encode(r), r.request_id);
    ASSERT_TRUE(reply.has_value()) << "no reply";
    EXPECT_EQ(reply->status, flexid::rpc_reply_t::kUnauthorized) << reply->error;
    EXPECT_NE(reply->error.find("not authorised: " + why), std::string::npos) << reply->error;
  };
  const std::string identify_args = R"({"actuator": "S1", "latest": 1})";
  // 1. Unsigned.
  expect_refused(Make("identify", identify_args), "no signature");
  // 2. Signed with another key.
  flexid::rpc_request_t wrong = Make("identify", identify_args);
  auth::Sign(TestKey(), &wrong);
  expect_refused(wrong, "bad signature");
  // 3. Signed, but two minutes old.
  flexid::rpc_request_t stale = Make("identify", identify_args);
  stale.utime -= 120'000'000;
  auth::Sign(key_, &stale);
  expect_refused(stale, "request time 120 s behind the daemon's clock (window 30 s)");
  // 4. Signed correctly: accepted and done.
  flexid::rpc_request_t start = Make("trial_start", R"({"actuator": "S1", "protocol": "a"})");
  auth::Sign(key_, &start);
  const Bytes start_bytes = Encode(start);
  const auto started = Call(start_bytes, start.request_id);
  ASSERT_TRUE(started.has_value());
  ASSERT_EQ(started->status, flexid::rpc_reply_t::kOk) << started->error;
  EXPECT_EQ(StoredTrials(), 1u);
  // 5. The exact bytes of (4) again: a replay.
  const auto replayed = Call(start_bytes, start.request_id, 2);
  ASSERT_TRUE(replayed.has_value()) << "no reply to the replay";
  EXPECT_EQ(replayed->status, flexid::rpc_reply_t::kUnauthorized);
  EXPECT_EQ(replayed->error, "not authorised: replayed nonce");
  // 6. Read-only without a key.
  const flexid::rpc_request_t trials = Make("trials", "{}");
  const auto listed = Call(Encode(trials), trials.request_id);
  ASSERT_TRUE(listed.has_value());
  EXPECT_EQ(listed->status, flexid::rpc_reply_t::kOk) << listed->error;
  EXPECT_EQ(nlohmann::json::parse(listed->result_json).size(), 1u);

  // Nothing changed but what (4) did: one trial, no model.
  EXPECT_EQ(StoredTrials(), 1u);
  EXPECT_EQ(StoredModels(), 0u);
  EXPECT_EQ(daemon_->counters().refused_unauthorized, 4);
  const flexid::rpc_request_t status = Make("status", "{}");
  const auto counted = Call(Encode(status), status.request_id);
  ASSERT_TRUE(counted.has_value());
  EXPECT_EQ(nlohmann::json::parse(counted->result_json)["requests_refused_unauthorized"], 4);

  const std::string log = Log();
  for (const std::string& line :
       {"request refused [method: identify, client: auth_test, request: a1, args: " +
            identify_args + "] not authorised: no signature",
        std::string("request refused [method: identify, client: auth_test, request: a2"),
        std::string("] not authorised: bad signature"),
        std::string("not authorised: request time 120 s behind the daemon's clock"),
        std::string("request accepted [method: trial_start, client: auth_test, request: a4, "
                    "args: {\"actuator\": \"S1\", \"protocol\": \"a\"}] done"),
        std::string("request refused [method: trial_start, client: auth_test, request: a4, "
                    "args: {\"actuator\": \"S1\", \"protocol\": \"a\"}] not authorised: replayed "
                    "nonce")})
    EXPECT_NE(log.find(line), std::string::npos) << "not in the log: " << line << "\n" << log;
  EXPECT_EQ(log.find("request accepted [method: trials"), std::string::npos)
      << "read-only requests are not logged one by one";
  const std::string key_text = ReadFile(daemon::KeyFilePath(config_)).substr(0, 64);
  EXPECT_EQ(log.find(key_text), std::string::npos) << "the key is in the log";
  EXPECT_EQ(log.find(start.auth), std::string::npos) << "a signature is in the log";
}

TEST_F(AuthenticatedDaemon, RefusesUnsignedBadlySignedAndReplayedTrialControl) {
  const int64_t message_time = 1'000'000'000'000;  // far from the wall clock (a replayed log)
  // The unsigned trial_control_t of earlier versions.
  flexid::trial_control_t old;
  old.utime = message_time;
  old.actuator_id = "S1";
  old.action = flexid::trial_control_t::kStart;
  old.protocol = "old";
  Send("FLEXID/TRIAL", Encode(old));
  // trial_control2_t without a signature, and with another key's.
  flexid::trial_control2_t bare = Control(flexid::trial_control2_t::kStart, message_time);
  bare.nonce = auth::RandomNonce();
  Send("FLEXID/TRIAL", Encode(bare));
  flexid::trial_control2_t wrong = Control(flexid::trial_control2_t::kStart, message_time);
  auth::Sign(TestKey(), &wrong);
  Send("FLEXID/TRIAL", Encode(wrong));
  Drive([] { return false; }, 300ms);  // three commit intervals: what they wrote is stored
  EXPECT_EQ(StoredTrials(), 0u);
  EXPECT_EQ(daemon_->counters().refused_unauthorized, 3);

  // Signed: the trial starts at its message time.
  flexid::trial_control2_t start = Control(flexid::trial_control2_t::kStart, message_time);
  auth::Sign(key_, &start);
  const Bytes start_bytes = Encode(start);
  Send("FLEXID/TRIAL", start_bytes);
  // The writer thread stores it within its commit interval.
  ASSERT_TRUE(Drive([&] { return StoredTrials() == 1u; }, 3s));
  EXPECT_EQ(storage::Database::Open(config_.database).Trials(std::nullopt, 10)[0].start_utime,
            message_time);
  // Its replay, and a signed stop sent too long ago: refused, the trial goes on.
  Send("FLEXID/TRIAL", start_bytes);
  flexid::trial_control2_t stop = Control(flexid::trial_control2_t::kStop, message_time + 1);
  stop.sent_utime -= 40'000'000;
  auth::Sign(key_, &stop);
  Send("FLEXID/TRIAL", Encode(stop));
  Drive([] { return false; }, 300ms);  // three commit intervals: what they wrote is stored
  const auto trials = storage::Database::Open(config_.database).Trials(std::nullopt, 10);
  ASSERT_EQ(trials.size(), 1u);
  EXPECT_EQ(trials[0].state, storage::TrialState::kRecording);
  EXPECT_EQ(daemon_->counters().refused_unauthorized, 5);
  EXPECT_EQ(daemon_->counters().rejected_malformed, 0);

  const std::string log = Log();
  for (const std::string line :
       {"trial control refused [actuator: S1, action: 1] not authorised: unsigned trial_control_t",
        "trial control refused [actuator: S1, action: 1, protocol: auth test] not authorised: no "
        "signature",
        "not authorised: bad signature", "trial control accepted [actuator: S1, action: start",
        "not authorised: replayed nonce",
        "trial control refused [actuator: S1, action: 2, protocol: auth test] not authorised: "
        "request time 40 s behind the daemon's clock (window 30 s)"})
    EXPECT_NE(log.find(line), std::string::npos) << "not in the log: " << line << "\n" << log;
}

// ---------------------------------------------------------------------------------------
// The programs: flexidd's start-up and the command line
// ---------------------------------------------------------------------------------------

TEST(AuthPrograms, FlexiddRefusesToStartOnAKeyFileOthersMayRead) {
  const testing::ScratchDir scratch;
  const std::string key = scratch.File("flexidd.key");
  {
    std::ofstream out(key);
    out << std::string(64, 'a') << "\n";
  }
  ASSERT_EQ(chmod(key.c_str(), 0644), 0);
  testing::ChildProcess daemon(
      {FLEXIDD_BINARY, "--db", scratch.File("flexid.db"), "--lcm", RandomUrl(), "--log-file",
       scratch.File("flexidd.log"), "--key-file", key},
      scratch.File("out"), scratch.File("err"));
  const auto status = daemon.Wait(10s);
  ASSERT_TRUE(status.has_value()) << "flexidd runs with a key file others may read";
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 1);
  const std::string err = ReadFile(scratch.File("err"));
  EXPECT_NE(err.find("key file " + key + " may be read or written by group or others (mode 0644)"),
            std::string::npos)
      << err;
}

TEST(AuthPrograms, TheCommandLineSignsWhatChangesDataAndSaysWhenItCannot) {
  const testing::ScratchDir scratch;
  testing::LiveDaemon daemon(scratch.path());
  ASSERT_TRUE(daemon.ready());
  // S1 becomes known to flexidd by its samples (at 0 V: no automatic trial).
  const auto rig = testing::RunCommand(std::string(FLEXID_RIG_BINARY) + " --lcm '" + daemon.url() +
                                           "' --actuator S1 --protocol hold:level=0,duration=2 "
                                           "--speed 0",
                                       scratch.path());
  ASSERT_EQ(rig.exit_code, 0) << rig.err;
  for (int i = 0; i < 50 && daemon.Flexid("rpc actuators").out.find("\"S1\"") == std::string::npos;
       ++i)
    std::this_thread::sleep_for(100ms);
  const std::string flexid = std::string(FLEXID_BINARY) + " --lcm '" + daemon.url() + "' ";
  // No key: read-only requests work; one that changes data fails at once, naming the file.
  const std::string missing = scratch.File("absent.key");
  auto r = testing::RunCommand(flexid + "--key-file '" + missing + "' trials list --json",
                               scratch.path());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = testing::RunCommand(flexid + "--key-file '" + missing + "' trials start --actuator S1",
                          scratch.path());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_EQ(r.err.rfind("flexid: cannot read key file " + missing, 0), 0u) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  // Another key: refused by flexidd, exit 1 with its one line.
  const std::string other = scratch.File("other.key");
  auth::LoadOrCreateKeyFile(other);
  r = testing::RunCommand(flexid + "--key-file '" + other + "' trials start --actuator S1",
                          scratch.path());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("not authorised: bad signature"), std::string::npos) << r.err;
  // The key from the environment.
  r = testing::RunCommand("FLEXID_KEY_FILE='" + daemon.key_file().string() + "' " + flexid +
                              "trials start --actuator S1 --json",
                          scratch.path());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  // And from --key-file (LiveDaemon passes it).
  r = daemon.Flexid("trials stop --actuator S1 --json");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = daemon.Flexid("rpc status");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(nlohmann::json::parse(r.out)["requests_refused_unauthorized"], 1);
}

}  // namespace
}  // namespace flexid
