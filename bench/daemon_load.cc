// flexidd under the DESIGN.md daemon load target, end to end on real LCM and SQLite:
//
//   "16 actuators at 500 Hz each (8,000 deflection + 8,000 voltage messages/s) recorded
//    with no sample lost between what LCM delivered and what SQLite holds; prediction
//    published < 1 ms (p99) after the deflection message arrives, also while an
//    identification runs."
//
//   build/bench/daemon_load [--seconds 20] [--actuators 16] [--rate-hz 500]
//       [--identify-at 10 (0: none)] [--period-s 4] [--first-trial-s 22]
//       [--recv-buf-size BYTES (LCM udpm recv_buf_size=, daemon and bench)]
//       [--commit-interval-ms MS (the daemon's setting)] [--tap-deflections 1]
//       [--log-level warn] [--dump FILE.csv] [--keep]
//   experiments on the daemon's threads (not its own behaviour; labelled in the output):
//       [--renice-workers NICE] (sample writer + identification worker at that nice)
//       [--pin-threads] (the daemon's pin_threads: loop + LCM receive on CPU 0, writer + worker on
//       the others)
//
// A program that prints figures, not a test: no thresholds are checked; the targets are
// printed beside the measurements. The machine is shared (2 cores): the figures say how
// busy other processes kept it, second by second.
//
// What runs, all in this process: flexidd (daemon::Daemon looping RunOnce(20) on its own
// thread, a temporary database, lcm_url udpm://239.255.76.67:<random port>?ttl=0), a
// publisher thread and a subscriber thread, each with its own LCM instance.
//  - Publisher: per actuator L00..L<N-1>, at the rate in message time paced in real time
//    (sleep_until; lateness is reported), a voltage_sample_t (0/5 V square wave, phases
//    staggered) and then a deflection_sample_t (first-order lag with dead time + noise),
//    utime = message time. trial_control kStart for every actuator first, kStop for every
//    one at the end. L00's trial is stopped and restarted 1 s before --identify-at, so that
//    a finished trial exists; that first trial also gets a history published before t0
//    (faster than real time), so that it holds --first-trial-s of samples: the daemon's
//    identification needs max_delay_s / dt + 50 samples (10 s at the default max_delay_s),
//    and 22 s at 500 Hz is the 11,000 samples of DESIGN.md's identification target.
//  - Subscriber: FLEXID/.*/PREDICTION (and, with --tap-deflections 1, FLEXID/.*/DEFLECTION,
//    only for its kernel receive time stamp) and the RPC replies.
//  - At --identify-at: "identify" {"actuator": "L00", "latest": 1} (L00's first trial).
//  - At the end: "status" RPCs until samples_stored == predictions_published -
//    dropped_queue_full (every accepted deflection is in a trial), then the daemon is
//    stopped and destroyed and the database is read back and compared with what was
//    published, sample by sample.
//
// Latency figures, per deflection sample matched to its prediction (from t0 on):
//  - external: steady_clock before the deflection's publish -> steady_clock in the
//    subscriber's handler. Two loopback UDP hops, the daemon, and this program's own LCM
//    receive thread and dispatch.
//  - socket to socket: the kernel's receive time stamp (SO_TIMESTAMP, 1 us, which LCM
//    passes as recv_utime) of the deflection on this program's socket -> that of the
//    prediction. Multicast loopback queues a datagram on every member socket in the same
//    sendmsg, so the first stamp is also when the deflection reached the daemon's socket:
//    this figure is the daemon's handling (its LCM receive thread, queue, loop, handler,
//    publish) plus one loopback hop, without this program's scheduling. It is the closest
//    to the target's "after the deflection message arrives". The daemon's own time inside
//    is not exposed, so nothing finer is measured.
#include <pthread.h>
#include <sched.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cinttypes>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <ctime>
#include <filesystem>
#include <flexid/deflection_sample_t.hpp>
#include <flexid/prediction_t.hpp>
#include <flexid/rpc_reply_t.hpp>
#include <flexid/rpc_request_t.hpp>
#include <flexid/trial_control_t.hpp>
#include <flexid/voltage_sample_t.hpp>
#include <fstream>
#include <future>
#include <lcm/lcm-cpp.hpp>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "daemon/config.h"
#include "daemon/daemon.h"
#include "storage/database.h"

namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;
using flexid::daemon::Counters;

constexpr int64_t kUnset = INT64_MIN;
constexpr int64_t kBaseUtime = 1'700'000'000'000'000;  // message time of sample 0
constexpr double kHighV = 5.0;  // square wave 0 / 5 V, duty 0.5, first half period at 0 V
constexpr double kGainMmPerV = 0.35, kTauS = 0.4, kDeadTimeS = 0.05, kNoiseMm = 0.003;
constexpr const char* kClientId = "load";

// --- options ---------------------------------------------------------------------------

struct Options {
  double seconds = 20;
  int actuators = 16;
  double rate_hz = 500;
  double identify_at = 10;    // <= 0: no identification
  double period_s = 4;        // square-wave period
  double first_trial_s = 22;  // L00's first trial, identified at identify_at (message time)
  double history_speed = 8;   // L00's history before t0 goes this much faster than real time
  int64_t recv_buf_size = 0;  // LCM udpm recv_buf_size= (0: LCM's default, the kernel's)
  bool tap_deflections = true;
  std::string log_level = "warn";
  bool keep = false;           // keep the temporary database
  std::string dump;            // CSV of every timed sample, for offline analysis
  int renice_workers = 0;      // experiment: nice of the daemon's writer and worker threads
  int commit_interval_ms = 0;  // the daemon's commit_interval_ms (0: its default)
  bool pin_threads = false;    // the daemon's pin_threads setting (daemon/config.h)
};

[[noreturn]] void Usage(const std::string& problem) {
  std::fprintf(stderr,
               "daemon_load: %s\nusage: daemon_load [--seconds S] [--actuators N] [--rate-hz R] "
               "[--identify-at S] [--period-s S] [--first-trial-s S] [--recv-buf-size BYTES] "
               "[--tap-deflections 0|1] "
               "[--log-level LEVEL] [--dump FILE.csv] [--commit-interval-ms MS] "
               "[--renice-workers NICE] [--pin-threads] [--keep]\n",
               problem.c_str());
  std::exit(2);
}

double Number(const std::string& flag, const char* text) {
  char* end = nullptr;
  const double value = std::strtod(text, &end);
  if (end == text || *end != '\0' || !std::isfinite(value))
    Usage(flag + " needs a number, not \"" + text + "\"");
  return value;
}

