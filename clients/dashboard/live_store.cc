// The dashboard's state and event stream (live_store.h): per-actuator series with
// decimated batches, alerts, model summaries and versions, and the JSON the page reads.
#include "clients/dashboard/live_store.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "bus/ids.h"

namespace flexid::dashboard {
namespace {

using nlohmann::json;

// Message time in seconds, to the millisecond (shortest JSON form, e.g. 1795250559.123).
double SecondsOf(int64_t utime) { return static_cast<double>(utime / 1000) / 1000.0; }

json Number(double x) { return std::isfinite(x) ? json(RoundSignificant(x, 6)) : json(nullptr); }

json PointJson(const Point& p) {
  return {{"t_s", SecondsOf(p.utime)},
          {"voltage_V", Number(p.voltage_V)},
          {"measured_mm", Number(p.measured_mm)},
          {"predicted_mm", Number(p.predicted_mm)},
          {"residual_mm", Number(p.residual_mm)}};
}

// Column arrays as uPlot takes them.
template <typename Points>
json ColumnsJson(const Points& points, const std::vector<size_t>& indices) {
  json t = json::array(), v = json::array(), measured = json::array(), predicted = json::array(),
       residual = json::array();
  for (const size_t i : indices) {
    const Point& p = points[i];
    t.push_back(SecondsOf(p.utime));
    v.push_back(Number(p.voltage_V));
    measured.push_back(Number(p.measured_mm));
    predicted.push_back(Number(p.predicted_mm));
    residual.push_back(Number(p.residual_mm));
  }
  return {{"t_s", std::move(t)},
          {"voltage_V", std::move(v)},
          {"measured_mm", std::move(measured)},
          {"predicted_mm", std::move(predicted)},
          {"residual_mm", std::move(residual)}};
}

// The reference's columns, with every end of control (NaN) kept through the decimation,
// so that a line never joins two control runs.
template <typename Points>
json ReferenceJson(const Points& points, std::vector<size_t> indices) {
  for (size_t i = 0; i < points.size(); ++i)
    if (std::isnan(points[i].reference_mm)) indices.push_back(i);
  std::sort(indices.begin(), indices.end());
  indices.erase(std::unique(indices.begin(), indices.end()), indices.end());
  json t = json::array(), reference = json::array();
  for (const size_t i : indices) {
    t.push_back(SecondsOf(points[i].utime));
    reference.push_back(Number(points[i].reference_mm));
  }
  return {{"t_s", std::move(t)}, {"reference_mm", std::move(reference)}};
}

json MembershipsJson(const std::vector<double>& memberships) {
  json out = json::array();
  for (const double m : memberships) out.push_back(Number(m));
  return out;
}

json CountersJson(const Counters& c) {
  return {{"predictions", c.predictions},
          {"samples", c.samples},
          {"references", c.references},
          {"alerts", c.alerts},
          {"bad_messages", c.bad_messages},
          {"out_of_order", c.out_of_order},
          {"too_many_actuators", c.too_many_actuators},
          {"bad_replies", c.bad_replies}};
}

// A problem's text as kept for the page: one line of at most 300 characters (an error
// from the bus could be anything).
std::string OneLine(const std::string& text) {
  constexpr size_t kMaxChars = 300;
  std::string out = text.substr(0, kMaxChars);
  std::replace(out.begin(), out.end(), '\n', ' ');
  if (text.size() > kMaxChars) out += "...";
  return out;
}

// Keeps every other point of a buffer that no batch emptied for a long while.
template <typename Points>
void Thin(Points* points) {
  size_t kept = 0;
  for (size_t i = 0; i < points->size(); i += 2) (*points)[kept++] = (*points)[i];
  points->resize(kept);
}

bool SameAlert(const Alert& a, const Alert& b) {
  return a.utime == b.utime && a.actuator_id == b.actuator_id && a.kind == b.kind &&
         a.text == b.text;
}

const json* Member(const json& object, const char* key) {
  if (!object.is_object()) return nullptr;
  const auto it = object.find(key);
  return it == object.end() ? nullptr : &*it;
}

}  // namespace

bool StoreOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* why) {
    if (error) *error = why;
    return false;
  };
  if (history_points == 0) return fail("history_points must be > 0");
  if (max_points_per_batch < 2) return fail("max_points_per_batch must be >= 2");
  if (max_pending_points < max_points_per_batch)
    return fail("max_pending_points must be >= max_points_per_batch");
  if (max_actuators == 0) return fail("max_actuators must be > 0");
  if (max_alerts == 0) return fail("max_alerts must be > 0");
  if (max_events < 2) return fail("max_events must be >= 2");
  if (restart_gap_us < 0) return fail("restart_gap_us must be >= 0");
  if (prediction_timeout.count() <= 0) return fail("prediction_timeout must be > 0");
  if (max_model_versions == 0) return fail("max_model_versions must be > 0");
  return true;
}

