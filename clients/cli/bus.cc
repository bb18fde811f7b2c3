#include "clients/cli/bus.h"

#include <unistd.h>

#include <filesystem>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <optional>
#include <utility>

#include "bus/channels.h"
#include "bus/lcm_url.h"
#include "bus/rpc_client.h"
#include "clients/cli/command.h"

namespace flexid::cli {

std::string& LcmUrl() {
  static std::string url = "udpm://239.255.76.67:7667?ttl=0";
  return url;
}

std::string& ChannelPrefix() {
  static std::string prefix = bus::kDefaultPrefix;
  return prefix;
}

bus::Channels BusChannels() { return bus::Channels(ChannelPrefix()); }

std::vector<std::string>& KeyFileOptions() {
  static std::vector<std::string> values;
  return values;
}

std::string& KeyDir() {
  static std::string dir;
  return dir;
}

namespace {

// "ID=PATH" split, when the text before the first '=' is a daemon id (no '/').
std::optional<std::pair<std::string, std::string>> DaemonKeyFile(const std::string& value) {
  const size_t equals = value.find('=');
  if (equals == std::string::npos) return std::nullopt;
  const std::string id = value.substr(0, equals);
  if (!bus::IsValidPrefix(id)) return std::nullopt;
  return std::make_pair(id, value.substr(equals + 1));
}

}  // namespace

std::string KeyFileOptionProblem(const std::string& value) {
  if (value.empty()) return "expected PATH or ID=PATH, got an empty value";
  if (const auto pair = DaemonKeyFile(value); pair && pair->second.empty())
    return "expected ID=PATH, got no path after \"" + pair->first + "=\"";
  return "";
}

std::string KeyFileFor(const std::string& daemon_id) {
  std::string plain;
  for (const std::string& value : KeyFileOptions()) {
    const auto pair = DaemonKeyFile(value);
    if (!pair)
      plain = value;
    else if (!daemon_id.empty() && pair->first == daemon_id)
      return pair->second;
  }
  if (!KeyDir().empty() && !daemon_id.empty())
    return (std::filesystem::path(KeyDir()) / (daemon_id + ".key")).string();
  return auth::ClientKeyFilePath(plain);
}

const auth::Key& SigningKey(const std::string& daemon_id) {
  static std::map<std::string, auth::Key> keys;  // by file
  const std::string path = KeyFileFor(daemon_id);
  const auto it = keys.find(path);
  if (it != keys.end()) return it->second;
  try {
    return keys.emplace(path, auth::ReadKeyFile(path)).first->second;
  } catch (const auth::KeyError& e) {
    throw OperationError(std::string(e.what()) + " (a request that changes data needs the key of " +
                         (daemon_id.empty() ? std::string("flexidd") : "flexidd " + daemon_id) +
                         ": --key-file PATH, --key-file ID=PATH, --key-dir DIR or "
                         "FLEXID_KEY_FILE)");
  }
}

namespace {

// A page of trial samples is up to ~1 MB of JSON, sent as one burst of fragments: a
// receive buffer that holds a whole reply, so that a busy machine does not drop a fragment
// (and with it the reply) before this process reads it.
constexpr int64_t kReceiveBufferBytes = 4194304;

}  // namespace

std::unique_ptr<lcm::LCM> JoinBus() {
  auto lcm = std::make_unique<lcm::LCM>(bus::WithReceiveBuffer(LcmUrl(), kReceiveBufferBytes));
  if (!lcm->good()) throw OperationError("cannot join the LCM bus at " + LcmUrl());
  return lcm;
}

RpcResult CallDaemon(const std::string& method, const nlohmann::json& args,
                     std::chrono::milliseconds timeout, const std::string& daemon_id) {
  const auth::Key* key = auth::ChangesData(method) ? &SigningKey(daemon_id) : nullptr;
  nlohmann::json addressed = args;
  if (!daemon_id.empty()) addressed["daemon_id"] = daemon_id;
  const std::unique_ptr<lcm::LCM> lcm = JoinBus();
  bus::RpcClient client(*lcm, BusChannels(), "cli-" + std::to_string(getpid()), key);
  const std::optional<bus::RpcReply> reply = client.Call(method, addressed.dump(), timeout);
  if (!reply)
    throw OperationError(
        (daemon_id.empty() ? std::string("no flexidd") : "flexidd " + daemon_id) +
        (daemon_id.empty() ? " answered \"" : " did not answer \"") + method + "\" on " + LcmUrl() +
        (ChannelPrefix() == bus::kDefaultPrefix ? ""
                                                : " (channel prefix " + ChannelPrefix() + ")") +
        " within " + std::to_string(timeout.count() / 1000) + " s");
  RpcResult out;
  out.status = reply->message.status;
  out.error = reply->message.error;
  out.daemon_id = reply->message.daemon_id;
  out.result = nlohmann::json::parse(reply->message.result_json, nullptr, false);
  return out;
}

namespace {
volatile sig_atomic_t stop_signal_received = 0;
extern "C" void OnStopSignal(int) { stop_signal_received = 1; }
}  // namespace

StopOnSignal::StopOnSignal() {
  stop_signal_received = 0;
  struct sigaction action {};
  action.sa_handler = OnStopSignal;
  sigemptyset(&action.sa_mask);
  sigaction(SIGINT, &action, &previous_interrupt_);
  sigaction(SIGTERM, &action, &previous_terminate_);
}

StopOnSignal::~StopOnSignal() {
  sigaction(SIGINT, &previous_interrupt_, nullptr);
  sigaction(SIGTERM, &previous_terminate_, nullptr);
}

bool StopOnSignal::requested() const { return stop_signal_received != 0; }

}  // namespace flexid::cli
