// flexid-dashboard: the live web page of an actuator's samples, flexid's predictions, model
// versions and alerts (DESIGN.md, "Command lines").
//
//   flexid-dashboard [--lcm URL] [--channel-prefix FLEXID] [--listen 127.0.0.1:8080]
//
// Subscribes to PREFIX/<actuator>/VOLTAGE, DEFLECTION and PREDICTION and PREFIX/ALERT
// (bus.h; PREFIX is flexidd's channel_prefix), asks flexidd for model summaries and
// version lists, keeps the recent points, alerts and models (live_store.h) and serves the
// page at / with a server-sent event stream (server.h). The page and uPlot are compiled in: no
// files and no network are needed at run time.
//
// Prints one line on stdout once it serves: "flexid-dashboard: serving http://HOST:PORT/
// (LCM URL)" (with --listen HOST:0 the port is the one the system chose). Errors are one
// line on stderr; exit 0 after SIGINT or SIGTERM, 1 when it cannot run (the bus, the
// address), 2 bad usage.
#include <pthread.h>
#include <signal.h>

#include <CLI/CLI.hpp>
#include <atomic>
#include <iostream>
#include <lcm/lcm-cpp.hpp>
#include <string>
#include <thread>

#include "bus/channels.h"
#include "clients/dashboard/bus.h"
#include "clients/dashboard/listen_address.h"
#include "clients/dashboard/live_store.h"
#include "clients/dashboard/server.h"
#include "flexid/version.h"

namespace flexid::dashboard {
namespace {

struct DashboardArgs {
  std::string lcm_url = "udpm://239.255.76.67:7667?ttl=0";
  std::string channel_prefix = bus::kDefaultPrefix;
  std::string listen = "127.0.0.1:8080";
};

// Returns the exit code.
int RunDashboard(const DashboardArgs& args) {
  std::string why;
  const std::optional<ListenAddress> listen = ParseListenAddress(args.listen, &why);
  if (!listen) {
    std::cerr << "flexid-dashboard: " << why << '\n';
    return 2;
  }
  // Signal handling without handlers: SIGINT and SIGTERM are blocked before any thread
  // starts (LCM's, the server's workers inherit the mask) and the main thread waits for
  // them with sigwait, then shuts everything down in order.
  sigset_t stop_signals;
  sigemptyset(&stop_signals);
  sigaddset(&stop_signals, SIGINT);
  sigaddset(&stop_signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &stop_signals, nullptr);

  lcm::LCM lcm(args.lcm_url);
  if (!lcm.good()) {
    std::cerr << "flexid-dashboard: cannot open the LCM bus [url: " << args.lcm_url << "]\n";
    return 1;
  }
  LiveStore store;
  BusOptions bus_options;
  bus_options.channel_prefix = args.channel_prefix;
  BusAdapter bus(lcm, store, bus_options);
  ServerOptions server_options;
  server_options.host = listen->host;
  server_options.port = listen->port;
  server_options.lcm_url = args.lcm_url;
  DashboardServer server(store, server_options);
  try {
    server.Bind();
  } catch (const std::exception& e) {
    std::cerr << "flexid-dashboard: " << e.what() << '\n';
    return 1;
  }
  if (!IsLoopback(listen->host))
    std::cerr << "flexid-dashboard: warning: " << listen->host
              << " is reachable from other hosts; the dashboard has no authentication\n";

  std::atomic<bool> stop{false};
  std::thread bus_thread([&] { bus.Run(stop); });
  server.Start();
  std::cout << "flexid-dashboard: serving " << server.url() << " (" << args.lcm_url << ")"
            << std::endl;

  int signal_number = 0;
  sigwait(&stop_signals, &signal_number);
  stop.store(true);
  bus_thread.join();
  server.Stop();
  return 0;
}

}  // namespace
}  // namespace flexid::dashboard

int main(int argc, char** argv) {
  CLI::App app{
      "flexid-dashboard: the live web page of flexid's actuators (voltage, measured and predicted "
      "deflection, residual, the active model and its fit, model versions and proposals, "
      "alerts)"};
  app.set_version_flag("--version", flexid::kVersion);
  flexid::dashboard::DashboardArgs args;
  app.add_option("--lcm", args.lcm_url, "LCM URL of the bus flexidd publishes on")
      ->capture_default_str();
  app.add_option("--channel-prefix", args.channel_prefix,
                 "Channel prefix of the bus, flexidd's channel_prefix")
      ->capture_default_str()
      ->check([](const std::string& prefix) { return flexid::bus::PrefixProblem(prefix); });
  app.add_option("--listen", args.listen,
                 "HOST:PORT to serve on; port 0 picks a free one (the printed URL names it)")
      ->capture_default_str();
  app.footer(
      "Examples:\n  flexid-dashboard\n"
      "  flexid-dashboard --lcm 'udpm://239.255.76.67:7667?ttl=0' --listen 127.0.0.1:0");
  try {
    app.parse(argc, argv);
  } catch (const CLI::Success& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    std::cerr << "flexid-dashboard: " << e.what() << '\n';
    return 2;
  }
  try {
    return flexid::dashboard::RunDashboard(args);
  } catch (const std::exception& e) {
    std::cerr << "flexid-dashboard: " << e.what() << '\n';
    return 1;
  }
}
