// Fuzz target: a bus message of any flexid type, the way flexidd, flexid and
// flexid-dashboard take it off the bus: wire::WellFormed (lcmtypes/wire_check.h), then
// lcm-gen's decode(); for an RPC request also the daemon's own checks of what it decoded
// (daemon/rpc.h: ParseArguments; bus/ids.h: IsValidId). The daemon's other checks (finite
// values, time order, channel agreement) live inside daemon/daemon.cc and are covered by
// tests/daemon_faults_test.cc.
//
// Input: byte 0 picks the type (its low 7 bits modulo 11, in the order of the switch below);
// with bit 7 set the first 8 message bytes are overwritten by that type's fingerprint, so
// that mutations reach the fields instead of stopping at the fingerprint. The other bytes
// are the message.
//
// Invariants (abort otherwise):
//   - WellFormed accepts the message and the fingerprint is the type's => decode() reads
//     exactly the message (the daemon rejects anything else) and never out of bounds;
//   - re-encoding the decoded message gives the same bytes;
//   - a wrong fingerprint is never decoded.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/ownership_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/status_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_command_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <vector>

#include "bus/channels.h"
#include "bus/ids.h"
#include "daemon/rpc.h"
#include "lcmtypes/command_check.h"
#include "lcmtypes/wire_check.h"

namespace {

namespace wire = flexid::wire;

[[noreturn]] void Fail(const char* type, const char* what) {
  std::fprintf(stderr, "fuzz_lcm_message: %s: %s\n", type, what);
  std::abort();
}

// The 8 fingerprint bytes of Message: its hash, big-endian, as encode() writes it.
template <typename Message>
std::vector<uint8_t> Fingerprint() {
  const auto hash = static_cast<uint64_t>(Message::getHash());
  std::vector<uint8_t> bytes(8);
  for (size_t i = 0; i < 8; ++i) bytes[i] = static_cast<uint8_t>(hash >> (56 - 8 * i));
  return bytes;
}

// What the daemon does with a decoded request before it acts on it.
void AfterDecode(const flexid::rpc_request_t& request) {
  (void)flexid::bus::IsValidId(request.client_id);
  try {
    (void)flexid::daemon::ParseArguments(request.args_json);
  } catch (const flexid::daemon::ArgumentError&) {
  }
}
// What every reader of an announcement checks first (bus/fan_out.h, DecodeOwnership).
void AfterDecode(const flexid::ownership_t& announcement) {
  (void)flexid::bus::IsValidPrefix(announcement.daemon_id);
}
// What the rig and the dashboard do with a decoded command before they use it.
void AfterDecode(const flexid::voltage_command_t& command) {
  (void)wire::VoltageCommandProblem(command);
}
template <typename Message>
void AfterDecode(const Message&) {}

template <typename Message>
void Check(const char* type, std::initializer_list<wire::Field> layout, const uint8_t* data,
           size_t size, bool patch_fingerprint) {
  static const std::vector<uint8_t> fingerprint = Fingerprint<Message>();
  // An exact-size heap copy: AddressSanitizer catches any read past the message.
  std::vector<uint8_t> bytes(data, data + size);
  if (patch_fingerprint && bytes.size() >= 8)
    std::copy(fingerprint.begin(), fingerprint.end(), bytes.begin());
  if (!wire::WellFormed(bytes.data(), bytes.size(), layout)) return;
  const int length = static_cast<int>(bytes.size());
  Message message;
  const int decoded = message.decode(bytes.data(), 0, length);
  if (!std::equal(fingerprint.begin(), fingerprint.end(), bytes.begin())) {
    if (decoded >= 0) Fail(type, "decoded a message with another type's fingerprint");
    return;
  }
  if (decoded != length) Fail(type, "WellFormed accepted a message that decode() rejects");
  AfterDecode(message);
  std::vector<uint8_t> again(static_cast<size_t>(message.getEncodedSize()));
  if (again.size() != bytes.size() ||
      message.encode(again.data(), 0, static_cast<int>(again.size())) != length || again != bytes)
    Fail(type, "re-encoding the decoded message gives other bytes");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const bool patch = (data[0] & 0x80) != 0;
  const uint8_t* message = data + 1;
  const size_t n = size - 1;
  switch ((data[0] & 0x7F) % 11) {  // which message type; bit 7: patch in its fingerprint
    case 0:
      Check<flexid::voltage_sample_t>("voltage_sample_t", wire::kVoltageSample, message, n, patch);
      break;
    case 1:
      Check<flexid::deflection_sample_t>("deflection_sample_t", wire::kDeflectionSample, message, n,
                                         patch);
      break;
    case 2:
      Check<flexid::prediction_t>("prediction_t", wire::kPrediction, message, n, patch);
      break;
    case 3:
      Check<flexid::alert_t>("alert_t", wire::kAlert, message, n, patch);
      break;
    case 4:
      Check<flexid::trial_control_t>("trial_control_t", wire::kTrialControl, message, n, patch);
      break;
    case 5:
      Check<flexid::rpc_request_t>("rpc_request_t", wire::kRpcRequest, message, n, patch);
      break;
    case 6:
      Check<flexid::rpc_reply_t>("rpc_reply_t", wire::kRpcReply, message, n, patch);
      break;
    case 7:
      Check<flexid::status_t>("status_t", wire::kStatus, message, n, patch);
      break;
    case 8:
      Check<flexid::trial_control2_t>("trial_control2_t", wire::kTrialControl2, message, n, patch);
      break;
    case 9:
      Check<flexid::voltage_command_t>("voltage_command_t", wire::kVoltageCommand, message, n,
                                       patch);
      break;
    case 10:
      Check<flexid::ownership_t>("ownership_t", wire::kOwnership, message, n, patch);
      break;
  }
  return 0;
}
