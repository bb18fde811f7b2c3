#include "bus/fan_out.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "bus/clock.h"
#include "bus/rpc_client.h"
#include "lcmtypes/wire_check.h"

namespace flexid::bus {

std::optional<flexid::ownership_t> DecodeOwnership(const lcm::ReceiveBuffer& rbuf) {
  flexid::ownership_t message;
  if (!wire::WellFormed(rbuf.data, rbuf.data_size, wire::kOwnership) ||
      message.decode(rbuf.data, 0, static_cast<int>(rbuf.data_size)) <= 0 ||
      !IsValidPrefix(message.daemon_id))
    return std::nullopt;
  return message;
}

FanOutCollector::FanOutCollector(std::string request_id, std::vector<std::string> daemons)
    : request_id_(std::move(request_id)), asked_(daemons.begin(), daemons.end()) {
  for (const std::string& id : asked_) Entry(id).named = true;
}

RollCallEntry& FanOutCollector::Entry(const std::string& daemon_id) {
  RollCallEntry& entry = daemons_[daemon_id];
  entry.daemon_id = daemon_id;
  return entry;
}

bool FanOutCollector::Expected(const RollCallEntry& entry) const {
  if (!asked_.empty()) return asked_.count(entry.daemon_id) > 0;
  return entry.announced || entry.named;
}

void FanOutCollector::Heard(const flexid::ownership_t& announcement, int64_t now_utime) {
  Entry(announcement.daemon_id).announced = true;
  const size_t peers = std::min(announcement.peer_ids.size(), announcement.peer_heard_utime.size());
  for (size_t i = 0; i < peers; ++i) {
    const std::string& peer = announcement.peer_ids[i];
    if (!IsValidPrefix(peer)) continue;
    RollCallEntry& entry = Entry(peer);
    entry.named = true;
    const double ago_s =
        std::max(0.0, 1e-6 * static_cast<double>(now_utime - announcement.peer_heard_utime[i]));
    if (!entry.last_heard_s || ago_s < *entry.last_heard_s) {
      entry.last_heard_s = ago_s;
      entry.last_heard_by = announcement.daemon_id;
    }
  }
}

FanOutCollector::Taken FanOutCollector::Reply(const flexid::rpc_reply_t& reply, bool late) {
  if (reply.request_id != request_id_) return Taken::kOtherRequest;
  if (!IsValidPrefix(reply.daemon_id) || (!asked_.empty() && !asked_.count(reply.daemon_id)))
    return Taken::kNotAsked;
  if (late) {
    ++late_[reply.daemon_id];
    return Taken::kLate;
  }
  RollCallEntry& entry = Entry(reply.daemon_id);
  if (entry.answered) {
    ++duplicates_[reply.daemon_id];
    return Taken::kDuplicate;
  }
  entry.answered = true;
  replies_.push_back(reply);
  return Taken::kKept;
}

bool FanOutCollector::Complete() const {
  if (replies_.empty()) return false;
  return std::all_of(daemons_.begin(), daemons_.end(), [this](const auto& item) {
    return !Expected(item.second) || item.second.answered;
  });
}

std::vector<RollCallEntry> FanOutCollector::RollCall() const {
  std::vector<RollCallEntry> out;
  for (const auto& [id, entry] : daemons_)
    if (entry.answered || Expected(entry)) out.push_back(entry);
  return out;
}

std::vector<std::string> FanOutCollector::Notes(std::chrono::milliseconds timeout) const {
  char seconds[32];
  std::snprintf(seconds, sizeof seconds, "%g s", 1e-3 * static_cast<double>(timeout.count()));
  std::vector<std::string> notes;
  for (const RollCallEntry& entry : RollCall()) {
    if (!entry.answered) {
      std::string note = entry.daemon_id + " did not answer within " + seconds;
      if (entry.last_heard_s) {
        char ago[64];
        std::snprintf(ago, sizeof ago, "%.0f s ago", *entry.last_heard_s);
        note += std::string(" (last heard ") + ago + " by " + entry.last_heard_by + ")";
      } else if (entry.announced) {
        note += " (it announced itself during the wait)";
      }
      notes.push_back(note);
    } else if (!entry.announced && !entry.named) {
      notes.push_back(entry.daemon_id +
                      " answered but was not heard of on the bus (no announcement on "
                      "OWNERSHIP): its rows are kept, marked as from a daemon not announced");
    }
  }
  for (const auto& [id, count] : duplicates_)
    notes.push_back(std::to_string(count) + " duplicate repl" + (count == 1 ? "y" : "ies") +
                    " from " + id + " ignored (one reply per daemon is counted)");
  for (const auto& [id, count] : late_)
    notes.push_back(std::to_string(count) + " repl" + (count == 1 ? "y" : "ies") + " from " + id +
                    " came after the " + seconds + " timeout and " + (count == 1 ? "was" : "were") +
                    " ignored");
  return notes;
}

namespace {

struct Listening {
  FanOutCollector* collector;
  bool late = false;
  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string&, Listening* self) {
    if (const auto reply = DecodeReply(*rbuf)) self->collector->Reply(*reply, self->late);
  }
  static void OnOwnership(const lcm::ReceiveBuffer* rbuf, const std::string&, Listening* self) {
    if (const auto announcement = DecodeOwnership(*rbuf))
      self->collector->Heard(*announcement, WallClockUtime());
  }
};

}  // namespace

FanOutResult FanOut(lcm::LCM& lcm, const Channels& channels, const std::string& client_id,
                    const std::string& method, const std::string& args_json,
                    const std::vector<std::string>& daemons, const FanOutOptions& options) {
  const flexid::rpc_request_t request =
      MakeRequest(client_id, RandomRequestId(), method, args_json, nullptr);
  FanOutCollector collector(request.request_id, daemons);
  Listening listening{&collector};
  lcm::Subscription* replies =
      lcm.subscribeFunction(Exactly(channels.RpcReply(client_id)), &Listening::OnReply, &listening);
  replies->setQueueCapacity(1000);
  lcm::Subscription* announcements =
      lcm.subscribeFunction(Exactly(channels.Ownership()), &Listening::OnOwnership, &listening);
  announcements->setQueueCapacity(1000);
  using Clock = std::chrono::steady_clock;
  const Clock::time_point start = Clock::now();
  lcm.publish(channels.RpcRequest(), &request);
  // Daemons named: who is to answer is known, nothing to wait for beyond their replies.
  const auto min_wait = daemons.empty() ? options.min_wait : std::chrono::milliseconds(0);
  bool complete = false;
  while (true) {
    const Clock::time_point now = Clock::now();
    if (now - start >= min_wait && collector.Complete()) {
      complete = true;
      break;
    }
    if (now - start >= options.timeout) break;
    const auto left =
        std::chrono::duration_cast<std::chrono::milliseconds>(start + options.timeout - now);
    lcm.handleTimeout(static_cast<int>(std::clamp<int64_t>(left.count(), 1, 20)));
  }
  if (!complete) {  // what came after the timeout, already here: counted, not kept
    listening.late = true;
    for (int i = 0; i < 1000 && lcm.handleTimeout(0) > 0; ++i) {
    }
  }
  lcm.unsubscribe(replies);
  lcm.unsubscribe(announcements);
  return {collector.replies(), collector.RollCall(), collector.Notes(options.timeout)};
}

}  // namespace flexid::bus
