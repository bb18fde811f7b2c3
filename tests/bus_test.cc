// bus/: the rules every program on the bus shares.
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/trial_control2_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include "bus/channels.h"
#include "bus/clock.h"
#include "bus/ids.h"
#include "bus/lcm_url.h"
#include "bus/rpc_client.h"
#include "bus/sample_publisher.h"
#include "lcmtypes/message_auth.h"

namespace flexid::bus {
namespace {

TEST(BusIds, OneRuleForActuatorAndClientIds) {
  for (const char* ok : {"S1", "a", "gel_3-b", "Z9"}) EXPECT_TRUE(IsValidId(ok)) << ok;
  EXPECT_TRUE(IsValidId(std::string(64, 'x')));
  EXPECT_FALSE(IsValidId(std::string(65, 'x')));
  EXPECT_FALSE(IsValidId(""));
  // '.' is a regular expression in a channel subscription; '/' separates channel parts.
  for (const char* bad : {"S.1", "S/1", "S 1", "S*", "é", "S1\n"})
    EXPECT_FALSE(IsValidId(bad)) << bad;
  EXPECT_FALSE(
      IsValidId(std::string("S\0"
                            "1",
                            3)));
}

TEST(BusLcmUrl, ReceiveBufferOnlyWhereUdpmAndNotGiven) {
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667", 4096),
            "udpm://239.255.76.67:7667?recv_buf_size=4096");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667?ttl=0", 8388608),
            "udpm://239.255.76.67:7667?ttl=0&recv_buf_size=8388608");
  EXPECT_EQ(WithReceiveBuffer("udpm://239.255.76.67:7667?recv_buf_size=1024", 4096),
            "udpm://239.255.76.67:7667?recv_buf_size=1024");
  EXPECT_EQ(WithReceiveBuffer("memq://", 4096), "memq://");
}

TEST(BusClock, WallClockIsMicrosecondsSinceTheEpoch) {
  const int64_t system_us = std::chrono::duration_cast<std::chrono::microseconds>(
                                std::chrono::system_clock::now().time_since_epoch())
                                .count();
  const int64_t utime = WallClockUtime();
  EXPECT_GE(utime, system_us);
  EXPECT_LT(utime - system_us, 5'000'000);
}

TEST(BusChannels, NamesFollowThePrefix) {
  const Channels standard;  // the default
  EXPECT_EQ(standard.prefix(), "FLEXID");
  EXPECT_EQ(standard.Voltage("S1"), "FLEXID/S1/VOLTAGE");
  EXPECT_EQ(standard.Deflection("S1"), "FLEXID/S1/DEFLECTION");
  EXPECT_EQ(standard.Prediction("S1"), "FLEXID/S1/PREDICTION");
  EXPECT_EQ(standard.Alert(), "FLEXID/ALERT");
  EXPECT_EQ(standard.Status(), "FLEXID/STATUS");
  EXPECT_EQ(standard.TrialControl(), "FLEXID/TRIAL");
  EXPECT_EQ(standard.RpcRequest(), "FLEXID/RPC/REQUEST");
  EXPECT_EQ(standard.RpcReply("cli-12"), "FLEXID/RPC/REPLY/cli-12");

  const Channels lab("lab.2-b_c");
  EXPECT_EQ(lab.Voltage("S1"), "lab.2-b_c/S1/VOLTAGE");
  EXPECT_EQ(lab.RpcReply("dashboard-1"), "lab.2-b_c/RPC/REPLY/dashboard-1");
  // A subscription is a regular expression: the prefix's '.' is escaped there.
  EXPECT_EQ(lab.AllVoltages(), "lab\\.2-b_c/.*/VOLTAGE");
  EXPECT_EQ(lab.AllDeflections(), "lab\\.2-b_c/.*/DEFLECTION");
  EXPECT_EQ(lab.AllPredictions(), "lab\\.2-b_c/.*/PREDICTION");
  EXPECT_EQ(Exactly(lab.Alert()), "lab\\.2-b_c/ALERT");
  EXPECT_EQ(Exactly("a.b*c+d?e(f)[g]{h}|i^j$k\\l"),
            "a\\.b\\*c\\+d\\?e\\(f\\)\\[g\\]\\{h\\}\\|i\\^j\\$k\\\\l");
}

