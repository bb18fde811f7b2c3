#include "daemon/config.h"

#include <toml++/toml.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <set>
#include <sstream>

#include "bus/channels.h"
#include "bus/ids.h"

namespace flexid::daemon {
namespace {

[[noreturn]] void Fail(const std::string& where, const std::string& problem) {
  throw ConfigError(where + ": " + problem);
}

void CheckKeys(const toml::table& table, const std::set<std::string>& known,
               const std::string& where) {
  for (const auto& [key, value] : table) {
    (void)value;
    if (!known.count(std::string(key.str())))
      Fail(where, "unknown setting \"" + std::string(key.str()) + "\"");
  }
}

template <typename T>
void Read(const toml::table& table, const char* key, const std::string& where, T* out) {
  const toml::node* node = table.get(key);
  if (!node) return;
  if constexpr (std::is_same_v<T, bool>) {
    if (!node->is_boolean()) Fail(where + "." + key, "expected true or false");
    *out = **node->as_boolean();
  } else if constexpr (std::is_same_v<T, std::string>) {
    if (!node->is_string()) Fail(where + "." + key, "expected a string");
    *out = **node->as_string();
  } else if constexpr (std::is_integral_v<T>) {
    if (!node->is_integer()) Fail(where + "." + key, "expected an integer");
    const int64_t value = **node->as_integer();
    // No silent wrap-around: commit_interval_ms = 4294967297 must not read as 1.
    if (value < static_cast<int64_t>(std::numeric_limits<T>::min()) ||
        value > static_cast<int64_t>(std::numeric_limits<T>::max()))
      Fail(where + "." + key, "integer out of range");
    *out = static_cast<T>(value);
  } else {
    if (node->is_integer())
      *out = static_cast<T>(**node->as_integer());
    else if (node->is_floating_point())
      *out = static_cast<T>(**node->as_floating_point());
    else
      Fail(where + "." + key, "expected a number");
  }
}

}  // namespace

Config LoadConfigFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) Fail(path, std::string("cannot open: ") + std::strerror(errno));
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) Fail(path, "cannot read");
  return ParseConfigText(text.str(), path);
}

