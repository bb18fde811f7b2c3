// flexid: the command line of the flexid lab service. Errors become exit codes here and
// only here: 0 success, 1 the operation failed, 2 bad usage or bad input.
#include <CLI/CLI.hpp>
#include <iostream>

#include "bus/channels.h"
#include "clients/cli/bus.h"
#include "clients/cli/command.h"
#include "clients/cli/source.h"
#include "flexid/version.h"
#include "model/core/errors.h"

int main(int argc, char** argv) {
  CLI::App app{"flexid: identify, simulate and diagnose models of ionic soft actuators"};
  app.set_version_flag("--version", flexid::kVersion);
  app.require_subcommand(1);
  app.fallthrough();  // --lcm, --channel-prefix and --db may also follow the command
  flexid::cli::RegisterTfCommand(app);
  flexid::cli::RegisterSimulateCommand(app);
  flexid::cli::RegisterPhysicsCommand(app);
  flexid::cli::RegisterIdentifyCommand(app);
  flexid::cli::RegisterDiagnoseCommand(app);
  flexid::cli::RegisterPlotCommand(app);
  flexid::cli::RegisterStatusCommands(app);
  flexid::cli::RegisterTrialsCommand(app);
  flexid::cli::RegisterModelsCommand(app);
  flexid::cli::RegisterAlertsCommand(app);
  flexid::cli::RegisterReportCommand(app);
  flexid::cli::RegisterDbCommand(app);
  flexid::cli::RegisterBusCommands(app);
  app.add_option("--lcm", flexid::cli::LcmUrl(),
                 "LCM URL of the flexidd bus (default udpm://239.255.76.67:7667?ttl=0)");
  app.add_option("--channel-prefix", flexid::cli::ChannelPrefix(),
                 "Channel prefix of the flexidd bus, its channel_prefix (default FLEXID)")
      ->check([](const std::string& prefix) { return flexid::bus::PrefixProblem(prefix); });
  app.add_option("--key-file", flexid::cli::KeyFileOptions(),
                 "Key for requests that change data: PATH for any daemon, or ID=PATH for "
                 "daemon ID (repeatable; default $FLEXID_KEY_FILE, else var/flexidd.key)")
      ->allow_extra_args(false)
      ->check([](const std::string& value) { return flexid::cli::KeyFileOptionProblem(value); });
  app.add_option("--key-dir", flexid::cli::KeyDir(),
                 "Directory of per-daemon keys: the key of daemon ID is DIR/ID.key");
  app.add_option("--db", flexid::cli::DbPaths(),
                 "Read this database file directly instead of asking flexidd (offline forms; "
                 "repeatable: read-only commands merge the files)")
      ->allow_extra_args(false);
  app.add_option("--daemon", flexid::cli::DaemonIds(),
                 "Ask only this flexidd (its daemon_id; repeatable for read-only commands); a "
                 "request that changes data goes to it")
      ->allow_extra_args(false)
      ->check([](const std::string& id) { return flexid::bus::PrefixProblem(id); });
  app.add_option("--reply-timeout", flexid::cli::ReplyTimeout_s(),
                 "Seconds read-only requests wait for every daemon to answer (default 10)")
      ->check(CLI::PositiveNumber);
  // A parse error is one line, as for every other bad input (CLI11 would add a second,
  // "Run with --help").
  return flexid::cli::RunMain(
      app, "flexid",
      [&] {
        app.parse(argc, argv);
        return 0;
      },
      " (see flexid --help)");
}
