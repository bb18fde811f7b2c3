// Fuzz target: flexidd's TOML configuration (daemon/config.h): ParseConfigText, the
// in-memory half of LoadConfigFile, then Validate and Describe as flexidd's start-up does.
//
// Invariants (abort otherwise): only ConfigError is thrown (any other exception escapes
// and libFuzzer reports it).
#include <cstdint>
#include <string_view>

#include "daemon/config.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  try {
    const flexid::daemon::Config config = flexid::daemon::ParseConfigText(text, "fuzz.toml");
    flexid::daemon::Validate(config);
    (void)flexid::daemon::Describe(config);
  } catch (const flexid::daemon::ConfigError&) {
  }
  return 0;
}
