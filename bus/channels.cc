#include "bus/channels.h"

#include <algorithm>
#include <stdexcept>

namespace flexid::bus {

bool IsValidPrefix(std::string_view prefix) {
  if (prefix.empty() || prefix.size() > 64) return false;
  return std::all_of(prefix.begin(), prefix.end(), [](char c) {
    return (c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
           c == '-' || c == '.';
  });
}

std::string PrefixProblem(const std::string& prefix) {
  if (IsValidPrefix(prefix)) return "";
  return std::string("must be ") + kPrefixRule + " (got \"" + prefix + "\")";
}

std::string Exactly(std::string_view channel) {
  std::string out;
  out.reserve(channel.size() + 8);
  for (const char c : channel) {
    if (std::string_view(".[]()*+?{}|^$\\").find(c) != std::string_view::npos) out += '\\';
    out += c;
  }
  return out;
}

Channels::Channels(std::string prefix) : prefix_(std::move(prefix)) {
  if (!IsValidPrefix(prefix_))
    throw std::invalid_argument("channel prefix " + PrefixProblem(prefix_));
}

std::string Channels::Named(std::string_view middle, std::string_view kind) const {
  std::string out = prefix_;
  out += '/';
  if (!middle.empty()) {
    out += middle;
    out += '/';
  }
  out += kind;
  return out;
}

std::string Channels::Voltage(std::string_view actuator_id) const {
  return Named(actuator_id, "VOLTAGE");
}
std::string Channels::Deflection(std::string_view actuator_id) const {
  return Named(actuator_id, "DEFLECTION");
}
std::string Channels::Prediction(std::string_view actuator_id) const {
  return Named(actuator_id, "PREDICTION");
}
std::string Channels::Command(std::string_view actuator_id) const {
  return Named(actuator_id, "COMMAND");
}
std::string Channels::Alert() const { return Named("", "ALERT"); }
std::string Channels::Status() const { return Named("", "STATUS"); }
std::string Channels::Ownership() const { return Named("", "OWNERSHIP"); }
std::string Channels::TrialControl() const { return Named("", "TRIAL"); }
std::string Channels::RpcRequest() const { return Named("RPC", "REQUEST"); }
std::string Channels::RpcReply(std::string_view client_id) const {
  return Named("RPC/REPLY", client_id);
}

std::string Channels::AllVoltages() const { return Exactly(prefix_) + "/.*/VOLTAGE"; }
std::string Channels::AllDeflections() const { return Exactly(prefix_) + "/.*/DEFLECTION"; }
std::string Channels::AllPredictions() const { return Exactly(prefix_) + "/.*/PREDICTION"; }

}  // namespace flexid::bus
