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
//       [--channel-prefix FLEXID (the daemon's channel_prefix, and this program's channels)]
//   soak (issue 7; bench/soak runs --seconds 600 --identify-every 60):
//       [--identify-every S (instead of --identify-at)] [--sample-every 10]
//       [--warmup-s 60 (S + 30 with --identify-every)]
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
//  - Subscriber: PREFIX/.*/PREDICTION (and, with --tap-deflections 1, PREFIX/.*/DEFLECTION,
//    only for its kernel receive time stamp) and the RPC replies.
//  - At --identify-at: "identify" {"actuator": "L00", "latest": 1} (L00's first trial).
//  - Or, with --identify-every S, at S, 2S, ...: "identify" {"actuator": L<j mod N>,
//    "latest": 1}, each on a trial of --first-trial-s (default 22 s, 11,000 samples at 500 Hz):
//    that actuator's trial is stopped and restarted --first-trial-s + 1 s and 1 s before.
//    Every --sample-every seconds a line: the process's VmRSS and VmHWM, the daemon's
//    counters and backlogs, and the latency in that window (fixed-size histograms, so that
//    this program's memory does not grow with the run; its per-sample arrays, used for the
//    read-back, are allocated and written before t0). A soak summary ends the output.
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
//  - bus floor, from the same run: 100 times a second the publisher sends a small message
//    on the same multicast address one port up; a thread of this program with its own LCM
//    (receive thread, a loop polling LCM's descriptor, a handler that publishes) echoes it,
//    and the subscriber takes both kernel stamps, as for socket to socket. The summary
//    gives the floor's p50/p99, the daemon's p50/p99/p99.9 and their ratio, outside and
//    during identification, with the load average before and after the run.
//  - scheduling by thread, outside and during identification: CPU, run-queue wait and
//    preemptions of every thread (/proc/self/task/T/schedstat and status).
#include <poll.h>
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
#include <flexid/status_t.hpp>
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

#include "bus/channels.h"
#include "bus/lcm_url.h"
#include "bus/rpc_client.h"
#include "bus/sample_publisher.h"
#include "daemon/config.h"
#include "daemon/daemon.h"
#include "lcmtypes/message_auth.h"
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
// The bus floor: a small message echoed by a thread that does nothing else (Echo), on the
// same multicast address one port up, so that neither the daemon nor the echo reads the
// other's traffic.
constexpr const char* kPingChannel = "DAEMON_LOAD_PING";
constexpr const char* kPongChannel = "DAEMON_LOAD_PONG";
constexpr double kPingHz = 100;  // pings per second, sent by the publisher after a tick

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
  std::string channel_prefix = flexid::bus::kDefaultPrefix;  // the daemon's and ours
  bool keep = false;                                         // keep the temporary database
  std::string dump;            // CSV of every timed sample, for offline analysis
  int renice_workers = 0;      // experiment: nice of the daemon's writer and worker threads
  int commit_interval_ms = 0;  // the daemon's commit_interval_ms (0: its default)
  bool pin_threads = false;    // the daemon's pin_threads setting (daemon/config.h)
  // soak
  double identify_every = 0;  // > 0: an identification every S seconds (rotating actuators)
  double sample_every = 10;   // seconds between sample lines
  double warmup_s = 60;       // the memory fit starts here (default with --identify-every: S + 30)
  bool identify_at_given = false;
  bool sample_every_given = false;
  bool warmup_given = false;
};

[[noreturn]] void Usage(const std::string& problem) {
  std::fprintf(stderr,
               "daemon_load: %s\nusage: daemon_load [--seconds S] [--actuators N] [--rate-hz R] "
               "[--identify-at S] [--period-s S] [--first-trial-s S] [--recv-buf-size BYTES] "
               "[--tap-deflections 0|1] "
               "[--log-level LEVEL] [--dump FILE.csv] [--commit-interval-ms MS] "
               "[--channel-prefix PREFIX] "
               "[--renice-workers NICE] [--pin-threads] [--keep] "
               "[--identify-every S] [--sample-every S] [--warmup-s S]\n",
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
    else if (flag == "--identify-at") {
      o.identify_at = Number(flag, value);
      o.identify_at_given = true;
    } else if (flag == "--identify-every")
      o.identify_every = Number(flag, value);
    else if (flag == "--sample-every") {
      o.sample_every = Number(flag, value);
      o.sample_every_given = true;
    } else if (flag == "--warmup-s") {
      o.warmup_s = Number(flag, value);
      o.warmup_given = true;
    } else if (flag == "--period-s")
      o.period_s = Number(flag, value);
    else if (flag == "--first-trial-s")
      o.first_trial_s = Number(flag, value);
    else if (flag == "--recv-buf-size")
      o.recv_buf_size = static_cast<int64_t>(Number(flag, value));
    else if (flag == "--tap-deflections")
      o.tap_deflections = Number(flag, value) != 0.0;
    else if (flag == "--log-level")
      o.log_level = value;
    else if (flag == "--channel-prefix")
      o.channel_prefix = value;
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
  if (!flexid::bus::IsValidPrefix(o.channel_prefix))
    Usage("--channel-prefix " + flexid::bus::PrefixProblem(o.channel_prefix));
  if (o.identify_every > 0) {
    if (o.identify_at_given && o.identify_at > 0)
      Usage("--identify-at and --identify-every exclude each other");
    o.identify_at = 0;
    if (o.identify_every < o.first_trial_s + 2 || o.identify_every > o.seconds - 0.5)
      Usage("--identify-every must be in [first-trial-s + 2, seconds - 0.5]");
  }
  if (o.sample_every < 1 || o.sample_every > 600) Usage("--sample-every must be 1..600");
  // The warm-up includes the first identification (its working memory, the worker's arena).
  if (o.identify_every > 0 && !o.warmup_given) o.warmup_s = o.identify_every + 30;
  if (o.warmup_s < 0) Usage("--warmup-s must be >= 0");
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
  int64_t ping_every = 5;  // a ping (the bus floor) after every ping_every-th tick
  // Every trial stop + restart (restart_k's among them), sorted by tick: {tick, actuator}.
  std::vector<std::pair<int64_t, int>> restarts;

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
  size_t Pings() const { return static_cast<size_t>(samples / ping_every + 1); }
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
  // Trial control is signed with `key`, that of the daemon under test.
  Publisher(const Plan& plan, const std::string& url, const std::string& floor_url,
            const flexid::bus::Channels& channels, Clock::time_point history_start,
            double history_speed, Clock::time_point t0, const flexid::auth::Key& key)
      : plan_(plan),
        key_(key),
        lcm_(url),
        floor_lcm_(floor_url),
        history_start_(history_start),
        history_speed_(history_speed),
        t0_(t0),
        publish_ns_(plan.Slots()),
        deflection_mm_(plan.Slots(), NAN),
        state_(static_cast<size_t>(plan.actuators), 0.0),
        dead_(static_cast<int64_t>(std::llround(kDeadTimeS * plan.rate_hz))),
        a_(std::exp(-1.0 / (plan.rate_hz * kTauS))) {
    for (auto& p : publish_ns_) p.store(kUnset, std::memory_order_relaxed);
    for (int i = 0; i < plan_.actuators; ++i)
      actuators_.emplace_back(lcm_, channels, ActuatorId(i), &key_);
    report_.late_by_s.assign(
        static_cast<size_t>(static_cast<double>(plan.samples) / plan.rate_hz) + 2, 0);
  }
  bool good() { return lcm_.good() && floor_lcm_.good(); }

  void Run() {
    NameThread("bench-pub");
    for (int i = 0; i < plan_.actuators; ++i)
      Control(i, flexid::bus::TrialAction::kStart, plan_.Utime(plan_.FirstK(i)) - 1, "daemon_load");
    for (int64_t k = -plan_.history; k < 0; ++k) {
      std::this_thread::sleep_until(history_start_ + std::chrono::nanoseconds(std::llround(
                                                         static_cast<double>(k + plan_.history) *
                                                         1e9 / (plan_.rate_hz * history_speed_))));
      PublishSample(0, k);
    }
    std::this_thread::sleep_until(t0_);
    const int64_t cpu_start = ThreadCpuNs();
    const double period_ns = 1e9 / plan_.rate_hz;
    size_t next_restart = 0;
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
      for (; next_restart < plan_.restarts.size() && plan_.restarts[next_restart].first <= k;
           ++next_restart) {
        const int a = plan_.restarts[next_restart].second;
        Control(a, flexid::bus::TrialAction::kStop, plan_.Utime(k) - 1, "");
        Control(a, flexid::bus::TrialAction::kStart, plan_.Utime(k), "daemon_load next trial");
      }
      for (int i = 0; i < plan_.actuators; ++i) PublishSample(i, k);
      if (k % plan_.ping_every == 0) Ping(k / plan_.ping_every);
      report_.max_tick_ns = std::max(report_.max_tick_ns, Since(start, Clock::now()));
      ++report_.ticks;
    }
    report_.end = Clock::now();
    report_.cpu_ns = ThreadCpuNs() - cpu_start;
    for (int i = 0; i < plan_.actuators; ++i)
      Control(i, flexid::bus::TrialAction::kStop, plan_.Utime(plan_.samples - 1) + 1, "");
  }

  const PublisherReport& report() const { return report_; }
  // Read by the subscriber's handler while the run goes on (relaxed atomics).
  const std::vector<std::atomic<int64_t>>& publish_ns() const { return publish_ns_; }
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
    const int64_t utime = plan_.Utime(k);
    const double driving = k - dead_ >= plan_.FirstK(i) ? plan_.Voltage(i, k - dead_) : 0.0;
    state_[s] = a_ * state_[s] + (1.0 - a_) * kGainMmPerV * driving;
    const double deflection_mm = state_[s] + noise_(random_);
    if (!actuators_[s].PublishVoltage(utime, plan_.Voltage(i, k))) ++report_.publish_failures;
    deflection_mm_[plan_.Slot(i, k)] = deflection_mm;
    publish_ns_[plan_.Slot(i, k)].store(Since(t0_, Clock::now()), std::memory_order_relaxed);
    if (!actuators_[s].PublishDeflection(utime, deflection_mm)) ++report_.publish_failures;
  }

  // The bus floor's ping: sequence number and publish time (steady ns since t0).
  void Ping(int64_t seq) {
    flexid::deflection_sample_t ping;
    ping.utime = Since(t0_, Clock::now());
    ping.actuator_id = "PING";
    ping.deflection_mm = static_cast<double>(seq);
    if (floor_lcm_.publish(kPingChannel, &ping) != 0) ++report_.publish_failures;
  }

  void Control(int actuator, flexid::bus::TrialAction action, int64_t utime,
               const std::string& protocol) {
    if (!actuators_[static_cast<size_t>(actuator)].PublishTrialControl(utime, action, protocol))
      ++report_.publish_failures;
  }

  const Plan plan_;
  const flexid::auth::Key key_;
  lcm::LCM lcm_;
  lcm::LCM floor_lcm_;  // pings only (publishes; no receive thread)
  const Clock::time_point history_start_;
  const double history_speed_;
  const Clock::time_point t0_;
  std::vector<std::atomic<int64_t>> publish_ns_;  // per slot: steady ns since t0 before publish
  std::vector<double> deflection_mm_;             // per slot: the value published
  std::vector<double> state_;                     // per actuator: the lag's output, mm
  const int64_t dead_;                            // dead time, samples
  const double a_;                                // the lag's pole
  std::mt19937_64 random_{42};
  std::normal_distribution<double> noise_{0.0, kNoiseMm};
  std::vector<flexid::bus::SamplePublisher> actuators_;  // L00, L01, ...
  PublisherReport report_;
};