Config ParseConfigText(std::string_view text, const std::string& path) {
  toml::table root;
  try {
    root = toml::parse(text, path);
  } catch (const toml::parse_error& e) {
    std::ostringstream where;
    where << path << ":" << e.source().begin.line << ":" << e.source().begin.column;
    Fail(where.str(), std::string(e.description()));
  }
  Config c;
  CheckKeys(root,
            {"daemon_id",
             "database",
             "lcm_url",
             "channel_prefix",
             "log_file",
             "log_level",
             "commit_interval_ms",
             "auto_trials",
             "trial_idle_stop_s",
             "accept_unknown_actuators",
             "ownership_wait_s",
             "max_message_bytes",
             "pin_threads",
             "auth_key_file",
             "auth_window_s",
             "actuators",
             "identification",
             "policy",
             "alerts",
             "health"},
            path);
  Read(root, "daemon_id", path, &c.daemon_id);
  Read(root, "database", path, &c.database);
  Read(root, "lcm_url", path, &c.lcm_url);
  Read(root, "channel_prefix", path, &c.channel_prefix);
  Read(root, "log_file", path, &c.log_file);
  Read(root, "log_level", path, &c.log_level);
  Read(root, "commit_interval_ms", path, &c.commit_interval_ms);
  Read(root, "auto_trials", path, &c.auto_trials);
  Read(root, "trial_idle_stop_s", path, &c.trial_idle_stop_s);
  Read(root, "accept_unknown_actuators", path, &c.accept_unknown_actuators);
  Read(root, "ownership_wait_s", path, &c.ownership_wait_s);
  Read(root, "max_message_bytes", path, &c.max_message_bytes);
  Read(root, "pin_threads", path, &c.pin_threads);
  Read(root, "auth_key_file", path, &c.auth_key_file);
  Read(root, "auth_window_s", path, &c.auth_window_s);
  if (const toml::table* id = root["identification"].as_table()) {
    const std::string where = path + ": identification";
    CheckKeys(*id,
              {"method", "zeros", "poles", "max_delay_s", "latest_trials", "max_diagnosis_samples"},
              where);
    Read(*id, "method", where, &c.identification.method);
    c.identification.orders_given = id->contains("zeros") || id->contains("poles");
    Read(*id, "zeros", where, &c.identification.zeros);
    Read(*id, "poles", where, &c.identification.poles);
    Read(*id, "max_delay_s", where, &c.identification.max_delay_s);
    Read(*id, "latest_trials", where, &c.identification.latest_trials);
    Read(*id, "max_diagnosis_samples", where, &c.identification.max_diagnosis_samples);
  }
  if (const toml::table* policy = root["policy"].as_table()) {
    const std::string where = path + ": policy";
    CheckKeys(*policy, {"on_alert", "adopt_min_gain", "min_interval_s"}, where);
    Read(*policy, "on_alert", where, &c.policy.on_alert);
    Read(*policy, "adopt_min_gain", where, &c.policy.adopt_min_gain);
    Read(*policy, "min_interval_s", where, &c.policy.min_interval_s);
  }
  if (const toml::table* alerts = root["alerts"].as_table()) {
    const std::string where = path + ": alerts";
    CheckKeys(*alerts,
              {"false_alarms_per_hour", "noise_mm", "min_hold_s", "settle_s", "min_effect_mm",
               "dropout_s", "rest_band_V", "sigma_floor_mm"},
              where);
    Read(*alerts, "false_alarms_per_hour", where, &c.alerts.false_alarms_per_hour);
    Read(*alerts, "noise_mm", where, &c.alerts.noise_mm);
    Read(*alerts, "min_hold_s", where, &c.alerts.min_hold_s);
    Read(*alerts, "settle_s", where, &c.alerts.settle_s);
    Read(*alerts, "min_effect_mm", where, &c.alerts.min_effect_mm);
    Read(*alerts, "dropout_s", where, &c.alerts.dropout_s);
    Read(*alerts, "rest_band_V", where, &c.alerts.rest_band_V);
    Read(*alerts, "sigma_floor_mm", where, &c.alerts.sigma_floor_mm);
  }
  if (const toml::table* health = root["health"].as_table()) {
    const std::string where = path + ": health";
    CheckKeys(*health,
              {"input_silence_s", "input_silence_stop_s", "clock_jump_back_s",
               "clock_jump_forward_s", "clock_jump_messages", "writer_queue_samples"},
              where);
    Read(*health, "input_silence_s", where, &c.health.input_silence_s);
    Read(*health, "input_silence_stop_s", where, &c.health.input_silence_stop_s);
    Read(*health, "clock_jump_back_s", where, &c.health.clock_jump_back_s);
    Read(*health, "clock_jump_forward_s", where, &c.health.clock_jump_forward_s);
    Read(*health, "clock_jump_messages", where, &c.health.clock_jump_messages);
    Read(*health, "writer_queue_samples", where, &c.health.writer_queue_samples);
  }
  if (const toml::array* actuators = root["actuators"].as_array()) {
    for (size_t i = 0; i < actuators->size(); ++i) {
      const std::string where = path + ": actuators[" + std::to_string(i) + "]";
      const toml::table* a = (*actuators)[i].as_table();
      if (!a) Fail(where, "expected a table");
      CheckKeys(*a,
                {"id", "length_mm", "width_mm", "thickness_mm", "pattern", "material",
                 "electrolyte", "concentration_M"},
                where);
      storage::Actuator actuator;
      Read(*a, "id", where, &actuator.id);
      Read(*a, "length_mm", where, &actuator.length_mm);
      Read(*a, "width_mm", where, &actuator.width_mm);
      Read(*a, "thickness_mm", where, &actuator.thickness_mm);
      Read(*a, "pattern", where, &actuator.pattern);
      Read(*a, "material", where, &actuator.material);
      Read(*a, "electrolyte", where, &actuator.electrolyte);
      Read(*a, "concentration_M", where, &actuator.concentration_M);
      c.actuators.push_back(actuator);
    }
  } else if (root.contains("actuators")) {
    Fail(path + ": actuators", "expected an array of tables ([[actuators]])");
  }
  return c;
}