Options ParseOptions(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (flag == "--keep") {
      o.keep = true;
      continue;
    }
    if (flag == "--pin-threads") {
      o.pin_threads = true;
      continue;
    }
    if (i + 1 >= argc) Usage(flag + " needs a value");
    const char* value = argv[++i];
    if (flag == "--seconds")
      o.seconds = Number(flag, value);
    else if (flag == "--actuators")
      o.actuators = static_cast<int>(Number(flag, value));
    else if (flag == "--rate-hz")
      o.rate_hz = Number(flag, value);
    else if (flag == "--identify-at")
      o.identify_at = Number(flag, value);
    else if (flag == "--period-s")
      o.period_s = Number(flag, value);
    else if (flag == "--first-trial-s")
      o.first_trial_s = Number(flag, value);
    else if (flag == "--recv-buf-size")
      o.recv_buf_size = static_cast<int64_t>(Number(flag, value));
    else if (flag == "--tap-deflections")
      o.tap_deflections = Number(flag, value) != 0.0;
    else if (flag == "--log-level")
      o.log_level = value;
    else if (flag == "--dump")
      o.dump = value;
    else if (flag == "--commit-interval-ms")
      o.commit_interval_ms = static_cast<int>(Number(flag, value));
    else if (flag == "--renice-workers")
      o.renice_workers = static_cast<int>(Number(flag, value));
    else
      Usage("unknown option " + flag);
  }
  if (o.seconds < 1 || o.seconds > 3600) Usage("--seconds must be 1..3600");
  if (o.actuators < 1 || o.actuators > 100) Usage("--actuators must be 1..100");
  if (o.rate_hz < 1 || o.rate_hz > 10000) Usage("--rate-hz must be 1..10000");
  if (o.period_s <= 0) Usage("--period-s must be positive");
  if (o.renice_workers < 0 || o.renice_workers > 19) Usage("--renice-workers must be 0..19");
  if (o.first_trial_s < 0 || o.first_trial_s > 3600) Usage("--first-trial-s must be 0..3600");
  if (o.recv_buf_size < 0) Usage("--recv-buf-size must be >= 0");
  if (o.identify_at > 0 && (o.identify_at < 2 || o.identify_at > o.seconds - 0.5))
    Usage("--identify-at must be 0 (off) or in [2, seconds - 0.5]");
  return o;
}

// --- the synthetic rig -----------------------------------------------------------------

// Sample k of an actuator is at message time Utime(k); k = 0 is published at t0 and the
// run has `samples` ticks. L00 alone also has `history` samples before it (k < 0),
// published faster than real time before t0, so that its first trial is long enough to be
// identified.
struct Plan {
  int actuators = 0;
  int64_t samples = 0;  // per actuator, from t0 on
  int64_t history = 0;  // L00's samples before t0
  double rate_hz = 0, period_s = 0;
  int64_t restart_k = -1;  // tick at which L00's trial is stopped and restarted (-1: never)

  int64_t FirstK(int actuator) const { return actuator == 0 ? -history : 0; }

  int64_t Utime(int64_t k) const {
    return kBaseUtime + std::llround(static_cast<double>(k) * 1e6 / rate_hz);
  }
  std::optional<int64_t> Index(int64_t utime) const {
    const int64_t k = std::llround(static_cast<double>(utime - kBaseUtime) * rate_hz / 1e6);
    if (k < -history || k >= samples || Utime(k) != utime) return std::nullopt;
    return k;
  }
  double Voltage(int actuator, int64_t k) const {
    const double t = static_cast<double>(k) / rate_hz +
                     period_s * static_cast<double>(actuator) / static_cast<double>(actuators);
    const double phase = std::fmod(std::fmod(t, period_s) + period_s, period_s);
    return phase < 0.5 * period_s ? 0.0 : kHighV;  // L00's run starts at rest
  }
  size_t Slot(int actuator, int64_t k) const {
    return static_cast<size_t>(actuator) * static_cast<size_t>(history + samples) +
           static_cast<size_t>(k + history);
  }
  size_t Slots() const {
    return static_cast<size_t>(actuators) * static_cast<size_t>(history + samples);
  }
};

std::string ActuatorId(int i) {
  // i < 100 (checked by ParseOptions)
  return std::string("L") + static_cast<char>('0' + i / 10 % 10) + static_cast<char>('0' + i % 10);
}

std::optional<int> ActuatorIndex(const std::string& id, int actuators) {
  if (id.size() != 3 || id[0] != 'L' || !std::isdigit(static_cast<unsigned char>(id[1])) ||
      !std::isdigit(static_cast<unsigned char>(id[2])))
    return std::nullopt;
  const int i = (id[1] - '0') * 10 + (id[2] - '0');
  if (i >= actuators) return std::nullopt;
  return i;
}

int64_t Since(Clock::time_point t0, Clock::time_point t) {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(t - t0).count();
}

void NameThread(const char* name) { pthread_setname_np(pthread_self(), name); }

pid_t ThreadId() { return static_cast<pid_t>(::syscall(SYS_gettid)); }

// --- publisher -------------------------------------------------------------------------

struct PublisherReport {
  int64_t ticks = 0, late_ticks = 0, publish_failures = 0;
  int64_t max_lateness_ns = 0, sum_lateness_ns = 0, max_tick_ns = 0;
  int64_t worst_tick = -1;         // the tick that started latest
  std::vector<int64_t> late_by_s;  // ticks later than one period, per second of the run
  int64_t cpu_ns = 0;              // of the publisher thread, from t0 to the last tick
  Clock::time_point end;           // after the last tick
};

class Publisher {
 public:
  // L00's history is published from history_start on, history_speed times faster than
  // real time; the run's tick k at t0 + k / rate.
  Publisher(const Plan& plan, const std::string& url, Clock::time_point history_start,
            double history_speed, Clock::time_point t0)
      : plan_(plan),
        lcm_(url),
        history_start_(history_start),
        history_speed_(history_speed),
        t0_(t0),
        publish_ns_(plan.Slots(), kUnset),
        deflection_mm_(plan.Slots(), NAN),
        state_(static_cast<size_t>(plan.actuators), 0.0),
        dead_(static_cast<int64_t>(std::llround(kDeadTimeS * plan.rate_hz))),
        a_(std::exp(-1.0 / (plan.rate_hz * kTauS))) {
    for (int i = 0; i < plan_.actuators; ++i) {
      ids_.push_back(ActuatorId(i));
      voltage_channel_.push_back("FLEXID/" + ids_.back() + "/VOLTAGE");
      deflection_channel_.push_back("FLEXID/" + ids_.back() + "/DEFLECTION");
    }
    report_.late_by_s.assign(
        static_cast<size_t>(static_cast<double>(plan.samples) / plan.rate_hz) + 2, 0);
  }
  bool good() { return lcm_.good(); }

  void Run() {
    NameThread("bench-pub");
    for (int i = 0; i < plan_.actuators; ++i)
      Control(i, flexid::trial_control_t::kStart, plan_.Utime(plan_.FirstK(i)) - 1, "daemon_load");
    for (int64_t k = -plan_.history; k < 0; ++k) {
      std::this_thread::sleep_until(history_start_ + std::chrono::nanoseconds(std::llround(
                                                         static_cast<double>(k + plan_.history) *
                                                         1e9 / (plan_.rate_hz * history_speed_))));
      PublishSample(0, k);
    }
    std::this_thread::sleep_until(t0_);
    const int64_t cpu_start = ThreadCpuNs();
    const double period_ns = 1e9 / plan_.rate_hz;
    for (int64_t k = 0; k < plan_.samples; ++k) {
      const Clock::time_point due =
          t0_ + std::chrono::nanoseconds(std::llround(static_cast<double>(k) * period_ns));
      std::this_thread::sleep_until(due);
      const Clock::time_point start = Clock::now();
      const int64_t lateness = Since(due, start);
      if (lateness > report_.max_lateness_ns) {
        report_.max_lateness_ns = lateness;
        report_.worst_tick = k;
      }
      report_.sum_lateness_ns += lateness;
      if (static_cast<double>(lateness) > period_ns) {
        ++report_.late_ticks;
        ++report_.late_by_s[std::min(report_.late_by_s.size() - 1,
                                     static_cast<size_t>(static_cast<double>(k) / plan_.rate_hz))];
      }
      if (k == plan_.restart_k) {
        Control(0, flexid::trial_control_t::kStop, plan_.Utime(k) - 1, "");
        Control(0, flexid::trial_control_t::kStart, plan_.Utime(k), "daemon_load second trial");
      }
      for (int i = 0; i < plan_.actuators; ++i) PublishSample(i, k);
      report_.max_tick_ns = std::max(report_.max_tick_ns, Since(start, Clock::now()));
      ++report_.ticks;
    }
    report_.end = Clock::now();
    report_.cpu_ns = ThreadCpuNs() - cpu_start;
    for (int i = 0; i < plan_.actuators; ++i)
      Control(i, flexid::trial_control_t::kStop, plan_.Utime(plan_.samples - 1) + 1, "");
  }

