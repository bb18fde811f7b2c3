// Inputs the fuzz targets (tests/fuzz/) found or were written against, replayed in the
// ordinary suite. Each crash input is kept as found under tests/fuzz/regressions/, named
// <target>-<what>; the tests check the fixed behaviour directly, so they fail without the
// fix also in a build without sanitizers.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <flexid/deflection_sample_t.hpp>
#include <fstream>
#include <iterator>
#include <limits>
#include <string>
#include <vector>

#include "daemon/config.h"
#include "daemon/rpc.h"
#include "lcmtypes/wire_check.h"

namespace flexid {
namespace {

std::string ReadRegression(const std::string& name) {
  const std::string path = std::string(FLEXID_SOURCE_DIR) + "/tests/fuzz/regressions/" + name;
  std::ifstream in(path, std::ios::binary);
  EXPECT_TRUE(in) << "cannot open " << path;
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

template <typename Message>
std::vector<uint8_t> Encode(const Message& message) {
  std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
  message.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  return bytes;
}

// The message bytes of a fuzz_lcm_message input: byte 0 selects the type, and with bit 7
// set the first 8 message bytes become that type's fingerprint (fuzz_lcm_message.cc).
template <typename Message>
std::vector<uint8_t> LcmMessageInput(const std::string& input) {
  std::vector<uint8_t> bytes(input.begin() + 1, input.end());
  if ((static_cast<uint8_t>(input[0]) & 0x80) != 0 && bytes.size() >= 8) {
    const std::vector<uint8_t> fingerprint = Encode(Message{});
    std::copy_n(fingerprint.begin(), 8, bytes.begin());
  }
  return bytes;
}

// fuzz_lcm_message: a deflection_sample_t whose actuator_id holds a NUL before its end
// passed wire::WellFormed and decoded, but lcm-gen's encoders write strlen() bytes, so
// decode -> encode changed the message. A request_id like that, echoed in an RPC reply,
// made flexidd publish a reply whose last bytes were never written.
TEST(FuzzRegression, WireCheckRejectsAStringWithANulInside) {
  const std::string input = ReadRegression("lcm_message-embedded-nul.bin");
  ASSERT_EQ(static_cast<uint8_t>(input.at(0)) & 0x07, 1) << "a deflection_sample_t input";
  const std::vector<uint8_t> bytes = LcmMessageInput<flexid::deflection_sample_t>(input);
  EXPECT_FALSE(wire::WellFormed(bytes.data(), bytes.size(), wire::kDeflectionSample));

  // The same by construction, and why it matters: the encoder drops what follows the NUL.
  flexid::deflection_sample_t message;
  message.actuator_id = std::string("S1\0xy", 5);
  std::vector<uint8_t> encoded(static_cast<size_t>(message.getEncodedSize()), 0xAA);
  const int written = message.encode(encoded.data(), 0, static_cast<int>(encoded.size()));
  EXPECT_LT(written, static_cast<int>(encoded.size()));
  std::vector<uint8_t> crafted = Encode(flexid::deflection_sample_t{});
  // fingerprint, utime, then the string: length 6 counting the NUL, "S1\0xy\0", deflection.
  crafted.resize(16);
  const uint8_t string_field[] = {0, 0, 0, 6, 'S', '1', 0, 'x', 'y', 0};
  crafted.insert(crafted.end(), std::begin(string_field), std::end(string_field));
  crafted.resize(crafted.size() + 8, 0);
  EXPECT_FALSE(wire::WellFormed(crafted.data(), crafted.size(), wire::kDeflectionSample));
  crafted[16 + 4 + 2] = 'z';  // "S1zxy": well formed again
  EXPECT_TRUE(wire::WellFormed(crafted.data(), crafted.size(), wire::kDeflectionSample));
  flexid::deflection_sample_t decoded;
  EXPECT_EQ(decoded.decode(crafted.data(), 0, static_cast<int>(crafted.size())),
            static_cast<int>(crafted.size()));
  EXPECT_EQ(decoded.actuator_id, "S1zxy");
}

// fuzz_rpc_arguments: a JSON integer above INT64_MAX parses as unsigned, and
// IntegerArgument read it with get<int64_t>(), which wrapped 18446744073709551615 to -1:
// accepted where the range is all of int64 (trial_samples' after_utime).
TEST(FuzzRegression, IntegerArgumentAboveInt64IsRejectedNotWrapped) {
  const nlohmann::json args =
      daemon::ParseArguments(ReadRegression("rpc_arguments-unsigned-above-int64.json"));
  constexpr int64_t kMin = std::numeric_limits<int64_t>::min();
  constexpr int64_t kMax = std::numeric_limits<int64_t>::max();
  EXPECT_THROW(daemon::IntegerArgument(args, "after_utime", kMin, kMin, kMax),
               daemon::ArgumentError);
  EXPECT_THROW(daemon::IntegerArgument(daemon::ParseArguments(R"({"n": 9223372036854775808})"), "n",
                                       0, kMin, kMax),
               daemon::ArgumentError);
  EXPECT_EQ(daemon::IntegerArgument(daemon::ParseArguments(R"({"n": 9223372036854775807})"), "n", 0,
                                    kMin, kMax),
            kMax);
  EXPECT_EQ(daemon::IntegerArgument(daemon::ParseArguments(R"({"n": -9223372036854775808})"), "n",
                                    0, kMin, kMax),
            kMin);
}

// Written with fuzz_config: an integer setting that does not fit its type was truncated
// (commit_interval_ms = 4294967297 read as 1 and passed validation).
TEST(FuzzRegression, ConfigIntegerOutOfRangeIsAnErrorNotTruncated) {
  try {
    daemon::Validate(daemon::ParseConfigText("commit_interval_ms = 4294967297\n", "big.toml"));
    FAIL() << "accepted";
  } catch (const daemon::ConfigError& e) {
    EXPECT_STREQ(e.what(), "big.toml.commit_interval_ms: integer out of range");
  }
  EXPECT_THROW(daemon::ParseConfigText("[identification]\npoles = -4294967292\n", "p.toml"),
               daemon::ConfigError);
  const daemon::Config fits = daemon::ParseConfigText("max_message_bytes = 1048576\n", "ok.toml");
  EXPECT_EQ(fits.max_message_bytes, 1048576);
}

// ParseConfigText names the text in errors as LoadConfigFile names the file.
TEST(FuzzRegression, ConfigTextErrorsNameTheSource) {
  try {
    daemon::ParseConfigText("daemon_id = \n", "text.toml");
    FAIL() << "accepted";
  } catch (const daemon::ConfigError& e) {
    EXPECT_EQ(std::string(e.what()).rfind("text.toml:1:", 0), 0u) << e.what();
  }
  EXPECT_THROW(daemon::ParseConfigText("no_such_setting = 1\n", "text.toml"), daemon::ConfigError);
}

}  // namespace
}  // namespace flexid