TEST(BusChannels, PrefixRuleIsTheIdRuleWithDots) {
  for (const char* ok : {"FLEXID", "lab.2", "a-b_c", "L", "..", "9"})
    EXPECT_TRUE(IsValidPrefix(ok)) << ok;
  EXPECT_TRUE(IsValidPrefix(std::string(64, 'x')));
  EXPECT_FALSE(IsValidPrefix(std::string(65, 'x')));
  EXPECT_FALSE(IsValidPrefix(""));
  for (const char* bad : {"A/B", "A B", "A*", "A|B", "é", "A\n"})
    EXPECT_FALSE(IsValidPrefix(bad)) << bad;
  EXPECT_EQ(PrefixProblem("lab.2"), "");
  EXPECT_EQ(PrefixProblem("A/B"), std::string("must be ") + kPrefixRule + " (got \"A/B\")");
  try {
    Channels bad("A/B");
    FAIL() << "a prefix with '/' was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("\"A/B\""), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(kPrefixRule), std::string::npos) << e.what();
  }
}

// Handles `lcm` until `done` or 2 s have passed.
template <typename Done>
void HandleUntil(lcm::LCM& lcm, Done done) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(2);
  while (!done() && std::chrono::steady_clock::now() < end) lcm.handleTimeout(10);
}

// What a subscription received: channel names, in order.
struct Heard {
  std::vector<std::string> channels;
  void On(const lcm::ReceiveBuffer*, const std::string& channel) { channels.push_back(channel); }
};

TEST(BusChannels, SubscriptionPatternsHearOnlyTheirPrefix) {
  lcm::LCM lcm("memq://");
  ASSERT_TRUE(lcm.good());
  const Channels lab("lab.2");
  Heard predictions, alerts;
  lcm.subscribe(lab.AllPredictions(), &Heard::On, &predictions);
  lcm.subscribe(Exactly(lab.Alert()), &Heard::On, &alerts);
  const char byte = 0;
  // Unescaped, "lab.2" would match "labx2" too: another installation's channels.
  for (const std::string& channel : {std::string("labx2/S1/PREDICTION"), lab.Prediction("S1"),
                                     std::string("labx2/ALERT"), lab.Alert()})
    lcm.publish(channel, &byte, 1);
  HandleUntil(lcm, [&] { return predictions.channels.size() + alerts.channels.size() >= 2; });
  lcm.handleTimeout(50);  // anything else that would (wrongly) come
  EXPECT_EQ(predictions.channels, std::vector<std::string>{"lab.2/S1/PREDICTION"});
  EXPECT_EQ(alerts.channels, std::vector<std::string>{"lab.2/ALERT"});
}

auth::Key TestKey() {
  auth::Key key;
  for (size_t i = 0; i < key.bytes.size(); ++i) key.bytes[i] = static_cast<uint8_t>(7 * i + 1);
  return key;
}

// Decodes every message of type T on the channels it is subscribed to.
template <typename T>
struct Catch {
  std::vector<T> messages;
  void On(const lcm::ReceiveBuffer*, const std::string&, const T* message) {
    messages.push_back(*message);
  }
};

