// flexidd [--config FILE] [--db PATH] [--lcm URL] [--channel-prefix P] [--key-file PATH]: the
// flexid lab service. Flags override the file; with no file it runs on the embedded defaults
// (DESIGN.md).
#include <pthread.h>
#include <spdlog/spdlog.h>

#include <CLI/CLI.hpp>
#include <csignal>

#include "daemon/daemon.h"
#include "flexid/version.h"
#include "storage/database.h"

int main(int argc, char** argv) {
  // SIGTERM, SIGINT and SIGHUP are handled by the event loop (signalfd). Block them before
  // anything else, so that one arriving during start-up waits for the loop instead of
  // ending the process.
  flexid::daemon::BlockHandledSignals();
  flexid::daemon::KeepFreedMemory();
  CLI::App app{
      "flexidd: records actuator trials from the bus, predicts live, raises alerts, identifies on "
      "demand"};
  app.set_version_flag("--version", flexid::kVersion);
  std::string config_path, db, lcm_url, channel_prefix, log_file, daemon_id, key_file;
  app.add_option("--config", config_path,
                 "TOML configuration file (deploy/flexidd.toml is an example)");
  app.add_option("--db", db, "SQLite database file (default var/flexid.db)");
  app.add_option("--lcm", lcm_url, "LCM URL (default udpm://239.255.76.67:7667?ttl=0)");
  app.add_option("--channel-prefix", channel_prefix,
                 "Prefix of every channel, the clients' --channel-prefix (default FLEXID)");
  app.add_option("--log-file", log_file, "Rotating log file (default var/flexidd.log)");
  app.add_option("--daemon-id", daemon_id, "Name of this instance on the bus");
  app.add_option("--key-file", key_file,
                 "Key of requests that change data (default flexidd.key next to the database; "
                 "created, mode 0600, when absent)");
  app.footer(
      "Example:\n  flexidd --config /etc/flexid/flexidd.toml\n  flexidd --db var/flexid.db --lcm "
      "'udpm://239.255.76.67:7667?ttl=0'");
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return 2;
  }
  flexid::daemon::Config config;
  try {
    if (!config_path.empty()) config = flexid::daemon::LoadConfigFile(config_path);
    if (!db.empty()) config.database = db;
    if (!lcm_url.empty()) config.lcm_url = lcm_url;
    if (!channel_prefix.empty()) config.channel_prefix = channel_prefix;  // Validate checks it
    if (!log_file.empty()) config.log_file = log_file;
    if (!daemon_id.empty()) config.daemon_id = daemon_id;
    if (!key_file.empty()) config.auth_key_file = key_file;
    flexid::daemon::Validate(config);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flexidd: %s\n", e.what());
    return 2;
  }
  flexid::daemon::SetUpLogging(config);
  try {
    flexid::daemon::Daemon daemon(config, config_path);
    return daemon.Run();
  } catch (const std::exception& e) {
    spdlog::critical("cannot run [error: {}]", e.what());
    return 1;
  }
}