std::vector<size_t> DecimationIndices(size_t n, size_t max_points) {
  std::vector<size_t> indices;
  if (n == 0 || max_points == 0) return indices;
  if (n <= max_points || max_points == 1) {
    if (max_points == 1) return {n - 1};
    indices.resize(n);
    for (size_t i = 0; i < n; ++i) indices[i] = i;
    return indices;
  }
  indices.reserve(max_points);
  // k (n - 1) / (max_points - 1), rounded down: strictly increasing since n > max_points.
  for (size_t k = 0; k < max_points; ++k) indices.push_back(k * (n - 1) / (max_points - 1));
  return indices;
}

double RoundSignificant(double x, int digits) {
  if (!std::isfinite(x) || x == 0.0) return x;
  const int exponent = digits - static_cast<int>(std::ceil(std::log10(std::fabs(x))));
  // Scale by an exact power of ten (<= 1e22), so the result is the double nearest to the
  // rounded decimal and prints as it.
  if (exponent > 22 || exponent < -22) return x;
  if (exponent >= 0) {
    const double scale = std::pow(10.0, exponent);
    return std::round(x * scale) / scale;
  }
  const double scale = std::pow(10.0, -exponent);
  return std::round(x / scale) * scale;
}

std::string SeverityName(int severity) {
  switch (severity) {
    case 0:
      return "info";
    case 2:
      return "critical";
    default:
      return "warning";
  }
}

json AlertJson(const Alert& a) {
  return {{"actuator", a.actuator_id},
          {"kind", a.kind},
          {"severity", SeverityName(a.severity)},
          {"utime", a.utime},
          {"t_s", SecondsOf(a.utime)},
          {"start_utime", a.start_utime},
          {"end_utime", a.end_utime},
          {"magnitude_mm", Number(a.magnitude_mm)},
          {"threshold_mm", Number(a.threshold_mm)},
          {"text", a.text}};
}

std::optional<Alert> AlertFromJson(const json& in) {
  const json* utime = Member(in, "utime");
  const json* kind = Member(in, "kind");
  if (!utime || !utime->is_number_integer() || !kind || !kind->is_string()) return std::nullopt;
  Alert a;
  a.utime = utime->get<int64_t>();
  a.kind = kind->get<std::string>();
  if (const json* v = Member(in, "actuator"); v && v->is_string()) a.actuator_id = *v;
  if (const json* v = Member(in, "severity"); v && v->is_number_integer()) a.severity = *v;
  if (const json* v = Member(in, "severity"); v && v->is_string())
    a.severity = *v == "info" ? 0 : *v == "critical" ? 2 : 1;
  if (const json* v = Member(in, "start_utime"); v && v->is_number_integer()) a.start_utime = *v;
  if (const json* v = Member(in, "end_utime"); v && v->is_number_integer()) a.end_utime = *v;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  a.magnitude_mm = nan;
  a.threshold_mm = nan;
  if (const json* v = Member(in, "magnitude_mm"); v && v->is_number()) a.magnitude_mm = *v;
  if (const json* v = Member(in, "threshold_mm"); v && v->is_number()) a.threshold_mm = *v;
  if (const json* v = Member(in, "text"); v && v->is_string()) a.text = *v;
  return a;
}

