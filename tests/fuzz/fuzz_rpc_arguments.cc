// Fuzz target: the arguments of an RPC request (rpc_request_t.args_json) as flexidd reads
// them (daemon/rpc.h): ParseArguments, then every typed accessor the methods use, with the
// daemon's own ranges. The same bytes are also tried as a client id (bus::IsValidId),
// which names the reply channel.
//
// Invariants (abort otherwise): only ArgumentError is thrown; a parsed document is an
// object; StringArgument returns the member's string, at most 4096 bytes; IntegerArgument
// returns a value in [min, max] that equals the JSON number exactly (no wrap-around of
// unsigned values above INT64_MAX); bus::IsValidId agrees with [A-Za-z0-9_-]{1,64}.
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <string>

#include "bus/ids.h"
#include "daemon/rpc.h"

namespace {

using flexid::daemon::ArgumentError;
using nlohmann::json;

[[noreturn]] void Fail(const char* what, const char* name) {
  std::fprintf(stderr, "fuzz_rpc_arguments: %s [argument: %s]\n", what, name);
  std::abort();
}

bool IsClientIdByHand(const std::string& id) {
  if (id.empty() || id.size() > 64) return false;
  for (char c : id)
    if (!((c >= 'A' && c <= 'Z') || (c >= 'a' && c <= 'z') || (c >= '0' && c <= '9') || c == '_' ||
          c == '-'))
      return false;
  return true;
}

void CheckString(const json& args, const char* name) {
  static const std::string fallback = "fallback";
  for (const std::string* with : {static_cast<const std::string*>(nullptr), &fallback}) {
    try {
      const std::string value = flexid::daemon::StringArgument(args, name, with);
      const auto it = args.find(name);
      if (it == args.end()) {
        if (!with || value != *with) Fail("a missing argument did not give the fallback", name);
      } else if (!it->is_string() || it->get<std::string>() != value || value.size() > 4096) {
        Fail("StringArgument returned something else than the member", name);
      }
    } catch (const ArgumentError&) {
    }
  }
}

void CheckInteger(const json& args, const char* name, int64_t fallback, int64_t min, int64_t max) {
  try {
    const int64_t value = flexid::daemon::IntegerArgument(args, name, fallback, min, max);
    const auto it = args.find(name);
    if (it == args.end()) {
      if (value != fallback) Fail("a missing argument did not give the fallback", name);
      return;
    }
    if (value < min || value > max) Fail("IntegerArgument returned a value out of range", name);
    const bool same = it->is_number_unsigned()
                          ? value >= 0 && it->get<uint64_t>() == static_cast<uint64_t>(value)
                          : it->is_number_integer() && it->get<int64_t>() == value;
    if (!same) Fail("IntegerArgument returned another value than the JSON number", name);
  } catch (const ArgumentError&) {
  }
  try {
    const int64_t value = flexid::daemon::RequiredIntegerArgument(args, name, min, max);
    if (value < min || value > max) Fail("RequiredIntegerArgument out of range", name);
  } catch (const ArgumentError&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  if (flexid::bus::IsValidId(text) != IsClientIdByHand(text))
    Fail("bus::IsValidId disagrees with [A-Za-z0-9_-]{1,64}", "client_id");
  json args;
  try {
    args = flexid::daemon::ParseArguments(text);
  } catch (const ArgumentError&) {
    return 0;
  }
  if (!args.is_object()) Fail("ParseArguments returned a non-object", "");
  constexpr int64_t kMin = std::numeric_limits<int64_t>::min();
  constexpr int64_t kMax = std::numeric_limits<int64_t>::max();
  constexpr int64_t kInt32Max = std::numeric_limits<int32_t>::max();
  // The methods' arguments and ranges (daemon/daemon.cc, HandleRequest).
  CheckString(args, "actuator");
  CheckString(args, "protocol");
  CheckString(args, "state");
  CheckInteger(args, "limit", 100, 1, 10000);
  CheckInteger(args, "limit", 5000, 1, 20000);
  CheckInteger(args, "trial", 1, 1, kMax);
  CheckInteger(args, "offset", 0, 0, kMax);
  CheckInteger(args, "after_utime", kMin, kMin, kMax);
  CheckInteger(args, "since_utime", 0, 0, kMax);
  CheckInteger(args, "version", 0, 0, kInt32Max);
  CheckInteger(args, "latest", 2, 1, 100);
  return 0;
}