// --- latency histogram -----------------------------------------------------------------

// Latencies in microseconds, in fixed memory (24 KiB): 1 us buckets below 1,024 us, then 64
// buckets per power of two (a bucket is < 1.6 % wide), up to 2^40 us. A quantile is the
// lower edge of the bucket holding the nearest-rank sample; the maximum is exact.
class Histogram {
 public:
  void Add(double us) {
    ++count_;
    max_ = std::max(max_, us);
    over_1ms_ += us > 1000.0;
    ++buckets_[Bucket(us)];
  }
  void Merge(const Histogram& other) {
    for (size_t b = 0; b < kBuckets; ++b) buckets_[b] += other.buckets_[b];
    count_ += other.count_;
    over_1ms_ += other.over_1ms_;
    max_ = std::max(max_, other.max_);
  }
  size_t count() const { return count_; }
  double Quantile(double q) const {
    if (count_ == 0) return NAN;
    const auto rank =
        std::max<size_t>(1, static_cast<size_t>(std::ceil(q * static_cast<double>(count_))));
    size_t seen = 0;
    for (size_t b = 0; b < kBuckets; ++b) {
      seen += buckets_[b];
      if (seen >= rank) return std::min(LowerEdge(b), max_);
    }
    return max_;
  }
  double max() const { return count_ ? max_ : NAN; }
  size_t over_1ms() const { return over_1ms_; }

 private:
  static constexpr size_t kLinear = 1024, kSub = 64, kBuckets = kLinear + 31 * kSub;
  static size_t Bucket(double us) {
    if (!(us > 0)) return 0;
    const auto v = static_cast<uint64_t>(std::min(us, 1e12));
    if (v < kLinear) return static_cast<size_t>(v);
    const int e = 63 - __builtin_clzll(v);  // >= 10
    const size_t b = kLinear + static_cast<size_t>(e - 10) * kSub + ((v >> (e - 6)) & (kSub - 1));
    return std::min(b, kBuckets - 1);
  }
  static double LowerEdge(size_t b) {
    if (b < kLinear) return static_cast<double>(b);
    const size_t e = (b - kLinear) / kSub + 10, sub = (b - kLinear) % kSub;
    return std::ldexp(1.0, static_cast<int>(e)) * (1.0 + static_cast<double>(sub) / kSub);
  }
  std::vector<uint64_t> buckets_ = std::vector<uint64_t>(kBuckets, 0);
  size_t count_ = 0, over_1ms_ = 0;
  double max_ = 0;
};

// What the subscriber's handler measured in one sample window, split by whether the
// deflection was published while an identify request was outstanding.
// floor: the echo of a ping (the bus floor), socket to socket like s2s.
struct LiveLatency {
  Histogram ext_in, ext_out, s2s_in, s2s_out, floor_in, floor_out;
  void Merge(const LiveLatency& o) {
    ext_in.Merge(o.ext_in);
    ext_out.Merge(o.ext_out);
    s2s_in.Merge(o.s2s_in);
    s2s_out.Merge(o.s2s_out);
    floor_in.Merge(o.floor_in);
    floor_out.Merge(o.floor_out);
  }
};

// --- the bus floor: an echo --------------------------------------------------------------

// Echoes every ping as a pong, on a thread and an LCM instance of its own, as the daemon
// handles a deflection (LCM's receive thread, a loop polling LCM's descriptor, a handler
// that publishes) but with no work in between: the round trip of a small message on the
// same machine at the same moment, the floor under the daemon's figure.
class Echo {
 public:
  explicit Echo(const std::string& url) : url_(url) {}
  bool Start() {
    std::promise<bool> ready;
    auto future = ready.get_future();
    thread_ = std::thread([this, &ready] {
      NameThread("bench-echo");  // LCM's receive thread inherits the name
      lcm::LCM lcm(url_);
      if (!lcm.good()) {
        ready.set_value(false);
        return;
      }
      lcm.subscribeFunction(flexid::bus::Exactly(kPingChannel), &Echo::OnPing, &lcm)
          ->setQueueCapacity(1000);
      ready.set_value(true);
      while (!stop_) lcm.handleTimeout(20);
    });
    return future.get();
  }
  void Stop() {
    stop_ = true;
    if (thread_.joinable()) thread_.join();
  }
  ~Echo() { Stop(); }

 private:
  static void OnPing(const lcm::ReceiveBuffer* rbuf, const std::string&, lcm::LCM* lcm) {
    lcm->publish(kPongChannel, rbuf->data, rbuf->data_size);
  }
  const std::string url_;
  std::thread thread_;
  std::atomic<bool> stop_{false};
};

// --- subscriber ------------------------------------------------------------------------

using ReplyRecord = flexid::bus::RpcReply;

class Subscriber {
 public:
  Subscriber(const Plan& plan, const std::string& url, const std::string& floor_url,
             const flexid::bus::Channels& channels, bool tap_deflections)
      : plan_(plan),
        url_(url),
        floor_url_(floor_url),
        channels_(channels),
        tap_(tap_deflections),
        prediction_rx_ns_(plan.Slots(), kUnset),
        prediction_kernel_us_(plan.Slots(), kUnset),
        deflection_kernel_us_(plan.Slots(), kUnset),
        model_version_(plan.Slots(), -1),
        ping_kernel_us_(plan.Pings(), kUnset) {}