TEST(BusSamplePublisher, PublishesOneActuatorsSamplesAndSignedTrialControl) {
  lcm::LCM lcm("memq://");
  ASSERT_TRUE(lcm.good());
  const Channels channels("lab.2");
  const auth::Key key = TestKey();
  Catch<flexid::voltage_sample_t> voltages;
  Catch<flexid::deflection_sample_t> deflections;
  Catch<flexid::trial_control2_t> controls;
  lcm.subscribe(Exactly(channels.Voltage("S1")), &Catch<flexid::voltage_sample_t>::On, &voltages);
  lcm.subscribe(Exactly(channels.Deflection("S1")), &Catch<flexid::deflection_sample_t>::On,
                &deflections);
  lcm.subscribe(Exactly(channels.TrialControl()), &Catch<flexid::trial_control2_t>::On, &controls);

  SamplePublisher publisher(lcm, channels, "S1", &key);
  const int64_t before_utime = WallClockUtime();
  EXPECT_TRUE(publisher.PublishTrialControl(1000, TrialAction::kStart, "step:level=2"));
  EXPECT_TRUE(publisher.PublishVoltage(1001, 2.0));
  EXPECT_TRUE(publisher.PublishDeflection(1001, 0.25));
  EXPECT_TRUE(publisher.PublishVoltage(1002, 0.0));
  EXPECT_TRUE(publisher.PublishTrialControl(1003, TrialAction::kStop, "step:level=2"));
  HandleUntil(lcm, [&] { return controls.messages.size() == 2 && voltages.messages.size() == 2; });

  ASSERT_EQ(voltages.messages.size(), 2u);
  EXPECT_EQ(voltages.messages[0].utime, 1001);
  EXPECT_EQ(voltages.messages[0].actuator_id, "S1");
  EXPECT_EQ(voltages.messages[0].voltage_V, 2.0);
  EXPECT_EQ(voltages.messages[1].utime, 1002);
  EXPECT_EQ(voltages.messages[1].voltage_V, 0.0);
  ASSERT_EQ(deflections.messages.size(), 1u);
  EXPECT_EQ(deflections.messages[0].utime, 1001);
  EXPECT_EQ(deflections.messages[0].actuator_id, "S1");
  EXPECT_EQ(deflections.messages[0].deflection_mm, 0.25);
  ASSERT_EQ(controls.messages.size(), 2u);
  auth::Verifier verifier(key, {});
  for (const flexid::trial_control2_t& c : controls.messages) {
    EXPECT_EQ(c.actuator_id, "S1");
    EXPECT_EQ(c.protocol, "step:level=2");
    // Message time stays the caller's; the signature's time is the wall clock.
    EXPECT_GE(c.sent_utime, before_utime);
    EXPECT_EQ(verifier.Check(c, WallClockUtime()), "") << "flexidd would refuse it";
  }
  EXPECT_EQ(controls.messages[0].utime, 1000);
  EXPECT_EQ(controls.messages[0].action, flexid::trial_control2_t::kStart);
  EXPECT_EQ(controls.messages[1].utime, 1003);
  EXPECT_EQ(controls.messages[1].action, flexid::trial_control2_t::kStop);
}

TEST(BusSamplePublisher, WithoutAKeyNoTrialControlIsSent) {
  lcm::LCM lcm("memq://");
  ASSERT_TRUE(lcm.good());
  const Channels channels;
  Heard trial;
  lcm.subscribe(Exactly(channels.TrialControl()), &Heard::On, &trial);
  SamplePublisher publisher(lcm, channels, "S1");
  EXPECT_FALSE(publisher.PublishTrialControl(1000, TrialAction::kStart, ""));
  lcm.handleTimeout(50);
  EXPECT_TRUE(trial.channels.empty());
}

// flexidd's side of RPC, reduced to what a client sees: it answers every request on the
// channels it was given, first with a reply to another request id (which a client must
// ignore), then with the reply, whose result names the method and whether it was signed.
class FakeDaemon {
 public:
  FakeDaemon(lcm::LCM& lcm, const Channels& channels, const auth::Key& key)
      : lcm_(lcm), channels_(channels), verifier_(key, {}) {
    lcm_.subscribe(Exactly(channels_.RpcRequest()), &FakeDaemon::On, this);
  }
  std::vector<flexid::rpc_request_t> requests;
  std::atomic<bool> answer{true};

