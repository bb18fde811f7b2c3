#include "storage/queries.h"

#include <limits>
#include <optional>
#include <vector>

#include "storage/record_json.h"

namespace flexid::storage {
namespace {

constexpr int64_t kInt64Min = std::numeric_limits<int64_t>::min();
constexpr int64_t kInt64Max = std::numeric_limits<int64_t>::max();

int64_t RequiredIntegerArgument(const nlohmann::json& args, const char* name, int64_t min,
                                int64_t max) {
  if (!args.contains(name)) throw QueryError(std::string("missing argument \"") + name + "\"");
  return IntegerArgument(args, name, min, min, max);
}

// The "actuator" argument, checked against the database; empty when absent and optional.
std::string ActuatorArgument(Database& db, const nlohmann::json& args, bool required) {
  const auto it = args.find("actuator");
  if (it == args.end() || (it->is_string() && it->get<std::string>().empty())) {
    if (required) throw QueryError("missing argument \"actuator\"");
    return "";
  }
  if (!it->is_string()) throw QueryError("argument \"actuator\" must be a string");
  const std::string id = it->get<std::string>();
  if (!db.FindActuator(id))
    throw QueryError("unknown actuator \"" + id + "\"", QueryError::Kind::kNotFound);
  return id;
}

std::optional<std::string> Filter(const std::string& id) {
  return id.empty() ? std::nullopt : std::optional<std::string>(id);
}

}  // namespace

int64_t IntegerArgument(const nlohmann::json& args, const char* name, int64_t fallback, int64_t min,
                        int64_t max) {
  const auto it = args.find(name);
  if (it == args.end()) return fallback;
  if (!it->is_number_integer())
    throw QueryError(std::string("argument \"") + name + "\" must be an integer");
  // JSON integers above INT64_MAX parse as unsigned; get<int64_t>() would wrap them.
  const bool above_int64 =
      it->is_number_unsigned() && it->get<uint64_t>() > static_cast<uint64_t>(kInt64Max);
  const int64_t value = above_int64 ? 0 : it->get<int64_t>();
  if (above_int64 || value < min || value > max)
    throw QueryError(std::string("argument \"") + name + "\" must be in [" + std::to_string(min) +
                     ", " + std::to_string(max) + "]");
  return value;
}

bool IsStoredQuery(const std::string& method) {
  return method == "trials" || method == "trial_samples" || method == "models" ||
         method == "model" || method == "alerts";
}

nlohmann::json AnswerQuery(Database& db, const std::string& method, const nlohmann::json& args) {
  if (!args.is_object()) throw QueryError("arguments must be a JSON object");
  if (method == "trials") {
    const std::string id = ActuatorArgument(db, args, false);
    nlohmann::json list = nlohmann::json::array();
    for (const Trial& t :
         db.Trials(Filter(id), static_cast<int>(IntegerArgument(args, "limit", 100, 1, 10000))))
      list.push_back(TrialJson(t));
    return list;
  }
  if (method == "trial_samples") {
    const int64_t id = RequiredIntegerArgument(args, "trial", 1, kInt64Max);
    const auto trial = db.FindTrial(id);
    if (!trial) throw QueryError("no trial " + std::to_string(id), QueryError::Kind::kNotFound);
    const int64_t offset = IntegerArgument(args, "offset", 0, 0, kInt64Max);
    const int64_t after = IntegerArgument(args, "after_utime", kInt64Min, kInt64Min, kInt64Max);
    const int64_t limit = IntegerArgument(args, "limit", 5000, 1, 20000);
    return SamplesPageJson(*trial, offset, db.SamplesPage(id, after, offset, limit));
  }
  if (method == "models") {
    nlohmann::json list = nlohmann::json::array();
    for (const ModelRecord& m : db.Models(ActuatorArgument(db, args, true)))
      list.push_back(ModelSummaryJson(m));
    return list;
  }
  if (method == "model") {
    const std::string id = ActuatorArgument(db, args, true);
    const auto version = static_cast<int32_t>(
        IntegerArgument(args, "version", 0, 0, std::numeric_limits<int32_t>::max()));
    const auto m = version == 0 ? db.ActiveModel(id) : db.FindModel(id, version);
    if (!m)
      throw QueryError(version == 0 ? id + " has no active model"
                                    : "no model version " + std::to_string(version) + " of " + id,
                       QueryError::Kind::kNotFound);
    nlohmann::json out = ModelSummaryJson(*m);
    out["model"] = nlohmann::json::parse(m->model_json);
    return out;
  }
  if (method == "alerts") {
    const std::string id = ActuatorArgument(db, args, false);
    nlohmann::json list = nlohmann::json::array();
    for (const AlertRecord& a :
         db.Alerts(Filter(id), IntegerArgument(args, "since_utime", 0, 0, kInt64Max),
                   static_cast<int>(IntegerArgument(args, "limit", 100, 1, 10000))))
      list.push_back(AlertJson(a));
    return list;
  }
  throw std::invalid_argument("\"" + method + "\" is not answered from the database alone");
}

}  // namespace flexid::storage