  // The daemon's key, for the requests that change data; before the first Call().
  void SetKey(const flexid::auth::Key& key) { key_ = key; }

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
  // Live latency (the soak's sample windows): set before the publisher starts.
  void SetPublishTimes(const std::vector<std::atomic<int64_t>>* publish_ns) {
    live_publish_ns_ = publish_ns;
  }
  // An identify request outstanding from sent_ns (ns since t0) until IdentificationEnded.
  void IdentificationStarted(int64_t sent_ns) {
    ident_end_ns_ = INT64_MAX;
    ident_sent_ns_ = sent_ns;
  }
  void IdentificationEnded(int64_t end_ns) { ident_end_ns_ = end_ns; }
  // The latency measured since the last call.
  LiveLatency TakeWindow() {
    LiveLatency out;
    std::lock_guard lock(live_mutex_);
    std::swap(out, live_);
    return out;
  }
  // The daemon's last PREFIX/STATUS heartbeat (once a second), if any.
  std::optional<flexid::status_t> LatestStatus() {
    std::lock_guard lock(live_mutex_);
    return status_;
  }

  // Sends a request and waits for its reply (handled on the subscriber's thread); `sent`:
  // just before the request is built and signed.
  std::optional<ReplyRecord> Call(const std::string& method, const nlohmann::json& args,
                                  std::chrono::milliseconds timeout,
                                  Clock::time_point* sent = nullptr) {
    if (sent) *sent = Clock::now();
    return rpc_->Call(method, args.dump(), timeout);
  }

