#include "model/core/model_file.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>

#include "model/core/errors.h"
#include "scratch_dir.h"

namespace flexid::model {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::ScratchDir;

constexpr double kInf = std::numeric_limits<double>::infinity();

// DESIGN.md's smallest valid file, exactly as written there.
constexpr const char* kSmallestFile =
    R"({"format": "flexid.model/1", "kind": "tf",
 "num": [0.0085, 0.842, 1.924, 1.97], "den": [1, 0.5898, 367.2, 29.41, 0.2275], "delay_s": 3.67})";

// A two-rule T-S model with shoulders, fit figures and provenance.
constexpr const char* kTsFile = R"({
  "format": "flexid.model/1",
  "kind": "ts_fuzzy",
  "fit": {"fit_percent": 93.5, "recordings": ["a.csv", "b.csv"]},
  "created_by": "flexid 0.1.0",
  "local_models": [
    {"level_V": 2, "num": [0.0085, 0.842, 1.924, 1.97], "den": [1, 0.5898, 367.2, 29.41, 0.2275],
     "delay_s": 3.67, "fit_percent": 95.1, "interval95": {"num": [[0.008, 0.009]]}},
    {"level_V": 5, "num": [0.01, 1.0, 2.0, 3.0], "den": [1, 0.6, 370, 30, 0.25],
     "rmse_mm": 0.012}
  ],
  "scheduling": {
    "variable": "abs_voltage",
    "memberships": [
      {"shape": "trapezoidal", "params": [null, null, 2, 5]},
      {"shape": "trapezoidal", "params": [2, 5, null, null]}
    ]
  },
  "augmentations": [{"effect": "back_relaxation", "params": {"tau_s": 40.0, "gain": -0.1}}]
})";

std::string ParseError(std::string_view text) {
  try {
    ParseModelJson(text, "model.json");
  } catch (const InputError& error) {
    return error.what();
  }
  return "";
}

void ExpectError(std::string_view text, const std::string& prefix,
                 std::initializer_list<std::string> words) {
  const std::string message = ParseError(text);
  ASSERT_FALSE(message.empty()) << "no error for:\n" << text;
  EXPECT_EQ(message.rfind(prefix, 0), 0u) << message;
  EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  for (const std::string& word : words) EXPECT_NE(message.find(word), std::string::npos) << message;
}

// The smallest file with one member replaced (or removed when value is empty).
std::string SmallestWith(const std::string& key, const std::string& value) {
  json document = json::parse(kSmallestFile);
  if (value.empty()) {
    document.erase(key);
  } else {
    document[key] = json::parse(value);
  }
  return document.dump();
}

std::string TsWith(const std::string& pointer, const std::string& value) {
  json document = json::parse(kTsFile);
  document[json::json_pointer(pointer)] = json::parse(value);
  return document.dump();
}

TEST(ModelFile, SmallestFileParsesToTheExactCoefficients) {
  const ModelDocument document = ParseModelJson(kSmallestFile, "model.json");
  ASSERT_EQ(document.kind, ModelDocument::Kind::kTransferFunction);
  EXPECT_EQ(document.tf.num, (std::vector<double>{0.0085, 0.842, 1.924, 1.97}));
  EXPECT_EQ(document.tf.den, (std::vector<double>{1, 0.5898, 367.2, 29.41, 0.2275}));
  EXPECT_EQ(document.tf.delay_s, 3.67);
  EXPECT_TRUE(document.augmentations.empty());
  EXPECT_TRUE(document.extra.empty());
}

TEST(ModelFile, DelayIsOptional) {
  const ModelDocument document = ParseModelJson(SmallestWith("delay_s", ""), "model.json");
  EXPECT_EQ(document.tf.delay_s, 0.0);
}

