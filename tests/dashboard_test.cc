// Tests of flexid-dashboard: the ring buffer, decimation and JSON of the live store; the
// HTTP server on 127.0.0.1 (a free port) in-process, fed from LCM memq:// with a fake
// flexidd answering RPC on the same bus; --listen validation, also through the binary.
// The page itself is tested in headless Chromium by tests/dashboard/run_e2e.sh.
#include <gtest/gtest.h>
#include <httplib.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <flexid/alert_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <string>
#include <thread>
#include <vector>

#include "cli_process.h"
#include "lcm_subscribe.h"
#include "clients/dashboard/assets.h"
#include "clients/dashboard/bus.h"
#include "clients/dashboard/listen_address.h"
#include "clients/dashboard/live_store.h"
#include "clients/dashboard/ring_buffer.h"
#include "clients/dashboard/server.h"
#include "scratch_dir.h"

namespace flexid::dashboard {
namespace {

using nlohmann::json;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

Prediction MakePrediction(const std::string& id, int64_t utime, double measured_mm,
                          int32_t model_version = 0) {
  Prediction p;
  p.actuator_id = id;
  p.point = {utime, 2.0, measured_mm, measured_mm - 0.01, 0.01};
  p.model_version = model_version;
  p.trial_id = 3;
  p.memberships = {0.25, 0.75};
  return p;
}

Alert MakeAlert(const std::string& id, int64_t utime, const std::string& kind) {
  Alert a;
  a.utime = utime;
  a.actuator_id = id;
  a.kind = kind;
  a.severity = 1;
  a.start_utime = utime - 1'000'000;
  a.end_utime = utime;
  a.magnitude_mm = 0.163;
  a.threshold_mm = 0.161;
  a.text = id + ": " + kind;
  return a;
}

// ---------------------------------------------------------------------------------------
// Ring buffer, decimation, rounding

TEST(RingBuffer, KeepsTheNewestInOrder) {
  RingBuffer<int> ring(3);
  EXPECT_TRUE(ring.empty());
  for (int i = 1; i <= 5; ++i) ring.Push(i);
  ASSERT_EQ(ring.size(), 3u);
  EXPECT_EQ(ring[0], 3);
  EXPECT_EQ(ring[1], 4);
  EXPECT_EQ(ring[2], 5);
  EXPECT_EQ(ring.Back(), 5);
  ring.Clear();
  EXPECT_TRUE(ring.empty());
  ring.Push(9);
  EXPECT_EQ(ring[0], 9);
  EXPECT_THROW(RingBuffer<int>(0), std::invalid_argument);
}

TEST(Decimation, KeepsFirstAndLastEvenlySpread) {
  EXPECT_TRUE(DecimationIndices(0, 10).empty());
  EXPECT_EQ(DecimationIndices(4, 10), (std::vector<size_t>{0, 1, 2, 3}));
  EXPECT_EQ(DecimationIndices(5, 1), (std::vector<size_t>{4}));
  const std::vector<size_t> kept = DecimationIndices(75, 25);  // 500 Hz over 150 ms
  ASSERT_EQ(kept.size(), 25u);
  EXPECT_EQ(kept.front(), 0u);
  EXPECT_EQ(kept.back(), 74u);
  for (size_t i = 1; i < kept.size(); ++i) {
    EXPECT_GT(kept[i], kept[i - 1]);
    EXPECT_LE(kept[i] - kept[i - 1], 4u);  // 74 / 24 rounded up: evenly spread
  }
}

TEST(Decimation, RoundsToSignificantDigitsForShortJson) {
  EXPECT_EQ(json(RoundSignificant(1.23456789, 6)).dump(), "1.23457");
  EXPECT_EQ(json(RoundSignificant(-0.000123456789, 6)).dump(), "-0.000123457");
  EXPECT_EQ(json(RoundSignificant(123456789.0, 6)).dump(), "123457000.0");
  EXPECT_EQ(RoundSignificant(0.0, 6), 0.0);
  EXPECT_TRUE(std::isnan(RoundSignificant(kNaN, 6)));
}

// ---------------------------------------------------------------------------------------
// The live store

TEST(LiveStore, BatchesAreDecimatedAndGoToHistory) {
  StoreOptions options;
  options.max_points_per_batch = 10;
  LiveStore store(options);
  for (int k = 0; k < 100; ++k)
    ASSERT_EQ(store.AddPrediction(MakePrediction("S1", 1'000'000 + k * 2000, 0.01 * k)),
              AddOutcome::kAccepted);
  EXPECT_EQ(store.FlushBatch(), 10u);
  EXPECT_EQ(store.FlushBatch(), 0u);  // nothing new: no event
  const EventWait wait = store.WaitEvents(0, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  EXPECT_EQ(wait.events[0].name, "points");
  const json batch = json::parse(wait.events[0].data);
  const json& s1 = batch["actuators"][0];
  EXPECT_EQ(s1["id"], "S1");
  EXPECT_EQ(s1["received"], 100);
  ASSERT_EQ(s1["t_s"].size(), 10u);
  EXPECT_DOUBLE_EQ(s1["t_s"][0].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(s1["t_s"][9].get<double>(), 1.198);  // the last point is always kept
  EXPECT_DOUBLE_EQ(s1["measured_mm"][9].get<double>(), 0.99);
  EXPECT_EQ(s1["memberships"], json({0.25, 0.75}));

  const json state = store.StateJson();
  EXPECT_EQ(state["event_id"], 1);
  ASSERT_EQ(state["actuators"].size(), 1u);
  EXPECT_EQ(state["actuators"][0]["history"]["t_s"].size(), 10u);
  EXPECT_DOUBLE_EQ(state["actuators"][0]["latest"]["measured_mm"].get<double>(), 0.99);
}

TEST(LiveStore, SixteenActuatorsAt500HzStayCheap) {
  LiveStore store;  // defaults: 25 points per actuator and batch
  // 150 ms of 16 actuators at 500 Hz: 75 predictions each.
  for (int a = 0; a < 16; ++a)
    for (int k = 0; k < 75; ++k)
      store.AddPrediction(MakePrediction("A" + std::to_string(a), 1'000'000 + k * 2000, 0.5));
  EXPECT_EQ(store.FlushBatch(), 16u * 25u);
  const EventWait wait = store.WaitEvents(0, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  EXPECT_LT(wait.events[0].data.size(), 60'000u);  // ~7 such batches a second
}

TEST(LiveStore, RejectsAndCountsBadPredictions) {
  LiveStore store;
  Prediction bad = MakePrediction("S1", 1'000'000, 1.0);
  bad.point.voltage_V = kNaN;
  EXPECT_EQ(store.AddPrediction(bad), AddOutcome::kInvalid);
  EXPECT_EQ(store.AddPrediction(MakePrediction("S 1", 1'000'000, 1.0)), AddOutcome::kInvalid);
  // No model yet: NaN prediction and residual are fine (JSON null).
  Prediction no_model = MakePrediction("S1", 2'000'000, 1.0);
  no_model.point.predicted_mm = kNaN;
  no_model.point.residual_mm = kNaN;
  EXPECT_EQ(store.AddPrediction(no_model), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddPrediction(MakePrediction("S1", 2'000'000, 1.0)), AddOutcome::kOutOfOrder);
  const Counters c = store.counters();
  EXPECT_EQ(c.bad_messages, 2);
  EXPECT_EQ(c.out_of_order, 1);
  EXPECT_EQ(c.predictions, 1);
  store.FlushBatch();
  const json batch = json::parse(store.WaitEvents(0, std::chrono::milliseconds(0)).events[0].data);
  EXPECT_TRUE(batch["actuators"][0]["predicted_mm"][0].is_null());
}

TEST(LiveStore, AStreamFarBackInTimeRestarts) {
  LiveStore store;
  store.AddPrediction(MakePrediction("S1", 100'000'000, 1.0));
  store.FlushBatch();
  EXPECT_EQ(store.AddPrediction(MakePrediction("S1", 10'000'000, 2.0)), AddOutcome::kAccepted);
  store.FlushBatch();
  const EventWait wait = store.WaitEvents(1, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  const json batch = json::parse(wait.events[0].data);
  EXPECT_TRUE(batch["actuators"][0]["reset"].get<bool>());
  EXPECT_EQ(store.StateJson()["actuators"][0]["history"]["t_s"].size(), 1u);
}

TEST(LiveStore, CapsActuators) {
  StoreOptions options;
  options.max_actuators = 2;
  LiveStore store(options);
  EXPECT_EQ(store.AddPrediction(MakePrediction("A", 1, 0)), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddPrediction(MakePrediction("B", 1, 0)), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddPrediction(MakePrediction("C", 1, 0)), AddOutcome::kTooManyActuators);
  EXPECT_EQ(store.counters().too_many_actuators, 1);
}

TEST(LiveStore, AlertsAreDeduplicatedAndNewestFirst) {
  LiveStore store;
  EXPECT_TRUE(store.AddAlert(MakeAlert("S1", 5'000'000, "residual")));
  EXPECT_TRUE(store.AddAlert(MakeAlert("S1", 9'000'000, "back_relaxation")));
  EXPECT_TRUE(store.AddAlert(MakeAlert("S1", 7'000'000, "drift")));  // e.g. from the RPC
  EXPECT_FALSE(store.AddAlert(MakeAlert("S1", 9'000'000, "back_relaxation")));
  const json state = store.StateJson();
  ASSERT_EQ(state["alerts"].size(), 3u);
  EXPECT_EQ(state["alerts"][0]["kind"], "back_relaxation");
  EXPECT_EQ(state["alerts"][1]["kind"], "drift");
  EXPECT_EQ(state["alerts"][2]["kind"], "residual");
  EXPECT_EQ(state["alerts"][0]["severity"], "warning");
  EXPECT_DOUBLE_EQ(state["alerts"][0]["magnitude_mm"].get<double>(), 0.163);
  // An alert makes its actuator's card.
  ASSERT_EQ(state["actuators"].size(), 1u);
  EXPECT_EQ(state["actuators"][0]["id"], "S1");
  EXPECT_TRUE(state["actuators"][0]["latest"].is_null());
  EXPECT_EQ(store.WaitEvents(0, std::chrono::milliseconds(0)).events.size(), 3u);
}

TEST(LiveStore, AlertFromTheRpcList) {
  const json stored = {{"id", 4},
                       {"actuator", "S1"},
                       {"kind", "drift"},
                       {"severity", 2},
                       {"utime", 1234567},
                       {"start_utime", 1000000},
                       {"end_utime", 1234567},
                       {"magnitude_mm", nullptr},
                       {"threshold_mm", 0.2},
                       {"text", "drifting"}};
  const std::optional<Alert> a = AlertFromJson(stored);
  ASSERT_TRUE(a);
  EXPECT_EQ(a->severity, 2);
  EXPECT_EQ(a->kind, "drift");
  EXPECT_TRUE(std::isnan(a->magnitude_mm));
  EXPECT_EQ(AlertJson(*a)["severity"], "critical");
  EXPECT_TRUE(AlertJson(*a)["magnitude_mm"].is_null());
  EXPECT_FALSE(AlertFromJson({{"kind", "drift"}}));
  EXPECT_FALSE(AlertFromJson(json::array()));
}

TEST(LiveStore, SummarizesAModelReply) {
  const json reply = {
      {"actuator", "S1"},
      {"version", 2},
      {"active", true},
      {"trials", {2, 1}},
      {"samples_hash", "abc"},
      {"fit",
       {{"fit_percent", 97.87555801336588},
        {"rmse_mm", 0.2589262031808752},
        {"samples", 8800},
        {"levels_V", {2.0, 8.0}},
        {"whiteness", {{"passed", false}}}}},
      {"model", {{"kind", "ts_fuzzy"}, {"local_models", {{{"level_V", 2}}, {{"level_V", 8}}}}}}};
  const std::optional<json> s = SummarizeModel(reply);
  ASSERT_TRUE(s);
  EXPECT_EQ((*s)["version"], 2);
  EXPECT_EQ((*s)["kind"], "ts_fuzzy");
  EXPECT_EQ((*s)["levels_V"], json({2, 8}));
  EXPECT_EQ((*s)["fit"]["fit_percent"].dump(), "97.88");
  EXPECT_EQ((*s)["fit"]["rmse_mm"].dump(), "0.2589");
  EXPECT_FALSE((*s)["fit"].contains("whiteness"));
  EXPECT_FALSE(s->contains("samples_hash"));
  EXPECT_FALSE(SummarizeModel({{"version", 2}}));

  LiveStore store;
  store.SetModel(*s);
  EXPECT_EQ(store.StateJson()["actuators"][0]["model"]["version"], 2);
}

TEST(LiveStore, StreamsThatFallBehindResync) {
  StoreOptions options;
  options.max_events = 4;
  LiveStore store(options);
  for (int k = 0; k < 10; ++k) store.AddAlert(MakeAlert("S1", 1'000'000 * (k + 1), "residual"));
  EventWait wait = store.WaitEvents(1, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  EXPECT_EQ(wait.events[0].name, "resync");
  wait = store.WaitEvents(7, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 3u);
  EXPECT_EQ(wait.events[0].id, 8u);
  // After the last event (a page from before a restart): from now on.
  EXPECT_TRUE(store.WaitEvents(1000, std::chrono::milliseconds(0)).events.empty());
  store.Close();
  EXPECT_TRUE(store.WaitEvents(10, std::chrono::seconds(10)).closed);
}

// ---------------------------------------------------------------------------------------
// --listen

TEST(Listen, AcceptsHostAndPort) {
  std::string why;
  auto a = ParseListenAddress("127.0.0.1:8080", &why);
  ASSERT_TRUE(a) << why;
  EXPECT_EQ(a->host, "127.0.0.1");
  EXPECT_EQ(a->port, 8080);
  a = ParseListenAddress("localhost:0", &why);
  ASSERT_TRUE(a) << why;
  EXPECT_EQ(a->port, 0);
  a = ParseListenAddress("[::1]:9000", &why);
  ASSERT_TRUE(a) << why;
  EXPECT_EQ(a->host, "::1");
  EXPECT_EQ(UrlOf(a->host, a->port), "http://[::1]:9000/");
  EXPECT_EQ(UrlOf("127.0.0.1", 8080), "http://127.0.0.1:8080/");
  EXPECT_TRUE(IsLoopback("127.0.0.1"));
  EXPECT_FALSE(IsLoopback("0.0.0.0"));
}

TEST(Listen, RejectsWithOneLine) {
  for (const char* bad :
       {"8080", "127.0.0.1", "127.0.0.1:", ":8080", "127.0.0.1:65536", "127.0.0.1:80a",
        "256.0.0.1:80", "1.2.3:80", "example.com:80", "[zz]:80", "127.0.0.1:-1"}) {
    std::string why;
    EXPECT_FALSE(ParseListenAddress(bad, &why)) << bad;
    EXPECT_NE(why.find("--listen must be HOST:PORT"), std::string::npos) << why;
    EXPECT_EQ(why.find('\n'), std::string::npos);
  }
}

TEST(Listen, TheBinaryExitsWithUsageError) {
  testing::ScratchDir scratch;
  const testing::ProcessResult r = testing::RunCommand(
      std::string(FLEXID_DASHBOARD_BINARY) + " --listen nonsense", scratch.path());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_EQ(r.err.rfind("flexid-dashboard: --listen must be HOST:PORT", 0), 0u) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1);
  EXPECT_TRUE(r.out.empty());
}

// ---------------------------------------------------------------------------------------
// The server in-process on memq://, with a fake flexidd on the same bus

class FakeDaemon {
 public:
  explicit FakeDaemon(lcm::LCM& lcm) : lcm_(lcm) {
    testing::SubscribeMember<&FakeDaemon::OnRequest>(lcm_, "FLEXID/RPC/REQUEST", this);
  }
  std::atomic<int> model_requests{0};
  std::atomic<int> alert_requests{0};

 private:
  void OnRequest(const lcm::ReceiveBuffer*, const std::string&,
                 const flexid::rpc_request_t* request) {
    flexid::rpc_reply_t reply;
    reply.utime = request->utime;
    reply.request_id = request->request_id;
    reply.daemon_id = "fake";
    reply.status = flexid::rpc_reply_t::kOk;
    const json args = json::parse(request->args_json);
    if (request->method == "model") {
      ++model_requests;
      reply.result_json =
          json{{"actuator", args["actuator"]},
               {"version", args["version"]},
               {"active", true},
               {"trials", {2, 1}},
               {"fit", {{"fit_percent", 97.9}, {"rmse_mm", 0.259}}},
               {"model",
                {{"kind", "ts_fuzzy"}, {"local_models", {{{"level_V", 2}}, {{"level_V", 8}}}}}}}
              .dump();
    } else if (request->method == "alerts") {
      ++alert_requests;
      reply.result_json = json::array({{{"actuator", "S9"},
                                        {"kind", "drift"},
                                        {"severity", 1},
                                        {"utime", 42'000'000},
                                        {"text", "an old alert"}}})
                              .dump();
    } else {
      reply.status = flexid::rpc_reply_t::kBadRequest;
      reply.error = "unknown method";
    }
    lcm_.publish("FLEXID/RPC/REPLY/" + request->client_id, &reply);
  }
  lcm::LCM& lcm_;
};

class DashboardServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(lcm_.good());
    BusOptions bus_options;
    bus_options.batch_interval = std::chrono::milliseconds(50);
    bus_ = std::make_unique<BusAdapter>(lcm_, store_, bus_options);
    ServerOptions server_options;
    server_options.port = 0;
    server_options.lcm_url = "memq://";
    server_options.keepalive = std::chrono::milliseconds(200);
    server_ = std::make_unique<DashboardServer>(store_, server_options);
    port_ = server_->Bind();
    ASSERT_GT(port_, 0);
    bus_thread_ = std::thread([this] { bus_->Run(stop_); });
    server_->Start();
  }
  void TearDown() override {
    stop_ = true;
    if (bus_thread_.joinable()) bus_thread_.join();
    server_->Stop();
  }

  httplib::Client Client() {
    httplib::Client client("127.0.0.1", port_);
    client.set_read_timeout(5, 0);
    return client;
  }

  void Publish(const std::string& id, int64_t utime, double measured_mm, int32_t version = 0) {
    flexid::prediction_t p;
    p.utime = utime;
    p.actuator_id = id;
    p.voltage_V = 2.0;
    p.measured_mm = measured_mm;
    p.predicted_mm = measured_mm - 0.01;
    p.residual_mm = 0.01;
    p.model_version = version;
    p.trial_id = 1;
    p.num_memberships = 2;
    p.memberships = {0.5, 0.5};
    lcm_.publish("FLEXID/" + id + "/PREDICTION", &p);
  }

  // Polls /api/state until `done` holds for it (at most 5 s).
  json WaitForState(const std::function<bool(const json&)>& done) {
    httplib::Client client = Client();
    json state;
    for (int i = 0; i < 100; ++i) {
      const auto res = client.Get("/api/state");
      if (res && res->status == 200) {
        state = json::parse(res->body);
        if (done(state)) return state;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    ADD_FAILURE() << "state never got there: " << state.dump();
    return state;
  }

  lcm::LCM lcm_{"memq://"};
  LiveStore store_;
  std::unique_ptr<BusAdapter> bus_;
  std::unique_ptr<DashboardServer> server_;
  std::thread bus_thread_;
  std::atomic<bool> stop_{false};
  int port_ = 0;
};

TEST_F(DashboardServerTest, ServesThePageAndUPlotWithAStrictPolicy) {
  httplib::Client client = Client();
  const auto page = client.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_EQ(page->get_header_value("Content-Type"), "text/html; charset=utf-8");
  EXPECT_NE(page->body.find("<title>flexid"), std::string::npos);
  EXPECT_NE(page->body.find("/vendor/uPlot.iife.min.js"), std::string::npos);
  const std::string policy = page->get_header_value("Content-Security-Policy");
  EXPECT_NE(policy.find("default-src 'none'"), std::string::npos);
  EXPECT_NE(policy.find("script-src 'self'"), std::string::npos);
  EXPECT_EQ(policy.find("http"), std::string::npos);  // no remote source allowed

  const auto uplot = client.Get("/vendor/uPlot.iife.min.js");
  ASSERT_TRUE(uplot);
  EXPECT_EQ(uplot->status, 200);
  EXPECT_EQ(uplot->get_header_value("Content-Type"), "text/javascript; charset=utf-8");
  EXPECT_NE(uplot->body.find("var uPlot="), std::string::npos);
  EXPECT_GT(uplot->body.size(), 30'000u);
  for (const char* path : {"/app.js", "/app.css", "/vendor/uPlot.min.css", "/vendor/LICENSE"}) {
    const auto res = client.Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_EQ(res->status, 200) << path;
  }
  EXPECT_EQ(client.Get("/nope")->status, 404);
  EXPECT_EQ(client.Post("/api/state", "", "text/plain")->status, 405);
  EXPECT_EQ(client.Get("/healthz")->status, 200);
  // Another host name (DNS rebinding) is refused.
  const auto rebound = client.Get("/api/state", {{"Host", "attacker.example:80"}});
  ASSERT_TRUE(rebound);
  EXPECT_EQ(rebound->status, 403);
}

TEST_F(DashboardServerTest, StateShowsAPredictionAndItsModel) {
  FakeDaemon daemon(lcm_);
  Publish("S1", 1'000'000'000, 3.25, 2);
  const json state = WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["model"].is_object() &&
           !s["alerts"].empty();
  });
  ASSERT_FALSE(state["actuators"].empty());
  const json& s1 = state["actuators"][0];
  EXPECT_EQ(s1["id"], "S1");
  EXPECT_DOUBLE_EQ(s1["latest"]["measured_mm"].get<double>(), 3.25);
  EXPECT_EQ(s1["model_version"], 2);
  EXPECT_EQ(s1["model"]["version"], 2);
  EXPECT_DOUBLE_EQ(s1["model"]["fit"]["fit_percent"].get<double>(), 97.9);
  EXPECT_EQ(state["lcm_url"], "memq://");
  // The start-up "alerts" request brought the daemon's recent alerts.
  EXPECT_EQ(state["alerts"][0]["kind"], "drift");
  EXPECT_EQ(state["alerts"][0]["actuator"], "S9");
  // One request per new model version, not one per prediction.
  for (int k = 1; k <= 20; ++k) Publish("S1", 1'000'000'000 + k * 100'000, 3.25, 2);
  WaitForState([](const json& s) { return s["actuators"][0]["received"] == 21; });
  EXPECT_EQ(daemon.model_requests.load(), 1);
  EXPECT_EQ(daemon.alert_requests.load(), 1);
}

TEST_F(DashboardServerTest, EventsStreamDeliversAPrediction) {
  std::string received;
  std::atomic<bool> streaming{false};
  std::thread reader([&] {
    httplib::Client client = Client();
    client.Get("/events", [&](const char* data, size_t size) {
      streaming = true;
      received.append(data, size);
      return received.find("\"S7\"") == std::string::npos;  // stop once it came
    });
  });
  for (int i = 0; i < 100 && !streaming; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  ASSERT_TRUE(streaming.load());
  Publish("S7", 2'000'000'000, 4.5);
  reader.join();
  EXPECT_NE(received.find("retry: 2000"), std::string::npos);
  EXPECT_NE(received.find("event: points"), std::string::npos) << received;
  EXPECT_NE(received.find("\"measured_mm\":[4.5]"), std::string::npos) << received;
  // The stream's slot is given back when the client goes.
  for (int i = 0; i < 100 && server_->active_streams() > 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(server_->active_streams(), 0);
}

TEST_F(DashboardServerTest, MalformedMessagesAreCountedNotFatal) {
  const std::string garbage = "not an lcm message";
  lcm_.publish("FLEXID/S1/PREDICTION", garbage.data(), static_cast<unsigned>(garbage.size()));
  lcm_.publish("FLEXID/ALERT", garbage.data(), static_cast<unsigned>(garbage.size()));
  // A prediction whose string length field claims ~2 GB.
  flexid::prediction_t p;
  p.utime = 1'000'000;
  p.actuator_id = "S1";
  p.voltage_V = 1.0;
  p.measured_mm = 1.0;
  p.predicted_mm = 1.0;
  p.residual_mm = 0.0;
  p.model_version = 0;
  p.trial_id = 0;
  p.num_memberships = 0;
  std::vector<uint8_t> bytes(static_cast<size_t>(p.getEncodedSize()));
  p.encode(bytes.data(), 0, static_cast<int>(bytes.size()));
  bytes[16] = 0x7f;  // the high byte of actuator_id's length, after fingerprint and utime
  lcm_.publish("FLEXID/S1/PREDICTION", bytes.data(), static_cast<unsigned>(bytes.size()));
  // A well-formed prediction on another actuator's channel.
  Publish("S2", 1'000'000, 1.0);  // fine
  p.actuator_id = "S3";
  lcm_.publish("FLEXID/S2/PREDICTION", &p);
  const json state = WaitForState([](const json& s) {
    return s["counters"]["bad_messages"] == 4 && s["counters"]["predictions"] == 1;
  });
  EXPECT_EQ(state["actuators"].size(), 1u);
  const auto health = Client().Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(json::parse(health->body)["bad_messages"], 4);
}

TEST(Assets, EveryAssetIsEmbedded) {
  std::vector<std::string> paths;
  for (const Asset& a : Assets()) {
    paths.emplace_back(a.path);
    EXPECT_FALSE(a.body.empty()) << a.path;
  }
  EXPECT_EQ(paths,
            (std::vector<std::string>{"/", "/app.js", "/app.css", "/vendor/uPlot.iife.min.js",
                                      "/vendor/uPlot.min.css", "/vendor/LICENSE"}));
}

}  // namespace
}  // namespace flexid::dashboard