std::optional<json> SummarizeModel(const json& r) {
  const json* actuator = Member(r, "actuator");
  const json* version = Member(r, "version");
  if (!actuator || !actuator->is_string() || !version || !version->is_number_integer())
    return std::nullopt;
  json out = {{"actuator", *actuator}, {"version", *version}};
  for (const char* key : {"active", "created_utime", "trials"})
    if (const json* v = Member(r, key)) out[key] = *v;
  if (const json* model = Member(r, "model")) {
    if (const json* kind = Member(*model, "kind"); kind && kind->is_string()) out["kind"] = *kind;
    json levels = json::array();
    if (const json* locals = Member(*model, "local_models"); locals && locals->is_array())
      for (const json& local : *locals)
        if (const json* level = Member(local, "level_V"); level && level->is_number())
          levels.push_back(*level);
    out["levels_V"] = std::move(levels);
  }
  json fit = nullptr;
  if (const json* f = Member(r, "fit"); f && f->is_object()) {
    fit = json::object();
    for (const char* key : {"fit_percent", "rmse_mm"})
      if (const json* v = Member(*f, key); v && v->is_number())
        fit[key] = RoundSignificant(v->get<double>(), 4);
    for (const char* key : {"samples", "levels_V"})
      if (const json* v = Member(*f, key)) fit[key] = *v;
  }
  out["fit"] = std::move(fit);
  return out;
}

LiveStore::LiveStore(StoreOptions options) : options_(options) {
  std::string why;
  if (!options_.IsValid(&why)) throw std::invalid_argument("dashboard store: " + why);
}

LiveStore::Series* LiveStore::FindOrCreate(const std::string& actuator_id) {
  auto it = series_.find(actuator_id);
  if (it != series_.end()) return &it->second;
  if (series_.size() >= options_.max_actuators) return nullptr;
  return &series_.emplace(actuator_id, Series(options_.history_points)).first->second;
}

LiveStore::Series* LiveStore::Admit(const std::string& actuator_id, bool valid,
                                    AddOutcome* refused) {
  if (!valid) {
    ++counters_.bad_messages;
    *refused = AddOutcome::kInvalid;
    return nullptr;
  }
  Series* s = FindOrCreate(actuator_id);
  if (!s) {
    ++counters_.too_many_actuators;
    *refused = AddOutcome::kTooManyActuators;
  }
  return s;
}

bool LiveStore::InOrder(Series* s, const std::optional<int64_t>& last_utime, int64_t utime) {
  if (!last_utime || utime > *last_utime) return true;
  if (*last_utime - utime <= options_.restart_gap_us) {
    ++counters_.out_of_order;
    return false;
  }
  Restart(s);
  return true;
}

bool LiveStore::PredictionsFlow(const Series& s, Clock::time_point now) const {
  return s.last_prediction_at && now - *s.last_prediction_at < options_.prediction_timeout;
}

void LiveStore::Restart(Series* s) {
  // Far back in time: a new run (a replayed log, a rig restarted at an earlier time).
  s->history.Clear();
  s->pending.clear();
  s->held.clear();
  s->reset = true;
  s->has_point = false;
  s->last_prediction_utime.reset();
  s->last_deflection_utime.reset();
  s->reference_history.Clear();
  s->reference_pending.clear();
  s->last_reference_utime.reset();
}

void LiveStore::AppendPoint(Series* s, const Point& p) {
  // No batch for a long while: keep every other point.
  if (s->pending.size() >= options_.max_pending_points) Thin(&s->pending);
  s->pending.push_back(p);
  s->latest = p;
  s->has_point = true;
  s->last_utime = p.utime;
}

AddOutcome LiveStore::AddPrediction(const Prediction& in, Clock::time_point now) {
  const Point& p = in.point;
  const bool valid = bus::IsValidId(in.actuator_id) && std::isfinite(p.voltage_V) &&
                     std::isfinite(p.measured_mm) && !std::isinf(p.predicted_mm) &&
                     !std::isinf(p.residual_mm) && in.model_version >= 0 &&
                     std::all_of(in.memberships.begin(), in.memberships.end(),
                                 [](double m) { return std::isfinite(m); });
  std::lock_guard lock(mutex_);
  AddOutcome refused = AddOutcome::kInvalid;
  Series* s = Admit(in.actuator_id, valid, &refused);
  if (!s) return refused;
  if (!InOrder(s, s->last_prediction_utime, p.utime)) return AddOutcome::kOutOfOrder;
  bool covered = false;
  if (s->has_point && p.utime <= s->last_utime) {
    if (s->last_utime - p.utime > options_.restart_gap_us)
      Restart(s);
    else
      covered = true;  // drawn from the deflection channel before the predictions came
  }
  // The held samples up to this one are drawn by the predictions.
  const auto first_later = std::find_if(s->held.begin(), s->held.end(),
                                        [&](const Point& h) { return h.utime > p.utime; });
  s->held.erase(s->held.begin(), first_later);
  s->last_prediction_utime = p.utime;
  s->last_prediction_at = now;
  s->model_version = in.model_version;
  s->trial_id = in.trial_id;
  s->memberships = in.memberships;
  ++s->received;
  ++counters_.predictions;
  if (covered) return AddOutcome::kCovered;
  AppendPoint(s, p);
  return AddOutcome::kAccepted;
}