TEST(ModelFile, TransferFunctionRoundTripThroughAFile) {
  ScratchDir dir;
  const std::string path = dir.File("model.json");
  ModelDocument original = ParseModelJson(kSmallestFile, "model.json");
  original.extra["fit"] = {{"fit_percent", 91.25}};
  WriteModelFile(path, original);
  EXPECT_FALSE(fs::exists(path + ".tmp"));

  std::ifstream file(path);
  const std::string text((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  EXPECT_EQ(text.rfind("{\n  \"format\": \"flexid.model/1\",\n  \"kind\": \"tf\",\n", 0), 0u)
      << text;
  ASSERT_FALSE(text.empty());
  EXPECT_EQ(text.back(), '\n');

  const ModelDocument read = ReadModelFile(path);
  EXPECT_EQ(read.kind, ModelDocument::Kind::kTransferFunction);
  EXPECT_EQ(read.tf.num, original.tf.num);
  EXPECT_EQ(read.tf.den, original.tf.den);
  EXPECT_EQ(read.tf.delay_s, original.tf.delay_s);
  EXPECT_EQ(read.extra, original.extra);
  EXPECT_EQ(ModelToJson(read), ModelToJson(original));
}

TEST(ModelFile, TsRoundTripKeepsShouldersAndExtras) {
  ScratchDir dir;
  const ModelDocument original = ParseModelJson(kTsFile, "ts.json");
  ASSERT_EQ(original.kind, ModelDocument::Kind::kTsFuzzy);
  ASSERT_EQ(original.ts.rules.size(), 2u);
  EXPECT_EQ(original.ts.scheduling, SchedulingVariable::kAbsVoltage);
  EXPECT_EQ(original.ts.rules[0].level_V, 2.0);
  EXPECT_EQ(original.ts.rules[1].tf.delay_s, 0.0);
  EXPECT_EQ(original.ts.rules[0].membership.shape, MembershipShape::kTrapezoidal);
  EXPECT_EQ(original.ts.rules[0].membership.params, (std::vector<double>{-kInf, -kInf, 2, 5}));
  EXPECT_EQ(original.ts.rules[1].membership.params, (std::vector<double>{2, 5, kInf, kInf}));
  ASSERT_EQ(original.local_extra.size(), 2u);
  EXPECT_EQ(original.local_extra[0],
            json::parse(R"({"fit_percent": 95.1, "interval95": {"num": [[0.008, 0.009]]}})"));
  EXPECT_EQ(original.local_extra[1], json::parse(R"({"rmse_mm": 0.012})"));
  EXPECT_EQ(original.extra, json::parse(R"({"fit": {"fit_percent": 93.5, "recordings":
                                              ["a.csv", "b.csv"]}, "created_by": "flexid 0.1.0"})"));
  ASSERT_EQ(original.augmentations.size(), 1u);
  EXPECT_EQ(original.augmentations[0].effect, "back_relaxation");
  EXPECT_EQ(original.augmentations[0].params["tau_s"], 40.0);

  // The written document is the input document (delay_s 0 made explicit).
  json expected = json::parse(kTsFile);
  expected["local_models"][1]["delay_s"] = 0.0;
  EXPECT_EQ(ModelToJson(original), expected);

  const std::string path = dir.File("ts.json");
  WriteModelFile(path, original);
  const ModelDocument read = ReadModelFile(path);
  EXPECT_EQ(ModelToJson(read), expected);
  EXPECT_EQ(read.ts.rules[0].membership.params, original.ts.rules[0].membership.params);
  EXPECT_EQ(read.local_extra, original.local_extra);
}

TEST(ModelFile, MembershipShapesAndVoltageScheduling) {
  json document = json::parse(kTsFile);
  document["scheduling"] = json::parse(R"({"variable": "voltage", "memberships": [
      {"shape": "gaussian", "params": [2, 1.5]}, {"shape": "sigmoid", "params": [3.5, 2]}]})");
  const ModelDocument read = ParseModelJson(document.dump(), "m.json");
  EXPECT_EQ(read.ts.scheduling, SchedulingVariable::kVoltage);
  EXPECT_EQ(read.ts.rules[0].membership.shape, MembershipShape::kGaussian);
  EXPECT_EQ(read.ts.rules[1].membership.shape, MembershipShape::kSigmoid);
  EXPECT_EQ(ModelToJson(read)["scheduling"], document["scheduling"]);

  // The scheduling variable defaults to abs_voltage.
  document["scheduling"].erase("variable");
  EXPECT_EQ(ParseModelJson(document.dump(), "m.json").ts.scheduling,
            SchedulingVariable::kAbsVoltage);
}