 private:
  void On(const lcm::ReceiveBuffer*, const std::string&, const flexid::rpc_request_t* request) {
    requests.push_back(*request);
    if (!answer) return;
    flexid::rpc_reply_t reply;
    reply.request_id = "not-" + request->request_id;
    reply.daemon_id = "fake";
    reply.status = flexid::rpc_reply_t::kOk;
    reply.result_json = "\"wrong reply\"";
    lcm_.publish(channels_.RpcReply(request->client_id), &reply);
    const bool signed_ok = verifier_.Check(*request, WallClockUtime()).empty();
    reply.request_id = request->request_id;
    reply.result_json = "{\"method\": \"" + request->method +
                        "\", \"signed\": " + (signed_ok ? "true" : "false") + "}";
    lcm_.publish(channels_.RpcReply(request->client_id), &reply);
  }
  lcm::LCM& lcm_;
  Channels channels_;
  auth::Verifier verifier_;
};

// A client and the fake daemon on one memq:// bus.
class BusRpcClient : public ::testing::Test {
 protected:
  lcm::LCM lcm_{"memq://"};
  const Channels channels_{"lab.2"};
  const auth::Key key_ = TestKey();
  FakeDaemon daemon_{lcm_, channels_, key_};
};

TEST_F(BusRpcClient, MatchesTheReplyAndSignsWhatChangesData) {
  RpcClient client(lcm_, channels_, "cli-7", &key_);
  const std::optional<RpcReply> status =
      client.Call("status", "{}", std::chrono::milliseconds(2000));
  ASSERT_TRUE(status);
  EXPECT_EQ(status->message.result_json, "{\"method\": \"status\", \"signed\": false}");
  const std::optional<RpcReply> identify =
      client.Call("identify", "{\"actuator\": \"S1\"}", std::chrono::milliseconds(2000));
  ASSERT_TRUE(identify);
  EXPECT_EQ(identify->message.result_json, "{\"method\": \"identify\", \"signed\": true}");

  ASSERT_EQ(daemon_.requests.size(), 2u);
  EXPECT_EQ(daemon_.requests[0].client_id, "cli-7");
  EXPECT_EQ(daemon_.requests[0].args_json, "{}");
  EXPECT_TRUE(daemon_.requests[0].auth.empty());  // read-only: not signed
  EXPECT_TRUE(auth::IsValidNonce(daemon_.requests[0].nonce));
  EXPECT_NE(daemon_.requests[0].request_id, daemon_.requests[1].request_id);
  EXPECT_EQ(daemon_.requests[1].args_json, "{\"actuator\": \"S1\"}");
}

TEST_F(BusRpcClient, NoReplyWithinTheTimeoutIsNone) {
  daemon_.answer = false;
  RpcClient client(lcm_, channels_, "cli-8");
  const auto start = std::chrono::steady_clock::now();
  EXPECT_FALSE(client.Call("status", "{}", std::chrono::milliseconds(200)));
  const auto waited = std::chrono::steady_clock::now() - start;
  EXPECT_GE(waited, std::chrono::milliseconds(200));
  EXPECT_LT(waited, std::chrono::seconds(2));
  EXPECT_EQ(daemon_.requests.size(), 1u);
}

TEST_F(BusRpcClient, WaitsForAReplyHandledOnAnotherThread) {
  RpcClient client(lcm_, channels_, "load", &key_, RpcClient::Dispatch::kElsewhere);
  std::atomic<bool> stop{false};
  std::thread handler([&] {
    while (!stop) lcm_.handleTimeout(10);
  });
  const auto sent = std::chrono::steady_clock::now();
  const std::optional<RpcReply> reply =
      client.Call("identify", "{}", std::chrono::milliseconds(2000));
  stop = true;
  handler.join();
  ASSERT_TRUE(reply);
  EXPECT_EQ(reply->message.result_json, "{\"method\": \"identify\", \"signed\": true}");
  EXPECT_GE(reply->received, sent);
}

}  // namespace
}  // namespace flexid::bus
