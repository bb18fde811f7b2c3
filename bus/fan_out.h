// Asking every flexidd on the bus at once (docs/architecture.md, "Several daemons"): one
// request on PREFIX/RPC/REQUEST, which every daemon answers, and the replies collected
// until every daemon heard of has answered or the timeout has passed.
//
// Who is expected to answer: the daemons the caller names, when it names some (the
// command line's --daemon); otherwise every daemon heard of during the call, from the
// announcements on PREFIX/OWNERSHIP (ownership_t: flexidd announces itself when it gets a
// request sent to every daemon, and once a second) and the peers each announcement names
// (the daemons it heard in the last 10 minutes). A daemon killed before the call is thus
// still named, by the others, as one that did not answer.
//
// How replies are taken (FanOutCollector, pure, so the rules are tested without a bus):
//  - one per daemon: a second reply of the same daemon to the same request is a duplicate,
//    ignored and counted;
//  - a reply of a daemon neither announced nor named is kept but marked (announced and
//    named false): a flexidd from before ownership, or a program that is no flexidd;
//  - with daemons named by the caller, replies of other daemons are ignored;
//  - replies after the timeout are ignored and counted (those that arrive while the call
//    drains the bus once more at the end).
#pragma once

#include <chrono>
#include <flexid/ownership_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include "bus/channels.h"

namespace flexid::bus {

// The announcement in a received buffer, if it is one (well formed before decoding).
std::optional<flexid::ownership_t> DecodeOwnership(const lcm::ReceiveBuffer& rbuf);

// One daemon in the answer to a fan-out.
struct RollCallEntry {
  std::string daemon_id;
  bool answered = false;
  bool announced = false;  // its own announcement was heard during the call
  bool named = false;      // given by the caller, or named as a peer by another daemon
  // Seconds since a daemon that names it as a peer last heard it (the smallest), if any.
  std::optional<double> last_heard_s;
  std::string last_heard_by;
};

class FanOutCollector {
 public:
  // `request_id`: of the request sent. `daemons`: those the caller names (empty: every
  // daemon heard of).
  FanOutCollector(std::string request_id, std::vector<std::string> daemons);

  // An announcement, heard at this host's wall clock `now_utime`.
  void Heard(const flexid::ownership_t& announcement, int64_t now_utime);

  enum class Taken { kKept, kDuplicate, kOtherRequest, kNotAsked, kLate };
  // A reply; `late`: it came after the timeout.
  Taken Reply(const flexid::rpc_reply_t& reply, bool late);

  // Every expected daemon has answered (and one at least).
  bool Complete() const;

  // The kept replies, in arrival order.
  const std::vector<flexid::rpc_reply_t>& replies() const { return replies_; }
  // Every daemon answered or expected, by daemon_id.
  std::vector<RollCallEntry> RollCall() const;
  // One line each: daemons that did not answer (and when they were last heard), replies
  // kept from daemons not heard of, duplicates and late replies ignored.
  std::vector<std::string> Notes(std::chrono::milliseconds timeout) const;

 private:
  RollCallEntry& Entry(const std::string& daemon_id);
  bool Expected(const RollCallEntry& entry) const;

  std::string request_id_;
  std::set<std::string> asked_;  // named by the caller
  std::map<std::string, RollCallEntry> daemons_;
  std::vector<flexid::rpc_reply_t> replies_;
  std::map<std::string, int> duplicates_;  // by daemon
  std::map<std::string, int> late_;        // by daemon
};

struct FanOutOptions {
  std::chrono::milliseconds timeout{3000};
  // Never done before this, so that the announcements of every daemon (and the peers they
  // name) arrive before the call ends on the replies it has (not when daemons are named).
  std::chrono::milliseconds min_wait{100};
};

struct FanOutResult {
  std::vector<flexid::rpc_reply_t> replies;
  std::vector<RollCallEntry> roll_call;
  std::vector<std::string> notes;
};

// Sends the read-only `method` with `args_json` (a JSON object; the caller adds
// "daemon_id" to address one daemon) from `client_id` and collects as above. The caller's
// thread handles LCM meanwhile. A request that changes data goes to one daemon, its
// owner's, with RpcClient (rpc_client.h).
FanOutResult FanOut(lcm::LCM& lcm, const Channels& channels, const std::string& client_id,
                    const std::string& method, const std::string& args_json,
                    const std::vector<std::string>& daemons, const FanOutOptions& options);

}  // namespace flexid::bus
