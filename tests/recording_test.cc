#include "model/core/recording.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <limits>
#include <numbers>
#include <random>
#include <sstream>
#include <string>

#include "model/core/errors.h"
#include "scratch_dir.h"

namespace flexid::model {
namespace {

namespace fs = std::filesystem;
using testing::ScratchDir;

// The message of the InputError that parsing `text` throws ("" if it parses).
std::string ParseError(const std::string& text, const CsvReadOptions& options = {}) {
  try {
    ParseRecordingCsv(text, "rec.csv", options);
  } catch (const InputError& error) {
    return error.what();
  }
  return "";
}

// Checks one "FILE:LINE:COLUMN: problem" line that starts with `prefix` and contains
// every word in `words`.
void ExpectError(const std::string& text, const std::string& prefix,
                 std::initializer_list<std::string> words, const CsvReadOptions& options = {}) {
  const std::string message = ParseError(text, options);
  ASSERT_FALSE(message.empty()) << "no error for:\n" << text;
  EXPECT_EQ(message.rfind(prefix, 0), 0u) << message;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  for (const std::string& word : words) EXPECT_NE(message.find(word), std::string::npos) << message;
}

TEST(RecordingCsv, RoundTripIsExact) {
  ScratchDir dir;
  Recording original;
  original.t_s = {0.0, 0.1, 0.30000000000000004, 1.0 / 3.0, 2.5e6};
  original.voltage_V = {0.0, -5.0, 1e-300, 4.9e-324, std::nextafter(5.0, 6.0)};
  original.deflection_mm = {-0.0, std::numbers::pi, -1.7976931348623157e308,
                            2.2250738585072014e-308, 42.0};
  const std::string path = dir.File("trial.csv");
  WriteRecordingCsv(path, original);
  EXPECT_FALSE(fs::exists(path + ".tmp"));

  std::ifstream file(path);
  std::string header;
  std::getline(file, header);
  EXPECT_EQ(header, "t_s,voltage_V,deflection_mm");

  const Recording read = ReadRecordingCsv(path);
  EXPECT_EQ(read.source, path);
  EXPECT_EQ(read.t_s, original.t_s);
  EXPECT_EQ(read.voltage_V, original.voltage_V);
  EXPECT_EQ(read.deflection_mm, original.deflection_mm);
  EXPECT_TRUE(std::signbit(read.deflection_mm[0]));
}

TEST(RecordingCsv, WritesWithoutDeflectionWhenItIsEmpty) {
  ScratchDir dir;
  Recording original;
  original.t_s = {0.0, 1.0};
  original.voltage_V = {2.0, 3.0};
  const std::string path = dir.File("protocol.csv");
  WriteRecordingCsv(path, original);
  const Recording read = ReadRecordingCsv(path, {.require_deflection = false});
  EXPECT_EQ(read.t_s, original.t_s);
  EXPECT_EQ(read.voltage_V, original.voltage_V);
  EXPECT_TRUE(read.deflection_mm.empty());
}

TEST(RecordingCsv, WriteRejectsColumnsOfDifferentLengths) {
  ScratchDir dir;
  Recording bad;
  bad.t_s = {0.0, 1.0};
  bad.voltage_V = {1.0};
  bad.deflection_mm = {1.0, 2.0};
  EXPECT_THROW(WriteRecordingCsv(dir.File("bad.csv"), bad), std::invalid_argument);
}

TEST(RecordingCsv, WriteToMissingDirectoryIsAnInputError) {
  ScratchDir dir;
  Recording recording;
  recording.t_s = {0.0, 1.0};
  recording.voltage_V = {1.0, 1.0};
  recording.deflection_mm = {0.0, 0.1};
  const std::string path = dir.File("no/such/dir/out.csv");
  try {
    WriteRecordingCsv(path, recording);
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find(path + ": cannot write: No such file"),
              std::string::npos)
        << error.what();
  }
}

TEST(RecordingCsv, ColumnsInAnyOrderAndExtraColumnsIgnored) {
  const Recording r = ParseRecordingCsv(
      "deflection_mm, note ,t_s,voltage_V,temperature_C\n"
      "0.5,first,0,2,21.5\n"
      "0.75,not a number here,0.1,2,n/a\n",
      "rec.csv");
  EXPECT_EQ(r.t_s, (std::vector<double>{0.0, 0.1}));
  EXPECT_EQ(r.voltage_V, (std::vector<double>{2.0, 2.0}));
  EXPECT_EQ(r.deflection_mm, (std::vector<double>{0.5, 0.75}));
  EXPECT_EQ(r.source, "rec.csv");
}

TEST(RecordingCsv, CommentsBlankLinesCrlfAndSpaces) {
  const Recording r = ParseRecordingCsv(
      "\xEF\xBB\xBF# exported by the rig\r\n"
      "   # sample S1, 2 V step\r\n"
      "\r\n"
      " t_s , voltage_V ,\tdeflection_mm \r\n"
      "# first sample\r\n"
      "0 , 2 , 0\r\n"
      "   \t \r\n"
      "\t# mid-file comment\r\n"
      " 0.1,+2.0,  1e-3\r\n"
      "0.2,2,-5E-1",  // no final line end
      "rec.csv");
  EXPECT_EQ(r.t_s, (std::vector<double>{0.0, 0.1, 0.2}));
  EXPECT_EQ(r.voltage_V, (std::vector<double>{2.0, 2.0, 2.0}));
  EXPECT_EQ(r.deflection_mm, (std::vector<double>{0.0, 1e-3, -0.5}));
}

TEST(RecordingCsv, NonUniformTimeAccepted) {
  const Recording r = ParseRecordingCsv(
      "t_s,voltage_V,deflection_mm\n-1,0,0\n0,0,0\n0.001,5,0.01\n0.5,5,0.2\n10,5,0.3\n", "rec.csv");
  EXPECT_EQ(r.t_s, (std::vector<double>{-1.0, 0.0, 0.001, 0.5, 10.0}));
}

TEST(RecordingCsv, DeflectionOptionalOnlyWhenRequested) {
  const std::string text = "t_s,voltage_V\n0,1\n1,2\n";
  const Recording r = ParseRecordingCsv(text, "protocol.csv", {.require_deflection = false});
  EXPECT_EQ(r.voltage_V, (std::vector<double>{1.0, 2.0}));
  EXPECT_TRUE(r.deflection_mm.empty());
  ExpectError(text, "rec.csv:1:1: ", {"missing required column", "\"deflection_mm\""});
  // A deflection column that is present is read even when not required.
  const Recording with = ParseRecordingCsv("t_s,voltage_V,deflection_mm\n0,1,3\n1,2,4\n", "rec.csv",
                                           {.require_deflection = false});
  EXPECT_EQ(with.deflection_mm, (std::vector<double>{3.0, 4.0}));
}

TEST(RecordingCsv, UnderflowReadsAsZero) {
  const Recording r = ParseRecordingCsv(
      "t_s,voltage_V,deflection_mm\n0,1e-400,-1e-999999999999\n1,0.00001e-320,4.9e-324\n",
      "rec.csv");
  EXPECT_EQ(r.voltage_V, (std::vector<double>{0.0, 0.0}));
  EXPECT_EQ(r.deflection_mm[0], 0.0);
  EXPECT_TRUE(std::signbit(r.deflection_mm[0]));
  EXPECT_EQ(r.deflection_mm[1], 4.9e-324);
}

// --- errors ----------------------------------------------------------------------------

TEST(RecordingCsvErrors, EmptyOrCommentOnlyFileHasNoHeader) {
  ExpectError("", "rec.csv:1:1: ", {"missing header"});
  ExpectError("# just a comment\n\n   \n", "rec.csv:4:1: ", {"missing header", "t_s"});
}

TEST(RecordingCsvErrors, MissingColumnIsNamed) {
  ExpectError("# c\nt_s,deflection_mm\n0,0\n1,1\n", "rec.csv:2:1: ",
              {"missing required column \"voltage_V\"", "header has: \"t_s\", \"deflection_mm\""});
  ExpectError("time,volts\n0,0\n1,1\n", "rec.csv:1:1: ",
              {"missing required columns \"t_s\", \"voltage_V\", \"deflection_mm\""});
  // Names are case-sensitive.
  ExpectError("T_S,voltage_V,deflection_mm\n0,0,0\n1,1,1\n", "rec.csv:1:1: ", {"\"t_s\""});
}

TEST(RecordingCsvErrors, DuplicateRequiredColumn) {
  ExpectError("t_s,voltage_V,deflection_mm, t_s\n0,0,0,0\n1,1,1,1\n",
              "rec.csv:1:30: ", {"duplicate column \"t_s\"", "first in column 1"});
  // Duplicated extra columns are fine.
  EXPECT_EQ(ParseError("t_s,x,voltage_V,x,deflection_mm\n0,a,0,b,0\n1,a,1,b,1\n"), "");
}

TEST(RecordingCsvErrors, WrongNumberOfFields) {
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,1,1,7\n",
              "rec.csv:3:7: ", {"wrong number of fields", "expected 3", "found 4"});
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,1\n",
              "rec.csv:3:4: ", {"wrong number of fields", "expected 3", "found 2"});
}

