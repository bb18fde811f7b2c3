// Tests of flexid-dashboard: the ring buffer, decimation and JSON of the live store (points
// from samples before any prediction, the hand-over to predictions), the model version
// list parsed from a "models" reply; the HTTP server on 127.0.0.1 (a free port)
// in-process, fed from LCM memq:// with a fake flexidd answering RPC on the same bus;
// --listen validation, also through the binary.
// The page itself is tested in headless Chromium by tests/dashboard/run_e2e.sh.
#include <gtest/gtest.h>
#include <httplib.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <flexid/alert_t.hpp>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/voltage_command_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <functional>
#include <lcm/lcm-cpp.hpp>
#include <limits>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "cli_process.h"
#include "clients/dashboard/assets.h"
#include "clients/dashboard/bus.h"
#include "clients/dashboard/listen_address.h"
#include "clients/dashboard/live_store.h"
#include "clients/dashboard/model_versions.h"
#include "clients/dashboard/ring_buffer.h"
#include "clients/dashboard/server.h"
#include "lcm_subscribe.h"
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

// The points event of the last batch flushed, parsed.
json LastPoints(const LiveStore& store) {
  const EventWait wait = store.WaitEvents(0, std::chrono::milliseconds(0), 1000);
  for (auto it = wait.events.rbegin(); it != wait.events.rend(); ++it)
    if (it->name == "points") return json::parse(it->data);
  return json();
}