  // The bus floor over the whole run, outside and during identification (after Stop()).
  const Histogram& floor_out() const { return floor_run_.floor_out; }
  const Histogram& floor_in() const { return floor_run_.floor_in; }
  int64_t pongs_unmatched() const { return pongs_unmatched_; }

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
    floor_lcm_ = std::make_unique<lcm::LCM>(floor_url_);
    if (!lcm_->good() || !floor_lcm_->good()) {
      ready->set_value(false);
      return;
    }
    lcm_->subscribeFunction(channels_.AllPredictions(), &Subscriber::OnPrediction, this)
        ->setQueueCapacity(1 << 20);
    if (tap_)
      lcm_->subscribeFunction(channels_.AllDeflections(), &Subscriber::OnDeflection, this)
          ->setQueueCapacity(1 << 20);
    rpc_ = std::make_unique<flexid::bus::RpcClient>(*lcm_, channels_, kClientId, &key_,
                                                    flexid::bus::RpcClient::Dispatch::kElsewhere);
    lcm_->subscribeFunction(flexid::bus::Exactly(channels_.Status()), &Subscriber::OnStatus, this)
        ->setQueueCapacity(10);
    floor_lcm_->subscribeFunction(flexid::bus::Exactly(kPingChannel), &Subscriber::OnPing, this)
        ->setQueueCapacity(1000);
    floor_lcm_->subscribeFunction(flexid::bus::Exactly(kPongChannel), &Subscriber::OnPong, this)
        ->setQueueCapacity(1000);
    ready->set_value(true);
    while (!stop_) {
      pollfd fds[2] = {{lcm_->getFileno(), POLLIN, 0}, {floor_lcm_->getFileno(), POLLIN, 0}};
      if (poll(fds, 2, 10) <= 0) continue;
      if (fds[0].revents & POLLIN) lcm_->handleTimeout(0);
      if (fds[1].revents & POLLIN) floor_lcm_->handleTimeout(0);
    }
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
    const int64_t rx_ns = Since(Clock::time_point(Clock::duration(self->t0_ns_.load())), now);
    self->prediction_rx_ns_[s] = rx_ns;
    self->prediction_kernel_us_[s] = rbuf->recv_utime;
    self->model_version_[s] = p.model_version;
    if (*k < 0 || !self->live_publish_ns_) return;  // L00's history is not timed
    const int64_t pub = (*self->live_publish_ns_)[s].load(std::memory_order_relaxed);
    if (pub == kUnset) return;
    const int64_t sent = self->ident_sent_ns_.load(), end = self->ident_end_ns_.load();
    const bool in = sent != kUnset && pub >= sent && pub <= end;
    const int64_t dk = self->deflection_kernel_us_[s];
    std::lock_guard lock(self->live_mutex_);
    (in ? self->live_.ext_in : self->live_.ext_out).Add(1e-3 * static_cast<double>(rx_ns - pub));
    if (dk != kUnset)
      (in ? self->live_.s2s_in : self->live_.s2s_out)
          .Add(static_cast<double>(rbuf->recv_utime - dk));
  }

  // The ping's kernel stamp on this program's socket (also when it reached the echo's).
  static void OnPing(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::deflection_sample_t ping;
    if (ping.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    const auto seq = static_cast<size_t>(ping.deflection_mm);
    if (seq < self->ping_kernel_us_.size()) self->ping_kernel_us_[seq] = rbuf->recv_utime;
  }

  static void OnPong(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::deflection_sample_t pong;
    if (pong.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    const auto seq = static_cast<size_t>(pong.deflection_mm);
    if (seq >= self->ping_kernel_us_.size() || self->ping_kernel_us_[seq] == kUnset) {
      ++self->pongs_unmatched_;
      return;
    }
    const int64_t pub = pong.utime;  // steady ns since t0 when the ping was published
    const int64_t sent = self->ident_sent_ns_.load(), end = self->ident_end_ns_.load();
    const bool in = sent != kUnset && pub >= sent && pub <= end;
    const auto us = static_cast<double>(rbuf->recv_utime - self->ping_kernel_us_[seq]);
    std::lock_guard lock(self->live_mutex_);
    (in ? self->live_.floor_in : self->live_.floor_out).Add(us);
    (in ? self->floor_run_.floor_in : self->floor_run_.floor_out).Add(us);
  }

  static void OnStatus(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::status_t st;
    if (st.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    std::lock_guard lock(self->live_mutex_);
    self->status_ = st;
  }

  static void OnDeflection(const lcm::ReceiveBuffer* rbuf, const std::string&, Subscriber* self) {
    flexid::deflection_sample_t d;
    if (d.decode(rbuf->data, 0, static_cast<int>(rbuf->data_size)) <= 0) return;
    const auto i = ActuatorIndex(d.actuator_id, self->plan_.actuators);
    const auto k = self->plan_.Index(d.utime);
    if (i && k) self->deflection_kernel_us_[self->plan_.Slot(*i, *k)] = rbuf->recv_utime;
  }

  const Plan plan_;
  const std::string url_, floor_url_;
  const flexid::bus::Channels channels_;
  const bool tap_;
  flexid::auth::Key key_;  // SetKey()
  std::atomic<Clock::rep> t0_ns_{0};
  std::unique_ptr<lcm::LCM> lcm_;
  std::unique_ptr<lcm::LCM> floor_lcm_;          // the bus floor's pings and pongs
  std::unique_ptr<flexid::bus::RpcClient> rpc_;  // on lcm_, replies handled by Run()
  std::thread thread_;
  std::atomic<bool> stop_{false};
  pid_t tid_ = 0;
  // Written by the subscriber thread only; read after it has been joined.
  int64_t received_ = 0, unmatched_ = 0, duplicates_ = 0;
  std::vector<int64_t> prediction_rx_ns_;      // steady ns since t0 in the handler
  std::vector<int64_t> prediction_kernel_us_;  // SO_TIMESTAMP of the prediction, us
  std::vector<int64_t> deflection_kernel_us_;  // SO_TIMESTAMP of the deflection, us
  std::vector<int32_t> model_version_;
  std::vector<int64_t> ping_kernel_us_;  // SO_TIMESTAMP of each ping, us
  int64_t pongs_unmatched_ = 0;
  // Live figures, shared with the soak's sampler.
  const std::vector<std::atomic<int64_t>>* live_publish_ns_ = nullptr;
  std::atomic<int64_t> ident_sent_ns_{kUnset}, ident_end_ns_{kUnset};
  std::mutex live_mutex_;
  LiveLatency live_;
  LiveLatency floor_run_;  // only the floor, over the whole run
  std::optional<flexid::status_t> status_;
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
  // The counters while the daemon runs (thread-safe: relaxed atomics); between Start and Stop.
  Counters Live() const { return daemon_->counters(); }
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

// What the scheduler did with one thread: CPU time, time spent runnable but waiting for
// a CPU (/proc/self/task/T/schedstat: run-queue wait), time slices, and context switches
// (status: voluntary ones are waits for input, involuntary ones preemptions).
struct ThreadSched {
  std::string name;
  int64_t cpu_ns = 0, wait_ns = 0, slices = 0, voluntary = 0, involuntary = 0, faults = 0;
  void Add(const ThreadSched& later, const ThreadSched& earlier) {
    faults += later.faults - earlier.faults;
    cpu_ns += later.cpu_ns - earlier.cpu_ns;
    wait_ns += later.wait_ns - earlier.wait_ns;
    slices += later.slices - earlier.slices;
    voluntary += later.voluntary - earlier.voluntary;
    involuntary += later.involuntary - earlier.involuntary;
  }
};

std::map<pid_t, ThreadSched> ThreadScheds() {
  std::map<pid_t, ThreadSched> out;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/proc/self/task", ec)) {
    const pid_t tid = static_cast<pid_t>(std::stol(entry.path().filename().string()));
    ThreadSched t;
    std::ifstream comm(entry.path() / "comm");
    std::getline(comm, t.name);
    std::ifstream stat(entry.path() / "schedstat");
    stat >> t.cpu_ns >> t.wait_ns >> t.slices;
    {
      // stat: "tid (comm) state ..." with minflt the 10th field; comm may hold spaces.
      std::ifstream stat_file(entry.path() / "stat");
      std::string text;
      std::getline(stat_file, text);
      const size_t close = text.rfind(')');
      if (close != std::string::npos) {
        std::istringstream fields(text.substr(close + 2));
        std::string field;
        for (int n = 3; n <= 10 && fields >> field; ++n)
          if (n == 10) t.faults = std::stoll(field);
      }
    }
    std::ifstream status(entry.path() / "status");
    std::string line;
    while (std::getline(status, line)) {
      if (line.rfind("voluntary_ctxt_switches:", 0) == 0) t.voluntary = std::stoll(line.substr(24));
      if (line.rfind("nonvoluntary_ctxt_switches:", 0) == 0)
        t.involuntary = std::stoll(line.substr(27));
    }
    out[tid] = t;
  }
  return out;
}

// The threads' scheduling split into time outside and during identification: Mark() at
// each change, the difference since the last mark goes to the phase that ended.
class SchedSplit {
 public:
  void Start() {
    last_ = ThreadScheds();
    last_at_ = Clock::now();
  }
  void Mark(bool ended_identification) {
    const auto now = ThreadScheds();
    const Clock::time_point at = Clock::now();
    auto& phase = ended_identification ? during_ : outside_;
    (ended_identification ? during_s_ : outside_s_) +=
        1e-9 * static_cast<double>(Since(last_at_, at));
    for (const auto& [tid, t] : now) {
      ThreadSched& sum = phase[tid];
      sum.name = t.name;
      const auto it = last_.find(tid);
      sum.Add(t, it != last_.end() ? it->second : ThreadSched{});
    }
    last_ = now;
    last_at_ = at;
  }
  std::map<pid_t, ThreadSched> outside_, during_;
  double outside_s_ = 0, during_s_ = 0;

 private:
  std::map<pid_t, ThreadSched> last_;
  Clock::time_point last_at_;
};

std::string LoadAverage() {
  std::ifstream in("/proc/loadavg");
  std::string one, five, fifteen;
  in >> one >> five >> fifteen;
  return one + " " + five + " " + fifteen;
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

// --- soak: a sample line every few seconds ------------------------------------------------

// VmRSS and VmHWM of this process, KiB (/proc/self/status).
std::pair<int64_t, int64_t> ResidentKiB() {
  std::ifstream in("/proc/self/status");
  std::string line;
  int64_t rss = -1, hwm = -1;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) rss = std::stoll(line.substr(6));
    if (line.rfind("VmHWM:", 0) == 0) hwm = std::stoll(line.substr(6));
  }
  return {rss, hwm};
}

struct SoakRow {
  double t_s = 0;
  // Polled every 50 ms within the window (a single snapshot every 10 s would alias with the
  // daemon's 100 ms commits): VmRSS mean and max, the backlog mean and max.
  double rss_mean_kib = 0, backlog_mean = 0;
  int64_t rss_max_kib = 0, hwm_kib = 0, backlog_max = 0;
  int64_t writer_depth_max = -1;  // max writer_queue_depth of the STATUS heartbeats (1/s)
  int64_t socket_rx_queue_max = -1, socket_drops = -1;  // the daemon's UDP socket
  Counters c;                                           // at the end of the window
  bool identification = false;  // an identify request was outstanding in the window
  double machine_cores = 0, self_cores = 0;
  Stats ext, s2s;  // this window
};

Stats FromHistogram(const Histogram& h) {
  Stats s;
  s.n = h.count();
  s.p50 = h.Quantile(0.50);
  s.p90 = h.Quantile(0.90);
  s.p99 = h.Quantile(0.99);
  s.p999 = h.Quantile(0.999);
  s.max = h.max();
  s.over_1ms = h.over_1ms();
  return s;
}

std::string Ratio(double daemon_us, double floor_us) {
  if (!std::isfinite(daemon_us) || !std::isfinite(floor_us) || floor_us <= 0) return "-";
  char b[32];
  std::snprintf(b, sizeof b, "%.1fx", daemon_us / floor_us);
  return b;
}

// The figures of the README's table, from one run: the bus floor (a ping's echo) and the
// daemon (a deflection's prediction), both socket to socket, outside and during
// identification, their ratio, and the load average before and after.
void PrintTableFigures(const Stats& daemon_out, const Stats& daemon_in, const Histogram& floor_out,
                       const Histogram& floor_in, const std::string& load_start,
                       const std::string& load_end, bool identify) {
  std::printf(
      "\n== summary: bus floor and daemon, socket to socket (ms) ==   target: daemon p99 < 1 "
      "ms, also during identification\n");
  std::printf("  load average (1, 5, 15 min): %s before, %s after\n", load_start.c_str(),
              load_end.c_str());
  std::printf("  %-34s %8s %8s %8s %8s %8s %9s %8s\n", "", "n", "p50", "p90", "p99", "p99.9", "max",
              ">1ms");
  const Stats fo = FromHistogram(floor_out), fi = FromHistogram(floor_in);
  PrintStatsRow("bus floor, outside identification", fo);
  if (identify) PrintStatsRow("bus floor, during identification", fi);
  PrintStatsRow("daemon, outside identification", daemon_out);
  if (identify) PrintStatsRow("daemon, during identification", daemon_in);
  std::printf("  ratio daemon / floor: outside p50 %s, p99 %s",
              Ratio(daemon_out.p50, fo.p50).c_str(), Ratio(daemon_out.p99, fo.p99).c_str());
  if (identify)
    std::printf("; during p50 %s, p99 %s", Ratio(daemon_in.p50, fi.p50).c_str(),
                Ratio(daemon_in.p99, fi.p99).c_str());
  const bool met = daemon_out.p99 < 1000 && (!identify || daemon_in.n == 0 || daemon_in.p99 < 1000);
  std::printf("\n  daemon p99 < 1 ms outside%s: %s\n", identify ? " and during identification" : "",
              met ? "met" : "NOT MET");
  // One line with every figure, for a table.
  std::printf(
      "  table: load %s | floor p50/p99 %s/%s | outside p50/p99/p99.9 %s/%s/%s | during "
      "p50/p99/p99.9 %s/%s/%s | floor during p50/p99 %s/%s | p99 ratio %s / %s\n",
      load_start.substr(0, load_start.find(' ')).c_str(), Ms(fo.p50).c_str(), Ms(fo.p99).c_str(),
      Ms(daemon_out.p50).c_str(), Ms(daemon_out.p99).c_str(), Ms(daemon_out.p999).c_str(),
      Ms(daemon_in.p50).c_str(), Ms(daemon_in.p99).c_str(), Ms(daemon_in.p999).c_str(),
      Ms(fi.p50).c_str(), Ms(fi.p99).c_str(), Ratio(daemon_out.p99, fo.p99).c_str(),
      Ratio(daemon_in.p99, fi.p99).c_str());
}

// From t0 until stopped: polls memory and backlogs every 50 ms and, every `every` seconds
// (and for the last, partial window when stopped), prints one SoakRow at once. Latency
// comes from the subscriber's handler, in fixed-size histograms.
class SoakSampler {
 public:
  SoakSampler(Subscriber* subscriber, const DaemonThread* daemon, int port, uint64_t daemon_inode)
      : subscriber_(subscriber), daemon_(daemon), port_(port), daemon_inode_(daemon_inode) {}
  void Start(Clock::time_point t0, double every) {
    std::printf(
        "\n== soak: a line every %g s (rss and backlog: mean/max of 50 ms polls; wq: max of the "
        "STATUS heartbeats; sock_rxq: max bytes queued at the daemon's socket; latency in ms "
        "for the deflections of that window; ours/others: cores busy) ==\n",
        every);
    std::printf(
        "  %6s %7s %7s %7s %6s %7s %7s %8s %5s %9s %9s %5s %9s %6s %6s %7s %6s %7s %5s "
        "%5s %6s\n",
        "t_s", "rss_avg", "rss_max", "hwm_MiB", "wq_max", "bl_avg", "bl_max", "sock_rxq", "drops",
        "accepted", "stored", "dropd", "predicted", "s2s50", "s2s99", "s2s_max", "ext99", "ext_max",
        "ident", "ours", "others");
    std::fflush(stdout);
    thread_ = std::thread([this, t0, every] {
      NameThread("bench-soak");
      last_machine_ = ReadMachineCpu();
      last_self_ = SelfCpu();
      last_at_ = t0;
      const auto poll = std::chrono::milliseconds(50);
      Clock::time_point next_poll = t0 + poll;
      for (int n = 1;; ++n) {
        const auto due = t0 + std::chrono::nanoseconds(std::llround(n * every * 1e9));
        bool stopping = false;
        for (; next_poll <= due && !stopping; next_poll += poll) {
          std::unique_lock lock(mutex_);
          stopping = wake_.wait_until(lock, next_poll, [this] { return stop_; });
          lock.unlock();
          Poll();
        }
        if (stopping) {
          if (Clock::now() - last_at_ > std::chrono::milliseconds(500)) Emit(t0);
          break;
        }
        Emit(t0);
      }
    });
  }
  // Called by the identification loop.
  void IdentificationRunning(bool running) {
    ident_now_ = running;
    if (running) ident_in_window_ = true;
  }
  void Stop() {
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
    }
    wake_.notify_all();
    if (thread_.joinable()) thread_.join();
  }
  ~SoakSampler() { Stop(); }
  const std::vector<SoakRow>& rows() const { return rows_; }  // after Stop()
  const LiveLatency& total() const { return total_; }         // after Stop()

 private:
  static double SelfCpu() {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
  }

  void Poll() {
    const auto [rss, hwm] = ResidentKiB();
    const Counters c = daemon_->Live();
    const int64_t backlog = c.predictions_published - c.dropped_queue_full - c.samples_stored;
    ++polls_;
    rss_sum_ += static_cast<double>(rss);
    rss_max_ = std::max(rss_max_, rss);
    hwm_ = hwm;
    backlog_sum_ += static_cast<double>(backlog);
    backlog_max_ = std::max(backlog_max_, backlog);
    const auto sockets = UdpSockets(port_);
    if (const auto it = sockets.find(daemon_inode_); it != sockets.end()) {
      rx_queue_max_ = std::max(rx_queue_max_, it->second.rx_queue);
      drops_ = it->second.drops;
    }
    if (const auto st = subscriber_->LatestStatus(); st && st->utime != last_status_utime_) {
      last_status_utime_ = st->utime;
      writer_depth_max_ = std::max<int64_t>(writer_depth_max_, st->writer_queue_depth);
    }
  }

  void Emit(Clock::time_point t0) {
    const Clock::time_point now = Clock::now();
    SoakRow r;
    r.t_s = 1e-9 * static_cast<double>(Since(t0, now));
    if (polls_ == 0) Poll();
    r.rss_mean_kib = rss_sum_ / static_cast<double>(polls_);
    r.rss_max_kib = rss_max_;
    r.hwm_kib = hwm_;
    r.backlog_mean = backlog_sum_ / static_cast<double>(polls_);
    r.backlog_max = backlog_max_;
    r.writer_depth_max = writer_depth_max_;
    r.socket_rx_queue_max = rx_queue_max_;
    r.socket_drops = drops_;
    polls_ = 0;
    rss_sum_ = backlog_sum_ = 0;
    rss_max_ = backlog_max_ = 0;
    writer_depth_max_ = rx_queue_max_ = -1;
    r.c = daemon_->Live();
    r.identification = ident_in_window_.exchange(ident_now_.load()) || ident_now_;
    const MachineCpu machine = ReadMachineCpu();
    const double self = SelfCpu();
    const double wall = 1e-9 * static_cast<double>(Since(last_at_, now));
    const double hz = static_cast<double>(sysconf(_SC_CLK_TCK));
    if (wall > 0) {
      r.machine_cores = static_cast<double>(machine.busy - last_machine_.busy) / hz / wall;
      r.self_cores = (self - last_self_) / wall;
    }
    last_machine_ = machine;
    last_self_ = self;
    last_at_ = now;
    const LiveLatency window = subscriber_->TakeWindow();
    total_.Merge(window);
    Histogram ext = window.ext_in, s2s = window.s2s_in;
    ext.Merge(window.ext_out);
    s2s.Merge(window.s2s_out);
    r.ext = FromHistogram(ext);
    r.s2s = FromHistogram(s2s);
    std::printf("  %6.1f %7.1f %7.1f %7.1f %6" PRId64 " %7.0f %7" PRId64 " %8" PRId64 " %5" PRId64
                " %9" PRId64 " %9" PRId64 " %5" PRId64 " %9" PRId64
                " %6s %6s %7s %6s %7s %5s %5.2f %6.2f\n",
                r.t_s, r.rss_mean_kib / 1024.0, static_cast<double>(r.rss_max_kib) / 1024.0,
                static_cast<double>(r.hwm_kib) / 1024.0, r.writer_depth_max, r.backlog_mean,
                r.backlog_max, r.socket_rx_queue_max, r.socket_drops, r.c.samples_accepted,
                r.c.samples_stored, r.c.dropped_queue_full, r.c.predictions_published,
                Ms(r.s2s.p50).c_str(), Ms(r.s2s.p99).c_str(), Ms(r.s2s.max).c_str(),
                Ms(r.ext.p99).c_str(), Ms(r.ext.max).c_str(), r.identification ? "yes" : "no",
                r.self_cores, std::max(0.0, r.machine_cores - r.self_cores));
    std::fflush(stdout);
    rows_.push_back(r);
  }

  Subscriber* subscriber_;
  const DaemonThread* daemon_;
  const int port_;
  const uint64_t daemon_inode_;
  std::thread thread_;
  std::mutex mutex_;
  std::condition_variable wake_;
  bool stop_ = false;
  std::atomic<bool> ident_now_{false}, ident_in_window_{false};
  // The window's polls (sampler thread only).
  int64_t polls_ = 0;
  double rss_sum_ = 0, backlog_sum_ = 0;
  int64_t rss_max_ = 0, hwm_ = 0, backlog_max_ = 0, writer_depth_max_ = -1, rx_queue_max_ = -1,
          drops_ = -1, last_status_utime_ = 0;
  MachineCpu last_machine_;
  double last_self_ = 0;
  Clock::time_point last_at_;
  std::vector<SoakRow> rows_;
  LiveLatency total_;
};

