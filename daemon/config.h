// flexidd's configuration: embedded defaults, then a TOML file, then command-line flags
// (DESIGN.md: "flags override the file; with no file it runs on the embedded defaults").
#pragma once

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "bus/channels.h"
#include "model/diagnose/monitor.h"
#include "storage/database.h"

namespace flexid::daemon {

// The residual monitor is pure logic and lives in model/ (model/diagnose/monitor.h).
using model::Alert;
using model::MonitorOptions;
using model::ResidualMonitor;

struct IdentificationConfig {
  // "global": the whole T-S model in one fit, its structure chosen on held-out data
  // (model/identify/identify_global.h), as `flexid identify` does; "time": a transfer function per
  // level, blended (model/identify/identify_ts.h).
  std::string method = "global";
  // Orders: "time" always uses them; "global" only when the configuration gives them,
  // and chooses them on held-out data otherwise.
  int zeros = 3;
  int poles = 4;
  bool orders_given = false;
  double max_delay_s = 10.0;
  int latest_trials = 2;  // "identify" without trial ids uses this many latest complete trials
  // A diagnosis request for a trial with more samples is refused (a no-model diagnosis of
  // 77,000 samples takes minutes on the worker thread, and memory grows with them).
  int64_t max_diagnosis_samples = 200000;
};

// What flexidd does when a trial that raised a residual or back-relaxation alert ends
// (README "Proposals"): "none"; "diagnose" it on the worker against the active model;
// "propose" the augmented model as a new inactive version; or "adopt" it (activate it)
// when its held-out gain (RMSE before / after) reaches adopt_min_gain, else propose it.
// At most one such diagnosis per actuator per min_interval_s (wall clock). Every step is
// an alert (kind "policy", or the diagnosis's own) and a log line.
struct PolicyConfig {
  std::string on_alert = "diagnose";
  double adopt_min_gain = 3.0;
  double min_interval_s = 600.0;
};

// How the daemon notices faults other than bad messages (daemon/health.h, README
// "Reliability so far"). Times of silence are wall-clock (steady) seconds: message time
// stops when the source does. Clock jumps are in message time.
struct HealthConfig {
  double input_silence_s = 5.0;          // an open trial's actuator sends nothing this long: alert
  double input_silence_stop_s = 60.0;    // ... this long: its trial ends "interrupted" (0: never)
  double clock_jump_back_s = 5.0;        // a source's utime going back at least this far, and
  double clock_jump_forward_s = 3600.0;  // forward (during a trial) this far, is a clock jump
  int clock_jump_messages = 10;  // once this many consecutive messages agree on the new time
  // Samples held in memory while the database cannot be written (queued for the writer);
  // beyond this, samples are dropped and counted (dropped_queue_full). 2^18: 32 s of
  // 16 actuators x 500 Hz.
  int64_t writer_queue_samples = 1 << 18;
};

struct Config {
  std::string daemon_id = "flexidd";
  std::string database = "var/flexid.db";
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  std::string channel_prefix = bus::kDefaultPrefix;  // bus/channels.h
  std::string log_file = "var/flexidd.log";
  std::string log_level = "info";
  int commit_interval_ms = 100;
  bool auto_trials = true;           // a trial starts when an idle actuator gets a non-zero voltage
  double trial_idle_stop_s = 300.0;  // an automatic trial stops after this long at 0 V
  bool accept_unknown_actuators = true;
  // Several daemons on one bus (docs/architecture.md, "Several daemons"): an actuator not
  // in the configuration is pending this long (its messages held, not dropped) while the
  // other daemons' claims on it are heard, at start-up and whenever other daemons are
  // about; 0 adopts it at once.
  double ownership_wait_s = 0.5;
  int64_t max_message_bytes = 65536;
  // Pin the loop and LCM's receive thread to CPU 0, and the sample writer and the
  // identification worker to the other CPUs. Keeps a fit from delaying predictions on a
  // small machine; leave it off when several daemons share a host.
  bool pin_threads = false;
  // Requests that change data are signed with the key in this file (README "Security");
  // empty: flexidd.key next to the database. Created (mode 0600) when absent; flexidd
  // refuses to start on a file group or others may read or write.
  std::string auth_key_file;
  // A signed request's time must be within this many seconds of flexidd's wall clock, and
  // its nonce is remembered this long (replay protection).
  double auth_window_s = 30.0;
  std::vector<storage::Actuator> actuators;
  IdentificationConfig identification;
  PolicyConfig policy;
  MonitorOptions alerts;
  HealthConfig health;
};

// Thrown for a bad file or flag: one line naming the input and the problem.
struct ConfigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The file's settings over the defaults. Unknown keys are errors (a typo must not pass
// silently); an integer that does not fit its setting is an error, not truncated.
Config LoadConfigFile(const std::string& path);

// The same from TOML text in memory; source_name names it in errors ("NAME:LINE:COLUMN:
// problem" for TOML syntax, "NAME: key: problem" for content). Throws ConfigError only,
// whatever the text (tests/fuzz/fuzz_config.cc).
Config ParseConfigText(std::string_view text, const std::string& source_name);

// Checks ranges and cross-field rules; throws ConfigError.
void Validate(const Config& config);

// The key file flexidd uses: auth_key_file, or flexidd.key in the database's directory.
std::string KeyFilePath(const Config& config);

// One line per setting, for the start-up log.
std::vector<std::string> Describe(const Config& config);

}  // namespace flexid::daemon
