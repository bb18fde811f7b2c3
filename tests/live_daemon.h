// flexidd running as a real program on its own bus (udpm, ttl=0, random port) and its own
// database file, with the flexid and flexid-rig programs to talk to it: the setting of
// the command line's end-to-end tests. Needs FLEXIDD_BINARY, FLEXID_BINARY and
// FLEXID_RIG_BINARY defined by the build. flexidd creates its key next to the database
// (scratch/flexidd.key); Flexid() and RecordTrial() pass it with --key-file.
#pragma once

#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <thread>

#include "child_process.h"
#include "cli_process.h"

namespace flexid::testing {

class LiveDaemon {
 public:
  // Starts flexidd on scratch/flexid.db and waits (up to 20 s) until it answers `status`.
  explicit LiveDaemon(const std::filesystem::path& scratch)
      : scratch_(scratch),
        url_(RandomUrl()),
        db_(scratch / "flexid.db"),
        key_file_(scratch / "flexidd.key") {
    daemon_ = std::make_unique<ChildProcess>(
        std::vector<std::string>{FLEXIDD_BINARY, "--db", db_.string(), "--lcm", url_},
        (scratch / "flexidd.out").string(), (scratch / "flexidd.err").string());
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (std::chrono::steady_clock::now() < end) {
      if (Flexid("rpc status --timeout 0.3").exit_code == 0) {
        ready_ = true;
        break;
      }
      if (!daemon_->Running()) break;
    }
    EXPECT_TRUE(ready_) << "flexidd did not answer on " << url_;
  }
  ~LiveDaemon() {
    if (daemon_->Signal(SIGTERM)) daemon_->Wait(std::chrono::seconds(10));
  }
  LiveDaemon(const LiveDaemon&) = delete;
  LiveDaemon& operator=(const LiveDaemon&) = delete;

  bool ready() const { return ready_; }
  const std::string& url() const { return url_; }
  const std::filesystem::path& db() const { return db_; }
  const std::filesystem::path& key_file() const { return key_file_; }

  // `flexid --lcm URL --key-file KEY ARGS` (ARGS as a shell would split them).
  ProcessResult Flexid(const std::string& args) const {
    return RunCommand(std::string(FLEXID_BINARY) + " --lcm '" + url_ + "' --key-file '" +
                          key_file_.string() + "' " + args,
                      scratch_);
  }

  // One trial of PROTOCOL from the rig at 100 times real time, message time running on
  // from the previous trial; waits until flexidd lists it as finished. Returns its id.
  int64_t RecordTrial(const std::string& protocol, const std::string& extra = "",
                      const std::string& actuator = "S1") {
    const ProcessResult rig =
        RunCommand(std::string(FLEXID_RIG_BINARY) + " --lcm '" + url_ + "' --actuator " + actuator +
                       " --speed 100 --noise-mm 0.02 --trial-control --key-file '" +
                       key_file_.string() + "' --start-utime " + std::to_string(next_utime_) +
                       " --protocol " + protocol + " " + extra,
                   scratch_);
    EXPECT_EQ(rig.exit_code, 0) << rig.err;
    next_utime_ += 2'000'000'000;  // 2000 s of message time per trial, rest included
    // Finished, and its sample count the same in two polls 200 ms apart (the daemon
    // commits within its commit interval).
    int64_t previous_count = -1;
    const auto end = std::chrono::steady_clock::now() + std::chrono::seconds(20);
    while (std::chrono::steady_clock::now() < end) {
      const ProcessResult r =
          Flexid("rpc trials '{\"actuator\": \"" + actuator + "\", \"limit\": 1}' --timeout 2");
      const nlohmann::json list = nlohmann::json::parse(r.out, nullptr, false);
      if (r.exit_code == 0 && list.is_array() && !list.empty() &&
          list[0].value("state", "") != "recording" &&
          list[0].value("id", int64_t{0}) > last_trial_) {
        const int64_t count = list[0].value("samples", int64_t{0});
        if (count > 0 && count == previous_count) {
          last_trial_ = list[0]["id"].get<int64_t>();
          return last_trial_;
        }
        previous_count = count;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    ADD_FAILURE() << "flexidd did not record the trial " << protocol;
    return 0;
  }

 private:
  std::filesystem::path scratch_;
  std::string url_;
  std::filesystem::path db_;
  std::filesystem::path key_file_;
  std::unique_ptr<ChildProcess> daemon_;
  bool ready_ = false;
  int64_t next_utime_ = 1'700'000'000'000'000;
  int64_t last_trial_ = 0;
};

}  // namespace flexid::testing
