#include "clients/cli/bus.h"

#include <unistd.h>

#include <lcm/lcm-cpp.hpp>
#include <optional>

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

std::string& KeyFilePath() {
  static std::string path;
  return path;
}

const auth::Key& SigningKey() {
  static std::optional<auth::Key> key;
  if (!key) {
    try {
      key = auth::ReadKeyFile(auth::ClientKeyFilePath(KeyFilePath()));
    } catch (const auth::KeyError& e) {
      throw OperationError(std::string(e.what()) +
                           " (a request that changes data needs flexidd's key: --key-file PATH "
                           "or FLEXID_KEY_FILE)");
    }
  }
  return *key;
}

namespace {

// A page of trial samples is up to ~1 MB of JSON, sent as one burst of fragments: a
// receive buffer that holds a whole reply, so that a busy machine does not drop a fragment
// (and with it the reply) before this process reads it.
constexpr int64_t kReceiveBufferBytes = 4194304;

}  // namespace

RpcResult CallDaemon(const std::string& method, const nlohmann::json& args,
                     std::chrono::milliseconds timeout) {
  const auth::Key* key = auth::ChangesData(method) ? &SigningKey() : nullptr;
  lcm::LCM lcm(bus::WithReceiveBuffer(LcmUrl(), kReceiveBufferBytes));
  if (!lcm.good()) throw OperationError("cannot join the LCM bus at " + LcmUrl());
  bus::RpcClient client(lcm, BusChannels(), "cli-" + std::to_string(getpid()), key);
  const std::optional<bus::RpcReply> reply = client.Call(method, args.dump(), timeout);
  if (!reply)
    throw OperationError("no flexidd answered \"" + method + "\" on " + LcmUrl() +
                         (ChannelPrefix() == bus::kDefaultPrefix
                              ? ""
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
