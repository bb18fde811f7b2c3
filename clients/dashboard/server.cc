// The dashboard's HTTP server (server.h).
#include "clients/dashboard/server.h"

#include <httplib.h>

#include <stdexcept>

#include "clients/dashboard/assets.h"
#include "clients/dashboard/listen_address.h"
#include "flexid/version.h"

namespace flexid::dashboard {
namespace {

// Nothing from elsewhere: scripts, styles, images and connections only from this server;
// no inline script; no framing.
constexpr char kContentSecurityPolicy[] =
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
    "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'";

// The host part of a Host header ("127.0.0.1:8080" -> "127.0.0.1", "[::1]:80" -> "::1").
std::string HostOf(const std::string& header) {
  if (!header.empty() && header.front() == '[') {
    const size_t close = header.find(']');
    return close == std::string::npos ? header : header.substr(1, close - 1);
  }
  return header.substr(0, header.find(':'));
}

std::string SseEvent(const Event& e) {
  return "id: " + std::to_string(e.id) + "\nevent: " + e.name + "\ndata: " + e.data + "\n\n";
}

// Holds one of the /events slots for as long as its response lives.
struct StreamSlot {
  explicit StreamSlot(std::shared_ptr<std::atomic<int>> count) : count_(std::move(count)) {}
  ~StreamSlot() { --*count_; }
  StreamSlot(const StreamSlot&) = delete;
  StreamSlot& operator=(const StreamSlot&) = delete;
  std::shared_ptr<std::atomic<int>> count_;
};

}  // namespace

DashboardServer::DashboardServer(LiveStore& store, ServerOptions options)
    : store_(store), options_(std::move(options)), server_(std::make_unique<httplib::Server>()) {
  // One worker per stream plus some for the page, its assets and /api/state.
  const auto workers = static_cast<size_t>(options_.max_streams) + 8;
  server_->new_task_queue = [workers] { return new httplib::ThreadPool(workers); };
  // Idle keep-alive connections hold a worker until this runs out, also at shutdown.
  server_->set_keep_alive_timeout(1);
  Route();
}

DashboardServer::~DashboardServer() { Stop(); }

void DashboardServer::Route() {
  httplib::Server& s = *server_;
  s.set_default_headers({{"Content-Security-Policy", kContentSecurityPolicy},
                         {"X-Content-Type-Options", "nosniff"},
                         {"Referrer-Policy", "no-referrer"},
                         {"X-Frame-Options", "DENY"}});
  const bool loopback = IsLoopback(options_.host);
  s.set_pre_routing_handler([loopback](const httplib::Request& req, httplib::Response& res) {
    if (req.method != "GET" && req.method != "HEAD") {
      res.status = 405;
      res.set_content("only GET\n", "text/plain; charset=utf-8");
      return httplib::Server::HandlerResponse::Handled;
    }
    if (loopback && !IsLoopback(HostOf(req.get_header_value("Host")))) {
      res.status = 403;
      res.set_content("this dashboard answers to loopback host names only\n",
                      "text/plain; charset=utf-8");
      return httplib::Server::HandlerResponse::Handled;
    }
    return httplib::Server::HandlerResponse::Unhandled;
  });

  for (const Asset& asset : Assets()) {
    s.Get(std::string(asset.path), [asset](const httplib::Request&, httplib::Response& res) {
      res.set_header("Cache-Control", "no-cache");
      res.set_content(asset.body.data(), asset.body.size(), std::string(asset.content_type));
    });
  }

  s.Get("/api/state", [this](const httplib::Request&, httplib::Response& res) {
    // A page (re)loads: the model version lists are asked again (bus.h).
    store_.NotePageLoad();
    nlohmann::json state = store_.StateJson();
    state["lcm_url"] = options_.lcm_url;
    state["version"] = kVersion;
    res.set_header("Cache-Control", "no-store");
    res.set_content(state.dump(), "application/json");
  });

  s.Get("/healthz", [this](const httplib::Request&, httplib::Response& res) {
    const Counters c = store_.counters();
    const nlohmann::json health = {{"ok", true},
                                   {"streams", active_streams_->load()},
                                   {"predictions", c.predictions},
                                   {"samples", c.samples},
                                   {"alerts", c.alerts},
                                   {"bad_messages", c.bad_messages},
                                   {"bad_replies", c.bad_replies},
                                   {"last_problem", store_.last_problem()}};
    res.set_header("Cache-Control", "no-store");
    res.set_content(health.dump(), "application/json");
  });

  s.Get("/events", [this](const httplib::Request& req, httplib::Response& res) {
    uint64_t after = store_.last_event_id();
    if (req.has_param("after")) {
      try {
        after = std::stoull(req.get_param_value("after"));
      } catch (const std::exception&) {
        res.status = 400;
        res.set_content("after: expected an event id\n", "text/plain; charset=utf-8");
        return;
      }
    }
    if (++*active_streams_ > options_.max_streams) {
      --*active_streams_;
      res.status = 503;
      res.set_header("Retry-After", "5");
      res.set_content("too many event streams\n", "text/plain; charset=utf-8");
      return;
    }
    auto slot = std::make_shared<StreamSlot>(active_streams_);
    res.set_header("Cache-Control", "no-store");
    res.set_header("X-Accel-Buffering", "no");
    const auto keepalive = options_.keepalive;
    bool first = true;
    res.set_chunked_content_provider(
        "text/event-stream",
        [this, slot, after, keepalive, first](size_t, httplib::DataSink& sink) mutable {
          if (first) {
            first = false;
            const std::string hello = "retry: 2000\n: flexid-dashboard\n\n";
            return sink.write(hello.data(), hello.size());
          }
          const EventWait wait = store_.WaitEvents(after, keepalive);
          if (wait.closed) {
            sink.done();
            return true;
          }
          std::string text;
          for (const Event& e : wait.events) {
            text += SseEvent(e);
            after = e.id;
          }
          if (text.empty()) text = ": keepalive\n\n";
          return sink.write(text.data(), text.size());
        });
  });
}

int DashboardServer::Bind() {
  if (options_.port == 0)
    port_ = server_->bind_to_any_port(options_.host);
  else
    port_ = server_->bind_to_port(options_.host, options_.port) ? options_.port : -1;
  if (port_ < 0)
    throw std::runtime_error("cannot listen on " + UrlOf(options_.host, options_.port) +
                             " (address in use, not on this host, or not permitted)");
  return port_;
}

void DashboardServer::Start() {
  if (port_ < 0) throw std::logic_error("DashboardServer::Start before Bind");
  thread_ = std::thread([this] { server_->listen_after_bind(); });
  // stop() is a no-op until the server runs: wait for it, so Stop() right after Start()
  // cannot leave the thread serving.
  for (int i = 0; i < 1000 && !server_->is_running(); ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
}

void DashboardServer::Stop() {
  store_.Close();
  if (server_) server_->stop();
  if (thread_.joinable()) thread_.join();
}

std::string DashboardServer::url() const { return UrlOf(options_.host, port_); }

}  // namespace flexid::dashboard
