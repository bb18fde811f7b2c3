// The LCM channels of the flexid bus, built from one prefix (flexidd's channel_prefix,
// the clients' --channel-prefix; default FLEXID), so that several flexid installations can
// share a network without hearing each other:
//   PREFIX/<actuator>/VOLTAGE     voltage_sample_t      source -> flexidd
//   PREFIX/<actuator>/DEFLECTION  deflection_sample_t   source -> flexidd
//   PREFIX/<actuator>/PREDICTION  prediction_t          flexidd -> clients
//   PREFIX/<actuator>/COMMAND     voltage_command_t     flexid-control -> rig, DAQ (signed)
//   PREFIX/ALERT                  alert_t               flexidd -> clients
//   PREFIX/STATUS                 status_t              flexidd -> clients, once a second
//   PREFIX/OWNERSHIP              ownership_t           flexidd -> flexidd, clients: its
//                                                       actuators and the daemons it heard
//   PREFIX/TRIAL                  trial_control2_t      rig, CLI -> flexidd (signed)
//   PREFIX/RPC/REQUEST            rpc_request_t         clients -> flexidd
//   PREFIX/RPC/REPLY/<client>     rpc_reply_t           flexidd -> that client
//
// LCM reads a subscription as a POSIX extended regular expression matched against the
// whole channel name. A prefix may hold '.', so a subscription never uses a name as it
// is: Exactly() escapes it, and the All*() patterns escape the prefix.
#pragma once

#include <string>
#include <string_view>

namespace flexid::bus {

inline constexpr char kDefaultPrefix[] = "FLEXID";

// What IsValidPrefix accepts, in words (for error messages).
inline constexpr char kPrefixRule[] = "1 to 64 of A-Z a-z 0-9 _ . -";

// 1 to 64 characters of [A-Za-z0-9_.-]: the id rule (ids.h) with '.' too. The same rule
// holds for flexidd's configuration and every client's --channel-prefix.
bool IsValidPrefix(std::string_view prefix);
// Empty when IsValidPrefix(prefix); otherwise what is wrong with it, for a command-line
// option's check ("must be 1 to 64 of ... (got \"a/b\")").
std::string PrefixProblem(const std::string& prefix);

// A regular expression that matches `channel` and nothing else: every character that
// means something in an extended regular expression is escaped.
std::string Exactly(std::string_view channel);

class Channels {
 public:
  // Throws std::invalid_argument naming the prefix and the rule when !IsValidPrefix.
  explicit Channels(std::string prefix = kDefaultPrefix);

  const std::string& prefix() const { return prefix_; }

  // Names, to publish on (and to compare a received channel with).
  std::string Voltage(std::string_view actuator_id) const;
  std::string Deflection(std::string_view actuator_id) const;
  std::string Prediction(std::string_view actuator_id) const;
  std::string Command(std::string_view actuator_id) const;
  std::string Alert() const;
  std::string Status() const;
  std::string Ownership() const;
  std::string TrialControl() const;
  std::string RpcRequest() const;
  std::string RpcReply(std::string_view client_id) const;

  // Subscription patterns for the channel of that kind of every actuator (the actuator
  // part is not checked here: a handler compares the channel with the message's id).
  std::string AllVoltages() const;
  std::string AllDeflections() const;
  std::string AllPredictions() const;

 private:
  std::string Named(std::string_view middle, std::string_view kind) const;
  std::string prefix_;
};

}  // namespace flexid::bus
