// The dashboard's state and the event stream derived from it, without the bus or HTTP.
//
// The bus adapter (bus.h) feeds decoded samples, predictions, alerts, model summaries and
// model version lists in; the HTTP server (server.h) reads a JSON snapshot (/api/state)
// and waits for events (/events). Both sides share one mutex, so a snapshot and the id of
// the last event it contains always agree: a page that loads the snapshot and then streams
// the events after that id sees every point and alert exactly once.
//
// Where the points come from. A point is one deflection sample: its time, the voltage in
// force, the measured deflection and, when flexidd predicted it, the predicted deflection
// and the residual. flexidd's prediction_t carries the whole point (the sample's utime and
// value, flexidd's voltage in force, the prediction), so per actuator:
//   - while predictions flow (one arrived within prediction_timeout of wall time), the
//     points are the predictions. Deflection samples that arrive meanwhile are held until a
//     prediction at or after their time covers them, so no sample is drawn twice;
//   - otherwise (no model, no flexidd, a source flexidd refuses) the points are the
//     deflection samples (PREFIX/<id>/DEFLECTION) with the voltage in force from
//     PREFIX/<id>/VOLTAGE, predicted and residual NaN. Held samples become points when the
//     predictions stop, so none is lost either.
// A point is never joined from two messages: joining by time would leave the newest point
// of every batch without its prediction (it arrives a moment after the sample), a gap in
// the predicted line 7 times a second. At the hand-over from samples to predictions the
// few samples already drawn stay without a prediction and theirs are skipped ("covered").
//
// Points are batched: they gather per actuator and FlushBatch() (called every ~150 ms)
// turns them into one "points" event, decimated to at most max_points_per_batch points per
// actuator. At 16 actuators x 500 Hz that is 16 x 25 points per batch instead of 16 x 75,
// ~7 batches a second, each one JSON document. The decimated points also go into a
// per-actuator ring buffer, the history a freshly loaded page draws first.
//
// The reference. An actuator under control (flexid-control) has a reference deflection:
// every voltage command (PREFIX/<id>/COMMAND) carries the reference at the deflection
// sample it answers. It is a series of its own, with its own times, batched and decimated
// like the points (never joined to them: the command comes after its sample, and after
// flexidd's prediction of it); a stop command adds a gap (reference null), so that the
// line ends where control ended.
//
// Event payloads (JSON; times are message time):
//   points: {"actuators": [{"id", "received", "samples", "reset", "model_version", "trial",
//             "memberships", "t_s": [..], "voltage_V": [..], "measured_mm": [..],
//             "predicted_mm": [..], "residual_mm": [..],
//             "reference": {"t_s": [..], "reference_mm": [..]}}], "counters": {..}}
//   alert:  AlertJson(alert)       model: SummarizeModel(...)       resync: {}
//   versions: {"actuator", "versions": ModelVersionsFromJson(...) or null, "total" (versions
//             flexidd has), "problem": null or why flexidd gave no list}
//   daemon: {"actuator", "daemon"}: the flexidd that records the actuator
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "clients/dashboard/ring_buffer.h"

namespace flexid::dashboard {

using Clock = std::chrono::steady_clock;

// One point of one actuator's charts: a deflection sample, predicted or not.
struct Point {
  int64_t utime = 0;          // message time, microseconds
  double voltage_V = 0.0;     // voltage in force (NaN: none heard yet)
  double measured_mm = 0.0;   // measured deflection
  double predicted_mm = 0.0;  // model prediction (NaN: no model, or not predicted)
  double residual_mm = 0.0;   // measured - predicted (NaN: as predicted_mm)
};

// One point of an actuator's reference: its message time and value (NaN: control ended).
struct ReferencePoint {
  int64_t utime = 0;  // message time, microseconds
  double reference_mm = 0.0;
};

// A sample as on PREFIX/<id>/VOLTAGE (voltage_sample_t) or PREFIX/<id>/DEFLECTION
// (deflection_sample_t), without the channel.
struct VoltageSample {
  std::string actuator_id;
  int64_t utime = 0;  // message time, microseconds; the voltage holds from then on
  double voltage_V = 0.0;
};
struct DeflectionSample {
  std::string actuator_id;
  int64_t utime = 0;  // message time, microseconds
  double deflection_mm = 0.0;
};

// The reference a controller follows, from a voltage command (voltage_command_t): the
// reference at the deflection sample of message time utime, or the end of control (a
// stop command at its utime: reference_mm NaN).
struct ReferenceSample {
  std::string actuator_id;
  int64_t utime = 0;  // message time, microseconds
  double reference_mm = 0.0;
};

struct Prediction {
  std::string actuator_id;
  Point point;
  int32_t model_version = 0;  // 0: no model yet
  int32_t trial_id = 0;       // 0: no trial recording
  std::vector<double> memberships;
};

// An alert as on FLEXID/ALERT (alert_t) or from the "alerts" RPC.
struct Alert {
  int64_t utime = 0;  // when it was raised, message time, microseconds
  std::string actuator_id;
  std::string kind;
  int severity = 1;  // 0 info, 1 warning, 2 critical (alert_t::kInfo ...)
  int64_t start_utime = 0;
  int64_t end_utime = 0;
  double magnitude_mm = 0.0;
  double threshold_mm = 0.0;
  std::string text;
};

struct StoreOptions {
  size_t history_points = 4000;        // decimated points kept per actuator for new pages
  size_t max_points_per_batch = 25;    // per actuator and batch, after decimation
  size_t max_pending_points = 20000;   // per actuator between two batches (then thinned)
  size_t max_actuators = 64;           // further actuator ids are counted and ignored
  size_t max_alerts = 200;             // most recent alerts kept
  size_t max_events = 512;             // events kept for streams that lag behind
  int64_t restart_gap_us = 5'000'000;  // a point this far before the last one restarts the stream
  // Predictions of an actuator count as flowing until this long (wall time) after the last
  // one; meanwhile its deflection samples wait for them (see the file comment).
  std::chrono::milliseconds prediction_timeout{1000};
  size_t max_model_versions = 20;  // newest versions kept per actuator (the list shows them)

