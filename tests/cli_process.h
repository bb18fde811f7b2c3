// Runs a flexid executable as a child process and captures its output, for end-to-end
// tests of the command line (scratch directories: scratch_dir.h).
#pragma once

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#include "sanitizer_report.h"

namespace flexid::testing {

struct ProcessResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

// Runs `command` with /bin/sh; stderr is captured through a file in `scratch`. A sanitizer
// report in it fails the test (sanitizer_report.h).
inline ProcessResult RunCommand(const std::string& command, const std::filesystem::path& scratch) {
  const auto err_path = scratch / "stderr.txt";
  ProcessResult result;
  FILE* pipe = popen((command + " 2>'" + err_path.string() + "'").c_str(), "r");
  if (!pipe) return result;
  std::array<char, 4096> buffer;
  size_t n;
  while ((n = fread(buffer.data(), 1, buffer.size(), pipe)) > 0)
    result.out.append(buffer.data(), n);
  const int status = pclose(pipe);
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  std::ifstream err(err_path);
  std::stringstream text;
  text << err.rdbuf();
  result.err = text.str();
  ExpectNoSanitizerReport(command, result.err);
  return result;
}

inline void WriteFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream(path) << text;
}

// The rows of a read-only command's --json document (source.h's MergedDocument:
// {"<key>": rows, "daemons" | "databases": [...], "notes": [...]}) without what names
// their source ("daemon_id", "database"), so that a daemon's rows and a file's compare.
inline nlohmann::json RowsWithoutSource(const std::string& out, const std::string& key) {
  nlohmann::json doc = nlohmann::json::parse(out, nullptr, false);
  if (!doc.is_object() || !doc.contains(key)) return nullptr;
  nlohmann::json rows = doc[key];
  for (nlohmann::json& row : rows) {
    row.erase("daemon_id");
    row.erase("database");
  }
  return rows;
}

}  // namespace flexid::testing