AddOutcome LiveStore::AddDeflection(const DeflectionSample& in, Clock::time_point now) {
  const bool valid = bus::IsValidId(in.actuator_id) && std::isfinite(in.deflection_mm);
  std::lock_guard lock(mutex_);
  AddOutcome refused = AddOutcome::kInvalid;
  Series* s = Admit(in.actuator_id, valid, &refused);
  if (!s) return refused;
  if (!InOrder(s, s->last_deflection_utime, in.utime)) return AddOutcome::kOutOfOrder;
  s->last_deflection_utime = in.utime;
  ++s->samples;
  ++counters_.samples;
  // The voltage in force at the sample's time.
  double voltage_V = std::numeric_limits<double>::quiet_NaN();
  if (s->voltage && s->voltage->utime <= in.utime)
    voltage_V = s->voltage->voltage_V;
  else if (s->previous_voltage && s->previous_voltage->utime <= in.utime)
    voltage_V = s->previous_voltage->voltage_V;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const Point point{in.utime, voltage_V, in.deflection_mm, nan, nan};
  if (PredictionsFlow(*s, now)) {
    if (s->last_prediction_utime && in.utime <= *s->last_prediction_utime)
      return AddOutcome::kCovered;  // its prediction came first
    if (s->held.size() >= options_.max_pending_points) Thin(&s->held);
    s->held.push_back(point);
    return AddOutcome::kHeld;
  }
  if (s->has_point && in.utime <= s->last_utime) {
    if (s->last_utime - in.utime <= options_.restart_gap_us) return AddOutcome::kCovered;
    Restart(s);
    s->last_deflection_utime = in.utime;
  }
  AppendPoint(s, point);
  return AddOutcome::kAccepted;
}

AddOutcome LiveStore::AddVoltage(const VoltageSample& in) {
  const bool valid = bus::IsValidId(in.actuator_id) && std::isfinite(in.voltage_V);
  std::lock_guard lock(mutex_);
  AddOutcome refused = AddOutcome::kInvalid;
  Series* s = Admit(in.actuator_id, valid, &refused);
  if (!s) return refused;
  if (s->voltage && in.utime <= s->voltage->utime) {
    if (s->voltage->utime - in.utime <= options_.restart_gap_us) {
      ++counters_.out_of_order;
      return AddOutcome::kOutOfOrder;
    }
    s->voltage.reset();  // a new run: the old voltages are not in force in it
  }
  s->previous_voltage = std::move(s->voltage);
  s->voltage = in;
  ++counters_.samples;
  return AddOutcome::kAccepted;
}

AddOutcome LiveStore::AddReference(const ReferenceSample& in) {
  const bool valid = bus::IsValidId(in.actuator_id) && !std::isinf(in.reference_mm);
  std::lock_guard lock(mutex_);
  AddOutcome refused = AddOutcome::kInvalid;
  Series* s = Admit(in.actuator_id, valid, &refused);
  if (!s) return refused;
  if (s->last_reference_utime && in.utime <= *s->last_reference_utime) {
    if (*s->last_reference_utime - in.utime <= options_.restart_gap_us) {
      ++counters_.out_of_order;
      return AddOutcome::kOutOfOrder;
    }
    // A new run far back in time: the old reference is not its reference.
    s->reference_history.Clear();
    s->reference_pending.clear();
  }
  s->last_reference_utime = in.utime;
  if (s->reference_pending.size() >= options_.max_pending_points) Thin(&s->reference_pending);
  s->reference_pending.push_back({in.utime, in.reference_mm});
  ++s->references;
  ++counters_.references;
  return AddOutcome::kAccepted;
}

