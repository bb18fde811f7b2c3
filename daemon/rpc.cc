#include "daemon/rpc.h"

#include <algorithm>
#include <limits>
#include <regex>

#include "storage/queries.h"

namespace flexid::daemon {

nlohmann::json ParseArguments(const std::string& args_json) {
  if (args_json.empty()) return nlohmann::json::object();
  nlohmann::json args = nlohmann::json::parse(args_json, nullptr, /*allow_exceptions=*/false);
  if (args.is_discarded()) throw ArgumentError("args_json is not valid JSON");
  if (!args.is_object()) throw ArgumentError("args_json must be a JSON object");
  return args;
}

std::string StringArgument(const nlohmann::json& args, const char* name,
                           const std::string* fallback) {
  const auto it = args.find(name);
  if (it == args.end()) {
    if (fallback) return *fallback;
    throw ArgumentError(std::string("missing argument \"") + name + "\"");
  }
  if (!it->is_string() || it->get<std::string>().size() > 4096)
    throw ArgumentError(std::string("argument \"") + name +
                        "\" must be a string (at most 4096 characters)");
  return it->get<std::string>();
}

int64_t IntegerArgument(const nlohmann::json& args, const char* name, int64_t fallback, int64_t min,
                        int64_t max) {
  try {
    return storage::IntegerArgument(args, name, fallback, min, max);
  } catch (const storage::QueryError& e) {
    throw ArgumentError(e.what());
  }
}

int64_t RequiredIntegerArgument(const nlohmann::json& args, const char* name, int64_t min,
                                int64_t max) {
  if (!args.contains(name)) throw ArgumentError(std::string("missing argument \"") + name + "\"");
  return IntegerArgument(args, name, min, min, max);
}

bool BoolArgument(const nlohmann::json& args, const char* name, bool fallback) {
  const auto it = args.find(name);
  if (it == args.end()) return fallback;
  if (!it->is_boolean())
    throw ArgumentError(std::string("argument \"") + name + "\" must be true or false");
  return it->get<bool>();
}

std::vector<int64_t> TrialIdsArgument(const nlohmann::json& args, const char* name,
                                      size_t max_count) {
  const std::string what = std::string("argument \"") + name + "\" must be a list of 1-" +
                           std::to_string(max_count) + " distinct trial ids";
  const auto it = args.find(name);
  if (it == args.end() || !it->is_array() || it->empty() || it->size() > max_count)
    throw ArgumentError(what);
  std::vector<int64_t> ids;
  for (const auto& id : *it) {
    if (!id.is_number_integer() || id.get<int64_t>() < 1) throw ArgumentError(what);
    if (std::find(ids.begin(), ids.end(), id.get<int64_t>()) != ids.end())
      throw ArgumentError(what + " (" + std::to_string(id.get<int64_t>()) + " is given twice)");
    ids.push_back(id.get<int64_t>());
  }
  return ids;
}

std::string ArgumentSummary(const std::string& args_json) {
  std::string out = args_json.substr(0, 200);
  for (char& c : out)
    if (static_cast<unsigned char>(c) < 0x20 || c == 0x7f) c = '?';
  if (args_json.size() > 200) out += "...";
  return out;
}

}  // namespace flexid::daemon