TEST(LiveStore, SamplesDrawAnActuatorWithoutPredictions) {
  LiveStore store;
  const Clock::time_point t0 = Clock::now();
  // A deflection sample before any voltage: voltage unknown (null), still a point.
  EXPECT_EQ(store.AddDeflection({"S2", 1'000'000, 0.5}, t0), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddVoltage({"S2", 1'100'000, 2.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 1'100'000, 0.6}, t0), AddOutcome::kAccepted);
  // A step at 1.3 s arrives before the sample stamped 1.2 s: 2 V was still in force then.
  EXPECT_EQ(store.AddVoltage({"S2", 1'300'000, 8.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 1'200'000, 0.7}, t0), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 1'300'000, 0.8}, t0), AddOutcome::kAccepted);
  EXPECT_EQ(store.FlushBatch(t0), 4u);
  const json s2 = LastPoints(store)["actuators"][0];
  EXPECT_EQ(s2["id"], "S2");
  EXPECT_EQ(s2["samples"], 4);
  EXPECT_EQ(s2["received"], 0);
  EXPECT_EQ(s2["measured_mm"], json({0.5, 0.6, 0.7, 0.8}));
  EXPECT_EQ(s2["voltage_V"], json({nullptr, 2.0, 2.0, 8.0}));
  EXPECT_EQ(s2["predicted_mm"], json({nullptr, nullptr, nullptr, nullptr}));
  EXPECT_EQ(s2["residual_mm"], json({nullptr, nullptr, nullptr, nullptr}));
  EXPECT_EQ(store.counters().samples, 6);
  EXPECT_EQ(store.StateJson()["actuators"][0]["history"]["t_s"].size(), 4u);

  // A voltage alone makes the actuator's card (discovery from the sample channels).
  EXPECT_EQ(store.AddVoltage({"S3", 5, 1.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.ActuatorIds(), (std::vector<std::string>{"S2", "S3"}));
}

TEST(LiveStore, SamplesAreValidatedAndOrdered) {
  LiveStore store;
  const Clock::time_point t0 = Clock::now();
  EXPECT_EQ(store.AddDeflection({"S2", 1'000'000, kNaN}, t0), AddOutcome::kInvalid);
  EXPECT_EQ(store.AddDeflection({"S 2", 1'000'000, 1.0}, t0), AddOutcome::kInvalid);
  EXPECT_EQ(store.AddVoltage({"S2", 1'000'000, std::numeric_limits<double>::infinity()}),
            AddOutcome::kInvalid);
  EXPECT_EQ(store.AddDeflection({"S2", 2'000'000, 1.0}, t0), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 2'000'000, 1.0}, t0), AddOutcome::kOutOfOrder);
  EXPECT_EQ(store.AddVoltage({"S2", 2'000'000, 1.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddVoltage({"S2", 1'999'999, 1.0}), AddOutcome::kOutOfOrder);
  const Counters c = store.counters();
  EXPECT_EQ(c.bad_messages, 3);
  EXPECT_EQ(c.out_of_order, 2);
  // Far back in time: a new run, the page is told to clear.
  store.FlushBatch(t0);
  EXPECT_EQ(store.AddVoltage({"S2", 100'000'000'000, 1.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 100'000'000'000, 1.0}, t0), AddOutcome::kAccepted);
  store.FlushBatch(t0);
  EXPECT_EQ(store.AddVoltage({"S2", 10'000, 3.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddDeflection({"S2", 10'000, 2.0}, t0), AddOutcome::kAccepted);
  store.FlushBatch(t0);
  const json batch = LastPoints(store)["actuators"][0];
  EXPECT_TRUE(batch["reset"].get<bool>());
  EXPECT_EQ(batch["voltage_V"], json({3.0}));
  EXPECT_EQ(store.StateJson()["actuators"][0]["history"]["t_s"].size(), 1u);
}

// Prediction of sample k (utime 1 s + k ms) of S1, measured 0.001 k, predicted 0.001 k - 0.01.
Prediction PredictionOf(int k, int32_t version = 2) {
  return MakePrediction("S1", 1'000'000 + k * 1000, 0.001 * k, version);
}
DeflectionSample SampleOf(int k) { return {"S1", 1'000'000 + k * 1000, 0.001 * k}; }

// Every point's time appears once, in order: nothing drawn twice.
void ExpectEachTimeOnce(const json& t_s) {
  for (size_t i = 1; i < t_s.size(); ++i)
    EXPECT_GT(t_s[i].get<double>(), t_s[i - 1].get<double>()) << t_s.dump();
}

TEST(LiveStore, PredictionsTakeOverFromSamplesWithoutDrawingOneTwice) {
  StoreOptions options;
  options.max_points_per_batch = 1000;  // no decimation: every point counts
  LiveStore store(options);
  const Clock::time_point t0 = Clock::now();
  // Samples 0-9 without predictions (no model yet): ten points.
  for (int k = 0; k < 10; ++k)
    EXPECT_EQ(store.AddDeflection(SampleOf(k), t0), AddOutcome::kAccepted);
  // A model becomes active: samples 10-12 arrive, then the predictions of 9-12 (flexidd
  // runs a little behind the source). 9's sample is drawn already: covered.
  for (int k = 10; k < 13; ++k)
    EXPECT_EQ(store.AddDeflection(SampleOf(k), t0), AddOutcome::kAccepted);
  EXPECT_EQ(store.AddPrediction(PredictionOf(9), t0), AddOutcome::kCovered);
  EXPECT_EQ(store.AddPrediction(PredictionOf(12), t0), AddOutcome::kCovered);
  // From now on samples wait for their predictions, which draw the points.
  for (int k = 13; k < 20; ++k) {
    EXPECT_EQ(store.AddDeflection(SampleOf(k), t0), AddOutcome::kHeld);
    EXPECT_EQ(store.AddPrediction(PredictionOf(k), t0), AddOutcome::kAccepted);
  }
  EXPECT_EQ(store.FlushBatch(t0), 20u);
  json s1 = LastPoints(store)["actuators"][0];
  ExpectEachTimeOnce(s1["t_s"]);
  ASSERT_EQ(s1["predicted_mm"].size(), 20u);
  EXPECT_TRUE(s1["predicted_mm"][12].is_null());  // drawn from its sample
  EXPECT_DOUBLE_EQ(s1["predicted_mm"][13].get<double>(), 0.013 - 0.01);
  EXPECT_EQ(s1["received"], 9);
  EXPECT_EQ(s1["samples"], 20);

  // The predictions stop (the model's flexidd went away): the held samples are not lost,
  // once prediction_timeout has passed they are the points.
  for (int k = 20; k < 25; ++k) EXPECT_EQ(store.AddDeflection(SampleOf(k), t0), AddOutcome::kHeld);
  EXPECT_EQ(store.FlushBatch(t0 + std::chrono::milliseconds(500)), 0u);  // still waiting
  const Clock::time_point later = t0 + options.prediction_timeout;
  EXPECT_EQ(store.FlushBatch(later), 5u);
  EXPECT_EQ(store.AddDeflection(SampleOf(25), later), AddOutcome::kAccepted);
  EXPECT_EQ(store.FlushBatch(later), 1u);
  const json history = store.StateJson()["actuators"][0]["history"];
  ASSERT_EQ(history["t_s"].size(), 26u);
  ExpectEachTimeOnce(history["t_s"]);
  EXPECT_DOUBLE_EQ(history["measured_mm"][24].get<double>(), 0.024);
  EXPECT_TRUE(history["predicted_mm"][24].is_null());
}

// A controller's reference, from its commands: a series of its own, batched, decimated,
// kept for new pages; a stop ends the line (null), and decimation never drops that.
TEST(LiveStore, CommandsBringTheReferenceAsASeriesOfItsOwn) {
  StoreOptions options;
  options.max_points_per_batch = 5;
  LiveStore store(options);
  for (int k = 0; k < 20; ++k)
    ASSERT_EQ(store.AddReference({"S1", 1'000'000 + k * 100'000, k < 10 ? 10.0 : 15.0}),
              AddOutcome::kAccepted);
  // Out of order, not finite, a bad id: refused and counted.
  EXPECT_EQ(store.AddReference({"S1", 1'500'000, 12.0}), AddOutcome::kOutOfOrder);
  EXPECT_EQ(store.AddReference({"S1", 3'000'000, std::numeric_limits<double>::infinity()}),
            AddOutcome::kInvalid);
  EXPECT_EQ(store.AddReference({"S 1", 3'000'000, 1.0}), AddOutcome::kInvalid);
  // The stop, then two more samples: the stop is kept though decimation keeps 5 of 23.
  ASSERT_EQ(store.AddReference({"S1", 3'050'000, kNaN}), AddOutcome::kAccepted);
  ASSERT_EQ(store.AddReference({"S1", 9'000'000, 20.0}), AddOutcome::kAccepted);
  ASSERT_EQ(store.AddReference({"S1", 9'100'000, 20.0}), AddOutcome::kAccepted);
  EXPECT_EQ(store.FlushBatch(), 0u);  // no points: only the reference
  const EventWait wait = store.WaitEvents(0, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  const json s1 = json::parse(wait.events[0].data)["actuators"][0];
  EXPECT_EQ(s1["id"], "S1");
  EXPECT_TRUE(s1["t_s"].empty());
  const json& reference = s1["reference"];
  ASSERT_EQ(reference["t_s"].size(), 6u);  // 5 evenly spread and the stop
  EXPECT_DOUBLE_EQ(reference["t_s"][0].get<double>(), 1.0);
  EXPECT_DOUBLE_EQ(reference["reference_mm"][0].get<double>(), 10.0);
  bool stop_kept = false;
  for (size_t i = 0; i < reference["t_s"].size(); ++i)
    if (reference["reference_mm"][i].is_null()) {
      stop_kept = true;
      EXPECT_DOUBLE_EQ(reference["t_s"][i].get<double>(), 3.05);
    }
  EXPECT_TRUE(stop_kept) << reference.dump();
  EXPECT_DOUBLE_EQ(reference["t_s"][5].get<double>(), 9.1);  // the last is always kept
  EXPECT_DOUBLE_EQ(reference["reference_mm"][5].get<double>(), 20.0);
  // New pages get it from the state.
  const json state = store.StateJson();
  EXPECT_EQ(state["actuators"][0]["reference"], reference);
  EXPECT_EQ(state["actuators"][0]["references"], 23);
  EXPECT_EQ(state["counters"]["references"], 23);
  EXPECT_EQ(state["counters"]["bad_messages"], 2);
  EXPECT_EQ(state["counters"]["out_of_order"], 1);
}

TEST(LiveStore, HeldSamplesAreBounded) {
  StoreOptions options;
  options.max_points_per_batch = 10;
  options.max_pending_points = 100;
  LiveStore store(options);
  const Clock::time_point t0 = Clock::now();
  store.AddPrediction(PredictionOf(0), t0);
  for (int k = 1; k <= 1000; ++k) store.AddDeflection(SampleOf(k), t0);
  EXPECT_EQ(store.FlushBatch(t0 + std::chrono::seconds(2)), 10u);
  const json s1 = LastPoints(store)["actuators"][0];
  ExpectEachTimeOnce(s1["t_s"]);
  EXPECT_DOUBLE_EQ(s1["t_s"][0].get<double>(), 1.0);  // the prediction's point, then samples
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
// Model versions from the "models" reply

// Rows as storage's ModelSummaryJson writes them, oldest first (as a reply need not be).
json ModelsReply(const std::string& actuator_id = "S1") {
  const json identified = {{"actuator", actuator_id},
                           {"version", 3},
                           {"created_utime", 1'700'000'000'000'000},
                           {"active", true},
                           {"trials", {1, 2}},
                           {"samples_hash", "abc"},
                           {"flexid_version", "0.9.0"},
                           {"fit", {{"fit_percent", 97.87555801336588}, {"rmse_mm", 0.0859}}},
                           {"lineage", nullptr}};
  json proposal = identified;
  proposal["version"] = 4;
  proposal["active"] = false;
  proposal["trials"] = {12};
  proposal["lineage"] = {{"parent_version", 3},
                         {"proposed_by", "diagnose"},
                         {"trials", {12}},
                         {"effects",
                          {{{"effect", "back_relaxation"},
                            {"params",
                             {{"fraction", {{"value", 0.21}, {"half_width_95", 0.03}}},
                              {"tau_s", {{"value", 31.0}, {"half_width_95", 4.0}}}}}}}},
                         {"heldout_rmse_before_mm", 0.085},
                         {"heldout_rmse_after_mm", 0.021},
                         {"heldout_gain", 4.0476190476}};
  json old = identified;  // from a flexidd before lineages: no field at all
  old.erase("lineage");
  old["version"] = 1;
  old["active"] = false;
  return json::array({old, identified, proposal});
}

TEST(ModelVersions, ParsesIdentifiedAndProposedNewestFirst) {
  std::string why;
  const std::optional<json> versions = ModelVersionsFromJson(ModelsReply(), "S1", &why);
  ASSERT_TRUE(versions) << why;
  ASSERT_EQ(versions->size(), 3u);
  const json& proposal = (*versions)[0];
  EXPECT_EQ(proposal["version"], 4);
  EXPECT_EQ(proposal["active"], false);
  const json& lineage = proposal["lineage"];
  EXPECT_EQ(lineage["parent_version"], 3);
  EXPECT_EQ(lineage["proposed_by"], "diagnose");
  EXPECT_EQ(lineage["trials"], json({12}));
  ASSERT_EQ(lineage["effects"].size(), 1u);
  EXPECT_EQ(lineage["effects"][0]["effect"], "back_relaxation");
  EXPECT_DOUBLE_EQ(lineage["effects"][0]["params"]["tau_s"]["value"].get<double>(), 31.0);
  EXPECT_DOUBLE_EQ(lineage["effects"][0]["params"]["fraction"]["half_width_95"].get<double>(),
                   0.03);
  EXPECT_DOUBLE_EQ(lineage["heldout_rmse_before_mm"].get<double>(), 0.085);
  EXPECT_DOUBLE_EQ(lineage["heldout_rmse_after_mm"].get<double>(), 0.021);
  EXPECT_EQ(lineage["heldout_gain"].dump(), "4.048");  // 4 significant digits
  const json& identified = (*versions)[1];
  EXPECT_EQ(identified["version"], 3);
  EXPECT_EQ(identified["active"], true);
  EXPECT_TRUE(identified["lineage"].is_null());
  EXPECT_EQ(identified["fit"]["fit_percent"].dump(), "97.88");
  EXPECT_EQ(identified["trials"], json({1, 2}));
  EXPECT_FALSE(identified.contains("samples_hash"));
  // Today's flexidd sends no lineage: identified.
  EXPECT_EQ((*versions)[2]["version"], 1);
  EXPECT_TRUE((*versions)[2]["lineage"].is_null());
  // An actuator without models: an empty list.
  EXPECT_EQ(ModelVersionsFromJson(json::array(), "S1", &why), json::array());
}

TEST(ModelVersions, FillsInTheGainAndTakesAProposalWithoutParent) {
  json reply = ModelsReply();
  reply[2]["lineage"].erase("heldout_gain");
  reply[2]["lineage"]["effects"][0]["params"]["fraction"] = 0.2;  // a bare value
  reply[2]["lineage"]["parent_version"] = 0;                      // no model was active: a baseline
  std::string why;
  const std::optional<json> versions = ModelVersionsFromJson(reply, "S1", &why);
  ASSERT_TRUE(versions) << why;
  EXPECT_EQ((*versions)[0]["lineage"]["heldout_gain"].dump(), "4.048");
  EXPECT_EQ((*versions)[0]["lineage"]["parent_version"], 0);
  const json& fraction = (*versions)[0]["lineage"]["effects"][0]["params"]["fraction"];
  EXPECT_DOUBLE_EQ(fraction["value"].get<double>(), 0.2);
  EXPECT_TRUE(fraction["half_width_95"].is_null());
}

TEST(ModelVersions, RejectsABadReplyNamingRowAndField) {
  struct Case {
    std::function<void(json&)> spoil;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {[](json& r) { r = json::object(); }, "expected an array of model versions"},
      {[](json& r) { r[0] = 7; }, "row 1: expected an object"},
      {[](json& r) { r[1]["actuator"] = "S2"; }, "row 2: actuator: expected \"S1\" (got \"S2\")"},
      {[](json& r) { r[1].erase("version"); }, "row 2: version: expected an integer"},
      {[](json& r) { r[1]["version"] = 0; }, "row 2: version: expected an integer from 1 to"},
      {[](json& r) { r[1]["version"] = "3"; }, "row 2: version: expected an integer"},
      {[](json& r) { r[0]["version"] = 3; }, "row 2: version 3 appears twice"},
      {[](json& r) { r[1]["active"] = 1; }, "row 2 (version 3): active: expected true or false"},
      {[](json& r) { r[2]["active"] = true; }, "versions 3 and 4 are both active"},
      {[](json& r) { r[2]["lineage"] = "diagnose"; },
       "row 3 (version 4): lineage: expected null or an object"},
      {[](json& r) { r[2]["lineage"].erase("parent_version"); },
       "row 3 (version 4): lineage.parent_version: expected an integer"},
      {[](json& r) { r[2]["lineage"]["parent_version"] = 4; },
       "row 3 (version 4): lineage.parent_version: expected an integer from 0 to 3 (got 4)"},
      {[](json& r) { r[2]["lineage"]["parent_version"] = -1; },
       "row 3 (version 4): lineage.parent_version: expected an integer from 0 to 3 (got -1)"},
      {[](json& r) { r[2]["lineage"]["effects"][0].erase("effect"); },
       "row 3 (version 4): lineage.effects[0].effect: expected a name of 1 to 64 characters"},
      {[](json& r) { r[2]["lineage"]["effects"] = "back_relaxation"; },
       "row 3 (version 4): lineage.effects: expected an array of at most 16 effects"},
      {[](json& r) { r[2]["lineage"]["effects"][0]["params"]["tau_s"]["value"] = "31"; },
       "row 3 (version 4): lineage.effects[0].params.tau_s.value: expected a finite number"},
      {[](json& r) { r[2]["lineage"]["heldout_rmse_after_mm"] = -0.1; },
       "row 3 (version 4): lineage.heldout_rmse_after_mm: expected a finite number >= 0"},
      {[](json& r) { r[2]["lineage"]["trials"] = {0}; },
       "row 3 (version 4): lineage.trials: expected trial ids >= 1"},
      {[](json& r) { r[1]["fit"] = 97.9; }, "row 2 (version 3): fit: expected null or an object"},
  };
  for (const Case& c : cases) {
    json reply = ModelsReply();
    c.spoil(reply);
    std::string why;
    EXPECT_FALSE(ModelVersionsFromJson(reply, "S1", &why)) << c.expected;
    EXPECT_EQ(why.rfind(c.expected, 0), 0u) << "got: " << why;
    EXPECT_EQ(why.find('\n'), std::string::npos) << why;
  }
}

TEST(ModelVersions, TheStoreKeepsTheNewestAndSendsAnEvent) {
  StoreOptions options;
  options.max_model_versions = 2;
  LiveStore store(options);
  std::string why;
  store.SetModelVersions("S1", *ModelVersionsFromJson(ModelsReply(), "S1", &why));
  const json state = store.StateJson();
  ASSERT_EQ(state["actuators"].size(), 1u);
  const json& s1 = state["actuators"][0];
  ASSERT_EQ(s1["versions"].size(), 2u);
  EXPECT_EQ(s1["versions"][0]["version"], 4);
  EXPECT_EQ(s1["versions_total"], 3);
  const EventWait wait = store.WaitEvents(0, std::chrono::milliseconds(0));
  ASSERT_EQ(wait.events.size(), 1u);
  EXPECT_EQ(wait.events[0].name, "versions");
  EXPECT_EQ(json::parse(wait.events[0].data)["actuator"], "S1");
  // Before flexidd answered: null, which the page shows as "asking".
  LiveStore fresh;
  fresh.AddVoltage({"S1", 1, 1.0});
  EXPECT_TRUE(fresh.StateJson()["actuators"][0]["versions"].is_null());
}

TEST(ModelVersions, AProblemFromTheBusIsKeptAsOneShortLine) {
  LiveStore store;
  store.NoteBadReply("models of S1: flexidd answered: " + std::string(400, 'x') + "\nmore");
  EXPECT_EQ(store.counters().bad_replies, 1);
  const std::string kept = store.last_problem();
  EXPECT_EQ(kept.size(), 303u);
  EXPECT_EQ(kept.find('\n'), std::string::npos);
  EXPECT_EQ(kept.substr(300), "...");
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
  static constexpr char kRefused[] = "S8";  // an actuator this flexidd does not know

  explicit FakeDaemon(lcm::LCM& lcm) : lcm_(lcm) {
    testing::SubscribeMember<&FakeDaemon::OnRequest>(lcm_, "FLEXID/RPC/REQUEST", this);
  }
  std::atomic<int> model_requests{0};
  std::atomic<int> alert_requests{0};
  // The "models" result for an actuator from now on (default: no versions).
  void SetModels(const std::string& actuator_id, json result) {
    std::lock_guard lock(mutex_);
    models_[actuator_id] = std::move(result);
  }
  int ModelsRequests(const std::string& actuator_id) {
    std::lock_guard lock(mutex_);
    return models_requests_[actuator_id];
  }

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
    } else if (request->method == "models") {
      std::lock_guard lock(mutex_);
      const std::string id = args["actuator"];
      ++models_requests_[id];
      reply.result_json = models_.contains(id) ? models_[id].dump() : "[]";
      if (id == kRefused) {  // as flexidd with accept_unknown_actuators = false
        reply.status = flexid::rpc_reply_t::kBadRequest;
        reply.error = "unknown actuator \"" + id + "\"";
      }
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
  std::mutex mutex_;
  std::map<std::string, json> models_;
  std::map<std::string, int> models_requests_;
};

class DashboardServerTest : public ::testing::Test {
 protected:
  void SetUp() override {
    ASSERT_TRUE(lcm_.good());
    BusOptions bus_options;
    bus_options.batch_interval = std::chrono::milliseconds(50);
    bus_options.models_refresh_min = std::chrono::milliseconds(100);
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

  // A voltage and a deflection sample of `id`, on the channels of `channel_id` (default id).
  void PublishSamples(const std::string& id, int64_t utime, double voltage_V, double deflection_mm,
                      std::string channel_id = "") {
    if (channel_id.empty()) channel_id = id;
    flexid::voltage_sample_t v;
    v.utime = utime;
    v.actuator_id = id;
    v.voltage_V = voltage_V;
    lcm_.publish("FLEXID/" + channel_id + "/VOLTAGE", &v);
    flexid::deflection_sample_t d;
    d.utime = utime;
    d.actuator_id = id;
    d.deflection_mm = deflection_mm;
    lcm_.publish("FLEXID/" + channel_id + "/DEFLECTION", &d);
  }

  // A controller's command for `id` answering its sample at reference_utime (as
  // flexid-control sends it; the dashboard does not check the signature).
  void PublishCommand(const std::string& id, int64_t reference_utime, double reference_mm,
                      int8_t mode = flexid::voltage_command_t::kTrack) {
    flexid::voltage_command_t c;
    c.utime = reference_utime + 100'000;
    c.actuator_id = id;
    c.voltage_V = mode == flexid::voltage_command_t::kTrack ? 3.5 : 0.0;
    c.sequence = ++sequence_;
    c.controller_id = "control-1";
    c.mode = mode;
    c.reference_mm = mode == flexid::voltage_command_t::kTrack ? reference_mm : 0.0;
    c.reference_utime = mode == flexid::voltage_command_t::kTrack ? reference_utime : 0;
    c.sent_utime = 1'800'000'000'000'000;
    c.nonce = "0123456789abcdef";
    c.auth = std::string(64, 'a');
    lcm_.publish("FLEXID/" + id + "/COMMAND", &c);
  }

  void PublishAlert(const std::string& id, int64_t utime, const std::string& kind) {
    flexid::alert_t a;
    a.utime = utime;
    a.actuator_id = id;
    a.kind = kind;
    a.severity = flexid::alert_t::kInfo;
    a.start_utime = a.end_utime = utime;
    a.magnitude_mm = 0.0;
    a.threshold_mm = 0.0;
    a.text = id + ": " + kind;
    lcm_.publish("FLEXID/ALERT", &a);
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
  int64_t sequence_ = 0;
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

TEST_F(DashboardServerTest, SamplesChartAnActuatorWithoutAModel) {
  FakeDaemon daemon(lcm_);  // S2 has no model: no prediction, no version
  for (int k = 0; k < 5; ++k) PublishSamples("S2", 1'000'000'000 + k * 100'000, 2.0, 0.1 * k);
  const json state = WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["history"]["t_s"].size() == 5 &&
           s["actuators"][0]["versions"].is_array();
  });
  ASSERT_FALSE(state["actuators"].empty());
  const json& s2 = state["actuators"][0];
  EXPECT_EQ(s2["id"], "S2");
  EXPECT_EQ(s2["samples"], 5);
  EXPECT_EQ(s2["received"], 0);
  EXPECT_EQ(s2["model_version"], 0);
  EXPECT_EQ(s2["history"]["measured_mm"], json({0.0, 0.1, 0.2, 0.3, 0.4}));
  EXPECT_EQ(s2["history"]["voltage_V"], json({2.0, 2.0, 2.0, 2.0, 2.0}));
  EXPECT_TRUE(s2["history"]["predicted_mm"][4].is_null());
  EXPECT_EQ(s2["versions"], json::array());
  EXPECT_EQ(state["counters"]["samples"], 10);
  EXPECT_EQ(state["counters"]["bad_replies"], 0);
}

// An actuator under control: the reference from its commands beside its samples, in
// /api/state; a command with an impossible value is counted and named, not drawn.
TEST_F(DashboardServerTest, TheStateCarriesTheReferenceOfAnActuatorUnderControl) {
  FakeDaemon daemon(lcm_);
  for (int k = 0; k < 5; ++k) {
    PublishSamples("S1", 1'000'000'000 + k * 100'000, 3.5, 9.0 + 0.1 * k);
    PublishCommand("S1", 1'000'000'000 + k * 100'000, k < 3 ? 10.0 : 12.5);
  }
  PublishCommand("S1", 1'000'400'000, 0.0, flexid::voltage_command_t::kStop);
  json state = WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["reference"]["t_s"].size() == 6 &&
           s["actuators"][0]["history"]["t_s"].size() == 5;
  });
  const json& s1 = state["actuators"][0];
  EXPECT_EQ(s1["reference"]["reference_mm"], json({10.0, 10.0, 10.0, 12.5, 12.5, nullptr}));
  EXPECT_EQ(s1["reference"]["t_s"],
            json({1000.0, 1000.1, 1000.2, 1000.3, 1000.4, 1000.5}));  // the stop: its utime
  EXPECT_EQ(s1["history"]["t_s"], json({1000.0, 1000.1, 1000.2, 1000.3, 1000.4}));
  EXPECT_EQ(state["counters"]["references"], 6);
  EXPECT_EQ(state["counters"]["bad_messages"], 0);

  // A reference that is not finite, one for a time after its command's, one on another
  // actuator's channel: each counted, the last named; none drawn.
  PublishCommand("S1", 1'000'500'000, kNaN);
  flexid::voltage_command_t ahead;
  ahead.utime = 1'000'600'000;
  ahead.actuator_id = "S1";
  ahead.voltage_V = 1.0;
  ahead.sequence = 99;
  ahead.controller_id = "control-1";
  ahead.mode = flexid::voltage_command_t::kTrack;
  ahead.reference_mm = 10.0;
  ahead.reference_utime = 1'000'700'000;
  ahead.sent_utime = 0;
  lcm_.publish("FLEXID/S1/COMMAND", &ahead);
  state = WaitForState([](const json& s) { return s["counters"]["bad_messages"] == 2; });
  EXPECT_EQ(state["last_problem"],
            "a command on FLEXID/S1/COMMAND: reference_utime 1000700000 is after the command's "
            "utime 1000600000");
  PublishCommand("S1", 1'000'600'000, 10.0);
  lcm_.publish("FLEXID/S2/COMMAND", &ahead);
  state = WaitForState([](const json& s) { return s["counters"]["bad_messages"] == 3; });
  EXPECT_EQ(state["last_problem"], "a command on FLEXID/S2/COMMAND is for actuator \"S1\"");
  EXPECT_EQ(state["counters"]["references"], 7);
  for (const json& actuator : state["actuators"]) EXPECT_NE(actuator["id"], "S2");
}

TEST_F(DashboardServerTest, AnActuatorFlexiddRefusesSaysWhyItHasNoVersions) {
  FakeDaemon daemon(lcm_);
  PublishSamples(FakeDaemon::kRefused, 1'000'000'000, 2.0, 0.1);
  const json state = WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["versions_problem"].is_string() &&
           !s["actuators"][0]["history"]["t_s"].empty();  // flexidd may answer before a batch
  });
  const json& s8 = state["actuators"][0];
  EXPECT_EQ(s8["history"]["measured_mm"], json({0.1}));  // charted all the same
  EXPECT_TRUE(s8["versions"].is_null());
  EXPECT_EQ(s8["versions_problem"], "flexidd answered: unknown actuator \"S8\"");
  EXPECT_EQ(state["last_problem"], "models of S8: flexidd answered: unknown actuator \"S8\"");
}

TEST_F(DashboardServerTest, VersionsAreAskedAgainWhenAModelAlertComes) {
  FakeDaemon daemon(lcm_);
  PublishSamples("S1", 1'000'000'000, 2.0, 0.1);
  WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["versions"].is_array();
  });
  // A diagnosis stores a proposal: flexidd says so with a "model_proposed" alert.
  json models = ModelsReply();
  daemon.SetModels("S1", models);
  PublishAlert("S1", 1'000'000'001, "model_proposed");
  json state = WaitForState([](const json& s) {
    const json& v = s["actuators"][0]["versions"];
    return v.is_array() && v.size() == 3;
  });
  json proposal = state["actuators"][0]["versions"][0];
  EXPECT_EQ(proposal["version"], 4);
  EXPECT_EQ(proposal["active"], false);
  EXPECT_EQ(proposal["lineage"]["parent_version"], 3);
  // `flexid models activate` makes it the active one: "model_changed".
  models[1]["active"] = false;
  models[2]["active"] = true;
  daemon.SetModels("S1", models);
  PublishAlert("S1", 1'000'000'002, "model_changed");
  state = WaitForState(
      [](const json& s) { return s["actuators"][0]["versions"][0]["active"] == true; });
  EXPECT_EQ(state["actuators"][0]["versions"][1]["active"], false);
  // A reply that does not parse is counted with its reason; the list stays as it was.
  models[1]["active"] = true;
  daemon.SetModels("S1", models);
  PublishAlert("S1", 1'000'000'003, "model_changed");
  state = WaitForState([](const json& s) { return s["counters"]["bad_replies"] >= 1; });
  EXPECT_EQ(state["last_problem"], "models of S1: versions 3 and 4 are both active");
  EXPECT_EQ(state["actuators"][0]["versions"][0]["active"], true);
  const auto health = Client().Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(json::parse(health->body)["last_problem"], state["last_problem"]);
}

TEST_F(DashboardServerTest, APageLoadAsksForTheVersionsAgain) {
  FakeDaemon daemon(lcm_);
  PublishSamples("S1", 1'000'000'000, 2.0, 0.1);
  WaitForState([](const json& s) {
    return !s["actuators"].empty() && s["actuators"][0]["versions"].is_array();
  });
  const int before = daemon.ModelsRequests("S1");
  std::this_thread::sleep_for(std::chrono::milliseconds(150));  // models_refresh_min
  ASSERT_TRUE(Client().Get("/api/state"));
  for (int i = 0; i < 100 && daemon.ModelsRequests("S1") == before; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_EQ(daemon.ModelsRequests("S1"), before + 1);
  EXPECT_EQ(store_.counters().bad_replies, 0);
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
  for (const char* channel : {"FLEXID/S1/PREDICTION", "FLEXID/ALERT", "FLEXID/S1/VOLTAGE",
                              "FLEXID/S1/DEFLECTION", "FLEXID/S1/COMMAND"})
    lcm_.publish(channel, garbage.data(), static_cast<unsigned>(garbage.size()));
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
  // Well-formed samples of S3 on S2's channels.
  PublishSamples("S3", 1'000'000, 1.0, 1.0, "S2");
  const json state = WaitForState([](const json& s) {
    return s["counters"]["bad_messages"] == 9 && s["counters"]["predictions"] == 1;
  });
  EXPECT_EQ(state["actuators"].size(), 1u);
  EXPECT_EQ(state["counters"]["samples"], 0);
  const auto health = Client().Get("/healthz");
  ASSERT_TRUE(health);
  EXPECT_EQ(json::parse(health->body)["bad_messages"], 9);
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