TEST(ModelFile, DelayedVoltageSchedulingKeepsItsDelay) {
  json document = json::parse(kTsFile);
  document["scheduling"]["variable"] = "abs_voltage_delayed";
  document["scheduling"]["delay_s"] = 3.5;
  const ModelDocument read = ParseModelJson(document.dump(), "m.json");
  EXPECT_EQ(read.ts.scheduling, SchedulingVariable::kAbsVoltageDelayed);
  EXPECT_EQ(read.ts.scheduling_delay_s, 3.5);
  EXPECT_EQ(ModelToJson(read)["scheduling"]["delay_s"], 3.5);

  // Without delay_s the premise takes the smallest dead time of the local models.
  document["scheduling"].erase("delay_s");
  document["local_models"][0]["delay_s"] = 4.0;
  document["local_models"][1]["delay_s"] = 2.5;
  EXPECT_EQ(ParseModelJson(document.dump(), "m.json").ts.scheduling_delay_s, 2.5);

  document["scheduling"]["delay_s"] = -1;
  EXPECT_THROW(
      {
        try {
          ParseModelJson(document.dump(), "m.json");
        } catch (const InputError& e) {
          EXPECT_NE(std::string(e.what()).find("/scheduling/delay_s"), std::string::npos);
          throw;
        }
      },
      InputError);
}

TEST(ModelFile, ParallelRealisationRoundTripsAndOldFilesStayFrozen) {
  json document = json::parse(kTsFile);
  EXPECT_EQ(ParseModelJson(document.dump(), "m.json").ts.realisation, TsRealisation::kFrozen);
  EXPECT_FALSE(
      ModelToJson(ParseModelJson(document.dump(), "m.json"))["scheduling"].contains("realisation"));
  document["local_models"][1]["delay_s"] = 3.67;  // parallel rules share one dead time
  document["scheduling"]["realisation"] = "parallel";
  const ModelDocument read = ParseModelJson(document.dump(), "m.json");
  EXPECT_EQ(read.ts.realisation, TsRealisation::kParallel);
  EXPECT_EQ(ModelToJson(read)["scheduling"]["realisation"], "parallel");

  document["scheduling"]["realisation"] = "series";
  EXPECT_NE(ParseError(document.dump()).find("/scheduling/realisation: unknown realisation"),
            std::string::npos)
      << ParseError(document.dump());
  document["scheduling"]["realisation"] = "parallel";
  document["local_models"][1]["delay_s"] = 2.0;
  EXPECT_NE(ParseError(document.dump()).find("share one dead time"), std::string::npos)
      << ParseError(document.dump());
}

TEST(ModelFile, TransferFunctionDocumentBecomesASingleRule) {
  const ModelDocument document = ParseModelJson(kSmallestFile, "model.json");
  const TsModel model = AsTsModel(document);
  ASSERT_EQ(model.rules.size(), 1u);
  EXPECT_EQ(model.rules[0].tf.num, document.tf.num);
  EXPECT_EQ(model.rules[0].tf.den, document.tf.den);
  EXPECT_EQ(model.rules[0].tf.delay_s, document.tf.delay_s);
  std::string why;
  EXPECT_TRUE(IsValid(model, &why)) << why;

  // A T-S document is returned as it is.
  const ModelDocument ts = ParseModelJson(kTsFile, "ts.json");
  EXPECT_EQ(AsTsModel(ts).rules.size(), 2u);
}

