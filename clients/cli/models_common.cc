// The helpers the `flexid models` subcommands share (models_common.h).
#include "clients/cli/models_common.h"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "model/core/model_file.h"

namespace flexid::cli::models {

std::string IsoUtc(int64_t utime) {
  const std::time_t seconds = static_cast<std::time_t>(utime / 1'000'000);
  std::tm tm{};
  if (utime <= 0 || gmtime_r(&seconds, &tm) == nullptr) return "-";
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return text;
}

std::string JoinNumbers(const json& list, const std::string& separator) {
  if (!list.is_array() || list.empty()) return "-";
  std::string text;
  for (const json& v : list) {
    if (!text.empty()) text += separator;
    text += v.is_number_integer() ? std::to_string(v.get<int64_t>())
            : v.is_number()       ? FormatNumber(v.get<double>(), 4)
            : v.is_string()       ? v.get<std::string>()
                                  : std::string("?");
  }
  return text;
}

double NumberIn(const json& object, const char* key) {
  if (!object.is_object()) return NAN;
  const auto it = object.find(key);
  return it != object.end() && it->is_number() ? it->get<double>() : NAN;
}

std::string Cell(double value, int significant) {
  return std::isfinite(value) ? FormatNumber(value, significant) : "-";
}

int32_t ParseVersion(const std::string& text, const std::string& what) {
  std::string digits = text;
  if (text == "active") return 0;
  if (!digits.empty() && (digits[0] == 'v' || digits[0] == 'V')) digits.erase(0, 1);
  const bool ok =
      !digits.empty() && digits.size() <= 9 &&
      std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; });
  if (!ok)
    throw UsageError(what + ": expected a model version such as 3 (or v3, or active), got \"" +
                     text + "\"");
  return static_cast<int32_t>(std::stol(digits));
}

void RequireActuator(const std::string& actuator) {
  if (actuator.empty())
    throw UsageError("--actuator: an actuator id is needed, e.g. --actuator S1");
}

StoredVersion FetchVersion(const std::string& actuator, int32_t version) {
  json args = {{"actuator", actuator}};
  if (version != 0) args["version"] = version;
  json reply = Query("model", args);
  StoredVersion out;
  out.document = reply.at("model");
  reply.erase("model");
  out.summary = reply;
  out.name = actuator + " model v" + std::to_string(reply.value("version", version));
  out.doc = model::ParseModelJson(out.document.dump(), out.name);
  return out;
}

std::vector<Local> LocalsOf(const model::ModelDocument& doc) {
  std::vector<Local> out;
  if (doc.kind == model::ModelDocument::Kind::kTransferFunction) {
    out.push_back({NumberIn(doc.extra, "level_V"), doc.tf, doc.extra.value("fit", json())});
    return out;
  }
  for (size_t i = 0; i < doc.ts.rules.size(); ++i) {
    json fit;
    if (i < doc.local_extra.size() && doc.local_extra[i].is_object())
      fit = doc.local_extra[i].value("fit", json());
    out.push_back({doc.ts.rules[i].level_V, doc.ts.rules[i].tf, fit});
  }
  return out;
}

namespace {

const json* LineageIn(const json& summary) {
  if (!summary.is_object()) return nullptr;
  const auto it = summary.find("lineage");
  return it != summary.end() && it->is_object() ? &*it : nullptr;
}

std::string EffectNames(const json& lineage) {
  std::string names;
  const json effects = lineage.value("effects", json::array());
  for (const json& e : effects)
    if (e.is_object()) names += (names.empty() ? "" : ", ") + e.value("effect", std::string("?"));
  return names;
}

std::string Parent(const json& lineage) {
  const int64_t parent = lineage.value("parent_version", int64_t{0});
  return parent > 0 ? "v" + std::to_string(parent) : std::string("an identified baseline");
}

}  // namespace

std::string LineageShort(const json& summary) {
  const json* lineage = LineageIn(summary);
  if (!lineage) return "";
  return Parent(*lineage) + " + " + EffectNames(*lineage) + ", " +
         Cell(NumberIn(*lineage, "heldout_gain"), 2) + "x";
}

std::string LineageLong(const json& summary) {
  const json* lineage = LineageIn(summary);
  if (!lineage) return "";
  std::string effects;
  const json effect_list = lineage->value("effects", json::array());
  for (const json& e : effect_list) {
    if (!e.is_object()) continue;
    std::string params;
    const json params_json = e.value("params", json::object());
    if (!params_json.is_object()) continue;
    for (const auto& [name, p] : params_json.items()) {
      params += (params.empty() ? "" : ", ") + name + " " + Cell(NumberIn(p, "value"), 3);
      const double half_width = NumberIn(p, "half_width_95");
      params += std::isfinite(half_width) ? " +- " + Cell(half_width, 2) : " (undetermined)";
    }
    effects +=
        (effects.empty() ? "" : "; ") + e.value("effect", std::string("?")) + " (" + params + ")";
  }
  return "proposed on " + Parent(*lineage) + " by " +
         lineage->value("proposed_by", std::string("?")) + " from trials " +
         JoinNumbers(lineage->value("trials", json())) + ": " + effects + "; held-out RMSE " +
         Cell(NumberIn(*lineage, "heldout_rmse_before_mm"), 3) + " -> " +
         Cell(NumberIn(*lineage, "heldout_rmse_after_mm"), 3) + " mm, " +
         Cell(NumberIn(*lineage, "heldout_gain"), 2) + " times smaller";
}

}  // namespace flexid::cli::models