bool LiveStore::AddAlert(const Alert& alert) {
  std::lock_guard lock(mutex_);
  for (const Alert& held : alerts_)
    if (SameAlert(held, alert)) return false;
  if (bus::IsValidId(alert.actuator_id)) FindOrCreate(alert.actuator_id);
  // Keep the list in message-time order (alerts from the RPC may arrive after live ones).
  auto at = std::upper_bound(alerts_.begin(), alerts_.end(), alert.utime,
                             [](int64_t utime, const Alert& a) { return utime < a.utime; });
  alerts_.insert(at, alert);
  while (alerts_.size() > options_.max_alerts) alerts_.pop_front();
  ++counters_.alerts;
  AppendEvent("alert", AlertJson(alert));
  return true;
}

void LiveStore::SetModel(const json& summary) {
  const json* actuator = Member(summary, "actuator");
  if (!actuator || !actuator->is_string()) return;
  std::lock_guard lock(mutex_);
  Series* s = FindOrCreate(actuator->get<std::string>());
  if (!s) return;
  s->model = summary;
  AppendEvent("model", summary);
}

void LiveStore::SetModelVersions(const std::string& actuator_id, const json& versions) {
  if (!versions.is_array()) return;
  std::lock_guard lock(mutex_);
  Series* s = FindOrCreate(actuator_id);
  if (!s) return;
  json kept = json::array();
  for (const json& v : versions) {
    if (kept.size() >= options_.max_model_versions) break;
    kept.push_back(v);
  }
  json event = {{"actuator", actuator_id},
                {"versions", kept},
                {"total", versions.size()},
                {"problem", nullptr}};
  s->versions = event;
  AppendEvent("versions", event);
}

void LiveStore::SetModelVersionsProblem(const std::string& actuator_id,
                                        const std::string& problem) {
  std::lock_guard lock(mutex_);
  Series* s = FindOrCreate(actuator_id);
  if (!s) return;
  // A list flexidd gave before stays: it is the best there is.
  if (s->versions.is_object() && s->versions["versions"].is_array()) return;
  json event = {{"actuator", actuator_id},
                {"versions", nullptr},
                {"total", nullptr},
                {"problem", OneLine(problem)}};
  s->versions = event;
  AppendEvent("versions", event);
}

void LiveStore::SetDaemon(const std::string& actuator_id, const std::string& daemon_id) {
  std::lock_guard lock(mutex_);
  std::string& known = daemons_[actuator_id];
  if (known == daemon_id) return;
  known = daemon_id;
  AppendEvent("daemon", {{"actuator", actuator_id}, {"daemon", daemon_id}});
}

void LiveStore::CountBadMessage() {
  std::lock_guard lock(mutex_);
  ++counters_.bad_messages;
}

void LiveStore::NoteBadMessage(const std::string& problem) {
  std::lock_guard lock(mutex_);
  ++counters_.bad_messages;
  last_problem_ = OneLine(problem);
}

void LiveStore::NoteBadReply(const std::string& problem) {
  std::lock_guard lock(mutex_);
  ++counters_.bad_replies;
  last_problem_ = OneLine(problem);
}

void LiveStore::NotePageLoad() {
  std::lock_guard lock(mutex_);
  ++page_loads_;
}

uint64_t LiveStore::page_loads() const {
  std::lock_guard lock(mutex_);
  return page_loads_;
}

std::vector<std::string> LiveStore::ActuatorIds() const {
  std::lock_guard lock(mutex_);
  std::vector<std::string> ids;
  ids.reserve(series_.size());
  for (const auto& entry : series_) ids.push_back(entry.first);
  return ids;
}