TEST(ModelFile, FromTransferFunctionAndFromTsModel) {
  const TransferFunction tf{{2.0}, {1.0, 3.0}, 0.5};
  const ModelDocument from_tf = FromTransferFunction(tf);
  EXPECT_EQ(ModelToJson(from_tf), json::parse(R"({"format": "flexid.model/1", "kind": "tf",
      "num": [2.0], "den": [1.0, 3.0], "delay_s": 0.5})"));

  const TsModel ts =
      MakeTsModelOnLevels({{2.0, tf, {}}, {5.0, TransferFunction{{4.0}, {1.0, 2.0}, 0.25}, {}}});
  const ModelDocument from_ts = FromTsModel(ts);
  const ModelDocument read = ParseModelJson(ModelToJson(from_ts).dump(), "ts.json");
  ASSERT_EQ(read.ts.rules.size(), 2u);
  for (std::size_t i = 0; i < 2; ++i) {
    EXPECT_EQ(read.ts.rules[i].level_V, ts.rules[i].level_V);
    EXPECT_EQ(read.ts.rules[i].tf.num, ts.rules[i].tf.num);
    EXPECT_EQ(read.ts.rules[i].tf.den, ts.rules[i].tf.den);
    EXPECT_EQ(read.ts.rules[i].tf.delay_s, ts.rules[i].tf.delay_s);
    EXPECT_EQ(read.ts.rules[i].membership.shape, ts.rules[i].membership.shape);
    EXPECT_EQ(read.ts.rules[i].membership.params, ts.rules[i].membership.params);
  }
}

TEST(ModelFile, ModelToJsonRejectsInvalidDocuments) {
  ModelDocument bad = FromTransferFunction({{1.0, 2.0, 3.0}, {1.0, 1.0}, 0.0});  // improper
  EXPECT_THROW(ModelToJson(bad), std::invalid_argument);
  bad = FromTransferFunction({{1.0}, {1.0, std::nan("")}, 0.0});
  EXPECT_THROW(ModelToJson(bad), std::invalid_argument);
  ModelDocument ts = ParseModelJson(kTsFile, "ts.json");
  ts.local_extra.pop_back();
  EXPECT_THROW(ModelToJson(ts), std::invalid_argument);
  ScratchDir dir;
  EXPECT_THROW(WriteModelFile(dir.File("bad.json"), bad), std::invalid_argument);
  EXPECT_FALSE(fs::exists(dir.File("bad.json")));
}

// --- errors ----------------------------------------------------------------------------

TEST(ModelFileErrors, SyntaxErrorsGiveLineAndColumn) {
  // The position is that of the first character that makes the text invalid: the "f"
  // of "tf" below, which cannot continue the literal "true".
  ExpectError("{\"format\": \"flexid.model/1\",\n  \"kind\": tf}",
              "model.json:2:12: ", {"syntax error", "invalid literal"});
  ExpectError("", "model.json:1:1: ", {"unexpected end of input"});
  ExpectError("{\"a\": 1}\n x", "model.json:2:2: ", {"expected end of input"});
  // Columns count characters: "µ" is two bytes.
  ExpectError("{\"µµ\": 1,, }", "model.json:1:10: ", {"syntax error"});
  ExpectError("{\"num\": [1,\n\n   2,]}", "model.json:3:6: ", {"syntax error"});
  ExpectError("{\"a\": \"\xff\"}", "model.json:1:8: ", {"ill-formed UTF-8"});
}

TEST(ModelFileErrors, NumberOverflowIsRejectedWithItsPosition) {
  ExpectError(
      "{\"format\": \"flexid.model/1\", \"kind\": \"tf\",\n \"num\": [1e400], \"den\": [1]}",
      "model.json:2:10: ", {"number out of range", "1e400"});
}

TEST(ModelFileErrors, TopLevelMustBeAnObject) {
  ExpectError("[1, 2]", "model.json: ", {"expected a JSON object at the top level", "array"});
  ExpectError("null", "model.json: ", {"expected a JSON object"});
}

TEST(ModelFileErrors, Format) {
  ExpectError(SmallestWith("format", "\"flexid.model/2\""),
              "model.json: /format: unsupported format \"flexid.model/2\" (this flexid reads "
              "flexid.model/1)",
              {});
  ExpectError(SmallestWith("format", ""), "model.json: /format: missing", {"flexid.model/1"});
  ExpectError(SmallestWith("format", "1"), "model.json: /format: ", {"found a number"});
}

TEST(ModelFileErrors, Kind) {
  ExpectError(SmallestWith("kind", ""), "model.json: /kind: missing", {"\"tf\" or \"ts_fuzzy\""});
  ExpectError(SmallestWith("kind", "\"nn\""), "model.json: /kind: unknown kind \"nn\"",
              {"\"tf\" or \"ts_fuzzy\""});
}