// Least-squares slope and intercept of y over x.
std::pair<double, double> LinearFit(const std::vector<double>& x, const std::vector<double>& y) {
  const size_t n = x.size();
  if (n < 2) return {NAN, NAN};
  double mx = 0, my = 0;
  for (size_t i = 0; i < n; ++i) {
    mx += x[i];
    my += y[i];
  }
  mx /= static_cast<double>(n);
  my /= static_cast<double>(n);
  double sxy = 0, sxx = 0;
  for (size_t i = 0; i < n; ++i) {
    sxy += (x[i] - mx) * (y[i] - my);
    sxx += (x[i] - mx) * (x[i] - mx);
  }
  if (sxx == 0) return {NAN, NAN};
  const double slope = sxy / sxx;
  return {slope, my - slope * mx};
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
  const std::string load_at_start = LoadAverage();
  std::printf("load average at start (1, 5, 15 min): %s\n", load_at_start.c_str());

  Plan plan;
  plan.actuators = opt.actuators;
  plan.rate_hz = opt.rate_hz;
  plan.period_s = opt.period_s;
  plan.samples = static_cast<int64_t>(std::llround(opt.seconds * opt.rate_hz));
  plan.ping_every = std::max<int64_t>(1, std::llround(opt.rate_hz / kPingHz));
  const bool soak = opt.identify_every > 0 || opt.sample_every_given;
  const bool identify = opt.identify_at > 0 || opt.identify_every > 0;
  std::vector<std::pair<double, int>> schedule;  // identifications: {t in s, actuator}
  if (opt.identify_at > 0) {
    plan.restart_k = static_cast<int64_t>(std::llround((opt.identify_at - 1) * opt.rate_hz));
    // The identification needs max_delay_s / dt + 50 samples (model/identify/identify.cc) and
    // the trial must end before the request: L00's first trial gets a history before t0.
    plan.history = std::max<int64_t>(
        0, static_cast<int64_t>(std::llround(opt.first_trial_s * opt.rate_hz)) - plan.restart_k);
    plan.restarts.push_back({plan.restart_k, 0});
    schedule.push_back({opt.identify_at, 0});
  } else if (opt.identify_every > 0) {
    // Identification j (from 1) at j * S, of actuator (j - 1) mod N, on a trial of
    // first_trial_s that ends 1 s before the request: the same work every time.
    for (int j = 1; j * opt.identify_every <= opt.seconds - 0.5; ++j) {
      const double at = j * opt.identify_every;
      const int a = (j - 1) % opt.actuators;
      plan.restarts.push_back(
          {static_cast<int64_t>(std::llround((at - opt.first_trial_s - 1) * opt.rate_hz)), a});
      plan.restarts.push_back({static_cast<int64_t>(std::llround((at - 1) * opt.rate_hz)), a});
      schedule.push_back({at, a});
    }
    std::sort(plan.restarts.begin(), plan.restarts.end());
  }

  std::random_device device;
  const int port = std::uniform_int_distribution<int>(20000, 60000)(device);
  std::string url = "udpm://239.255.76.67:" + std::to_string(port) + "?ttl=0";
  std::string floor_url = "udpm://239.255.76.67:" + std::to_string(port + 1) + "?ttl=0";
  if (opt.recv_buf_size > 0) {
    url = flexid::bus::WithReceiveBuffer(url, opt.recv_buf_size);
    floor_url = flexid::bus::WithReceiveBuffer(floor_url, opt.recv_buf_size);
  }
  const flexid::bus::Channels channels(opt.channel_prefix);

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
  config.channel_prefix = opt.channel_prefix;
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
  Subscriber subscriber(plan, url, floor_url, channels, opt.tap_deflections);
  if (!subscriber.Start()) {
    std::fprintf(stderr, "daemon_load: cannot join the LCM bus at %s\n", url.c_str());
    return 1;
  }
  Echo echo(floor_url);
  if (!echo.Start()) {
    std::fprintf(stderr, "daemon_load: the echo cannot join the LCM bus at %s\n", url.c_str());
    return 1;
  }
  const auto sockets_before = UdpSockets(port);
  const auto threads_before_daemon = ThreadScheds();
  flexid::daemon::KeepFreedMemory();  // as flexidd's main() does
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
  for (const auto& [tid, t] : ThreadScheds())
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
  // The key the daemon created next to its database signs trial control and "identify".
  flexid::auth::Key key;
  try {
    key = flexid::auth::ReadKeyFile(flexid::daemon::KeyFilePath(config));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "daemon_load: %s\n", e.what());
    subscriber.Stop();
    return 1;
  }
  subscriber.SetKey(key);
  Publisher publisher(plan, url, floor_url, channels, history_start, opt.history_speed, t0, key);
  if (!publisher.good()) {
    std::fprintf(stderr, "daemon_load: the publisher cannot join the bus\n");
    subscriber.Stop();
    return 1;
  }
  subscriber.SetPublishTimes(&publisher.publish_ns());
  // Per sample slot: publish time and value (publisher), receive times of the deflection and
  // of the prediction, and the model version (subscriber). Written before t0, constant after.
  const double per_sample_arrays_mib =
      static_cast<double>(plan.Slots()) * (8 + 8 + 8 + 8 + 8 + 4) / (1024.0 * 1024.0);
  if (opt.identify_every > 0)
    std::printf(
        "identifications: every %g s from %g s, rotating over the actuators, each on a "
        "trial of %g s (%" PRId64 " samples) stopped 1 s before\n",
        opt.identify_every, opt.identify_every, opt.first_trial_s,
        static_cast<int64_t>(std::llround(opt.first_trial_s * opt.rate_hz)));
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
  const auto threads_start = ThreadScheds();
  const Clock::time_point wall_start = t0;
  const MachineCpu machine_start = ReadMachineCpu();
  LoadMonitor monitor;
  monitor.Start(t0, static_cast<size_t>(std::ceil(opt.seconds)));
  SchedSplit sched;
  sched.Start();

  std::optional<SoakSampler> sampler;
  if (soak) {
    sampler.emplace(&subscriber, &daemon, port, daemon_inode);
    sampler->Start(t0, opt.sample_every);
  }

  // The identifications (--identify-at: L00 on its first trial), while the load goes on.
  struct Identification {
    int actuator = 0;
    Clock::time_point sent{};
    std::optional<ReplyRecord> reply;
  };
  std::vector<Identification> identifications;
  for (const auto& [at, a] : schedule) {
    std::this_thread::sleep_until(t0 + std::chrono::nanoseconds(std::llround(at * 1e9)));
    Identification id;
    id.actuator = a;
    sched.Mark(false);
    subscriber.IdentificationStarted(Since(t0, Clock::now()));
    if (sampler) sampler->IdentificationRunning(true);
    id.reply = subscriber.Call("identify", {{"actuator", ActuatorId(a)}, {"latest", 1}},
                               std::chrono::seconds(120), &id.sent);
    subscriber.IdentificationEnded(Since(t0, id.reply ? id.reply->received : Clock::now()));
    sched.Mark(true);
    if (sampler) {
      sampler->IdentificationRunning(false);
      const double sent_s = 1e-9 * static_cast<double>(Since(t0, id.sent));
      if (id.reply)
        std::printf("  # identification of %s sent at t = %.1f s: reply after %.0f ms, status %d\n",
                    ActuatorId(a).c_str(), sent_s,
                    1e-6 * static_cast<double>(Since(id.sent, id.reply->received)),
                    id.reply->message.status);
      else
        std::printf("  # identification of %s sent at t = %.1f s: NO REPLY within 120 s\n",
                    ActuatorId(a).c_str(), sent_s);
      std::fflush(stdout);
    }
    identifications.push_back(std::move(id));
  }
  publisher_thread.join();
  sched.Mark(false);
  const MachineCpu machine_end = ReadMachineCpu();
  monitor.Stop();
  if (sampler) sampler->Stop();

  // Drain: until the daemon has stored every deflection it accepted (all are in trials).
  Counters status;
  bool drained = false;
  const Clock::time_point drain_start = Clock::now();
  int64_t last_accepted = -1;
  while (Clock::now() - drain_start < std::chrono::seconds(30)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    const auto r = subscriber.Call("status", nlohmann::json::object(), std::chrono::seconds(5));
    if (!r || r->message.status != flexid::rpc_reply_t::kOk) continue;
    const auto j = nlohmann::json::parse(r->message.result_json);
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
  const auto threads_end = ThreadScheds();
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
  // Identify requests outstanding, ns since t0: from the request to its reply.
  std::vector<std::pair<int64_t, int64_t>> windows;
  for (const Identification& id : identifications)
    windows.push_back(
        {Since(t0, id.sent), id.reply ? Since(t0, id.reply->received) : int64_t{INT64_MAX}});
  auto in_window = [&](int64_t ns) {
    for (const auto& [from, to] : windows)
      if (ns >= from && ns <= to) return true;
    return false;
  };
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

  const std::string load_at_end = LoadAverage();
  if (opt.tap_deflections) {
    PrintTableFigures(Summarise(identify ? s2s_out : s2s_all), Summarise(s2s_in),
                      subscriber.floor_out(), subscriber.floor_in(), load_at_start, load_at_end,
                      identify);
    std::printf(
        "  bus floor: a small message (%g/s, one port up) echoed by a thread of this program with "
        "its own LCM\n  (receive thread, loop, publish), kernel stamps as above; unmatched "
        "echoes %" PRId64 "\n",
        kPingHz, subscriber.pongs_unmatched());
  }

  std::printf("\n== identification ==\n");
  if (!identify) std::printf("  off\n");
  for (const Identification& id : identifications) {
    const double sent_s = 1e-9 * static_cast<double>(Since(t0, id.sent));
    const std::string who = ActuatorId(id.actuator);
    if (!id.reply) {
      std::printf("  sent at t = %.3f s (%s): NO REPLY within 120 s\n", sent_s, who.c_str());
      continue;
    }
    const auto& r = id.reply->message;
    std::printf(
        "  \"identify\" {actuator %s, latest 1} sent at t = %.3f s, reply after %.1f ms: "
        "status %d%s%s\n",
        who.c_str(), sent_s, 1e-6 * static_cast<double>(Since(id.sent, id.reply->received)),
        r.status, r.error.empty() ? "" : ", error: ", r.error.c_str());
    if (r.status == flexid::rpc_reply_t::kOk) {
      const auto j = nlohmann::json::parse(r.result_json, nullptr, false);
      if (j.is_object())
        std::printf("  model version %s, trials %s, fit %s\n",
                    j.value("version", nlohmann::json()).dump().c_str(),
                    j.value("trials", nlohmann::json()).dump().c_str(),
                    j.value("fit", nlohmann::json()).dump().c_str());
    }
  }
  if (model_swapped_at_k >= 0)
    std::printf("  first L00 prediction with a new model: sample %" PRId64 " (t = %.3f s)\n",
                model_swapped_at_k, static_cast<double>(model_swapped_at_k) / plan.rate_hz);

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
    for (const auto& [k, a] : plan.restarts) {
      const auto at =
          static_cast<int64_t>(std::llround(static_cast<double>(k) * 1e9 / plan.rate_hz));
      events.push_back({ActuatorId(a) + " trial stop + start, +100 ms", at, at + 100'000'000});
    }
    for (size_t n = 0; n < windows.size(); ++n) {
      const auto [from, to] = windows[n];
      const std::string tag = windows.size() > 1 ? " #" + std::to_string(n + 1) : "";
      events.push_back({"identify request" + tag + ", +100 ms", from, from + 100'000'000});
      if (to != INT64_MAX) {
        events.push_back(
            {"identification" + tag + " running (rest)", from + 100'000'000, to - 20'000'000});
        events.push_back(
            {"identify reply" + tag + " -20 ms .. +100 ms", to - 20'000'000, to + 100'000'000});
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
    bool ident = false, restart = false;
    for (const auto& [from, to] : windows) ident |= to >= sec_ns && from < sec_ns + 1'000'000'000;
    for (const auto& [k, a] : plan.restarts)
      restart |= static_cast<size_t>(static_cast<double>(k) / plan.rate_hz) == sec;
    const bool sampled = sec < monitor.self_cores_.size();
    const double ours = sampled ? monitor.self_cores_[sec] : NAN;
    const double others = sampled ? std::max(0.0, monitor.machine_cores_[sec] - ours) : NAN;
    std::printf("  %4zu %6" PRId64 " %5" PRId64 " %6" PRId64 " %7" PRId64
                " %8s %8s %8s %8s %8s %8s %6.2f %6.2f%s%s\n",
                sec, published_by_s[sec], sec < pr.late_by_s.size() ? pr.late_by_s[sec] : 0,
                missing_by_s[sec], nopred_by_s[sec], Ms(e.p50).c_str(), Ms(e.p99).c_str(),
                Ms(e.max).c_str(), Ms(s.p50).c_str(), Ms(s.p99).c_str(), Ms(s.max).c_str(), ours,
                others, restart ? "  trial restart" : "", ident ? "  identification" : "");
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

  std::printf(
      "\n== scheduling by thread, outside (%.1f s) | during identification (%.1f s) ==\n"
      "  cpu: ms on a CPU per s; wait: ms runnable but waiting for a CPU per s, and per time "
      "slice (us);\n  invol: preemptions per s; flt: minor page faults per s\n  "
      "(/proc/self/task/T/schedstat, status and stat)\n",
      sched.outside_s_, sched.during_s_);
  std::printf("  %-12s %-22s %7s %7s %8s %7s %7s | %7s %7s %8s %7s %7s\n", "thread", "", "cpu",
              "wait", "wait/sl", "invol", "flt", "cpu", "wait", "wait/sl", "invol", "flt");
  for (const auto& [tid, out] : sched.outside_) {
    const auto it = sched.during_.find(tid);
    const ThreadSched in = it != sched.during_.end() ? it->second : ThreadSched{};
    auto figures = [](const ThreadSched& t, double s) {
      char b[64];
      if (s <= 0) return std::string(41, ' ');
      std::snprintf(
          b, sizeof b, "%7.1f %7.2f %8.1f %7.1f %7.1f", 1e-6 * static_cast<double>(t.cpu_ns) / s,
          1e-6 * static_cast<double>(t.wait_ns) / s,
          t.slices ? 1e-3 * static_cast<double>(t.wait_ns) / static_cast<double>(t.slices) : 0.0,
          static_cast<double>(t.involuntary) / s, static_cast<double>(t.faults) / s);
      return std::string(b);
    };
    std::string label = labels.count(tid) ? labels[tid] : "";
    if (out.name == "bench-pub") label = "publisher";
    if (out.name == "bench-echo") label = "bus floor echo";
    std::printf("  %-12s %-22s %s | %s\n", out.name.c_str(), label.c_str(),
                figures(out, sched.outside_s_).c_str(), figures(in, sched.during_s_).c_str());
  }

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

  if (sampler) {
    // --- soak summary ------------------------------------------------------------------
    const std::vector<SoakRow>& rows = sampler->rows();
    std::printf("\n== soak summary ==\n");
    std::printf(
        "  %g s, %d actuators x %g Hz (%g deflections + %g voltages/s), identification "
        "every %g s; lines every %g s: %zu\n",
        opt.seconds, opt.actuators, opt.rate_hz, opt.actuators * opt.rate_hz,
        opt.actuators * opt.rate_hz, opt.identify_every, opt.sample_every, rows.size());
    {
      const double hz = static_cast<double>(sysconf(_SC_CLK_TCK));
      const double machine_s = static_cast<double>(machine_end.busy - machine_start.busy) / hz;
      double worst_others = 0, worst_at = 0;
      for (const SoakRow& r : rows)
        if (r.machine_cores - r.self_cores > worst_others) {
          worst_others = r.machine_cores - r.self_cores;
          worst_at = r.t_s;
        }
      std::printf(
          "  machine (2 cores): %.2f cores busy on average, this process %.2f, other "
          "processes >= %.2f (worst window: %.2f at t = %.0f s)\n",
          wall_s > 0 ? machine_s / wall_s : 0.0, wall_s > 0 ? cpu_s / wall_s : 0.0,
          wall_s > 0 ? std::max(0.0, machine_s - cpu_s) / wall_s : 0.0, worst_others, worst_at);
    }

    // Memory and queues: per line, the means of its 50 ms polls, fitted after the warm-up.
    std::vector<double> t_min, rss_kib, backlog;
    int64_t wq_max = -1, backlog_max = 0, rxq_max = -1, rss_max = 0;
    for (const SoakRow& r : rows) {
      wq_max = std::max(wq_max, r.writer_depth_max);
      backlog_max = std::max(backlog_max, r.backlog_max);
      rxq_max = std::max(rxq_max, r.socket_rx_queue_max);
      if (r.t_s < opt.warmup_s) continue;
      t_min.push_back(r.t_s / 60.0);
      rss_kib.push_back(r.rss_mean_kib);
      rss_max = std::max(rss_max, r.rss_max_kib);
      backlog.push_back(r.backlog_mean);
    }
    const double rss_slope = LinearFit(t_min, rss_kib).first;  // KiB/min
    const double base_kib =
        rss_kib.empty() ? NAN : rss_kib.front() - per_sample_arrays_mib * 1024.0;
    const double allowed_per_10min = 0.01 * base_kib;  // KiB
    const double messages_per_10min = 2.0 * opt.actuators * opt.rate_hz * 600.0;
    std::printf(
        "\n  memory: VmRSS of the whole process = the daemon + this program's publisher,\n"
        "  subscriber and their LCM queues; this program's per-sample arrays (%.1f MiB)\n"
        "  were allocated and written before t0 and do not change size. Per line: the mean\n"
        "  of its 50 ms polls.\n",
        per_sample_arrays_mib);
    if (!rows.empty())
      std::printf(
          "    first line (t = %.0f s): RSS %.1f MiB; last line (t = %.0f s): RSS %.1f MiB; "
          "VmHWM at the end %.1f MiB\n",
          rows.front().t_s, rows.front().rss_mean_kib / 1024.0, rows.back().t_s,
          rows.back().rss_mean_kib / 1024.0, static_cast<double>(rows.back().hwm_kib) / 1024.0);
    if (!rss_kib.empty())
      std::printf(
          "    after the %g s warm-up (%zu lines): first %.1f MiB, last %.1f MiB, lowest line "
          "%.1f, highest line %.1f, highest poll %.1f MiB\n",
          opt.warmup_s, rss_kib.size(), rss_kib.front() / 1024.0, rss_kib.back() / 1024.0,
          *std::min_element(rss_kib.begin(), rss_kib.end()) / 1024.0,
          *std::max_element(rss_kib.begin(), rss_kib.end()) / 1024.0,
          static_cast<double>(rss_max) / 1024.0);
    std::printf(
        "    slope (least squares over those lines): %+.1f KiB/min = %+.0f KiB per 10 min\n",
        rss_slope, 10 * rss_slope);

    const double input_per_s = opt.actuators * opt.rate_hz;  // deflections/s
    const double backlog_slope = LinearFit(t_min, backlog).first;
    const int64_t final_backlog = c.predictions_published - c.dropped_queue_full - c.samples_stored;
    std::printf("\n  queues:\n");
    std::printf(
        "    accepted, not yet stored (predictions_published - dropped_queue_full - "
        "samples_stored,\n    polled every 50 ms): max %" PRId64
        ", mean of the last line %.0f, slope of the line means after warm-up %+.1f "
        "samples/min,\n    after the drain %" PRId64 "\n",
        backlog_max, rows.empty() ? 0.0 : rows.back().backlog_mean, backlog_slope, final_backlog);
    std::printf(
        "    sample writer queue (writer_queue_depth of the 1 s STATUS heartbeats): max %" PRId64
        "\n",
        wq_max);
    std::printf("    the daemon's UDP socket receive queue (/proc/net/udp, polled): max %" PRId64
                " bytes; kernel drops there %" PRId64 "\n",
                rxq_max, daemon_drops);
    std::printf(
        "    LCM's own queue per subscription (capacity %d messages) cannot be read: LCM 1.3\n"
        "    exposes no length; a message it drops shows as lost on the bus below.\n",
        1 << 17);

    // Samples.
    std::printf("\n  samples:\n");
    std::printf("    published deflections %" PRId64 ", delivered (accepted) %" PRId64
                ", stored rows %" PRId64 " (samples_stored %" PRId64 ")\n",
                published, delivered, stored_rows, c.samples_stored);
    std::printf("    lost between LCM delivery and SQLite: %" PRId64 " (dropped_queue_full %" PRId64
                "; stored values differing from published %" PRId64 ")\n",
                delivered - stored_rows, c.dropped_queue_full, value_mismatches);
    std::printf("    lost on the bus (published - delivered): %" PRId64
                " (kernel drops at the daemon's socket %" PRId64 ", host RcvbufErrors %" PRId64
                ")\n",
                published - delivered, daemon_drops, rcvbuf_errors_after - rcvbuf_errors_before);
    std::printf("    database integrity: %s; drain after the last sample %.2f s (%s)\n",
                integrity.c_str(), drain_s, drained ? "caught up" : "TIMED OUT");

    // Latency.
    const LiveLatency& total = sampler->total();
    Histogram ext_all_h = total.ext_in, s2s_all_h = total.s2s_in;
    ext_all_h.Merge(total.ext_out);
    s2s_all_h.Merge(total.s2s_out);
    std::printf(
        "\n  latency, deflection -> its prediction (ms; fixed-size histograms, 1 us below "
        "1 ms, < 1.6 %% above; during = published while an identify request was "
        "outstanding):\n");
    std::printf("  %-34s %8s %8s %8s %8s %8s %9s %8s\n", "", "n", "p50", "p90", "p99", "p99.9",
                "max", ">1ms");
    if (opt.tap_deflections) {
      PrintStatsRow("socket to socket, all", FromHistogram(s2s_all_h));
      PrintStatsRow("socket to socket, outside ident.", FromHistogram(total.s2s_out));
      PrintStatsRow("socket to socket, during ident.", FromHistogram(total.s2s_in));
    }
    PrintStatsRow("external, all", FromHistogram(ext_all_h));
    PrintStatsRow("external, outside identification", FromHistogram(total.ext_out));
    PrintStatsRow("external, during identification", FromHistogram(total.ext_in));
    if (opt.tap_deflections)
      PrintTableFigures(FromHistogram(total.s2s_out), FromHistogram(total.s2s_in), total.floor_out,
                        total.floor_in, load_at_start, load_at_end, true);

    // Identifications.
    std::vector<double> durations_ms;
    int ok = 0;
    std::printf("\n  identifications: %zu requested\n", identifications.size());
    for (const Identification& id : identifications) {
      const double sent_s = 1e-9 * static_cast<double>(Since(t0, id.sent));
      if (!id.reply) {
        std::printf("    t = %6.1f s %s: NO REPLY\n", sent_s, ActuatorId(id.actuator).c_str());
        continue;
      }
      const double ms = 1e-6 * static_cast<double>(Since(id.sent, id.reply->received));
      durations_ms.push_back(ms);
      const auto& r = id.reply->message;
      ok += r.status == flexid::rpc_reply_t::kOk;
      std::string what = r.error;
      if (r.status == flexid::rpc_reply_t::kOk) {
        const auto j = nlohmann::json::parse(r.result_json, nullptr, false);
        if (j.is_object()) {
          const nlohmann::json fit = j.value("fit", nlohmann::json::object());
          char figures[96];
          std::snprintf(figures, sizeof figures, ", fit %.1f %%, rmse %.4f mm, %lld samples",
                        fit.value("fit_percent", NAN), fit.value("rmse_mm", NAN),
                        static_cast<long long>(fit.value("samples", int64_t{0})));
          what = "model version " + j.value("version", nlohmann::json()).dump() + ", trials " +
                 j.value("trials", nlohmann::json()).dump() + figures;
        }
      }
      std::printf("    t = %6.1f s %s: %7.0f ms, status %d, %s\n", sent_s,
                  ActuatorId(id.actuator).c_str(), ms, r.status, what.c_str());
    }
    if (!durations_ms.empty()) {
      std::vector<double> sorted = durations_ms;
      std::sort(sorted.begin(), sorted.end());
      std::printf("    %d ok of %zu; reply time min %.0f ms, median %.0f ms, max %.0f ms\n", ok,
                  identifications.size(), sorted.front(), sorted[(sorted.size() - 1) / 2],
                  sorted.back());
    }

    // Verdicts: figures beside the criteria, not a test.
    const bool memory_flat = std::isfinite(rss_slope) && 10 * rss_slope < allowed_per_10min;
    const bool queues_flat = static_cast<double>(backlog_max) < input_per_s &&
                             std::isfinite(backlog_slope) && backlog_slope < 0.01 * input_per_s &&
                             final_backlog == 0 && c.dropped_queue_full == 0;
    const int64_t lost_store = delivered - stored_rows, lost_bus = published - delivered;
    std::printf("\n  soak criteria (figure | criterion | verdict):\n");
    std::printf(
        "    memory flat: RSS slope %+.0f KiB per 10 min after warm-up | < 1 %% of the RSS "
        "net of the per-sample arrays, %.0f KiB per 10 min (%.1f MiB; = %.2f bytes per "
        "message of the %.1f M in 10 min) | %s\n",
        10 * rss_slope, allowed_per_10min, base_kib / 1024.0,
        allowed_per_10min * 1024.0 / messages_per_10min, messages_per_10min / 1e6,
        memory_flat ? "flat" : "NOT FLAT");
    std::printf("    no growing queues: backlog max %" PRId64
                ", slope %+.1f /min, after drain %" PRId64 ", dropped_queue_full %" PRId64
                " | max < 1 s of input (%.0f), slope < 1 %% of "
                "that per min (%.0f), 0 after the drain, 0 dropped | %s\n",
                backlog_max, backlog_slope, final_backlog, c.dropped_queue_full, input_per_s,
                0.01 * input_per_s, queues_flat ? "not growing" : "GROWING OR DROPPING");
    std::printf("    no lost samples (LCM delivery -> SQLite): %" PRId64 " | 0 (DESIGN.md) | %s\n",
                lost_store, lost_store == 0 && drained ? "none lost" : "LOST");
    std::printf("    lost on the bus: %" PRId64 " of %" PRId64
                " | not a daemon target (UDP "
                "loopback on a shared machine) | %s\n",
                lost_bus, published, lost_bus == 0 ? "none" : "SOME LOST ON THE BUS");
    std::printf(
        "    prediction latency p99 socket to socket: outside %s ms, during %s ms | < 1 ms, "
        "also during identification (DESIGN.md) | %s\n",
        Ms(total.s2s_out.Quantile(0.99)).c_str(), Ms(total.s2s_in.Quantile(0.99)).c_str(),
        total.s2s_out.Quantile(0.99) < 1000 &&
                (total.s2s_in.count() == 0 || total.s2s_in.Quantile(0.99) < 1000)
            ? "met"
            : "NOT MET");
  }

  if (opt.keep) {
    std::printf("\ndatabase kept: %s\n", database.c_str());
  } else {
    std::error_code ignored;
    fs::remove_all(dir, ignored);
  }
  return 0;
}