  const PublisherReport& report() const { return report_; }
  const std::vector<int64_t>& publish_ns() const { return publish_ns_; }
  const std::vector<double>& deflection_mm() const { return deflection_mm_; }

 private:
  static int64_t ThreadCpuNs() {
    timespec cpu{};
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &cpu);
    return static_cast<int64_t>(cpu.tv_sec) * 1'000'000'000 + cpu.tv_nsec;
  }

  // The voltage, then the deflection (first-order lag with dead time, plus noise).
  void PublishSample(int i, int64_t k) {
    const size_t s = static_cast<size_t>(i);
    voltage_.utime = deflection_.utime = plan_.Utime(k);
    voltage_.actuator_id = deflection_.actuator_id = ids_[s];
    voltage_.voltage_V = plan_.Voltage(i, k);
    const double driving = k - dead_ >= plan_.FirstK(i) ? plan_.Voltage(i, k - dead_) : 0.0;
    state_[s] = a_ * state_[s] + (1.0 - a_) * kGainMmPerV * driving;
    deflection_.deflection_mm = state_[s] + noise_(random_);
    if (lcm_.publish(voltage_channel_[s], &voltage_) != 0) ++report_.publish_failures;
    deflection_mm_[plan_.Slot(i, k)] = deflection_.deflection_mm;
    publish_ns_[plan_.Slot(i, k)] = Since(t0_, Clock::now());
    if (lcm_.publish(deflection_channel_[s], &deflection_) != 0) ++report_.publish_failures;
  }

  void Control(int actuator, int8_t action, int64_t utime, const std::string& protocol) {
    flexid::trial_control_t c;
    c.utime = utime;
    c.actuator_id = ActuatorId(actuator);
    c.action = action;
    c.protocol = protocol;
    if (lcm_.publish("FLEXID/TRIAL", &c) != 0) ++report_.publish_failures;
  }

  const Plan plan_;
  lcm::LCM lcm_;
  const Clock::time_point history_start_;
  const double history_speed_;
  const Clock::time_point t0_;
  std::vector<int64_t> publish_ns_;    // per slot: steady ns since t0 just before publish
  std::vector<double> deflection_mm_;  // per slot: the value published
  std::vector<double> state_;          // per actuator: the lag's output, mm
  const int64_t dead_;                 // dead time, samples
  const double a_;                     // the lag's pole
  std::mt19937_64 random_{42};
  std::normal_distribution<double> noise_{0.0, kNoiseMm};
  flexid::voltage_sample_t voltage_;
  flexid::deflection_sample_t deflection_;
  std::vector<std::string> ids_, voltage_channel_, deflection_channel_;
  PublisherReport report_;
};

// --- subscriber ------------------------------------------------------------------------

struct ReplyRecord {
  flexid::rpc_reply_t reply;
  Clock::time_point received;
};

class Subscriber {
 public:
  Subscriber(const Plan& plan, const std::string& url, bool tap_deflections)
      : plan_(plan),
        url_(url),
        tap_(tap_deflections),
        prediction_rx_ns_(plan.Slots(), kUnset),
        prediction_kernel_us_(plan.Slots(), kUnset),
        deflection_kernel_us_(plan.Slots(), kUnset),
        model_version_(plan.Slots(), -1) {}

  // Starts the thread; false if LCM cannot be joined.
  bool Start() {
    std::promise<bool> ready;
    auto future = ready.get_future();
    thread_ = std::thread([this, &ready] { Run(&ready); });
    return future.get();
  }
  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  ~Subscriber() { Stop(); }
  Subscriber(const Subscriber&) = delete;
  Subscriber& operator=(const Subscriber&) = delete;
  // The origin of the recorded times; set before the publisher starts.
  void SetT0(Clock::time_point t0) { t0_ns_ = t0.time_since_epoch().count(); }
  pid_t tid() const { return tid_; }

  // Sends a request and waits for its reply.
  std::optional<ReplyRecord> Call(const std::string& method, const nlohmann::json& args,
                                  std::chrono::milliseconds timeout,
                                  Clock::time_point* sent = nullptr) {
    flexid::rpc_request_t request;
    request.request_id = "load-" + std::to_string(++requests_);
    request.client_id = kClientId;
    request.method = method;
    request.args_json = args.dump();
    request.utime = std::chrono::duration_cast<std::chrono::microseconds>(
                        std::chrono::system_clock::now().time_since_epoch())
                        .count();
    std::unique_lock lock(mutex_);
    if (sent) *sent = Clock::now();
    lcm_->publish("FLEXID/RPC/REQUEST", &request);  // LCM's publish is thread-safe
    replied_.wait_for(lock, timeout, [&] { return replies_.count(request.request_id) > 0; });
    const auto it = replies_.find(request.request_id);
    if (it == replies_.end()) return std::nullopt;
    return it->second;
  }

  int64_t received() const { return received_; }
  int64_t unmatched() const { return unmatched_; }
  int64_t duplicates() const { return duplicates_; }
  const std::vector<int64_t>& prediction_rx_ns() const { return prediction_rx_ns_; }
  const std::vector<int64_t>& prediction_kernel_us() const { return prediction_kernel_us_; }
  const std::vector<int64_t>& deflection_kernel_us() const { return deflection_kernel_us_; }
  const std::vector<int32_t>& model_version() const { return model_version_; }

 private:
  void Run(std::promise<bool>* ready) {
    NameThread("bench-sub");  // LCM's receive thread, created below, inherits the name
    tid_ = ThreadId();
    lcm_ = std::make_unique<lcm::LCM>(url_);
    if (!lcm_->good()) {
      ready->set_value(false);
      return;
    }
    lcm_->subscribeFunction("FLEXID/.*/PREDICTION", &Subscriber::OnPrediction, this)
        ->setQueueCapacity(1 << 20);
    if (tap_)
      lcm_->subscribeFunction("FLEXID/.*/DEFLECTION", &Subscriber::OnDeflection, this)
          ->setQueueCapacity(1 << 20);
    lcm_->subscribeFunction(std::string("FLEXID/RPC/REPLY/") + kClientId, &Subscriber::OnReply,
                            this)
        ->setQueueCapacity(100);
    ready->set_value(true);
    while (!stop_) lcm_->handleTimeout(10);
  }

