// A child process for end-to-end tests (flexidd, flexid-rig, flexid-dashboard started as
// real programs), and a fresh LCM URL for each test: udpm on this host only (ttl=0) at a
// random port, so that tests run in parallel never hear each other.
#pragma once

#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "sanitizer_report.h"

namespace flexid::testing {

inline std::string RandomUrl() {
  std::random_device device;
  std::uniform_int_distribution<int> port(20000, 60000);
  return "udpm://239.255.76.67:" + std::to_string(port(device)) + "?ttl=0";
}

// "exit N" or "signal N", for messages.
inline std::string DescribeStatus(int status) {
  if (WIFEXITED(status)) return "exit " + std::to_string(WEXITSTATUS(status));
  if (WIFSIGNALED(status)) return "signal " + std::to_string(WTERMSIG(status));
  return "status " + std::to_string(status);
}

// A child process started with posix_spawn (so that the test has its pid to signal),
// stdout and stderr to files. The child starts with no blocked signals and default
// dispositions for SIGTERM, SIGINT, SIGHUP and SIGPIPE: an in-process daemon::Daemon
// blocks SIGTERM/SIGINT/SIGHUP in the thread that built it, and a child would inherit
// that mask (the rig would then never see SIGTERM). Killed (SIGKILL) and reaped by the
// destructor if still running. extra_env ("NAME=value") is added to the test's environment.
// Once the child has exited, a sanitizer report in its stderr fails the test
// (sanitizer_report.h).
class ChildProcess {
 public:
  ChildProcess(const std::vector<std::string>& args, const std::string& stdout_path,
               const std::string& stderr_path, const std::vector<std::string>& extra_env = {})
      : args_(args), stderr_path_(stderr_path) {
    posix_spawn_file_actions_t actions;
    posix_spawn_file_actions_init(&actions);
    posix_spawn_file_actions_addopen(&actions, STDIN_FILENO, "/dev/null", O_RDONLY, 0);
    posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, stdout_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, stderr_path.c_str(),
                                     O_WRONLY | O_CREAT | O_TRUNC, 0644);
    posix_spawnattr_t attributes;
    posix_spawnattr_init(&attributes);
    sigset_t none, defaults;
    sigemptyset(&none);
    sigemptyset(&defaults);
    for (int signo : {SIGTERM, SIGINT, SIGHUP, SIGPIPE}) sigaddset(&defaults, signo);
    posix_spawnattr_setsigmask(&attributes, &none);
    posix_spawnattr_setsigdefault(&attributes, &defaults);
    posix_spawnattr_setflags(&attributes,
                             static_cast<short>(POSIX_SPAWN_SETSIGMASK | POSIX_SPAWN_SETSIGDEF));
    std::vector<char*> argv;
    for (std::string& arg : args_) argv.push_back(arg.data());
    argv.push_back(nullptr);
    std::vector<std::string> env_strings(extra_env);
    std::vector<char*> env;
    for (std::string& e : env_strings) env.push_back(e.data());
    for (char** e = environ; *e; ++e) env.push_back(*e);
    env.push_back(nullptr);
    const int error = posix_spawn(&pid_, argv[0], &actions, &attributes, argv.data(), env.data());
    posix_spawnattr_destroy(&attributes);
    posix_spawn_file_actions_destroy(&actions);
    if (error != 0) {
      pid_ = -1;
      ADD_FAILURE() << "cannot start " << args_[0] << ": " << std::strerror(error);
    }
  }
  ~ChildProcess() {
    if (pid_ > 0 && !status_) {
      kill(pid_, SIGKILL);
      int status = 0;
      waitpid(pid_, &status, 0);
      ExpectNoSanitizerReportInFile(args_[0], stderr_path_);  // if it died of one before
    }
  }
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;

  bool started() const { return pid_ > 0; }
  // Still running (not yet reaped by Wait).
  bool Running() {
    if (pid_ <= 0 || status_) return false;
    return !Wait(std::chrono::milliseconds(0)).has_value();
  }
  bool Signal(int signo) { return pid_ > 0 && !status_ && kill(pid_, signo) == 0; }
  // The wait status once the child has exited, or nothing after `timeout`.
  std::optional<int> Wait(std::chrono::milliseconds timeout) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (pid_ > 0 && !status_) {
      int status = 0;
      const pid_t done = waitpid(pid_, &status, WNOHANG);
      if (done == pid_) {
        status_ = status;
        ExpectNoSanitizerReportInFile(args_[0], stderr_path_);
        break;
      }
      if (done < 0 || std::chrono::steady_clock::now() >= end) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return status_;
  }

 private:
  std::vector<std::string> args_;
  std::string stderr_path_;
  pid_t pid_ = -1;
  std::optional<int> status_;
};

}  // namespace flexid::testing
