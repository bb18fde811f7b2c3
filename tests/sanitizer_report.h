// Sanitizer reports of the programs a test starts (flexidd, flexid, flexid-rig,
// flexid-dashboard). In the AddressSanitizer + UndefinedBehaviorSanitizer build
// (deploy/sanitize) a finding in a child process ends it with a non-zero status, but a
// test does not always look at a child's status (it may be polling, or expect a failure
// anyway); its stderr is where the report is certain to be. Every captured stderr is
// therefore checked here, and a report fails the test. In other builds no report appears.
#pragma once

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <sstream>
#include <string>
#include <string_view>

namespace flexid::testing {

// The sanitizer report in `text` (from its first line on, at most 8,000 characters), or
// an empty string when there is none.
inline std::string SanitizerReport(const std::string& text) {
  constexpr std::array<std::string_view, 4> kMarkers = {
      "ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "ERROR: UndefinedBehaviorSanitizer",
      ": runtime error: "};  // UBSan's one-line report
  size_t first = std::string::npos;
  for (std::string_view marker : kMarkers) first = std::min(first, text.find(marker));
  if (first == std::string::npos) return "";
  const size_t line = text.rfind('\n', first);
  return text.substr(line == std::string::npos ? 0 : line + 1, 8000);
}

// Fails the current test if `stderr_text`, the stderr of `program`, holds a sanitizer report.
inline void ExpectNoSanitizerReport(const std::string& program, const std::string& stderr_text) {
  const std::string report = SanitizerReport(stderr_text);
  if (!report.empty()) ADD_FAILURE() << "sanitizer report from " << program << ":\n" << report;
}

inline void ExpectNoSanitizerReportInFile(const std::string& program, const std::string& path) {
  std::ifstream file(path);
  std::stringstream text;
  text << file.rdbuf();
  ExpectNoSanitizerReport(program, text.str());
}

}  // namespace flexid::testing