TEST(RecordingCsvErrors, NotANumberIsQuoted) {
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,  2.5V ,1\n",
              "rec.csv:3:5: ", {"not a number", "\"voltage_V\"", "\"2.5V\""});
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,\n",
              "rec.csv:2:5: ", {"empty field", "\"deflection_mm\""});
  ExpectError("t_s,voltage_V,deflection_mm\n0x10,0,0\n1,1,1\n",
              "rec.csv:2:1: ", {"not a number", "\"0x10\""});
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,1,1e\n",
              "rec.csv:3:5: ", {"not a number", "\"1e\""});
}

TEST(RecordingCsvErrors, LongFieldTruncatedTo40Characters) {
  const std::string field(100, 'x');
  const std::string message = ParseError("t_s,voltage_V,deflection_mm\n0,0,0\n1,1," + field + "\n");
  EXPECT_NE(message.find("\"" + std::string(40, 'x') + "\"..."), std::string::npos) << message;
  EXPECT_EQ(message.find(std::string(41, 'x')), std::string::npos) << message;
}

TEST(RecordingCsvErrors, ColumnCountsCharactersNotBytes) {
  // "µ" is two bytes in UTF-8: the bad field starts at character 6 (byte 8).
  ExpectError("note,t_s,voltage_V,deflection_mm\nµµ,1,abc,3\n",
              "rec.csv:2:6: ", {"not a number", "\"abc\""});
}