TEST(ModelFileErrors, Coefficients) {
  ExpectError(SmallestWith("den", "[]"),
              "model.json: /den: expected a non-empty array of finite numbers", {"empty array"});
  ExpectError(SmallestWith("num", "[1, \"2\"]"),
              "model.json: /num: expected a non-empty array of finite numbers",
              {"element 1 is a string"});
  ExpectError(SmallestWith("num", "[1, true]"), "model.json: /num: ", {"element 1 is a boolean"});
  ExpectError(SmallestWith("num", "{\"a\": 1}"), "model.json: /num: ", {"found an object"});
  ExpectError(SmallestWith("den", ""), "model.json: /den: missing", {"non-empty array"});
  ExpectError(TsWith("/local_models/1/den", "[1, null]"),
              "model.json: /local_models/1/den: expected a non-empty array of finite numbers",
              {"element 1 is null"});
}

TEST(ModelFileErrors, LeadingDenominatorZero) {
  ExpectError(SmallestWith("den", "[0, 1, 2, 3, 4]"),
              "model.json: /den/0: ", {"leading denominator coefficient is 0"});
}

TEST(ModelFileErrors, ImproperModelUsesIsValidMessage) {
  ExpectError(SmallestWith("den", "[1, 2]"), "model.json: ",
              {"model is improper", "numerator degree 3 exceeds denominator degree 1"});
  ExpectError(TsWith("/local_models/0/num", "[1, 2, 3, 4, 5, 6]"),
              "model.json: /local_models/0: ", {"improper"});
}

TEST(ModelFileErrors, Delay) {
  ExpectError(SmallestWith("delay_s", "-1"), "model.json: /delay_s: ", {">= 0"});
  ExpectError(SmallestWith("delay_s", "\"3\""),
              "model.json: /delay_s: ", {"expected a finite number", "string"});
}

TEST(ModelFileErrors, LocalModels) {
  ExpectError(TsWith("/local_models", "[]"), "model.json: /local_models: ", {"empty array"});
  ExpectError(TsWith("/local_models/1", "3"),
              "model.json: /local_models/1: ", {"expected an object"});
  json no_level = json::parse(kTsFile);
  no_level["local_models"][0].erase("level_V");
  ExpectError(no_level.dump(), "model.json: /local_models/0/level_V: missing", {});
  ExpectError(TsWith("/local_models/1/den", "[1, 0.6, 370, 30]"),
              "model.json: /local_models: ", {"order 3 differs", "order 4"});
}

TEST(ModelFileErrors, Memberships) {
  ExpectError(TsWith("/scheduling/memberships",
                     R"([{"shape": "trapezoidal", "params": [null, null, 2, 5]}])"),
              "model.json: /scheduling/memberships: 1 memberships for 2 local models", {});
  ExpectError(TsWith("/scheduling/memberships/1/shape", "\"bell\""),
              "model.json: /scheduling/memberships/1/shape: unknown membership shape \"bell\"",
              {"triangular"});
  ExpectError(
      TsWith("/scheduling/memberships/1", R"({"shape": "triangular", "params": [3, 2, 1]})"),
      "model.json: /scheduling/memberships/1: ", {"a <= b <= c"});
  ExpectError(
      TsWith("/scheduling/memberships/0", R"({"shape": "triangular", "params": [null, 2, 3]})"),
      "model.json: /scheduling/memberships/0/params/0: ", {"null", "trapezoidal"});
  ExpectError(TsWith("/scheduling/memberships/0", R"({"shape": "gaussian", "params": [2]})"),
              "model.json: /scheduling/memberships/0: ", {"needs 2 parameters"});
  ExpectError(TsWith("/scheduling/memberships/0/params", "[null, 1, 2, 5]"),
              "model.json: /scheduling/memberships/0: ", {"shoulder"});
  ExpectError(TsWith("/scheduling/memberships/0/params", "[1, 2, null, null, null]"),
              "model.json: /scheduling/memberships/0/params/4: ", {"null"});
  ExpectError(TsWith("/scheduling/variable", "\"current\""),
              "model.json: /scheduling/variable: unknown scheduling variable \"current\"", {});
  json no_scheduling = json::parse(kTsFile);
  no_scheduling.erase("scheduling");
  ExpectError(no_scheduling.dump(), "model.json: /scheduling: missing", {});
}