  bool IsValid(std::string* error) const;
};

// What AddPrediction, AddDeflection or AddVoltage did with a message.
enum class AddOutcome {
  kAccepted,  // a new point (a voltage: the voltage in force from now on)
  kHeld,      // a deflection sample waiting for its prediction
  kCovered,   // a prediction whose sample is drawn already (hand-over from samples)
  kInvalid,
  kOutOfOrder,
  kTooManyActuators
};

struct Counters {
  int64_t predictions = 0;   // accepted (also those covered by a sample already drawn)
  int64_t samples = 0;       // voltage and deflection samples accepted
  int64_t references = 0;    // reference samples accepted (from voltage commands)
  int64_t alerts = 0;        // accepted (duplicates not counted)
  int64_t bad_messages = 0;  // malformed, invalid values, unknown channel
  int64_t out_of_order = 0;  // predictions not after the previous one of their actuator
  int64_t too_many_actuators = 0;
  int64_t batches = 0;
  int64_t bad_replies = 0;  // RPC replies that failed or did not parse (last_problem says why)
};

// One server-sent event: its id, "event:" name and "data:" JSON (serialised once).
struct Event {
  uint64_t id = 0;
  std::string name;
  std::string data;
};

struct EventWait {
  std::vector<Event> events;  // in id order
  bool closed = false;        // the store is shutting down: end the stream
};

// Indices of at most max_points evenly spread samples of n, always the first and the last
// (n <= max_points: all). Strided thinning keeps the shape of the smooth deflection; a
// single-sample spike can fall between two kept points.
std::vector<size_t> DecimationIndices(size_t n, size_t max_points);

// x rounded to `digits` significant digits (so JSON carries "1.23457", not 17 digits);
// non-finite stays as it is (JSON null).
double RoundSignificant(double x, int digits);

// "info", "warning", "critical" (unknown values: "warning").
std::string SeverityName(int severity);

nlohmann::json AlertJson(const Alert& alert);

// An alert from the "alerts" RPC's list (storage's AlertJson: actuator, kind, severity as
// a number, utime, ...). nullopt when a required field is missing or of the wrong type.
std::optional<Alert> AlertFromJson(const nlohmann::json& json);

// The page's view of a "model" RPC result: actuator, version, active, created_utime,
// trials, kind ("tf" or "ts_fuzzy"), levels_V (one per local model) and fit (fit_percent,
// rmse_mm, samples, levels_V where present). nullopt when actuator or version is missing.
std::optional<nlohmann::json> SummarizeModel(const nlohmann::json& rpc_result);

class LiveStore {
 public:
  explicit LiveStore(StoreOptions options = {});

  // `now` is when the message arrived (wall time, for prediction_timeout).
  AddOutcome AddPrediction(const Prediction& prediction, Clock::time_point now = Clock::now());
  AddOutcome AddDeflection(const DeflectionSample& sample, Clock::time_point now = Clock::now());
  // The voltage in force from sample.utime on, for the deflection samples that follow.
  AddOutcome AddVoltage(const VoltageSample& sample);
  // A reference sample (finite, or NaN for the end of control), after the actuator's
  // previous one; creates the actuator's card.
  AddOutcome AddReference(const ReferenceSample& sample);
  // True when new (an alert already held, same time, actuator, kind and text, is ignored).
  // An alert creates its actuator's card.
  bool AddAlert(const Alert& alert);
  // Stores the summary (SummarizeModel) as the actuator's model and sends a "model" event.
  void SetModel(const nlohmann::json& summary);
  // Stores an actuator's model versions (ModelVersionsFromJson, newest first; the first
  // max_model_versions kept) and sends a "versions" event. Creates the actuator's card.
  void SetModelVersions(const std::string& actuator_id, const nlohmann::json& versions);
  // flexidd answered the "models" request of an actuator whose list the store does not
  // have yet with an error (e.g. an actuator it refuses): the page says so instead of
  // "asking". A list already stored stays.
  void SetModelVersionsProblem(const std::string& actuator_id, const std::string& problem);
  // The flexidd that records the actuator (several daemons on one bus): kept for
  // /api/state ("daemon") and sent as a "daemon" event when it changes. Does not create a
  // card.
  void SetDaemon(const std::string& actuator_id, const std::string& daemon_id);
  void CountBadMessage();
  // A message whose values are invalid: counted as a bad message, and `problem` (one line,
  // naming the channel and the field) kept as the last problem.
  void NoteBadMessage(const std::string& problem);
  // An RPC reply that failed or did not parse: counted, and `problem` (one line) kept as
  // the last problem for /api/state and /healthz.
  void NoteBadReply(const std::string& problem);
  // A page loaded the state: the bus adapter refreshes what may have changed unseen.
  void NotePageLoad();
  uint64_t page_loads() const;
  std::vector<std::string> ActuatorIds() const;