  static void OnPrediction(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    const Clock::time_point now = Clock::now();
    flexid::prediction_t p;
    if (p.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    ++self->received_;
    const auto i = ActuatorIndex(p.actuator_id, self->plan_.actuators);
    const auto k = self->plan_.Index(p.utime);
    if (!i || !k) {
      ++self->unmatched_;
      return;
    }
    const size_t s = self->plan_.Slot(*i, *k);
    if (self->prediction_rx_ns_[s] != kUnset) {
      ++self->duplicates_;
      return;
    }
    self->prediction_rx_ns_[s] =
        Since(Clock::time_point(Clock::duration(self->t0_ns_.load())), now);
    self->prediction_kernel_us_[s] = rbuf->recv_utime;
    self->model_version_[s] = p.model_version;
  }

  static void OnDeflection(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::deflection_sample_t d;
    if (d.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    const auto i = ActuatorIndex(d.actuator_id, self->plan_.actuators);
    const auto k = self->plan_.Index(d.utime);
    if (i && k) self->deflection_kernel_us_[self->plan_.Slot(*i, *k)] = rbuf->recv_utime;
  }

  static void OnReply(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::rpc_reply_t r;
    if (r.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    {
      std::lock_guard lock(self->mutex_);
      self->replies_[r.request_id] = {r, Clock::now()};
    }
    self->replied_.notify_all();
  }

  const Plan plan_;
  const std::string url_;
  const bool tap_;
  std::atomic<Clock::rep> t0_ns_{0};
  std::unique_ptr<lcm::LCM> lcm_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  pid_t tid_ = 0;
  std::atomic<int> requests_{0};
  std::mutex mutex_;
  std::condition_variable replied_;
  std::map<std::string, ReplyRecord> replies_;
  // Written by the subscriber thread only; read after it has been joined.
  int64_t received_ = 0, unmatched_ = 0, duplicates_ = 0;
  std::vector<int64_t> prediction_rx_ns_;      // steady ns since t0 in the handler
  std::vector<int64_t> prediction_kernel_us_;  // SO_TIMESTAMP of the prediction, us
  std::vector<int64_t> deflection_kernel_us_;  // SO_TIMESTAMP of the deflection, us
  std::vector<int32_t> model_version_;
};

// --- the daemon on its own thread ------------------------------------------------------

class DaemonThread {
 public:
  // Constructs the daemon on its own thread (so that the threads it starts, the sample
  // writer, LCM's receive thread and the identification worker, are named "flexidd");
  // rethrows what the constructor threw.
  void Start(const flexid::daemon::Config& config) {
    std::promise<void> ready;
    auto future = ready.get_future();
    thread_ = std::thread([this, config, &ready] {
      NameThread("flexidd");
      try {
        daemon_ = std::make_unique<flexid::daemon::Daemon>(config);
      } catch (...) {
        ready.set_exception(std::current_exception());
        return;
      }
      NameThread("flexidd-loop");
      tid_ = ThreadId();
      ready.set_value();
      while (!stop_) daemon_->RunOnce(20);
      final_ = daemon_->counters();  // the loop has stopped: no race with RunOnce
      daemon_.reset();               // the writer commits what is left, threads join
    });
    future.get();
  }
  // Stops the loop, destroys the daemon and returns its last counters.
  Counters Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
    return final_;
  }
  pid_t tid() const { return tid_; }
  ~DaemonThread() { Stop(); }

 private:
  std::unique_ptr<flexid::daemon::Daemon> daemon_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
  pid_t tid_ = 0;
  Counters final_;
};

// --- /proc: sockets and threads of this process ----------------------------------------

struct UdpSocket {
  uint64_t inode = 0;
  int64_t drops = 0;
  int64_t rx_queue = 0;
};

// The UDP sockets bound to this port (from /proc/net/udp), by inode.
std::map<uint64_t, UdpSocket> UdpSockets(int port) {
  std::map<uint64_t, UdpSocket> out;
  std::ifstream in("/proc/net/udp");
  std::string line;
  std::getline(in, line);  // header
  while (std::getline(in, line)) {
    std::istringstream f(line);
    std::string sl, local, remote, st, queues, timer, retr, uid, timeout;
    UdpSocket s;
    std::string ref, pointer;
    f >> sl >> local >> remote >> st >> queues >> timer >> retr >> uid >> timeout >> s.inode >>
        ref >> pointer >> s.drops;
    const size_t colon = local.find(':');
    if (colon == std::string::npos) continue;
    if (std::stoi(local.substr(colon + 1), nullptr, 16) != port) continue;
    const size_t qcolon = queues.find(':');
    if (qcolon != std::string::npos)
      s.rx_queue = std::stoll(queues.substr(qcolon + 1), nullptr, 16);
    out[s.inode] = s;
  }
  return out;
}

// SO_RCVBUF of the socket of this process with that inode (-1 if not found).
int ReceiveBufferBytes(uint64_t inode) {
  const std::string wanted = "socket:[" + std::to_string(inode) + "]";
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/proc/self/fd", ec)) {
    std::error_code link_ec;
    if (fs::read_symlink(entry.path(), link_ec).string() != wanted) continue;
    const int fd = std::stoi(entry.path().filename().string());
    int size = 0;
    socklen_t len = sizeof size;
    if (getsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, &len) == 0) return size;
  }
  return -1;
}

int64_t ReadNumberFile(const std::string& path) {
  std::ifstream in(path);
  int64_t value = -1;
  in >> value;
  return value;
}

// UDP RcvbufErrors of the whole host (/proc/net/snmp).
int64_t UdpRcvbufErrors() {
  std::ifstream in("/proc/net/snmp");
  std::string header, values;
  while (std::getline(in, header)) {
    if (header.rfind("Udp:", 0) != 0) continue;
    std::getline(in, values);
    std::istringstream h(header), v(values);
    std::string name, value;
    while (h >> name && v >> value)
      if (name == "RcvbufErrors") return std::stoll(value);
  }
  return -1;
}

struct ThreadCpu {
  std::string name;
  int64_t cpu_ns = 0;
};

// CPU time of every thread of this process, by tid (schedstat: ns on a CPU).
std::map<pid_t, ThreadCpu> ThreadCpuTimes() {
  std::map<pid_t, ThreadCpu> out;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/proc/self/task", ec)) {
    const pid_t tid = static_cast<pid_t>(std::stol(entry.path().filename().string()));
    ThreadCpu t;
    std::ifstream comm(entry.path() / "comm");
    std::getline(comm, t.name);
    t.cpu_ns = ReadNumberFile((entry.path() / "schedstat").string());
    out[tid] = t;
  }
  return out;
}

// Busy and steal time of the whole machine, in USER_HZ ticks (/proc/stat, line "cpu").
struct MachineCpu {
  int64_t busy = 0, steal = 0;
};

MachineCpu ReadMachineCpu() {
  std::ifstream in("/proc/stat");
  std::string cpu;
  int64_t user = 0, nice = 0, system = 0, idle = 0, iowait = 0, irq = 0, softirq = 0, steal = 0;
  in >> cpu >> user >> nice >> system >> idle >> iowait >> irq >> softirq >> steal;
  return {user + nice + system + irq + softirq, steal};
}

// Once a second of the run: how much CPU the machine used, and how much of it was this
// process (the rest is other processes: on a shared machine they disturb the figures).
class LoadMonitor {
 public:
  void Start(Clock::time_point t0, size_t seconds) {
    thread_ = std::thread([this, t0, seconds] {
      NameThread("bench-mon");
      const double hz = static_cast<double>(sysconf(_SC_CLK_TCK));
      MachineCpu last = ReadMachineCpu();
      double last_self = SelfCpuSeconds();
      for (size_t sec = 1; sec <= seconds && !stop_; ++sec) {
        std::this_thread::sleep_until(t0 + std::chrono::seconds(sec));
        const MachineCpu now = ReadMachineCpu();
        const double self = SelfCpuSeconds();
        std::lock_guard lock(mutex_);
        machine_cores_.push_back(static_cast<double>(now.busy - last.busy) / hz);
        steal_cores_.push_back(static_cast<double>(now.steal - last.steal) / hz);
        self_cores_.push_back(self - last_self);
        last = now;
        last_self = self;
      }
    });
  }
  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  ~LoadMonitor() { Stop(); }
  // Per second: cores busy on the machine, of which this process, and steal.
  std::vector<double> machine_cores_, self_cores_, steal_cores_;

 private:
  static double SelfCpuSeconds() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
  }
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::mutex mutex_;
};