void Validate(const Config& c) {
  // The daemon id follows the prefix's rule: it names this instance in replies and logs.
  if (!bus::IsValidPrefix(c.daemon_id))
    Fail("daemon_id",
         std::string("expected ") + bus::kPrefixRule + " (got \"" + c.daemon_id + "\")");
  if (c.database.empty()) Fail("database", "must not be empty");
  if (c.lcm_url.empty()) Fail("lcm_url", "must not be empty");
  if (!bus::IsValidPrefix(c.channel_prefix))
    Fail("channel_prefix",
         std::string("expected ") + bus::kPrefixRule + " (got \"" + c.channel_prefix + "\")");
  if (c.commit_interval_ms < 1 || c.commit_interval_ms > 200)
    Fail("commit_interval_ms", "must be 1..200 (DESIGN.md: loss window <= 200 ms)");
  if (!(c.trial_idle_stop_s > 0.0) || !std::isfinite(c.trial_idle_stop_s))
    Fail("trial_idle_stop_s", "must be finite and > 0");
  if (!(c.ownership_wait_s >= 0.0 && c.ownership_wait_s <= 60.0))
    Fail("ownership_wait_s", "must be 0 .. 60 seconds");
  if (c.max_message_bytes < 256 || c.max_message_bytes > (64 << 20))
    Fail("max_message_bytes", "must be 256 .. 64 MiB");
  if (!(c.auth_window_s >= 1.0 && c.auth_window_s <= 3600.0))
    Fail("auth_window_s", "must be 1 .. 3600 seconds");
  static const std::set<std::string> levels = {"trace", "debug", "info", "warn", "error"};
  if (!levels.count(c.log_level)) Fail("log_level", "expected trace, debug, info, warn or error");
  const IdentificationConfig& id = c.identification;
  if (id.method != "global" && id.method != "time")
    Fail("identification.method", "expected global or time, got \"" + id.method + "\"");
  if (id.poles < 1 || id.poles > 8 || id.zeros < 0 || id.zeros >= id.poles)
    Fail("identification", "need 1 <= poles <= 8 and 0 <= zeros < poles");
  if (!(id.max_delay_s >= 0.0) || !std::isfinite(id.max_delay_s))
    Fail("identification.max_delay_s", "must be finite and >= 0");
  if (id.latest_trials < 1) Fail("identification.latest_trials", "must be >= 1");
  if (id.max_diagnosis_samples < 200)
    Fail("identification.max_diagnosis_samples", "must be >= 200 (a diagnosis needs 200 samples)");
  const PolicyConfig& p = c.policy;
  if (p.on_alert != "none" && p.on_alert != "diagnose" && p.on_alert != "propose" &&
      p.on_alert != "adopt")
    Fail("policy.on_alert",
         "expected none, diagnose, propose or adopt, got \"" + p.on_alert + "\"");
  if (!(p.adopt_min_gain >= 1.0) || !std::isfinite(p.adopt_min_gain))
    Fail("policy.adopt_min_gain", "must be finite and >= 1 (held-out RMSE before / after)");
  if (!(p.min_interval_s >= 0.0) || !std::isfinite(p.min_interval_s))
    Fail("policy.min_interval_s", "must be finite and >= 0");
  std::string why;
  if (!c.alerts.IsValid(&why)) Fail("alerts", why);
  const HealthConfig& h = c.health;
  auto positive = [](double v) { return v > 0.0 && std::isfinite(v); };
  if (!positive(h.input_silence_s)) Fail("health.input_silence_s", "must be finite and > 0");
  if (!(h.input_silence_stop_s == 0.0 ||
        (positive(h.input_silence_stop_s) && h.input_silence_stop_s >= h.input_silence_s)))
    Fail("health.input_silence_stop_s", "must be 0 (never) or >= input_silence_s");
  if (!positive(h.clock_jump_back_s) || !positive(h.clock_jump_forward_s))
    Fail("health", "clock_jump_back_s and clock_jump_forward_s must be finite and > 0");
  if (h.clock_jump_messages < 1 || h.clock_jump_messages > 10000)
    Fail("health.clock_jump_messages", "must be 1..10000");
  if (h.writer_queue_samples < 100 || h.writer_queue_samples > (int64_t{1} << 26))
    Fail("health.writer_queue_samples", "must be 100 .. 2^26");
  std::set<std::string> seen;
  for (const storage::Actuator& a : c.actuators) {
    if (!bus::IsValidId(a.id)) Fail("actuators", "id \"" + a.id + "\": expected " + bus::kIdRule);
    if (!seen.insert(a.id).second) Fail("actuators", "id \"" + a.id + "\" appears twice");
    for (double v : {a.length_mm, a.width_mm, a.thickness_mm})
      if (!(v > 0.0) || !std::isfinite(v))
        Fail("actuators." + a.id, "dimensions must be finite and > 0");
  }
}

