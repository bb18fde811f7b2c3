// The structural check of encoded messages agrees with lcm-gen's encoders for every
// flexid type, and refuses what would crash the generated decoders.
#include "lcmtypes/wire_check.h"

#include <gtest/gtest.h>

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
#include <random>
#include <vector>

namespace flexid::wire {
namespace {

template <typename Message>
std::vector<uint8_t> Encode(const Message& message) {
  std::vector<uint8_t> bytes(static_cast<size_t>(message.getEncodedSize()));
  EXPECT_EQ(message.encode(bytes.data(), 0, static_cast<int>(bytes.size())),
            static_cast<int>(bytes.size()));
  return bytes;
}

// Every encoding passes; every proper prefix and every one-byte extension fails.
template <typename Message>
void ExpectLayoutMatches(const Message& message, std::initializer_list<Field> layout) {
  const std::vector<uint8_t> bytes = Encode(message);
  EXPECT_TRUE(WellFormed(bytes.data(), bytes.size(), layout));
  for (size_t cut = 0; cut < bytes.size(); ++cut)
    EXPECT_FALSE(WellFormed(bytes.data(), cut, layout)) << cut;
  std::vector<uint8_t> longer = bytes;
  longer.push_back(0);
  EXPECT_FALSE(WellFormed(longer.data(), longer.size(), layout));
}

TEST(WireCheck, LayoutsMatchTheGeneratedEncoders) {
  flexid::voltage_sample_t voltage{};
  voltage.actuator_id = "S1";
  ExpectLayoutMatches(voltage, kVoltageSample);
  flexid::deflection_sample_t deflection;
  deflection.actuator_id = "actuator-with-a-longer-name";
  ExpectLayoutMatches(deflection, kDeflectionSample);
  flexid::prediction_t prediction{};
  prediction.actuator_id = "S1";
  prediction.memberships = {0.25, 0.75, 0.0};
  prediction.num_memberships = 3;
  ExpectLayoutMatches(prediction, kPrediction);
  prediction.memberships.clear();
  prediction.num_memberships = 0;
  ExpectLayoutMatches(prediction, kPrediction);
  flexid::alert_t alert;
  alert.actuator_id = "S1";
  alert.kind = "back_relaxation";
  alert.text = "a sentence";
  ExpectLayoutMatches(alert, kAlert);
  flexid::trial_control_t control;
  control.actuator_id = "S1";
  control.protocol = "square:level=5";
  ExpectLayoutMatches(control, kTrialControl);
  flexid::trial_control2_t signed_control;
  signed_control.actuator_id = "S1";
  signed_control.protocol = "square:level=5";
  signed_control.nonce = "0123456789abcdef";
  signed_control.auth = std::string(64, 'a');
  ExpectLayoutMatches(signed_control, kTrialControl2);
  flexid::voltage_command_t command;
  command.actuator_id = "S1";
  command.controller_id = "control-1";
  command.reference_mm = 10.0;
  command.nonce = "0123456789abcdef";
  command.auth = std::string(64, 'b');
  ExpectLayoutMatches(command, kVoltageCommand);
  flexid::rpc_request_t request;
  request.request_id = "r1";
  request.method = "status";
  request.args_json = "{}";
  ExpectLayoutMatches(request, kRpcRequest);
  flexid::rpc_reply_t reply;
  reply.result_json = "[]";
  ExpectLayoutMatches(reply, kRpcReply);
  flexid::status_t status;
  status.daemon_id = "flexidd";
  status.version = "0.1.0";
  ExpectLayoutMatches(status, kStatus);
  flexid::ownership_t ownership{};
  ownership.daemon_id = "lab-a";
  ownership.instance_id = "0123456789abcdef";
  ExpectLayoutMatches(ownership, kOwnership);  // no claims, no peers
  ownership.actuator_ids = {"S1", "S22"};
  ownership.claims = {flexid::ownership_t::kConfigured, flexid::ownership_t::kPending};
  ownership.first_seen_utime = {0, 1700000000000000};
  ownership.num_claims = 2;
  ownership.peer_ids = {"lab-b"};
  ownership.peer_heard_utime = {1700000000000000};
  ownership.num_peers = 1;
  ExpectLayoutMatches(ownership, kOwnership);
}

TEST(WireCheck, OwnershipArraysAreCheckedStringByString) {
  flexid::ownership_t ownership{};
  ownership.daemon_id = "lab-a";
  ownership.instance_id = "i";
  ownership.actuator_ids = {"S1"};
  ownership.claims = {flexid::ownership_t::kAdopted};
  ownership.first_seen_utime = {1};
  ownership.num_claims = 1;
  ownership.num_peers = 0;
  std::vector<uint8_t> bytes = Encode(ownership);
  // The claim's id: after fingerprint 8, utime 8, "lab-a" 4+6, "i" 4+2, count 2.
  const size_t id_at = 8 + 8 + 10 + 6 + 2;
  ASSERT_EQ(bytes[id_at + 3], 3);  // "S1\0"
  std::vector<uint8_t> bad = bytes;
  bad[id_at + 3] = 0x7F;  // a length beyond the message
  EXPECT_FALSE(WellFormed(bad.data(), bad.size(), kOwnership));
  bad = bytes;
  bad[id_at + 4 + 1] = 0;  // "S\0\0": a NUL inside the string
  EXPECT_FALSE(WellFormed(bad.data(), bad.size(), kOwnership));
  // One claim more than the arrays hold.
  bad = bytes;
  bad[id_at - 1] = 2;
  EXPECT_FALSE(WellFormed(bad.data(), bad.size(), kOwnership));
}

TEST(WireCheck, RefusesStringLengthsTheGeneratedDecoderWouldTrust) {
  flexid::voltage_sample_t voltage;
  voltage.actuator_id = "S1";
  const std::vector<uint8_t> good = Encode(voltage);
  // The actuator id's length field follows the fingerprint (8) and utime (8).
  for (uint32_t length : {0u, 0x80000000u, 0xFFFFFFFFu, 4u, 1000u}) {
    std::vector<uint8_t> bad = good;
    for (int i = 0; i < 4; ++i)
      bad[16 + static_cast<size_t>(i)] = static_cast<uint8_t>(length >> (24 - 8 * i));
    EXPECT_FALSE(WellFormed(bad.data(), bad.size(), kVoltageSample)) << length;
  }
  std::vector<uint8_t> no_nul = good;
  no_nul[16 + 4 + 2] = 'x';  // "S1\0" -> "S1x"
  EXPECT_FALSE(WellFormed(no_nul.data(), no_nul.size(), kVoltageSample));
}

TEST(WireCheck, NegativeArrayCountIsRefused) {
  flexid::prediction_t prediction{};  // lcm-gen leaves numbers uninitialised otherwise
  prediction.actuator_id = "S1";
  prediction.num_memberships = 0;
  std::vector<uint8_t> bytes = Encode(prediction);
  // num_memberships is the last 2 bytes of an empty-array prediction.
  bytes[bytes.size() - 2] = 0xFF;
  bytes[bytes.size() - 1] = 0xFF;
  EXPECT_FALSE(WellFormed(bytes.data(), bytes.size(), kPrediction));
}

TEST(WireCheck, RandomBytesNeverPassUnlessDecodable) {
  // Whatever passes the check must decode cleanly with the generated decoder.
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> byte(0, 255), length(0, 64);
  flexid::voltage_sample_t reference{};
  const std::vector<uint8_t> encoded = Encode(reference);
  const std::vector<uint8_t> fingerprint(encoded.begin(), encoded.begin() + 8);
  for (int trial = 0; trial < 20000; ++trial) {
    std::vector<uint8_t> bytes(fingerprint);
    const int extra = length(rng);
    for (int i = 0; i < extra; ++i) bytes.push_back(static_cast<uint8_t>(byte(rng)));
    if (!WellFormed(bytes.data(), bytes.size(), kVoltageSample)) continue;
    flexid::voltage_sample_t decoded;
    EXPECT_EQ(decoded.decode(bytes.data(), 0, static_cast<int>(bytes.size())),
              static_cast<int>(bytes.size()));
  }
}

}  // namespace
}  // namespace flexid::wire
