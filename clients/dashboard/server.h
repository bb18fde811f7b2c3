// The dashboard's HTTP server (cpp-httplib): the page and its assets (assets.h), the live
// store's snapshot and its server-sent event stream.
//
//   GET /                          the page (index.html)
//   GET /app.js, /app.css          the page's code and style
//   GET /vendor/uPlot.iife.min.js, /vendor/uPlot.min.css, /vendor/LICENSE   uPlot (MIT)
//   GET /api/state                 LiveStore::StateJson() plus "lcm_url" and "version"; also
//                                  tells the bus adapter to ask the model versions again
//   GET /events?after=ID           text/event-stream of the store's events after ID
//   GET /healthz                   {"ok": true, "streams", the counters, "last_problem"}
//
// Every response forbids loading anything from elsewhere (Content-Security-Policy
// default-src 'self'). Bound to a loopback address, requests must name a loopback host
// (Host header), so a web page elsewhere cannot read the dashboard through DNS rebinding.
#pragma once

#include <atomic>
#include <chrono>
#include <memory>
#include <string>
#include <thread>

#include "clients/dashboard/live_store.h"

namespace httplib {
class Server;
}

namespace flexid::dashboard {

struct ServerOptions {
  std::string host = "127.0.0.1";
  int port = 8080;                            // 0: any free port (Bind() returns it)
  std::string lcm_url;                        // shown on the page
  int max_streams = 8;                        // concurrent /events streams; more get 503
  std::chrono::milliseconds keepalive{5000};  // comment line on an idle stream
};

class DashboardServer {
 public:
  DashboardServer(LiveStore& store, ServerOptions options);
  ~DashboardServer();
  DashboardServer(const DashboardServer&) = delete;
  DashboardServer& operator=(const DashboardServer&) = delete;

  // Binds the listening socket and returns its port. Throws std::runtime_error (one line)
  // when it cannot.
  int Bind();
  // Serves on a thread of its own until Stop(). Bind() first.
  void Start();
  // Closes the store's event stream (ending every /events response) and stops serving.
  void Stop();

  int port() const { return port_; }
  std::string url() const;  // e.g. http://127.0.0.1:8080/
  int active_streams() const { return active_streams_->load(); }

 private:
  void Route();

  LiveStore& store_;
  ServerOptions options_;
  std::unique_ptr<httplib::Server> server_;
  std::thread thread_;
  int port_ = -1;
  std::shared_ptr<std::atomic<int>> active_streams_ = std::make_shared<std::atomic<int>>(0);
};

}  // namespace flexid::dashboard