  // Sends the points gathered since the last call as one "points" event (nothing when
  // there are none); first, held samples of actuators whose predictions stopped become
  // points. Returns the number of points sent.
  size_t FlushBatch(Clock::time_point now = Clock::now());

  // /api/state: {"event_id", "counters", "last_problem", "actuators": [{"id", "received",
  // "samples", "references", "daemon" (null until heard), "model_version", "trial",
  // "latest", "memberships", "model", "versions" (null until flexidd answered),
  // "versions_total", "versions_problem", "history": {"t_s", ...}, "reference": {"t_s",
  // "reference_mm"} (decimated as sent; null values end a control run)}], "alerts"
  // (newest first)}.
  nlohmann::json StateJson() const;
  Counters counters() const;
  std::string last_problem() const;
  uint64_t last_event_id() const;

  // Events with id > after_id, waiting up to `timeout` for the first. A stream that fell
  // behind the kept events gets one "resync" event (the page reloads the state). An
  // after_id beyond the last event (a page from before a restart) means "from now".
  EventWait WaitEvents(uint64_t after_id, std::chrono::milliseconds timeout,
                       size_t max_events = 64) const;
  // Wakes every waiter; WaitEvents returns closed from now on.
  void Close();

 private:
  struct Series {
    explicit Series(size_t capacity) : history(capacity), reference_history(capacity) {}
    RingBuffer<Point> history;   // decimated, as sent
    std::vector<Point> pending;  // since the last batch
    // The reference (ReferenceSample without the id), likewise.
    RingBuffer<ReferencePoint> reference_history;
    std::vector<ReferencePoint> reference_pending;
    std::optional<int64_t> last_reference_utime;
    int64_t references = 0;  // reference samples accepted
    std::deque<Point> held;  // deflection samples waiting for their prediction (oldest first)
    int64_t received = 0;    // predictions accepted
    int64_t samples = 0;     // deflection samples accepted
    int64_t last_utime = 0;  // of the newest point (pending or sent)
    bool has_point = false;
    bool reset = false;  // the stream restarted: the next batch tells the page to clear
    Point latest;
    int32_t model_version = 0;
    int32_t trial_id = 0;
    std::vector<double> memberships;
    nlohmann::json model;     // SummarizeModel, or null
    nlohmann::json versions;  // ModelVersionsFromJson, or null
    // Per stream, for time order and hand-over (see the file comment).
    std::optional<int64_t> last_prediction_utime;
    std::optional<Clock::time_point> last_prediction_at;
    std::optional<int64_t> last_deflection_utime;
    // The voltage in force: the newest voltage sample and the one before it (a deflection
    // sample may be stamped just before a voltage step that arrived first).
    std::optional<VoltageSample> voltage, previous_voltage;
  };

  Series* FindOrCreate(const std::string& actuator_id);  // nullptr: too many actuators
  // The series of a message's actuator; nullptr, with *refused set and counted, for an
  // invalid message or one actuator too many. With mutex_ held, as all below.
  Series* Admit(const std::string& actuator_id, bool valid, AddOutcome* refused);
  // Whether a stream's message at `utime` follows its previous one at `last_utime`; false
  // (counted) when out of order. Far back in time restarts the series: true.
  bool InOrder(Series* s, const std::optional<int64_t>& last_utime, int64_t utime);
  bool PredictionsFlow(const Series& s, Clock::time_point now) const;
  void Restart(Series* s);                          // the stream went back in time
  void AppendPoint(Series* s, const Point& point);  // after last_utime
  void AppendEvent(std::string name, const nlohmann::json& data);

  StoreOptions options_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::map<std::string, Series> series_;
  std::map<std::string, std::string> daemons_;  // actuator -> daemon_id
  std::deque<Alert> alerts_;                    // oldest first, by utime
  std::deque<Event> events_;
  uint64_t next_event_id_ = 1;
  bool closed_ = false;
  Counters counters_;
  std::string last_problem_;
  uint64_t page_loads_ = 0;
};

}  // namespace flexid::dashboard