TEST(RecordingCsvErrors, NanAndInfRejected) {
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,nan,1\n",
              "rec.csv:3:3: ", {"NaN or Inf", "\"nan\""});
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,-inf\n1,1,1\n",
              "rec.csv:2:5: ", {"NaN or Inf", "\"-inf\""});
  ExpectError("t_s,voltage_V,deflection_mm\n0,0,0\n1,1,1e400\n",
              "rec.csv:3:5: ", {"out of range", "\"1e400\""});
}

TEST(RecordingCsvErrors, TimeNotStrictlyIncreasingGivesBothValues) {
  ExpectError("t_s,voltage_V,deflection_mm\n12.6,0,0\n12.5,1,1\n",
              "rec.csv:3:1: ", {"time is not strictly increasing", "12.5 after 12.6"});
  ExpectError("voltage_V,deflection_mm,t_s\n0,0,3\n0,0,3\n",
              "rec.csv:3:5: ", {"not strictly increasing", "3 after 3"});
}

TEST(RecordingCsvErrors, FewerThanTwoDataRows) {
  ExpectError("t_s,voltage_V,deflection_mm\n", "rec.csv:1:1: ", {"fewer than 2 data rows", "0"});
  ExpectError("# c\nt_s,voltage_V,deflection_mm\n0,0,0\n# only one\n",
              "rec.csv:2:1: ", {"fewer than 2 data rows", "found 1"});
}

TEST(RecordingCsvErrors, CannotOpen) {
  ScratchDir dir;
  const std::string path = dir.File("absent.csv");
  try {
    ReadRecordingCsv(path);
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()), path + ": cannot open: No such file or directory");
  }
}

TEST(RecordingCsvErrors, DirectoryCannotBeOpened) {
  ScratchDir dir;
  const std::string path = dir.File("");
  try {
    ReadRecordingCsv(path);
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()), path + ": cannot open: Is a directory");
  }
}

TEST(RecordingCsvErrors, ControlCharactersAreEscapedInMessages) {
  const std::string message =
      ParseError(std::string("t_s,voltage_V,deflection_mm\n0,0,0\n1,\x01\x7f\xff\r\"q,1\n"));
  EXPECT_NE(message.find("\"\\x01\\x7F\\xFF\\x0D\\\"q\""), std::string::npos) << message;
}

TEST(RecordingCsvErrors, NeverCrashesOnGarbage) {
  std::mt19937 random(12345);
  const std::string alphabet = "0123456789.,-+eE \t\r\n#tsvdx_\xff";
  const std::string valid = "t_s,voltage_V,deflection_mm\n0,1,2\n0.5,1,2.5\n1,1,3\n";
  for (int trial = 0; trial < 3000; ++trial) {
    std::string text;
    if (trial % 2 == 0) {
      const std::size_t length = random() % 200;
      for (std::size_t i = 0; i < length; ++i) {
        text += trial % 4 == 0 ? static_cast<char>(random() % 256)
                               : alphabet[random() % alphabet.size()];
      }
    } else {
      text = valid;
      for (int edits = 0; edits < 3; ++edits) {
        const std::size_t at = random() % text.size();
        text[at] = alphabet[random() % alphabet.size()];
      }
    }
    try {
      const Recording r = ParseRecordingCsv(text, "fuzz.csv");
      ASSERT_GE(r.t_s.size(), 2u);
      ASSERT_EQ(r.voltage_V.size(), r.t_s.size());
      ASSERT_EQ(r.deflection_mm.size(), r.t_s.size());
      for (std::size_t k = 1; k < r.t_s.size(); ++k) ASSERT_LT(r.t_s[k - 1], r.t_s[k]);
    } catch (const InputError& error) {
      const std::string message = error.what();
      ASSERT_EQ(message.rfind("fuzz.csv:", 0), 0u) << message;
      ASSERT_EQ(message.find('\n'), std::string::npos) << message;
    }
  }
}