TEST(ModelFileErrors, Augmentations) {
  ExpectError(SmallestWith("augmentations", "{}"),
              "model.json: /augmentations: ", {"expected an array"});
  ExpectError(SmallestWith("augmentations", R"([{"params": {}}])"),
              "model.json: /augmentations/0/effect: missing", {});
  ExpectError(SmallestWith("augmentations", R"([{"effect": "hysteresis", "params": [1]}])"),
              "model.json: /augmentations/0/params: expected an object", {});
  const ModelDocument document =
      ParseModelJson(SmallestWith("augmentations", R"([{"effect": "sensor_drift"}])"), "m.json");
  ASSERT_EQ(document.augmentations.size(), 1u);
  EXPECT_EQ(document.augmentations[0].params, json::object());
}

TEST(ModelFileErrors, OversizedDocument) {
  std::string text = kSmallestFile;
  text.insert(text.size() - 1, std::string(kMaxModelFileBytes, ' '));
  ExpectError(text, "model.json: model file is too large", {"16 MiB"});

  ScratchDir dir;
  const std::string path = dir.File("big.json");
  {
    std::ofstream file(path);
    file << text;
  }
  try {
    ReadModelFile(path);
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find(path + ": model file is too large"),
              std::string::npos);
  }
}

TEST(ModelFileErrors, DeepNestingIsRejectedWithoutCrashing) {
  const std::size_t depth = 1'000'000;
  const std::string deep = std::string(depth, '[') + std::string(depth, ']');
  ExpectError("{\"x\": " + deep + "}", "model.json: JSON nesting deeper than 64 levels", {});
  const std::string too_deep = std::string(64, '[') + std::string(64, ']');
  ExpectError("{\"x\": " + too_deep + "}", "model.json: JSON nesting deeper than 64 levels", {});
  // 64 levels is fine (as an extra member kept on round trip).
  json document = json::parse(kSmallestFile);
  const std::string ok = std::string(63, '[') + std::string(63, ']');
  document["deep"] = json::parse(ok);
  EXPECT_EQ(ParseModelJson(document.dump(), "m.json").extra["deep"], json::parse(ok));
}

TEST(ModelFileErrors, CannotOpen) {
  ScratchDir dir;
  const std::string path = dir.File("absent.json");
  try {
    ReadModelFile(path);
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_EQ(std::string(error.what()), path + ": cannot open: No such file or directory");
  }
  try {
    ReadModelFile(dir.File(""));
    FAIL() << "no error";
  } catch (const InputError& error) {
    EXPECT_NE(std::string(error.what()).find(": cannot open: Is a directory"), std::string::npos);
  }
}

TEST(ModelFileErrors, NeverCrashesOnMutatedDocuments) {
  std::mt19937 random(2024);
  const std::string alphabet = "{}[],:\"0123456789.eE-+ntrufalsnul \n\\\xff";
  const std::string sources[] = {kSmallestFile, kTsFile};
  for (int trial = 0; trial < 4000; ++trial) {
    std::string text = sources[trial % 2];
    const int edits = 1 + static_cast<int>(random() % 4);
    for (int e = 0; e < edits; ++e) {
      const std::size_t at = random() % text.size();
      switch (random() % 3) {
        case 0:
          text[at] = alphabet[random() % alphabet.size()];
          break;
        case 1:
          text.erase(at, 1 + random() % 8);
          break;
        default:
          text.insert(at, 1, alphabet[random() % alphabet.size()]);
          break;
      }
      if (text.empty()) text.push_back('x');
    }
    try {
      const ModelDocument document = ParseModelJson(text, "fuzz.json");
      // Whatever was accepted can be written and read back.
      const ModelDocument again = ParseModelJson(ModelToJson(document).dump(), "again.json");
      ASSERT_EQ(ModelToJson(again), ModelToJson(document)) << text;
    } catch (const InputError& error) {
      const std::string message = error.what();
      ASSERT_EQ(message.rfind("fuzz.json:", 0), 0u) << message;
      ASSERT_EQ(message.find('\n'), std::string::npos) << message;
    }
  }
}

}  // namespace
}  // namespace flexid::model
