// The "models" RPC's rows as the page shows them (model_versions.h). Every field is
// checked before it is copied: the reply comes from the bus.
#include "clients/dashboard/model_versions.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <set>
#include <stdexcept>

#include "clients/dashboard/live_store.h"

namespace flexid::dashboard {
namespace {

using nlohmann::json;

// Names (effects, parameters, proposers) longer than this are not names.
constexpr size_t kMaxNameLength = 64;
// More effects or parameters than this in one proposal is not a proposal.
constexpr size_t kMaxEffects = 16;
constexpr size_t kMaxParams = 16;

// A row's field that is not what it should be; `what` names it ("row 2 (version 4):
// lineage.parent_version: expected an integer >= 1"), thrown only within this file.
struct FieldError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

const json* Member(const json& object, const char* key) {
  const auto it = object.find(key);
  return it == object.end() || it->is_null() ? nullptr : &*it;
}

double Rounded(double x) { return RoundSignificant(x, 4); }

class RowReader {
 public:
  explicit RowReader(std::string where) : where_(std::move(where)) {}

  [[noreturn]] void Fail(const std::string& field, const std::string& expected) const {
    throw FieldError(where_ + ": " + field + ": expected " + expected);
  }

  int64_t Integer(const json& object, const char* key, const std::string& field, int64_t min,
                  int64_t max) const {
    const json* v = Member(object, key);
    if (!v || !v->is_number_integer()) Fail(field, "an integer");
    const int64_t value = v->is_number_unsigned() && v->get<uint64_t>() > INT64_MAX
                              ? std::numeric_limits<int64_t>::max()
                              : v->get<int64_t>();
    if (value < min || value > max)
      Fail(field, "an integer from " + std::to_string(min) + " to " + std::to_string(max) +
                      " (got " + std::to_string(value) + ")");
    return value;
  }

  // A finite number >= min, or null when missing or null.
  json OptionalNumber(const json& object, const char* key, const std::string& field,
                      double min) const {
    const json* v = Member(object, key);
    if (!v) return nullptr;
    if (!v->is_number() || !std::isfinite(v->get<double>()) || v->get<double>() < min)
      Fail(field, min == 0.0 ? "a finite number >= 0" : "a finite number");
    return Rounded(v->get<double>());
  }

  // 1 to kMaxNameLength characters.
  std::string Name(const json& object, const char* key, const std::string& field) const {
    const json* v = Member(object, key);
    if (!v || !v->is_string() || v->get_ref<const std::string&>().empty() ||
        v->get_ref<const std::string&>().size() > kMaxNameLength)
      Fail(field, "a name of 1 to " + std::to_string(kMaxNameLength) + " characters");
    return v->get<std::string>();
  }

  // An array of trial ids (missing or null: empty).
  json Trials(const json& object, const std::string& field) const {
    json out = json::array();
    const json* v = Member(object, "trials");
    if (!v) return out;
    if (!v->is_array()) Fail(field, "an array of trial ids");
    for (const json& id : *v) {
      if (!id.is_number_integer() || id.get<int64_t>() < 1) Fail(field, "trial ids >= 1");
      out.push_back(id);
    }
    return out;
  }

  json Params(const json& effect, const std::string& field) const {
    json out = json::object();
    const json* params = Member(effect, "params");
    if (!params) return out;
    if (!params->is_object() || params->size() > kMaxParams)
      Fail(field, "an object of at most " + std::to_string(kMaxParams) + " parameters");
    for (const auto& [name, param] : params->items()) {
      const std::string at = field + "." + name;
      if (name.empty() || name.size() > kMaxNameLength) Fail(at, "a parameter name");
      if (param.is_number()) {  // a bare value, without an interval
        if (!std::isfinite(param.get<double>())) Fail(at, "a finite number");
        out[name] = {{"value", Rounded(param.get<double>())}, {"half_width_95", nullptr}};
        continue;
      }
      if (!param.is_object()) Fail(at, "{\"value\", \"half_width_95\"}");
      const json value = OptionalNumber(param, "value", at + ".value", -HUGE_VAL);
      if (value.is_null()) Fail(at + ".value", "a finite number");
      out[name] = {
          {"value", value},
          {"half_width_95", OptionalNumber(param, "half_width_95", at + ".half_width_95", 0.0)}};
    }
    return out;
  }

