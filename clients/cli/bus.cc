#include "clients/cli/bus.h"

#include <unistd.h>

#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <optional>
#include <random>

#include "bus/lcm_url.h"
#include "clients/cli/command.h"
#include "lcmtypes/wire_check.h"

namespace flexid::cli {

std::string& LcmUrl() {
  static std::string url = "udpm://239.255.76.67:7667?ttl=0";
  return url;
}

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

struct ReplyCatcher {
  std::string request_id;
  std::optional<flexid::rpc_reply_t> reply;
  static void On(const lcm::ReceiveBuffer* rbuf, const std::string&, ReplyCatcher* self) {
    flexid::rpc_reply_t r;
    if (r.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) > 0 &&
        r.request_id == self->request_id)
      self->reply = r;
  }
};

std::string RandomToken() {
  std::random_device device;
  std::uniform_int_distribution<uint64_t> any;
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(any(device)));
  return text;
}

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
  const std::string client_id = "cli-" + std::to_string(getpid());
  ReplyCatcher catcher{RandomToken(), std::nullopt};
  lcm.subscribeFunction("FLEXID/RPC/REPLY/" + client_id, &ReplyCatcher::On, &catcher);
  flexid::rpc_request_t request;
  request.utime = std::chrono::duration_cast<std::chrono::microseconds>(
                      std::chrono::system_clock::now().time_since_epoch())
                      .count();
  request.request_id = catcher.request_id;
  request.client_id = client_id;
  request.method = method;
  request.args_json = args.dump();
  request.nonce = auth::RandomNonce();
  if (key) auth::Sign(*key, &request);
  lcm.publish("FLEXID/RPC/REQUEST", &request);
  const auto end = std::chrono::steady_clock::now() + timeout;
  while (!catcher.reply && std::chrono::steady_clock::now() < end) lcm.handleTimeout(50);
  if (!catcher.reply)
    throw OperationError("no flexidd answered \"" + method + "\" on " + LcmUrl() + " within " +
                         std::to_string(timeout.count() / 1000) + " s");
  RpcResult out;
  out.status = catcher.reply->status;
  out.error = catcher.reply->error;
  out.daemon_id = catcher.reply->daemon_id;
  out.result = nlohmann::json::parse(catcher.reply->result_json, nullptr, false);
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