double CpuSeconds(const rusage& u) {
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

// --- statistics ------------------------------------------------------------------------

struct Stats {
  size_t n = 0;
  double p50 = NAN, p90 = NAN, p99 = NAN, p999 = NAN, max = NAN;
  size_t over_1ms = 0;
};

Stats Summarise(std::vector<double> us) {
  Stats s;
  s.n = us.size();
  if (us.empty()) return s;
  std::sort(us.begin(), us.end());
  auto at = [&](double q) {  // nearest rank
    const auto rank = static_cast<size_t>(std::ceil(q * static_cast<double>(us.size())));
    return us[std::min(us.size() - 1, rank == 0 ? 0 : rank - 1)];
  };
  s.p50 = at(0.50);
  s.p90 = at(0.90);
  s.p99 = at(0.99);
  s.p999 = at(0.999);
  s.max = us.back();
  s.over_1ms = static_cast<size_t>(us.end() - std::upper_bound(us.begin(), us.end(), 1000.0));
  return s;
}

std::string Ms(double us) {
  if (!std::isfinite(us)) return "-";
  char b[32];
  std::snprintf(b, sizeof b, "%.3f", us / 1000.0);
  return b;
}

void PrintStatsRow(const char* label, const Stats& s) {
  std::printf("  %-34s %8zu %8s %8s %8s %8s %9s %8zu\n", label, s.n, Ms(s.p50).c_str(),
              Ms(s.p90).c_str(), Ms(s.p99).c_str(), Ms(s.p999).c_str(), Ms(s.max).c_str(),
              s.over_1ms);
}

std::string Join(int argc, char** argv) {
  std::string out;
  for (int i = 0; i < argc; ++i) {
    if (i) out += ' ';
    out += argv[i];
  }
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  const Options opt = ParseOptions(argc, argv);
  std::printf("daemon_load: flexidd under load, in process, real LCM (udpm) and SQLite\n");
  std::printf("command: %s\n", Join(argc, argv).c_str());

  Plan plan;
  plan.actuators = opt.actuators;
  plan.rate_hz = opt.rate_hz;
  plan.period_s = opt.period_s;
  plan.samples = static_cast<int64_t>(std::llround(opt.seconds * opt.rate_hz));
  const bool identify = opt.identify_at > 0;
  if (identify) {
    plan.restart_k = static_cast<int64_t>(std::llround((opt.identify_at - 1) * opt.rate_hz));
    // The identification needs max_delay_s / dt + 50 samples (model/identify.cc) and
    // the trial must end before the request: L00's first trial gets a history before t0.
    plan.history = std::max<int64_t>(
        0, static_cast<int64_t>(std::llround(opt.first_trial_s * opt.rate_hz)) - plan.restart_k);
  }

  std::random_device device;
  const int port = std::uniform_int_distribution<int>(20000, 60000)(device);
  std::string url = "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0";
  if (opt.recv_buf_size > 0) url += "&recv_buf_size=" + std::to_string(opt.recv_buf_size);

  char dir_template[] = "/tmp/daemon_load.XXXXXX";
  if (!mkdtemp(dir_template)) {
    std::fprintf(stderr, "daemon_load: cannot create a temporary directory\n");
    return 1;
  }
  const fs::path dir = dir_template;
  const std::string database = (dir / "flexid.db").string();

  flexid::daemon::Config config;
  config.pin_threads = opt.pin_threads;
  config.database = database;
  config.lcm_url = url;
  config.log_file = "";
  config.log_level = opt.log_level;
  config.daemon_id = "load";
  if (opt.commit_interval_ms > 0) config.commit_interval_ms = opt.commit_interval_ms;
  try {
    flexid::daemon::Validate(config);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "daemon_load: %s\n", e.what());
    return 1;
  }
  flexid::daemon::SetUpLogging(config);

  std::printf("lcm url: %s   database: %s   commit_interval_ms: %d\n", url.c_str(),
              database.c_str(), config.commit_interval_ms);
  std::printf(
      "load: %d actuators x %g Hz = %g deflection + %g voltage messages/s for %g s (message "
      "time paced in real time); square wave 0/%g V, period %g s\n",
      opt.actuators, opt.rate_hz, opt.actuators * opt.rate_hz, opt.actuators * opt.rate_hz,
      opt.seconds, kHighV, opt.period_s);

  // The subscriber first, so that its socket can be told from the daemon's.
  Subscriber subscriber(plan, url, opt.tap_deflections);
  if (!subscriber.Start()) {
    std::fprintf(stderr, "daemon_load: cannot join the LCM bus at %s\n", url.c_str());
    return 1;
  }
  const auto sockets_before = UdpSockets(port);
  const auto threads_before_daemon = ThreadCpuTimes();
  DaemonThread daemon;
  try {
    daemon.Start(config);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "daemon_load: the daemon did not start: %s\n", e.what());
    subscriber.Stop();
    return 1;
  }
  // The threads the daemon started, in the order daemon.cc starts them (Impl's constructor).
  std::vector<pid_t> daemon_threads;
  for (const auto& [tid, t] : ThreadCpuTimes())
    if (!threads_before_daemon.count(tid) && t.name == "flexidd") daemon_threads.push_back(tid);
  const char* const kDaemonThreadRoles[] = {"sample writer", "LCM receive",
                                            "identification worker"};
  if (opt.renice_workers > 0) {
    // Experiment, not the daemon's behaviour: lower the priority of the sample writer and
    // the identification worker so that the loop and LCM's receive thread win the CPU.
    if (daemon_threads.size() == 3) {
      for (size_t n : {size_t{0}, size_t{2}})
        if (setpriority(PRIO_PROCESS, static_cast<id_t>(daemon_threads[n]), opt.renice_workers) !=
            0)
          std::fprintf(stderr, "daemon_load: cannot renice thread %d\n", daemon_threads[n]);
      std::printf("EXPERIMENT: daemon's sample writer and identification worker at nice %d\n",
                  opt.renice_workers);
    } else {
      std::fprintf(stderr, "daemon_load: --renice-workers: found %zu daemon threads, not 3\n",
                   daemon_threads.size());
    }
  }
  uint64_t daemon_inode = 0, bench_inode = 0;
  for (const auto& [inode, s] : UdpSockets(port))
    (sockets_before.count(inode) ? bench_inode : daemon_inode) = inode;
  const int64_t rcvbuf_errors_before = UdpRcvbufErrors();

  // The publisher sends the trial starts at once, L00's history (if any) from half a
  // second on, and the run's first tick at t0, half a second after the history.
  const Clock::time_point history_start = Clock::now() + std::chrono::milliseconds(500);
  const Clock::time_point t0 =
      history_start + std::chrono::milliseconds(500) +
      std::chrono::nanoseconds(std::llround(static_cast<double>(plan.history) * 1e9 /
                                            (opt.rate_hz * opt.history_speed)));
  subscriber.SetT0(t0);
  Publisher publisher(plan, url, history_start, opt.history_speed, t0);
  if (!publisher.good()) {
    std::fprintf(stderr, "daemon_load: the publisher cannot join the bus\n");
    subscriber.Stop();
    return 1;
  }
  if (plan.history > 0)
    std::printf("L00: %" PRId64
                " samples of history before t0 (%g x real time), so that its "
                "first trial, identified at %g s, holds %" PRId64 " samples (%g s)\n",
                plan.history, opt.history_speed, opt.identify_at, plan.history + plan.restart_k,
                static_cast<double>(plan.history + plan.restart_k) / opt.rate_hz);
  std::fflush(stdout);
  std::thread publisher_thread([&] { publisher.Run(); });
  // Figures of the run are taken from t0 on (the history is warm-up).
  std::this_thread::sleep_until(t0);
  rusage usage_start{};
  getrusage(RUSAGE_SELF, &usage_start);
  const auto threads_start = ThreadCpuTimes();
  const Clock::time_point wall_start = t0;
  const MachineCpu machine_start = ReadMachineCpu();
  LoadMonitor monitor;
  monitor.Start(t0, static_cast<size_t>(std::ceil(opt.seconds)));

  // Identification of L00 on its first trial, while the load goes on.
  std::optional<ReplyRecord> identify_reply;
  Clock::time_point identify_sent{};
  if (identify) {
    std::this_thread::sleep_until(t0 +
                                  std::chrono::nanoseconds(std::llround(opt.identify_at * 1e9)));
    identify_reply = subscriber.Call("identify", {{"actuator", "L00"}, {"latest", 1}},
                                     std::chrono::seconds(120), &identify_sent);
  }
  publisher_thread.join();
  const MachineCpu machine_end = ReadMachineCpu();
  monitor.Stop();

  // Drain: until the daemon has stored every deflection it accepted (all are in trials).
  Counters status;
  bool drained = false;
  const Clock::time_point drain_start = Clock::now();
  int64_t last_accepted = -1;
  while (Clock::now() - drain_start < std::chrono::seconds(30)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const auto r = subscriber.Call("status", nlohmann::json::object(), std::chrono::seconds(5));
    if (!r || r->reply.status != flexid::rpc_reply_t::kOk) continue;
    const auto j = nlohmann::json::parse(r->reply.result_json);
    status.samples_accepted = j.value("samples_accepted", int64_t{0});
    status.samples_stored = j.value("samples_stored", int64_t{0});
    status.predictions_published = j.value("predictions_published", int64_t{0});
    status.dropped_queue_full = j.value("dropped_queue_full", int64_t{0});
    // (messages_received moves with every status request; samples_accepted does not)
    const bool stable = status.samples_accepted == last_accepted;
    last_accepted = status.samples_accepted;
    if (stable &&
        status.samples_stored >= status.predictions_published - status.dropped_queue_full) {
      drained = true;
      break;
    }
  }
  const double drain_s = 1e-9 * static_cast<double>(Since(drain_start, Clock::now()));
  const Clock::time_point wall_end = publisher.report().end;
  rusage usage_end{};
  getrusage(RUSAGE_SELF, &usage_end);
  const auto threads_end = ThreadCpuTimes();
  const auto sockets_end = UdpSockets(port);
  const int64_t rcvbuf_errors_after = UdpRcvbufErrors();
  const int daemon_rcvbuf = ReceiveBufferBytes(daemon_inode);
  const int bench_rcvbuf = ReceiveBufferBytes(bench_inode);
  const pid_t daemon_loop_tid = daemon.tid(), subscriber_tid = subscriber.tid();

  const Counters c = daemon.Stop();  // destroys the daemon: the writer commits what is left
  subscriber.Stop();

  // --- what SQLite holds ---------------------------------------------------------------
  const size_t slots = plan.Slots();
  std::vector<char> stored(slots, 0);
  int64_t stored_rows = 0, value_mismatches = 0, stale_voltage = 0, foreign_rows = 0;
  std::vector<flexid::storage::Trial> trials;
  std::string integrity;
  try {
    flexid::storage::Database db = flexid::storage::Database::Open(database);
    trials = db.Trials(std::nullopt, -1);
    for (const auto& t : trials) {
      const auto i = ActuatorIndex(t.actuator_id, plan.actuators);
      for (const auto& s : db.Samples(t.id)) {
        ++stored_rows;
        const auto k = plan.Index(s.utime);
        if (!i || !k) {
          ++foreign_rows;
          continue;
        }
        const size_t slot = plan.Slot(*i, *k);
        stored[slot] = 1;
        if (s.deflection_mm != publisher.deflection_mm()[slot]) ++value_mismatches;
        if (s.voltage_V != plan.Voltage(*i, *k)) ++stale_voltage;
      }
    }
    integrity = db.IntegrityCheck();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "daemon_load: reading the database: %s\n", e.what());
    integrity = e.what();
  }

  // --- latency -------------------------------------------------------------------------
  const auto& pub = publisher.publish_ns();
  const auto& rx = subscriber.prediction_rx_ns();
  const auto& pk = subscriber.prediction_kernel_us();
  const auto& dk = subscriber.deflection_kernel_us();
  const int64_t window_start = identify ? Since(t0, identify_sent) : kUnset;
  const int64_t window_end =
      identify_reply ? Since(t0, identify_reply->received) : (identify ? INT64_MAX : kUnset);
  auto in_window = [&](int64_t ns) { return identify && ns >= window_start && ns <= window_end; };
  std::vector<double> ext_all, ext_out, ext_in, s2s_all, s2s_out, s2s_in;
  struct Point {
    int64_t publish_ns;
    double ext_us, s2s_us;  // s2s NAN when a kernel stamp is missing
  };
  std::vector<Point> points;
  const auto seconds = static_cast<size_t>(std::ceil(opt.seconds)) + 1;
  std::vector<std::vector<double>> ext_by_s(seconds), s2s_by_s(seconds);
  std::vector<int64_t> published_by_s(seconds, 0), missing_by_s(seconds, 0),
      nopred_by_s(seconds, 0);
  std::vector<int64_t> stored_by_actuator(static_cast<size_t>(plan.actuators), 0);
  int64_t published = 0, published_history = 0, history_not_in_db = 0, predictions_matched = 0,
          model_swapped_at_k = -1;
  for (int i = 0; i < plan.actuators; ++i) {
    for (int64_t k = plan.FirstK(i); k < plan.samples; ++k) {
      const size_t s = plan.Slot(i, k);
      if (pub[s] == kUnset) continue;
      ++published;
      if (k < 0) {  // L00's history: counted, not timed
        ++published_history;
        history_not_in_db += !stored[s];
        predictions_matched += rx[s] != kUnset;
        continue;
      }
      const size_t sec = std::min(seconds - 1, static_cast<size_t>(pub[s] / 1'000'000'000));
      ++published_by_s[sec];
      if (stored[s]) {
        ++stored_by_actuator[static_cast<size_t>(i)];
      } else {
        ++missing_by_s[sec];
      }
      if (rx[s] == kUnset) {
        ++nopred_by_s[sec];
        continue;
      }
      ++predictions_matched;
      if (i == 0 && model_swapped_at_k < 0 && subscriber.model_version()[s] > 0)
        model_swapped_at_k = k;
      const double ext_us = 1e-3 * static_cast<double>(rx[s] - pub[s]);
      points.push_back(
          {pub[s], ext_us,
           dk[s] != kUnset && pk[s] != kUnset ? static_cast<double>(pk[s] - dk[s]) : NAN});
      ext_all.push_back(ext_us);
      (in_window(pub[s]) ? ext_in : ext_out).push_back(ext_us);
      ext_by_s[sec].push_back(ext_us);
      if (dk[s] != kUnset && pk[s] != kUnset) {
        const auto s2s_us = static_cast<double>(pk[s] - dk[s]);
        s2s_all.push_back(s2s_us);
        (in_window(pub[s]) ? s2s_in : s2s_out).push_back(s2s_us);
        s2s_by_s[sec].push_back(s2s_us);
      }
    }
  }

  // --- report --------------------------------------------------------------------------
  const PublisherReport& pr = publisher.report();
  const double wall_s = 1e-9 * static_cast<double>(Since(wall_start, wall_end));
  const double cpu_s = CpuSeconds(usage_end) - CpuSeconds(usage_start);
  const int64_t delivered = c.predictions_published;  // one prediction per accepted deflection
  const int64_t delivered_voltages = c.samples_accepted - c.predictions_published;
  const int64_t rejected = c.rejected_malformed + c.rejected_nonfinite + c.rejected_out_of_order +
                           c.rejected_unknown_actuator;
  const int64_t daemon_drops =
      sockets_end.count(daemon_inode) ? sockets_end.at(daemon_inode).drops : -1;
  const int64_t bench_drops =
      sockets_end.count(bench_inode) ? sockets_end.at(bench_inode).drops : -1;

  std::printf(
      "sockets: daemon SO_RCVBUF %d bytes, bench SO_RCVBUF %d bytes "
      "(net.core.rmem_default %" PRId64 ", rmem_max %" PRId64 ")\n",
      daemon_rcvbuf, bench_rcvbuf, ReadNumberFile("/proc/sys/net/core/rmem_default"),
      ReadNumberFile("/proc/sys/net/core/rmem_max"));

  std::printf("\n== publisher (real-time schedule) ==\n");
  std::printf("  ticks %" PRId64 " of %" PRId64 ", each %d voltage + %d deflection messages\n",
              pr.ticks, plan.samples, plan.actuators, plan.actuators);
  std::printf(
      "  tick start lateness: mean %.3f ms, max %.3f ms; ticks later than one period "
      "(%.3f ms): %" PRId64 "%s\n",
      pr.ticks ? 1e-6 * static_cast<double>(pr.sum_lateness_ns) / static_cast<double>(pr.ticks)
               : 0.0,
      1e-6 * static_cast<double>(pr.max_lateness_ns), 1e3 / plan.rate_hz, pr.late_ticks,
      pr.late_ticks ? "  <-- FELL BEHIND (then caught up in a burst)" : "");
  if (pr.worst_tick >= 0)
    std::printf("  the latest tick was at t = %.3f s\n",
                static_cast<double>(pr.worst_tick) / plan.rate_hz);
  std::printf("  longest tick (publishing its messages): %.3f ms; publish failures: %" PRId64 "\n",
              1e-6 * static_cast<double>(pr.max_tick_ns), pr.publish_failures);

  std::printf("\n== counts ==                                         measured   target\n");
  std::printf("  published deflections                          %10" PRId64 "   (%" PRId64
              " of them L00's history before t0)\n",
              published, published_history);
  std::printf("  published voltages                             %10" PRId64 "\n", published);
  std::printf("  delivered deflections (daemon accepted;        %10" PRId64 "\n", delivered);
  std::printf("    = predictions_published)\n");
  std::printf("  delivered voltages (samples_accepted - above)  %10" PRId64 "\n",
              delivered_voltages);
  std::printf("  stored in SQLite (rows, all trials)            %10" PRId64
              "   (samples_stored "
              "counter %" PRId64 ")\n",
              stored_rows, c.samples_stored);
  std::printf("  LOST between delivery and storage              %10" PRId64
              "   0 (DESIGN.md: none)\n",
              delivered - stored_rows);
  std::printf("    of which dropped_queue_full                  %10" PRId64 "\n",
              c.dropped_queue_full);
  std::printf("  lost on the bus (published - delivered)        %10" PRId64
              "   (UDP loopback; not a daemon target)\n",
              published - delivered);
  std::printf("    kernel drops at the daemon's socket          %10" PRId64
              "   (all datagrams: voltages, deflections, its own predictions)\n",
              daemon_drops);
  std::printf("    host UDP RcvbufErrors during the run         %10" PRId64 "\n",
              rcvbuf_errors_after - rcvbuf_errors_before);
  std::printf("  rejected: malformed %" PRId64 ", nonfinite %" PRId64 ", out_of_order %" PRId64
              ", unknown_actuator %" PRId64 " (total %" PRId64 ")\n",
              c.rejected_malformed, c.rejected_nonfinite, c.rejected_out_of_order,
              c.rejected_unknown_actuator, rejected);
  std::printf("  stored rows: deflection differs from published %" PRId64
              ", voltage not the one published at that utime %" PRId64 ", unknown %" PRId64 "\n",
              value_mismatches, stale_voltage, foreign_rows);
  std::printf("  predictions received by this program           %10" PRId64 "   (matched %" PRId64
              ", duplicates %" PRId64 ", unmatched %" PRId64 "; return-path loss %" PRId64
              ", kernel drops at this program's socket %" PRId64 ")\n",
              subscriber.received(), predictions_matched, subscriber.duplicates(),
              subscriber.unmatched(), delivered - predictions_matched, bench_drops);
  std::printf("  alerts raised %" PRId64 "; messages_received %" PRId64 "\n", c.alerts_raised,
              c.messages_received);
  std::printf("  drain after the last sample: %.2f s (%s)\n", drain_s,
              drained ? "samples_stored caught up" : "TIMED OUT: samples_stored did not catch up");
  std::printf("  database integrity: %s\n", integrity.c_str());
  std::printf(
      "  wall time %.3f s (publishing); CPU time of the process %.3f s = %.0f%% of one "
      "core (2 cores here)\n",
      wall_s, cpu_s, wall_s > 0 ? 100.0 * cpu_s / wall_s : 0.0);
  {
    const double hz = static_cast<double>(sysconf(_SC_CLK_TCK));
    const double machine_s = static_cast<double>(machine_end.busy - machine_start.busy) / hz;
    const double steal_s = static_cast<double>(machine_end.steal - machine_start.steal) / hz;
    std::printf(
        "  machine: %.2f cores busy on average, of which other processes >= %.2f (steal %.2f; "
        "/proc/stat is tick-sampled and under-counts bursty threads)%s\n",
        wall_s > 0 ? machine_s / wall_s : 0.0,
        wall_s > 0 ? std::max(0.0, machine_s - cpu_s) / wall_s : 0.0,
        wall_s > 0 ? steal_s / wall_s : 0.0,
        machine_s - cpu_s > 0.1 * wall_s ? "  <-- SHARED MACHINE: other load disturbs the latency"
                                         : "");
  }

  std::printf(
      "\n== latency, deflection -> its prediction (ms) ==   target: p99 < 1 ms, also "
      "during identification\n");
  std::printf("  %-34s %8s %8s %8s %8s %8s %9s %8s\n", "", "n", "p50", "p90", "p99", "p99.9", "max",
              ">1ms");
  PrintStatsRow("external, all", Summarise(ext_all));
  if (identify) {
    PrintStatsRow("external, outside identification", Summarise(ext_out));
    PrintStatsRow("external, during identification", Summarise(ext_in));
  }
  if (opt.tap_deflections) {
    PrintStatsRow("socket to socket, all", Summarise(s2s_all));
    if (identify) {
      PrintStatsRow("socket to socket, outside ident.", Summarise(s2s_out));
      PrintStatsRow("socket to socket, during ident.", Summarise(s2s_in));
    }
  }
  std::printf(
      "  external: publish() call -> this program's handler: two loopback UDP hops + the "
      "daemon + this program's LCM receive thread and dispatch.\n");
  if (opt.tap_deflections)
    std::printf(
        "  socket to socket: kernel receive stamps (SO_TIMESTAMP, 1 us) of the deflection "
        "and of the prediction: the daemon (LCM receive thread, queue, loop, handler, "
        "publish) + one hop.\n");

  std::printf("\n== identification ==\n");
  if (!identify) {
    std::printf("  off\n");
  } else if (!identify_reply) {
    std::printf("  sent at t = %.3f s: NO REPLY within 120 s\n",
                1e-9 * static_cast<double>(window_start));
  } else {
    const auto& r = identify_reply->reply;
    std::printf(
        "  \"identify\" {actuator L00, latest 1} sent at t = %.3f s, reply after %.1f ms: "
        "status %d%s%s\n",
        1e-9 * static_cast<double>(window_start),
        1e-6 * static_cast<double>(window_end - window_start), r.status,
        r.error.empty() ? "" : ", error: ", r.error.c_str());
    if (r.status == flexid::rpc_reply_t::kOk) {
      const auto j = nlohmann::json::parse(r.result_json, nullptr, false);
      if (j.is_object())
        std::printf("  model version %s, trials %s, fit %s\n",
                    j.value("version", nlohmann::json()).dump().c_str(),
                    j.value("trials", nlohmann::json()).dump().c_str(),
                    j.value("fit", nlohmann::json()).dump().c_str());
    }
    if (model_swapped_at_k >= 0)
      std::printf("  first L00 prediction with the new model: sample %" PRId64 " (t = %.3f s)\n",
                  model_swapped_at_k, static_cast<double>(model_swapped_at_k) / plan.rate_hz);
  }

  if (!opt.dump.empty()) {
    std::ofstream out(opt.dump);
    out << "publish_ms,ext_ms,s2s_ms\n";
    for (const Point& p : points)
      out << 1e-6 * static_cast<double>(p.publish_ns) << ',' << 1e-3 * p.ext_us << ','
          << 1e-3 * p.s2s_us << '\n';
    std::printf("samples written to %s\n", opt.dump.c_str());
  }

  // Deflections published in a window after each event of the run: what the daemon did then
  // shows in their latency.
  {
    struct Event {
      std::string what;
      int64_t from_ns, to_ns;
    };
    std::vector<Event> events;
    if (plan.restart_k >= 0) {
      const auto at = static_cast<int64_t>(
          std::llround(static_cast<double>(plan.restart_k) * 1e9 / plan.rate_hz));
      events.push_back({"L00 trial stop + start, +100 ms", at, at + 100'000'000});
    }
    if (identify) {
      events.push_back({"identify request, +100 ms", window_start, window_start + 100'000'000});
      if (identify_reply) {
        events.push_back(
            {"identification running (rest)", window_start + 100'000'000, window_end - 20'000'000});
        events.push_back({"identify reply -20 ms .. +100 ms", window_end - 20'000'000,
                          window_end + 100'000'000});
      }
    }
    if (!events.empty()) {
      std::printf("\n== latency around events (ms) ==\n");
      std::printf("  %-34s %8s %8s %8s %8s %8s %9s %8s\n", "", "n", "p50", "p90", "p99", "p99.9",
                  "max", ">1ms");
      for (const Event& e : events) {
        std::vector<double> ext, s2s;
        for (const Point& p : points) {
          if (p.publish_ns < e.from_ns || p.publish_ns > e.to_ns) continue;
          ext.push_back(p.ext_us);
          if (std::isfinite(p.s2s_us)) s2s.push_back(p.s2s_us);
        }
        PrintStatsRow(("ext: " + e.what).c_str(), Summarise(ext));
        if (opt.tap_deflections) PrintStatsRow(("s2s: " + e.what).c_str(), Summarise(s2s));
      }
    }
  }

  std::printf("\n== per second of the run (by publish time of the deflection) ==\n");
  std::printf("  %4s %6s %5s %6s %7s %8s %8s %8s %8s %8s %8s %6s %6s\n", "s", "defl", "late",
              "not_db", "no_pred", "ext_p50", "ext_p99", "ext_max", "s2s_p50", "s2s_p99", "s2s_max",
              "ours", "others");
  for (size_t sec = 0; sec < seconds; ++sec) {
    if (published_by_s[sec] == 0) continue;
    const Stats e = Summarise(ext_by_s[sec]), s = Summarise(s2s_by_s[sec]);
    const auto sec_ns = static_cast<int64_t>(sec) * 1'000'000'000;
    const bool ident = identify && window_end >= sec_ns && window_start < sec_ns + 1'000'000'000;
    const bool restart =
        plan.restart_k >= 0 &&
        static_cast<size_t>(static_cast<double>(plan.restart_k) / plan.rate_hz) == sec;
    const bool sampled = sec < monitor.self_cores_.size();
    const double ours = sampled ? monitor.self_cores_[sec] : NAN;
    const double others = sampled ? std::max(0.0, monitor.machine_cores_[sec] - ours) : NAN;
    std::printf("  %4zu %6" PRId64 " %5" PRId64 " %6" PRId64 " %7" PRId64
                " %8s %8s %8s %8s %8s %8s %6.2f %6.2f%s%s\n",
                sec, published_by_s[sec], sec < pr.late_by_s.size() ? pr.late_by_s[sec] : 0,
                missing_by_s[sec], nopred_by_s[sec], Ms(e.p50).c_str(), Ms(e.p99).c_str(),
                Ms(e.max).c_str(), Ms(s.p50).c_str(), Ms(s.p99).c_str(), Ms(s.max).c_str(), ours,
                others, restart ? "  L00 trial restart" : "", ident ? "  identification" : "");
  }
  std::printf(
      "  ours / others: cores busy with this process / at least with other processes "
      "(2 cores; /proc/stat)\n");
  std::printf(
      "  late: publisher ticks that started more than one period late; not_db: deflections "
      "not in SQLite; no_pred: no prediction received\n");

  std::printf("\n== CPU by thread during the run (s) ==\n");
  std::map<pid_t, std::string> labels;
  {
    for (size_t n = 0; n < daemon_threads.size(); ++n)
      labels[daemon_threads[n]] = n < 3 ? kDaemonThreadRoles[n] : "started by the daemon";
    for (const auto& [tid, t] : threads_end)
      if (!threads_before_daemon.count(tid) && t.name == "flexidd" && !labels.count(tid))
        labels[tid] = "started by the daemon";
    labels[daemon_loop_tid] = "event loop";
    for (const auto& [tid, t] : threads_end)
      if (t.name == "bench-sub") labels[tid] = tid == subscriber_tid ? "dispatch" : "LCM receive";
  }
  for (const auto& [tid, t] : threads_end) {
    const auto it = threads_start.find(tid);
    const int64_t before = it != threads_start.end() ? it->second.cpu_ns : 0;
    std::printf("  %-14s %-22s tid %-7d %7.3f\n", t.name.c_str(),
                labels.count(tid) ? labels[tid].c_str() : "", tid,
                1e-9 * static_cast<double>(t.cpu_ns - before));
  }
  std::printf("  %-14s %-22s %-11s %7.3f\n", "bench-pub", "publisher", "",
              1e-9 * static_cast<double>(pr.cpu_ns));

  std::printf("\n== trials in the database ==\n");
  std::printf("  %5s %-4s %-10s %8s   published deflections in its span\n", "id", "act.", "state",
              "samples");
  for (auto it = trials.rbegin(); it != trials.rend(); ++it) {
    const auto i = ActuatorIndex(it->actuator_id, plan.actuators);
    int64_t expected = 0;
    if (i) {
      for (int64_t k = plan.FirstK(*i); k < plan.samples; ++k) {
        const int64_t u = plan.Utime(k);
        if (u >= it->start_utime && (it->end_utime == 0 || u <= it->end_utime) &&
            pub[plan.Slot(*i, k)] != kUnset)
          ++expected;
      }
    }
    std::printf("  %5" PRId64 " %-4s %-10s %8" PRId64 "   %" PRId64 "\n", it->id,
                it->actuator_id.c_str(), flexid::storage::TrialStateName(it->state), it->samples,
                expected);
  }

  if (opt.keep) {
    std::printf("\ndatabase kept: %s\n", database.c_str());
  } else {
    std::error_code ignored;
    fs::remove_all(dir, ignored);
  }
  return 0;
}