TEST(RecordingCsvErrors, VeryLongLine) {
  const std::string long_line(1 << 20, '7');
  ExpectError("t_s,voltage_V,deflection_mm\n" + long_line + "\n", "rec.csv:2:", {"wrong number"});
  ExpectError(long_line, "rec.csv:1:1: ", {"missing required column"});
}

// --- size and speed --------------------------------------------------------------------

TEST(RecordingCsv, Parses200kRowsQuickly) {
  constexpr int kRows = 200'000;
  std::string text = "# generated\nt_s,voltage_V,deflection_mm\n";
  text.reserve(static_cast<std::size_t>(kRows) * 40);
  for (int k = 0; k < kRows; ++k) {
    const double t_s = k * 0.01;
    text += std::to_string(t_s) + "," + (k % 2000 < 1000 ? "5" : "0") + "," +
            std::to_string(std::sin(t_s)) + "\n";
  }
  const auto start = std::chrono::steady_clock::now();
  const Recording r = ParseRecordingCsv(text, "big.csv");
  const double elapsed_ms =
      std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  ASSERT_EQ(r.t_s.size(), static_cast<std::size_t>(kRows));
  EXPECT_DOUBLE_EQ(r.t_s.back(), (kRows - 1) * 0.01);
  std::cout << "parsed " << kRows << " rows (" << static_cast<double>(text.size()) / 1e6
            << " MB) in " << elapsed_ms << " ms\n";
  RecordProperty("parse_ms", std::to_string(elapsed_ms));
#if defined(__SANITIZE_ADDRESS__)  // GCC
#define FLEXID_TEST_SANITIZED 1
#elif defined(__has_feature)  // clang
#if __has_feature(address_sanitizer)
#define FLEXID_TEST_SANITIZED 1
#endif
#endif
#if defined(NDEBUG) && !defined(FLEXID_TEST_SANITIZED)
  // 1,000,000 rows must take well under 1 s in Release: 200k rows get a fifth of that,
  // about 10 times what they take here, as a margin for loaded machines. (The sanitizer
  // build, deploy/sanitize, is RelWithDebInfo: NDEBUG, but several times slower.)
  EXPECT_LT(elapsed_ms, 200.0);
#else
  EXPECT_LT(elapsed_ms, 5000.0);  // unoptimised or sanitised builds: only catch blow-ups
#endif
}

// --- prediction output -----------------------------------------------------------------

TEST(PredictionCsv, WritesHeaderAndRoundTrippableNumbers) {
  const std::vector<double> t_s = {0.0, 0.1, 0.2};
  const std::vector<double> voltage_V = {0.0, 5.0, 5.0};
  const std::vector<double> predicted_mm = {0.0, 1.0 / 3.0, -2e-5};
  std::ostringstream out;
  WritePredictionCsv(out, t_s, voltage_V, predicted_mm);
  EXPECT_EQ(out.str(),
            "t_s,voltage_V,predicted_mm\n0,0,0\n0.1,5,0.3333333333333333\n0.2,5,-2e-05\n");
  const Recording back = ParseRecordingCsv(out.str(), "pred.csv", {.require_deflection = false});
  EXPECT_EQ(back.t_s, t_s);
  EXPECT_EQ(back.voltage_V, voltage_V);
}

TEST(PredictionCsv, RejectsDifferentLengths) {
  std::ostringstream out;
  const std::vector<double> two = {0.0, 1.0};
  const std::vector<double> three = {0.0, 1.0, 2.0};
  EXPECT_THROW(WritePredictionCsv(out, two, two, three), std::invalid_argument);
}

// --- third-party data ------------------------------------------------------------------

TEST(RecordingCsv, ThirdPartyHaselFileIsNotAFlexidRecording) {
  const std::string path =
      std::string(FLEXID_SHARED_DATA_DIR) + "/real/hasel-ethz-peano/step_staircase_440s_10ms.csv";
  if (!fs::exists(path)) GTEST_SKIP() << path << " is not present";
  // Its header is time_s,voltage_V,displacement_mm: no t_s and no deflection_mm.
  try {
    ReadRecordingCsv(path);
    FAIL() << "no error";
  } catch (const InputError& error) {
    const std::string message = error.what();
    EXPECT_EQ(message.rfind(path + ":1:1: missing required column", 0), 0u) << message;
    EXPECT_NE(message.find("\"t_s\""), std::string::npos) << message;
    EXPECT_NE(message.find("\"time_s\""), std::string::npos) << message;
  }
}

}  // namespace
}  // namespace flexid::model