  json Lineage(const json& row, int64_t version) const {
    const json* lineage = Member(row, "lineage");
    if (!lineage) return nullptr;  // identified, or a flexidd from before lineages
    if (!lineage->is_object()) Fail("lineage", "null or an object");
    const json& in = *lineage;
    // 0: no model was active; the baseline was identified on the diagnosed trials.
    json out = {{"parent_version",
                 Integer(in, "parent_version", "lineage.parent_version", 0, version - 1)}};
    out["proposed_by"] =
        Member(in, "proposed_by") ? json(Name(in, "proposed_by", "lineage.proposed_by")) : json();
    out["trials"] = Trials(in, "lineage.trials");
    json effects = json::array();
    if (const json* list = Member(in, "effects")) {
      if (!list->is_array() || list->size() > kMaxEffects)
        Fail("lineage.effects", "an array of at most " + std::to_string(kMaxEffects) + " effects");
      for (size_t i = 0; i < list->size(); ++i) {
        const std::string at = "lineage.effects[" + std::to_string(i) + "]";
        const json& effect = (*list)[i];
        if (!effect.is_object()) Fail(at, "an object with \"effect\"");
        effects.push_back({{"effect", Name(effect, "effect", at + ".effect")},
                           {"params", Params(effect, at + ".params")}});
      }
    }
    out["effects"] = std::move(effects);
    const json before =
        OptionalNumber(in, "heldout_rmse_before_mm", "lineage.heldout_rmse_before_mm", 0.0);
    const json after =
        OptionalNumber(in, "heldout_rmse_after_mm", "lineage.heldout_rmse_after_mm", 0.0);
    json gain = OptionalNumber(in, "heldout_gain", "lineage.heldout_gain", 0.0);
    if (gain.is_null() && before.is_number() && after.is_number() && after.get<double>() > 0.0)
      gain = Rounded(before.get<double>() / after.get<double>());
    out["heldout_rmse_before_mm"] = before;
    out["heldout_rmse_after_mm"] = after;
    out["heldout_gain"] = gain;
    return out;
  }

  json Fit(const json& row) const {
    const json* fit = Member(row, "fit");
    if (!fit) return nullptr;
    if (!fit->is_object()) Fail("fit", "null or an object");
    return {{"fit_percent", OptionalNumber(*fit, "fit_percent", "fit.fit_percent", -HUGE_VAL)},
            {"rmse_mm", OptionalNumber(*fit, "rmse_mm", "fit.rmse_mm", 0.0)}};
  }

 private:
  std::string where_;
};

json RowJson(const json& row, size_t index, const std::string& actuator_id) {
  const std::string row_name = "row " + std::to_string(index + 1);
  if (!row.is_object()) throw FieldError(row_name + ": expected an object");
  if (const json* actuator = Member(row, "actuator");
      actuator && (!actuator->is_string() || actuator->get<std::string>() != actuator_id))
    throw FieldError(row_name + ": actuator: expected \"" + actuator_id + "\" (got " +
                     actuator->dump() + ")");
  const int64_t version = RowReader(row_name).Integer(row, "version", "version", 1,
                                                      std::numeric_limits<int32_t>::max());
  const RowReader read(row_name + " (version " + std::to_string(version) + ")");
  const json* active = Member(row, "active");
  if (!active || !active->is_boolean()) read.Fail("active", "true or false");
  json created = nullptr;
  if (Member(row, "created_utime"))
    created =
        read.Integer(row, "created_utime", "created_utime", 0, std::numeric_limits<int64_t>::max());
  return {{"version", version},       {"active", *active},
          {"created_utime", created}, {"trials", read.Trials(row, "trials")},
          {"fit", read.Fit(row)},     {"lineage", read.Lineage(row, version)}};
}

}  // namespace

std::optional<json> ModelVersionsFromJson(const json& rpc_result, const std::string& actuator_id,
                                          std::string* error) {
  auto fail = [&](const std::string& why) -> std::optional<json> {
    if (error) *error = why;
    return std::nullopt;
  };
  if (!rpc_result.is_array()) return fail("expected an array of model versions");
  json rows = json::array();
  std::set<int64_t> versions;
  int64_t active_version = 0;
  try {
    for (size_t i = 0; i < rpc_result.size(); ++i) {
      json row = RowJson(rpc_result[i], i, actuator_id);
      const int64_t version = row["version"].get<int64_t>();
      if (!versions.insert(version).second)
        return fail("row " + std::to_string(i + 1) + ": version " + std::to_string(version) +
                    " appears twice");
      if (row["active"].get<bool>()) {
        if (active_version != 0)
          return fail("versions " + std::to_string(active_version) + " and " +
                      std::to_string(version) + " are both active");
        active_version = version;
      }
      rows.push_back(std::move(row));
    }
  } catch (const FieldError& e) {
    return fail(e.what());
  }
  std::sort(rows.begin(), rows.end(), [](const json& a, const json& b) {
    return a["version"].get<int64_t>() > b["version"].get<int64_t>();
  });
  return rows;
}

}  // namespace flexid::dashboard