std::string KeyFilePath(const Config& c) {
  if (!c.auth_key_file.empty()) return c.auth_key_file;
  return (std::filesystem::path(c.database).parent_path() / "flexidd.key").string();
}

std::vector<std::string> Describe(const Config& c) {
  std::vector<std::string> lines = {
      "daemon_id: " + c.daemon_id,
      "database: " + c.database,
      "lcm_url: " + c.lcm_url,
      "channel_prefix: " + c.channel_prefix,
      "log_file: " + c.log_file + " (level " + c.log_level + ")",
      "commit_interval_ms: " + std::to_string(c.commit_interval_ms),
      "auto_trials: " + std::string(c.auto_trials ? "true" : "false") +
          ", trial_idle_stop_s: " + std::to_string(c.trial_idle_stop_s),
      "accept_unknown_actuators: " + std::string(c.accept_unknown_actuators ? "true" : "false") +
          ", ownership_wait_s: " + std::to_string(c.ownership_wait_s),
      "max_message_bytes: " + std::to_string(c.max_message_bytes) +
          ", pin_threads: " + std::string(c.pin_threads ? "true" : "false"),
      "auth_key_file: " + KeyFilePath(c) + ", auth_window_s: " + std::to_string(c.auth_window_s),
      "health: input_silence_s " + std::to_string(c.health.input_silence_s) +
          ", input_silence_stop_s " + std::to_string(c.health.input_silence_stop_s) +
          ", clock_jump_back_s " + std::to_string(c.health.clock_jump_back_s) +
          ", clock_jump_forward_s " + std::to_string(c.health.clock_jump_forward_s) +
          ", clock_jump_messages " + std::to_string(c.health.clock_jump_messages) +
          ", writer_queue_samples " + std::to_string(c.health.writer_queue_samples),
      "identification: method " + c.identification.method + ", zeros " +
          (c.identification.method == "global" && !c.identification.orders_given
               ? std::string("chosen")
               : std::to_string(c.identification.zeros)) +
          ", poles " +
          (c.identification.method == "global" && !c.identification.orders_given
               ? std::string("chosen")
               : std::to_string(c.identification.poles)) +
          ", max_delay_s " + std::to_string(c.identification.max_delay_s) + ", latest_trials " +
          std::to_string(c.identification.latest_trials) + ", max_diagnosis_samples " +
          std::to_string(c.identification.max_diagnosis_samples),
      "policy: on_alert " + c.policy.on_alert + ", adopt_min_gain " +
          std::to_string(c.policy.adopt_min_gain) + ", min_interval_s " +
          std::to_string(c.policy.min_interval_s),
      "alerts: false_alarms_per_hour " + std::to_string(c.alerts.false_alarms_per_hour) +
          ", min_hold_s " + std::to_string(c.alerts.min_hold_s) + ", settle_s " +
          std::to_string(c.alerts.settle_s) + ", dropout_s " + std::to_string(c.alerts.dropout_s) +
          ", sigma_floor_mm " + std::to_string(c.alerts.sigma_floor_mm)};
  for (const storage::Actuator& a : c.actuators) {
    std::ostringstream line;
    line << "actuator " << a.id << ": " << a.length_mm << " x " << a.width_mm << " x "
         << a.thickness_mm << " mm, " << a.material << ", " << a.electrolyte << " "
         << a.concentration_M << " M";
    lines.push_back(line.str());
  }
  return lines;
}

}  // namespace flexid::daemon