size_t LiveStore::FlushBatch(Clock::time_point now) {
  std::lock_guard lock(mutex_);
  json actuators = json::array();
  size_t sent = 0;
  for (auto& [id, s] : series_) {
    if (!s.held.empty() && !PredictionsFlow(s, now)) {
      // The predictions stopped: the samples they would have drawn are the points now.
      for (const Point& h : s.held)
        if (!s.has_point || h.utime > s.last_utime) AppendPoint(&s, h);
      s.held.clear();
    }
    if (s.pending.empty() && s.reference_pending.empty() && !s.reset) continue;
    const std::vector<size_t> indices =
        DecimationIndices(s.pending.size(), options_.max_points_per_batch);
    json entry = ColumnsJson(s.pending, indices);
    const std::vector<size_t> reference_indices =
        DecimationIndices(s.reference_pending.size(), options_.max_points_per_batch);
    json reference = ReferenceJson(s.reference_pending, reference_indices);
    for (size_t i = 0; i < s.reference_pending.size(); ++i)
      if (std::binary_search(reference_indices.begin(), reference_indices.end(), i) ||
          std::isnan(s.reference_pending[i].reference_mm))
        s.reference_history.Push(s.reference_pending[i]);
    s.reference_pending.clear();
    entry["reference"] = std::move(reference);
    entry["id"] = id;
    entry["received"] = s.received;
    entry["samples"] = s.samples;
    entry["reset"] = s.reset;
    entry["model_version"] = s.model_version;
    entry["trial"] = s.trial_id;
    entry["memberships"] = MembershipsJson(s.memberships);
    actuators.push_back(std::move(entry));
    for (const size_t i : indices) s.history.Push(s.pending[i]);
    sent += indices.size();
    s.pending.clear();
    s.reset = false;
  }
  if (actuators.empty()) return 0;
  ++counters_.batches;
  AppendEvent("points",
              {{"actuators", std::move(actuators)}, {"counters", CountersJson(counters_)}});
  return sent;
}

json LiveStore::StateJson() const {
  std::lock_guard lock(mutex_);
  json actuators = json::array();
  for (const auto& [id, s] : series_) {
    std::vector<size_t> all(s.history.size());
    for (size_t i = 0; i < all.size(); ++i) all[i] = i;
    std::vector<size_t> all_references(s.reference_history.size());
    for (size_t i = 0; i < all_references.size(); ++i) all_references[i] = i;
    actuators.push_back(
        {{"id", id},
         {"daemon", daemons_.count(id) ? json(daemons_.at(id)) : json(nullptr)},
         {"received", s.received},
         {"samples", s.samples},
         {"references", s.references},
         {"model_version", s.model_version},
         {"trial", s.trial_id},
         {"latest", s.has_point ? PointJson(s.latest) : json(nullptr)},
         {"memberships", MembershipsJson(s.memberships)},
         {"model", s.model},
         {"versions", s.versions.is_object() ? s.versions.at("versions") : json()},
         {"versions_total", s.versions.is_object() ? s.versions.at("total") : json()},
         {"versions_problem", s.versions.is_object() ? s.versions.at("problem") : json()},
         {"history", ColumnsJson(s.history, all)},
         {"reference", ReferenceJson(s.reference_history, all_references)}});
  }
  json alerts = json::array();
  for (auto it = alerts_.rbegin(); it != alerts_.rend(); ++it) alerts.push_back(AlertJson(*it));
  return {{"event_id", next_event_id_ - 1},
          {"counters", CountersJson(counters_)},
          {"last_problem", last_problem_},
          {"actuators", std::move(actuators)},
          {"alerts", std::move(alerts)}};
}

Counters LiveStore::counters() const {
  std::lock_guard lock(mutex_);
  return counters_;
}

std::string LiveStore::last_problem() const {
  std::lock_guard lock(mutex_);
  return last_problem_;
}

uint64_t LiveStore::last_event_id() const {
  std::lock_guard lock(mutex_);
  return next_event_id_ - 1;
}

void LiveStore::AppendEvent(std::string name, const json& data) {
  events_.push_back({next_event_id_++, std::move(name), data.dump()});
  while (events_.size() > options_.max_events) events_.pop_front();
  changed_.notify_all();
}

EventWait LiveStore::WaitEvents(uint64_t after_id, std::chrono::milliseconds timeout,
                                size_t max_events) const {
  std::unique_lock lock(mutex_);
  const uint64_t last = next_event_id_ - 1;
  if (after_id > last) after_id = last;
  changed_.wait_for(lock, timeout, [&] { return closed_ || next_event_id_ - 1 > after_id; });
  EventWait out;
  out.closed = closed_;
  if (closed_ || next_event_id_ - 1 <= after_id) return out;
  if (events_.empty() || events_.front().id > after_id + 1) {
    // Fell behind what is kept: the page must reload the state.
    out.events.push_back({next_event_id_ - 1, "resync", "{}"});
    return out;
  }
  for (const Event& e : events_) {
    if (e.id <= after_id) continue;
    out.events.push_back(e);
    if (out.events.size() >= max_events) break;
  }
  return out;
}

void LiveStore::Close() {
  std::lock_guard lock(mutex_);
  closed_ = true;
  changed_.notify_all();
}

}  // namespace flexid::dashboard
