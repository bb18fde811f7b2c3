#include "bus/rpc_client.h"

#include <algorithm>
#include <cstdio>
#include <random>

#include "bus/clock.h"
#include "lcmtypes/wire_check.h"

namespace flexid::bus {

std::string RandomRequestId() {
  // One generator per thread, seeded once: std::random_device can be slow to open.
  thread_local std::mt19937_64 generator{std::random_device{}()};
  char text[17];
  std::snprintf(text, sizeof text, "%016llx", static_cast<unsigned long long>(generator()));
  return text;
}

flexid::rpc_request_t MakeRequest(const std::string& client_id, const std::string& request_id,
                                  const std::string& method, const std::string& args_json,
                                  const auth::Key* key) {
  flexid::rpc_request_t request;
  request.utime = WallClockUtime();
  request.request_id = request_id;
  request.client_id = client_id;
  request.method = method;
  request.args_json = args_json;
  request.nonce = auth::RandomNonce();
  if (key != nullptr && auth::ChangesData(method)) auth::Sign(*key, &request);
  return request;
}

std::optional<flexid::rpc_reply_t> DecodeReply(const lcm::ReceiveBuffer& rbuf) {
  flexid::rpc_reply_t reply;
  if (!wire::WellFormed(rbuf.data, rbuf.data_size, wire::kRpcReply) ||
      reply.decode(rbuf.data, 0, static_cast<int>(rbuf.data_size)) <= 0)
    return std::nullopt;
  return reply;
}

RpcClient::RpcClient(lcm::LCM& lcm, const Channels& channels, std::string client_id,
                     const auth::Key* key, Dispatch dispatch)
    : lcm_(lcm),
      request_channel_(channels.RpcRequest()),
      client_id_(std::move(client_id)),
      key_(key),
      dispatch_(dispatch) {
  subscription_ =
      lcm_.subscribeFunction(Exactly(channels.RpcReply(client_id_)), &RpcClient::OnReply, this);
  subscription_->setQueueCapacity(100);
}

RpcClient::~RpcClient() { lcm_.unsubscribe(subscription_); }

// Runs inside LCM's C callback: nothing here throws (a bad allocation aside).
void RpcClient::OnReply(const lcm::ReceiveBuffer* rbuf, const std::string&, RpcClient* self) {
  const auto received = std::chrono::steady_clock::now();
  std::optional<flexid::rpc_reply_t> reply = DecodeReply(*rbuf);
  if (!reply) return;
  {
    std::lock_guard lock(self->mutex_);
    const auto it = self->waiting_.find(reply->request_id);
    if (it == self->waiting_.end() || it->second) return;  // expired, or a duplicate
    it->second = RpcReply{std::move(*reply), received};
  }
  self->replied_.notify_all();
}

std::optional<RpcReply> RpcClient::Call(const std::string& method, const std::string& args_json,
                                        std::chrono::milliseconds timeout) {
  const flexid::rpc_request_t request =
      MakeRequest(client_id_, RandomRequestId(), method, args_json, key_);
  const auto end = std::chrono::steady_clock::now() + timeout;
  std::unique_lock lock(mutex_);
  auto& slot = waiting_[request.request_id];
  lock.unlock();
  lcm_.publish(request_channel_, &request);  // LCM's publish is thread-safe
  lock.lock();
  while (!slot && std::chrono::steady_clock::now() < end) {
    if (dispatch_ == Dispatch::kElsewhere) {
      replied_.wait_until(lock, end);
      continue;
    }
    lock.unlock();
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        end - std::chrono::steady_clock::now());
    lcm_.handleTimeout(static_cast<int>(std::clamp<int64_t>(left.count(), 0, 50)));
    lock.lock();
  }
  std::optional<RpcReply> out = std::move(slot);
  waiting_.erase(request.request_id);
  return out;
}

}  // namespace flexid::bus
