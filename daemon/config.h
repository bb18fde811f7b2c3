// flexidd's configuration: embedded defaults, then a TOML file, then command-line flags
// (DESIGN.md: "flags override the file; with no file it runs on the embedded defaults").
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "daemon/residual_monitor.h"
#include "storage/database.h"

namespace flexid::daemon {

struct IdentificationConfig {
  int zeros = 3;
  int poles = 4;
  double max_delay_s = 10.0;
  int latest_trials = 2;  // "identify" without trial ids uses this many latest complete trials
};

struct Config {
  std::string daemon_id = "flexidd";
  std::string database = "var/flexid.db";
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  std::string channel_prefix = "FLEXID";
  std::string log_file = "var/flexidd.log";
  std::string log_level = "info";
  int commit_interval_ms = 100;
  bool auto_trials = true;           // a trial starts when an idle actuator gets a non-zero voltage
  double trial_idle_stop_s = 300.0;  // an automatic trial stops after this long at 0 V
  bool accept_unknown_actuators = true;
  int64_t max_message_bytes = 65536;
  // Pin the loop and LCM's receive thread to CPU 0, and the sample writer and the
  // identification worker to the other CPUs. Keeps a fit from delaying predictions on a
  // small machine; leave it off when several daemons share a host.
  bool pin_threads = false;
  std::vector<storage::Actuator> actuators;
  IdentificationConfig identification;
  MonitorOptions alerts;
};

// Thrown for a bad file or flag: one line naming the input and the problem.
struct ConfigError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The file's settings over the defaults. Unknown keys are errors (a typo must not pass
// silently).
Config LoadConfigFile(const std::string& path);

// Checks ranges and cross-field rules; throws ConfigError.
void Validate(const Config& config);

// One line per setting, for the start-up log.
std::vector<std::string> Describe(const Config& config);

}  // namespace flexid::daemon
