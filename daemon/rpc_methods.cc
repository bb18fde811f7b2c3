// RPC (DESIGN.md: "RPC server"): requests on FLEXID/RPC/REQUEST, the signature check for
// methods that change data (lcmtypes/message_auth.h), and the table of methods.
#include "daemon/rpc_methods.h"

#include <algorithm>
#include <flexid/rpc_reply_t.hpp>

#include "bus/clock.h"
#include "bus/ids.h"
#include "daemon/predictor.h"
#include "daemon/proposal.h"
#include "daemon/service.h"
#include "flexid/version.h"
#include "model/core/errors.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify.h"
#include "storage/queries.h"
#include "storage/record_json.h"

namespace flexid::daemon {
namespace {

using ReplyStatus = flexid::rpc_reply_t;

}  // namespace

// A request may be addressed to one daemon (argument "daemon_id", covered by the
// signature of a signed request): the others ignore it. An unaddressed one goes to every
// daemon: each answers a read-only request (one that holds nothing says so), and a signed
// request about an actuator is left to its owner by the daemons that know the owner.
void Service::OnRequest(const lcm::ReceiveBuffer& rbuf) {
  flexid::rpc_request_t request;
  if (!Decode(rbuf, &request, wire::kRpcRequest)) return;
  const RpcContext context{request.request_id, request.client_id};
  nlohmann::json args = nlohmann::json::parse(request.args_json, nullptr, false);
  if (!args.is_object()) args = nlohmann::json::object();  // HandleRequest says what is wrong
  const auto address = args.find("daemon_id");
  const bool addressed = address != args.end();
  if (addressed && !address->is_string()) {
    Reply(context, {flexid::rpc_reply_t::kBadRequest, nullptr,
                    "argument \"daemon_id\" must be a string: the daemon_id of the flexidd the "
                    "request is for",
                    false});
    return;
  }
  if (addressed && address->get<std::string>() != config.daemon_id) return;
  const bool changes_data = ChangesData(request.method);
  const auto actuator = args.find("actuator");
  const std::string actuator_id =
      actuator != args.end() && actuator->is_string() ? actuator->get<std::string>() : "";
  if (changes_data && !addressed && !actuator_id.empty() && !ownership.Owns(actuator_id) &&
      !ownership.OwnerElsewhere(actuator_id).empty())
    return;                                     // its owner answers, with its own key
  if (!changes_data && !addressed) Announce();  // the client learns who is on the bus
  // Methods that change data need a valid signature, a fresh time and a new nonce; every
  // one is logged with its outcome. Read-only methods need none (an `auth` is ignored).
  if (changes_data) {
    const std::string refusal = verifier.Check(request, bus::WallClockUtime());
    if (!refusal.empty()) {
      ++counters.refused_unauthorized;
      spdlog::warn(
          "request refused [method: {}, client: {}, request: {}, args: {}] not authorised: {}",
          ArgumentSummary(request.method), ArgumentSummary(request.client_id),
          ArgumentSummary(request.request_id), ArgumentSummary(request.args_json), refusal);
      Reply(context,
            {flexid::rpc_reply_t::kUnauthorized, nullptr, "not authorised: " + refusal, false});
      return;
    }
    // About an actuator known here whose owner is being decided: answered once it is.
    if (actuators.count(actuator_id) && !actuators.at(actuator_id).owned &&
        RouteTo(actuator_id) == Ownership::Verdict::kHold) {
      Hold(actuator_id, [this, request] { Dispatch(request); });
      return;
    }
  }
  Dispatch(request);
}

// A request that reads the file sees every write queued before it (a trial stopped on the
// bus, then "identify"), as when the loop wrote itself: it waits for them, unless storage
// is failing (then it is answered from what the file holds).
void Service::Dispatch(const flexid::rpc_request_t& request) {
  if (ReadsTheFile(request.method) && last_done_ticket < last_ticket &&
      writer->last_error().empty()) {
    on_written.emplace(last_ticket,
                       [this, request](const storage::WriteOutcome&) { Answer(request); });
    return;
  }
  Answer(request);
}

bool Service::ReadsTheFile(const std::string& method) {
  return method != "status" && method != "actuators";
}

void Service::Answer(const flexid::rpc_request_t& request) {
  const RpcContext context{request.request_id, request.client_id};
  const bool changes_data = ChangesData(request.method);
  RpcOutcome outcome = HandleRequest(request);
  if (outcome.deferred && outcome.written != 0) return;  // see ReplyWhenWritten
  if (changes_data)
    LogAccepted(request, outcome.deferred ? "running on the worker"
                         : outcome.status == flexid::rpc_reply_t::kOk
                             ? "done"
                             : "failed: " + ArgumentSummary(outcome.error));
  if (outcome.deferred) return;  // identify: answered when the worker finishes
  Reply(context, outcome);
}

void Service::LogAccepted(const flexid::rpc_request_t& request, const std::string& how) {
  spdlog::info("request accepted [method: {}, client: {}, request: {}, args: {}] {}",
               ArgumentSummary(request.method), ArgumentSummary(request.client_id),
               ArgumentSummary(request.request_id), ArgumentSummary(request.args_json), how);
}

// A request that changed data is answered once the writer has committed its last write
// (then "ok" means stored, and `then` runs first), or refused it (then the reply says
// why). While storage fails the reply waits: the write is retried. Returns the deferred
// outcome for HandleRequest to return.
RpcOutcome Service::ReplyWhenWritten(uint64_t ticket, const flexid::rpc_request_t& request,
                                     RpcOutcome reply, std::function<void()> then) {
  on_written.emplace(ticket, [this, request, reply = std::move(reply),
                              then = std::move(then)](const storage::WriteOutcome& written) {
    RpcOutcome outcome = written.error.empty()
                             ? reply
                             : RpcOutcome{flexid::rpc_reply_t::kFailed, nullptr, written.error};
    try {
      if (written.error.empty() && then) then();
    } catch (const std::exception& e) {
      outcome = {flexid::rpc_reply_t::kFailed, nullptr, e.what()};
    }
    LogAccepted(request, outcome.status == flexid::rpc_reply_t::kOk
                             ? "done"
                             : "failed: " + ArgumentSummary(outcome.error));
    Reply({request.request_id, request.client_id}, outcome);
  });
  return {flexid::rpc_reply_t::kOk, nullptr, "", true, ticket};
}

namespace {

// One method: its name, whether requests for it must be signed (it changes data), and its
// handler. The access stated here is the one lcmtypes/message_auth.h's ChangesData() gives,
// which OnRequest checks and the clients sign by (tests/rpc_methods_test.cc: they agree).
struct RpcMethod {
  std::string_view name;
  Access access;
  RpcOutcome (Service::*handle)(const flexid::rpc_request_t& request, const nlohmann::json& args);
};

constexpr RpcMethod kRpcMethods[] = {
    {"status", Access::kReadOnly, &Service::RpcStatus},
    {"actuators", Access::kReadOnly, &Service::RpcActuators},
    {"trials", Access::kReadOnly, &Service::RpcStoredQuery},
    {"trial_samples", Access::kReadOnly, &Service::RpcStoredQuery},
    {"models", Access::kReadOnly, &Service::RpcStoredQuery},
    {"model", Access::kReadOnly, &Service::RpcStoredQuery},
    {"alerts", Access::kReadOnly, &Service::RpcStoredQuery},
    {"model_activate", Access::kSigned, &Service::RpcModelActivate},
    {"trial_start", Access::kSigned, &Service::RpcTrialControl},
    {"trial_stop", Access::kSigned, &Service::RpcTrialControl},
    {"identify", Access::kSigned, &Service::RpcIdentify},
    {"diagnose", Access::kSigned, &Service::RpcDiagnose},
};

}  // namespace

std::vector<RpcMethodAccess> RpcMethodAccesses() {
  std::vector<RpcMethodAccess> out;
  for (const RpcMethod& method : kRpcMethods) out.push_back({method.name, method.access});
  return out;
}

RpcOutcome Service::HandleRequest(const flexid::rpc_request_t& request) {
  if (!bus::IsValidId(request.client_id) || request.request_id.empty() ||
      request.request_id.size() > 128)
    return {ReplyStatus::kBadRequest, nullptr,
            "client_id must be [A-Za-z0-9_-]{1,64} and request_id 1-128 characters", false};
  try {
    const nlohmann::json args = ParseArguments(request.args_json);
    for (const RpcMethod& method : kRpcMethods)
      if (method.name == request.method) return (this->*method.handle)(request, args);
    return {ReplyStatus::kBadRequest, nullptr, "unknown method \"" + request.method + "\"", false};
  } catch (const ArgumentError& e) {
    return {ReplyStatus::kBadRequest, nullptr, e.what(), false};
  } catch (const std::exception& e) {
    return {ReplyStatus::kFailed, nullptr, e.what(), false};
  }
}

// The actuator a request's "actuator" argument names (nothing when it is optional and not
// given); throws ArgumentError for one flexidd does not know.
ActuatorState* Service::ActuatorArgument(const nlohmann::json& args, bool required) {
  const std::string empty;
  const std::string id = StringArgument(args, "actuator", required ? nullptr : &empty);
  if (id.empty()) return nullptr;
  auto it = actuators.find(id);
  if (it == actuators.end()) {
    if (!ownership.OwnerElsewhere(id).empty()) throw ArgumentError(NotOwnerText(id));
    throw ArgumentError("unknown actuator \"" + id + "\"");
  }
  return &it->second;
}

ActuatorState* Service::OwnedActuatorArgument(const nlohmann::json& args) {
  ActuatorState* state = ActuatorArgument(args, true);
  if (!state->owned) throw ArgumentError(NotOwnerText(state->info.id));
  return state;
}

RpcOutcome Service::RpcStatus(const flexid::rpc_request_t&, const nlohmann::json&) {
  const Counters c = Snapshot();
  // A source that starts again (flexid-rig) continues its message time after this one,
  // so that flexidd does not see its clock jump back: the latest sample seen since the
  // start, or stored before it (after a restart); null with neither.
  const int64_t latest_utime = std::max(LatestMessageUtime(), stored_latest_utime);
  // Several daemons (daemon/ownership.h): what this one records, and whom it heard.
  nlohmann::json owned = nlohmann::json::array();
  for (const auto& [id, state] : actuators)
    if (state.owned) owned.push_back(id);
  nlohmann::json peers = nlohmann::json::array();
  const int64_t now_utime = bus::WallClockUtime();
  for (const PeerHeard& peer : ownership.Announce(now_utime).peers)
    peers.push_back({{"daemon_id", peer.daemon_id},
                     {"last_heard_s", 1e-6 * static_cast<double>(now_utime - peer.heard_utime)}});
  return {ReplyStatus::kOk,
          {{"daemon_id", config.daemon_id},
           {"version", kVersion},
           {"database", config.database},
           {"messages_received", c.messages_received},
           {"samples_accepted", c.samples_accepted},
           {"samples_stored", c.samples_stored},
           {"rejected_malformed", c.rejected_malformed},
           {"rejected_nonfinite", c.rejected_nonfinite},
           {"rejected_out_of_order", c.rejected_out_of_order},
           {"rejected_unknown_actuator", c.rejected_unknown_actuator},
           {"dropped_queue_full", c.dropped_queue_full},
           {"predictions_published", c.predictions_published},
           {"alerts_raised", c.alerts_raised},
           {"alerts_dropped", c.alerts_dropped},
           {"writes_queued", writer->writes_queued()},
           {"requests_refused_unauthorized", c.refused_unauthorized},
           {"samples_not_owned", c.samples_not_owned},
           {"announcements_heard", counters.announcements_heard.load(std::memory_order_relaxed)},
           {"owned_actuators", owned},
           {"peers", peers},
           {"identification_running", worker->busy()},
           {"latest_utime",
            latest_utime == kNoTime ? nlohmann::json(nullptr) : nlohmann::json(latest_utime)}},
          "",
          false};
}

RpcOutcome Service::RpcActuators(const flexid::rpc_request_t&, const nlohmann::json&) {
  // Who records it: this daemon, another one it heard claim it, or none (null).
  auto OwnerJson = [this](const std::string& id, const ActuatorState& state) {
    const std::string owner = state.owned ? config.daemon_id : ownership.OwnerElsewhere(id);
    return owner.empty() ? nlohmann::json(nullptr) : nlohmann::json(owner);
  };
  nlohmann::json list = nlohmann::json::array();
  for (const auto& [id, state] : actuators)
    list.push_back({{"id", id},
                    {"claim", ClaimName(ownership.ClaimOn(id))},
                    {"owner", OwnerJson(id, state)},
                    {"length_mm", state.info.length_mm},
                    {"width_mm", state.info.width_mm},
                    {"thickness_mm", state.info.thickness_mm},
                    {"material", state.info.material},
                    {"electrolyte", state.info.electrolyte},
                    {"concentration_M", state.info.concentration_M},
                    {"model_version", state.predictor.version},
                    {"trial", state.trial_id},
                    {"voltage_V", state.voltage_V}});
  return {ReplyStatus::kOk, list, "", false};
}

// trials, trial_samples, models, model and alerts: storage/queries.h answers them from the
// file, as `flexid --db` does.
RpcOutcome Service::RpcStoredQuery(const flexid::rpc_request_t& request,
                                   const nlohmann::json& args) {
  try {
    return {ReplyStatus::kOk, storage::AnswerQuery(db, request.method, args), "", false};
  } catch (const storage::QueryError& e) {
    return {e.kind == storage::QueryError::Kind::kNotFound ? ReplyStatus::kNotFound
                                                           : ReplyStatus::kBadRequest,
            nullptr, e.what(), false};
  }
}

RpcOutcome Service::RpcModelActivate(const flexid::rpc_request_t& request,
                                     const nlohmann::json& args) {
  ActuatorState* state = OwnedActuatorArgument(args);
  const auto version = static_cast<int32_t>(RequiredIntegerArgument(args, "version", 1, INT32_MAX));
  const auto record = db.FindModel(state->info.id, version);
  if (!record) return {ReplyStatus::kNotFound, nullptr, "no such model version", false};
  try {
    PredictorOf(record->model_json, record->version, false);  // it must run live
  } catch (const model::InputError& e) {
    return {ReplyStatus::kBadRequest, nullptr, e.what(), false};
  }
  // A proposal is its parent with effects: once another version is active, it is stale
  // (its effects were fitted against a model no longer in use).
  const nlohmann::json lineage = storage::LineageJson(*record);
  const int64_t parent = lineage.is_object() ? lineage.value("parent_version", int64_t{0}) : 0;
  if (parent > 0 && !record->active) {
    const auto active = db.ActiveModel(state->info.id);
    if (!active || active->version != parent)
      return {ReplyStatus::kBadRequest, nullptr,
              "version " + std::to_string(version) + " is a proposal on version " +
                  std::to_string(parent) + ", but " +
                  (active ? "version " + std::to_string(active->version) + " is active"
                          : std::string("no version is active")) +
                  ": diagnose again against the active model",
              false};
  }
  // Swapped in once the writer has made it the active one.
  return ReplyWhenWritten(
      Store(storage::ModelActivation{state->info.id, version}), request,
      {ReplyStatus::kOk, {{"actuator", state->info.id}, {"version", version}}, ""},
      [this, actuator = state->info.id, record = *record] {
        LoadModel(&actuators.at(actuator), record);
        AnnounceModel(&actuators.at(actuator), record);
      });
}

RpcOutcome Service::RpcTrialControl(const flexid::rpc_request_t& request,
                                    const nlohmann::json& args) {
  ActuatorState* state = OwnedActuatorArgument(args);
  const int64_t now =
      state->voltage_utime != kNoTime ? state->voltage_utime : bus::WallClockUtime();
  if (request.method == "trial_start") {
    const std::string fallback = "manual";
    const std::string protocol = StringArgument(args, "protocol", &fallback);
    if (state->trial_id != 0) StopTrial(state, now, storage::TrialState::kComplete);
    const uint64_t ticket = StartTrial(state, protocol, now, false);
    return ReplyWhenWritten(
        ticket, request,
        {ReplyStatus::kOk, {{"actuator", state->info.id}, {"trial", state->trial_id}}, ""});
  }
  if (state->trial_id == 0)
    return {ReplyStatus::kNotFound, nullptr, state->info.id + " has no trial recording", false};
  // Answered once the end is written; the trial's samples are committed within one
  // commit interval, under its id (waiting for them would block the loop).
  const int64_t id = state->trial_id;
  const uint64_t ticket = StopTrial(state, now, storage::TrialState::kComplete);
  return ReplyWhenWritten(ticket, request,
                          {ReplyStatus::kOk, {{"actuator", state->info.id}, {"trial", id}}, ""});
}

RpcOutcome Service::RpcIdentify(const flexid::rpc_request_t& request, const nlohmann::json& args) {
  ActuatorState* state = OwnedActuatorArgument(args);
  std::vector<int64_t> trials;
  if (args.contains("trials")) {
    for (int64_t id : TrialIdsArgument(args, "trials", 100)) {
      const auto trial = db.FindTrial(id);
      if (!trial || trial->actuator_id != state->info.id)
        return {ReplyStatus::kNotFound, nullptr,
                "no trial " + std::to_string(id) + " of " + state->info.id, false};
      trials.push_back(trial->id);
    }
  } else {
    const auto latest =
        IntegerArgument(args, "latest", config.identification.latest_trials, 1, 100);
    // Only trials long enough to identify from (model::MinimumSamplesToIdentify, at the
    // trial's own sample period).
    const IdentificationConfig& ic = config.identification;
    auto long_enough = [&ic](const storage::Trial& t) {
      if (t.samples < 2 || t.end_utime <= t.start_utime) return false;
      const double dt_s = 1e-6 * static_cast<double>(t.end_utime - t.start_utime) /
                          static_cast<double>(t.samples - 1);
      return static_cast<size_t>(t.samples) >=
             model::MinimumSamplesToIdentify(ic.zeros + ic.poles + 2, ic.max_delay_s, dt_s);
    };
    for (const storage::Trial& t : db.Trials(state->info.id, 1000)) {
      if (t.state == storage::TrialState::kRecording || !long_enough(t)) continue;
      trials.push_back(t.id);
      if (static_cast<int64_t>(trials.size()) == latest) break;
    }
    if (trials.empty())
      return {ReplyStatus::kNotFound, nullptr,
              state->info.id + " has no finished trial long enough to identify from", false};
  }
  storage::SampleWriter* samples = writer.get();  // flushed on the worker: Flush() blocks
  const std::string database = config.database, id = state->info.id;
  const IdentificationConfig options = config.identification;
  const RpcContext context{request.request_id, request.client_id};
  if (!worker->Submit([database, id, trials, options, context, samples] {
        if (!samples->Flush())  // the worker reads what is committed
          return IdentificationResult{
              {context, id, "cannot commit samples: " + samples->last_error()}};
        return RunIdentification(database, id, trials, options, context);
      }))
    return {ReplyStatus::kBusy, nullptr,
            "an identification is already running; try again when it ends", false};
  spdlog::info("identification started [actuator: {}, trials: {}]", id,
               nlohmann::json(trials).dump());
  return {ReplyStatus::kOk, nullptr, "", true};
}

RpcOutcome Service::RpcDiagnose(const flexid::rpc_request_t& request, const nlohmann::json& args) {
  ActuatorState* state = OwnedActuatorArgument(args);
  // "trial": one; "trials": several, in the order given; "recent": the latest K
  // finished ones, oldest first; none: the latest finished one.
  if (args.contains("trial") + args.contains("trials") + args.contains("recent") > 1)
    throw ArgumentError("give one of \"trial\", \"trials\" and \"recent\"");
  std::vector<int64_t> trial_ids;
  if (args.contains("trial"))
    trial_ids = {RequiredIntegerArgument(args, "trial", 1, std::numeric_limits<int64_t>::max())};
  else if (args.contains("trials"))
    trial_ids = TrialIdsArgument(args, "trials", model::kMaxDiagnosedRecordings);
  for (int64_t trial_id : trial_ids) {
    const auto trial = db.FindTrial(trial_id);
    if (!trial || trial->actuator_id != state->info.id)
      return {ReplyStatus::kNotFound, nullptr,
              "no trial " + std::to_string(trial_id) + " of " + state->info.id, false};
  }
  if (trial_ids.empty()) {
    const int64_t recent = IntegerArgument(args, "recent", 1, 1, model::kMaxDiagnosedRecordings);
    for (const storage::Trial& t : db.Trials(state->info.id, 1000))
      if (t.state != storage::TrialState::kRecording && t.samples >= 200 &&
          static_cast<int64_t>(trial_ids.size()) < recent)
        trial_ids.insert(trial_ids.begin(), t.id);
    if (trial_ids.empty())
      return {ReplyStatus::kNotFound, nullptr,
              state->info.id + " has no finished trial to diagnose", false};
  }
  DiagnosisJob job{config.database, state->info.id, trial_ids,
                   BoolArgument(args, "use_model", true),
                   config.identification.max_diagnosis_samples};
  if (BoolArgument(args, "propose", false)) job.propose_by = "diagnose";
  if (!SubmitDiagnosis(job, {request.request_id, request.client_id}))
    return {ReplyStatus::kBusy, nullptr,
            "an identification or diagnosis is already running; try again when it ends", false};
  return {ReplyStatus::kOk, nullptr, "", true};
}

bool Service::SubmitDiagnosis(const DiagnosisJob& job, const RpcContext& context) {
  storage::SampleWriter* samples = writer.get();
  if (!worker->Submit([job, context, samples] {
        if (!samples->Flush()) {
          DiagnosisResult failed;
          failed.request = context;
          failed.actuator_id = job.actuator_id;
          failed.error = "cannot commit samples: " + samples->last_error();
          failed.trial_ids = job.trial_ids;
          return failed;
        }
        return RunDiagnosis(job, context);
      }))
    return false;
  spdlog::info("diagnosis started [actuator: {}, trials: {}, propose: {}]", job.actuator_id,
               nlohmann::json(job.trial_ids).dump(),
               job.propose_by.empty() ? "no" : job.propose_by);
  return true;
}

}  // namespace flexid::daemon
