// End-to-end tests of the flexid command line: the real binary, real files.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>

#include "cli_process.h"
#include "model/physics/physics.h"
#include "scratch_dir.h"

namespace flexid {
namespace {

using testing::RunCommand;
using testing::ScratchDir;
using testing::WriteFile;

const std::string kFlexid = FLEXID_BINARY;
const std::string kExamples = std::string(FLEXID_SOURCE_DIR) + "/examples";

class Cli : public ::testing::Test {
 protected:
  testing::ProcessResult Run(const std::string& args) {
    return RunCommand(kFlexid + " " + args, scratch_.path());
  }
  ScratchDir scratch_;
};

TEST_F(Cli, TfShowJsonGivesTheSeed8VPolesAndGain) {
  const auto r = Run("tf show " + kExamples + "/seed-8V.json --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_NEAR(doc["dc_gain"].get<double>(), 1.97 / 0.2275, 1e-12);
  ASSERT_EQ(doc["poles"].size(), 4u);
  ASSERT_EQ(doc["zeros"].size(), 3u);
  // The lightly damped pair: |p| = sqrt(b5-free part) ~ 19.16 rad/s, damping ~ 0.013.
  bool found_pair = false;
  for (const auto& mode : doc["modes"]) {
    if (!mode["oscillatory"].get<bool>()) continue;
    found_pair = true;
    EXPECT_NEAR(mode["natural_frequency_rad_s"].get<double>(), 19.16, 0.01);
    EXPECT_NEAR(mode["damping_ratio"].get<double>(), 0.0133, 0.0002);
  }
  EXPECT_TRUE(found_pair);
}

TEST_F(Cli, TfShowHumanOutputNamesTheFigures) {
  const auto r = Run("tf show " + kExamples + "/seed-8V.json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* word :
       {"DC gain: 8.65934", "dead time: 3.67 s", "damping", "zeros:", "real, negative poles"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << "\n" << r.out;
}

TEST_F(Cli, TfShowTsModelListsLocalModels) {
  const auto r = Run("tf show " + kExamples + "/seed-ts.json --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  ASSERT_EQ(doc["local_models"].size(), 2u);
  EXPECT_EQ(doc["local_models"][1]["level_V"].get<double>(), 8.0);
}

TEST_F(Cli, SimulateWritesPredictionsAndFit) {
  // A recording made from the 2 V model itself: simulate must reproduce it (fit ~100 %).
  const auto voltage_only = scratch_.path() / "volts.csv";
  std::string text = "t_s,voltage_V\n";
  for (int k = 0; k < 3000; ++k)
    text += std::to_string(0.1 * k) + "," + (k % 1000 < 500 ? "2" : "0") + "\n";
  WriteFile(voltage_only, text);
  auto r = Run("simulate --model " + kExamples + "/seed-2V.json " + voltage_only.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out.rfind("t_s,voltage_V,predicted_mm\n", 0), 0u);
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 3001);
  // Feed the predictions back as a recording with a deflection column.
  std::string recording = "t_s,voltage_V,deflection_mm\n" + r.out.substr(r.out.find('\n') + 1);
  WriteFile(scratch_.path() / "rec.csv", recording);
  r = Run("simulate --model " + kExamples + "/seed-2V.json " +
          (scratch_.path() / "rec.csv").string() + " --out " +
          (scratch_.path() / "pred.csv").string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("wrote 3000 predictions"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("fit 100 %"), std::string::npos) << r.out;
  EXPECT_TRUE(std::filesystem::exists(scratch_.path() / "pred.csv"));
}

TEST_F(Cli, BadInputExitsTwoWithOneLineNamingTheProblem) {
  WriteFile(scratch_.path() / "bad.csv", "t_s,voltage_V\n0,1\n0.1,abc\n");
  auto r = Run("simulate --model " + kExamples + "/seed-2V.json " +
               (scratch_.path() / "bad.csv").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("bad.csv:3:"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;

  WriteFile(scratch_.path() / "bad.json",
            R"({"format": "flexid.model/1", "kind": "tf", "num": [1], "den": [0]})");
  r = Run("tf show " + (scratch_.path() / "bad.json").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("bad.json"), std::string::npos) << r.err;

  r = Run("tf show " + (scratch_.path() / "missing.json").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("missing.json"), std::string::npos) << r.err;

  r = Run("simulate " + (scratch_.path() / "bad.csv").string());  // --model missing
  EXPECT_EQ(r.exit_code, 2);
  r = Run("no-such-command");
  EXPECT_EQ(r.exit_code, 2);
}

TEST_F(Cli, HelpOnEveryCommandHasAnExample) {
  for (const char* command : {"tf show", "simulate", "physics", "identify", "diagnose", "plot fit",
                              "plot residual", "plot bode", "plot memberships"}) {
    const auto r = Run(std::string(command) + " --help");
    EXPECT_EQ(r.exit_code, 0) << command;
    EXPECT_NE(r.out.find("Example"), std::string::npos) << command << "\n" << r.out;
  }
}

// Recordings of the seed's 2 V model under square waves are made with the CLI itself:
// voltage-only CSV -> simulate -> rename the prediction column.
TEST_F(Cli, IdentifyRecoversTheModelBehindARecordingAndValidates) {
  auto write_square = [&](const std::string& name, double period_s, int samples) {
    std::string text = "t_s,voltage_V\n";
    for (int k = 0; k < samples; ++k)
      text += std::to_string(0.1 * k) + "," +
              (std::fmod(0.1 * k, period_s) < period_s / 2 ? "2" : "0") + "\n";
    WriteFile(scratch_.File(name + "-volts.csv"), text);
    auto r = Run("simulate --model " + kExamples + "/seed-2V.json " +
                 scratch_.File(name + "-volts.csv"));
    EXPECT_EQ(r.exit_code, 0) << r.err;
    WriteFile(scratch_.File(name + ".csv"),
              "t_s,voltage_V,deflection_mm\n" + r.out.substr(r.out.find('\n') + 1));
    return scratch_.File(name + ".csv");
  };
  const std::string fit = write_square("fit", 220.0, 11000),
                    check = write_square("check", 150.0, 6000);
  // The orders of the model behind the recording: given, the fit recovers its dead time.
  const auto r = Run("identify " + fit + " --zeros 3 --poles 4 --validate " + check +
                     " --json --out " + scratch_.File("model.json"));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);
  EXPECT_EQ(doc["format"], "flexid.model/1");
  EXPECT_EQ(doc["kind"], "tf");
  EXPECT_NEAR(doc["dc_gain"]["value"].get<double>(), 1.14 / 0.2142, 1e-3);
  EXPECT_NEAR(doc["delay_s"].get<double>(), 3.67, 0.037);
  EXPECT_GT(doc["validation"]["fit_percent"].get<double>(), 99.9);
  EXPECT_TRUE(std::filesystem::exists(scratch_.File("model.json")));
  // The written file is a model the other commands read.
  EXPECT_EQ(Run("tf show " + scratch_.File("model.json")).exit_code, 0);
}

TEST_F(Cli, IdentifyRejectsBadRecordingsAndOptions) {
  std::string flat = "t_s,voltage_V,deflection_mm\n";
  for (int k = 0; k < 2000; ++k) flat += std::to_string(0.1 * k) + ",5,0\n";
  WriteFile(scratch_.File("flat.csv"), flat);
  auto r = Run("identify " + scratch_.File("flat.csv"));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("flat.csv"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("constant"), std::string::npos) << r.err;
  r = Run("identify " + scratch_.File("flat.csv") + " --structure nonsense");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--structure"), std::string::npos) << r.err;
  r = Run("identify " + scratch_.File("flat.csv") + " --zeros 4 --poles 4");
  EXPECT_EQ(r.exit_code, 2);
  r = Run("identify " + scratch_.File("flat.csv") + " --structure physics --geometry 40x8");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--geometry"), std::string::npos) << r.err;
  r = Run("identify " + scratch_.File("flat.csv") +
          " --structure physics --predict-geometry 0x8x2");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--predict-geometry"), std::string::npos) << r.err;
}

TEST_F(Cli, PhysicsTable1JsonGivesTheChainsExponentsAndTheDepartures) {
  const auto r = Run("physics --table1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto doc = nlohmann::json::parse(r.out);  // one document, nothing else on stdout
  ASSERT_EQ(doc["dimensions"].size(), 3u);
  // Expected exponents from PredictTable1's rows (S1 first), computed here by hand:
  // ln(y_i/y_1)/ln(x_i/x_1) for the one dimension in which row i differs from S1.
  const std::vector<model::Table1Row> rows = model::PredictTable1(model::SeedS1Parameters());
  ASSERT_EQ(rows.size(), 4u);
  const struct {
    const char* dimension;
    size_t row;
    double x_ratio;
  } expected[] = {{"thickness", 1, rows[1].h_mm / rows[0].h_mm},
                  {"width", 2, rows[2].W_mm / rows[0].W_mm},
                  {"length", 3, rows[3].L_mm / rows[0].L_mm}};
  for (const auto& e : expected) {
    const nlohmann::json* found = nullptr;
    for (const auto& d : doc["dimensions"])
      if (d["dimension"] == e.dimension) found = &d;
    ASSERT_NE(found, nullptr) << e.dimension;
    const auto& d = *found;
    EXPECT_EQ(d["beams"][0], "S1");
    EXPECT_EQ(d["beams"][1], rows[e.row].name);
    const double ln_x = std::log(e.x_ratio);
    EXPECT_NEAR(
        d["predicted_exponent"].get<double>(),
        std::log(rows[e.row].predicted_deflection_mm / rows[0].predicted_deflection_mm) / ln_x,
        1e-12)
        << e.dimension;
    EXPECT_NEAR(
        d["measured_exponent"].get<double>(),
        std::log(rows[e.row].measured_deflection_mm / rows[0].measured_deflection_mm) / ln_x, 1e-12)
        << e.dimension;
    EXPECT_NEAR(d["predicted_ratio"].get<double>(), rows[e.row].predicted_ratio_to_s1, 1e-12);
    EXPECT_NEAR(d["measured_ratio"].get<double>(), rows[e.row].measured_ratio_to_s1, 1e-12);
    const double uncertainty = d["exponent_uncertainty"].get<double>();
    EXPECT_GT(uncertainty, 0.0);
    EXPECT_EQ(d["departs"].get<bool>(),
              std::abs(d["measured_exponent"].get<double>() -
                       d["predicted_exponent"].get<double>()) > uncertainty);
    EXPECT_FALSE(d["explanation"].get<std::string>().empty());
  }
  // Table 1 departs in every dimension beyond its reading precision, thickness most.
  ASSERT_EQ(doc["departing"].size(), 3u);
  EXPECT_EQ(doc["departing"][0], "thickness");
  ASSERT_EQ(doc["beams"].size(), 4u);
  for (size_t i = 0; i < rows.size(); ++i) {
    const auto p = model::WithGeometry(model::SeedS1Parameters(), 1e-3 * rows[i].L_mm,
                                       1e-3 * rows[i].W_mm, 1e-3 * rows[i].h_mm);
    EXPECT_NEAR(doc["beams"][i]["slowest_diffusion_time_constant_s"].get<double>(),
                model::SlowestDiffusionTimeConstant_s(p), 1e-9);
  }
  EXPECT_TRUE(doc["seed_hold_s"].is_null());  // the seed does not state it
  EXPECT_FALSE(doc["notes"].empty());
  EXPECT_FALSE(doc.contains("truncation"));  // --table1 prints only the Table 1 analysis
}

TEST_F(Cli, PhysicsTable1HumanOutputIsATableAndFindings) {
  const auto r = Run("physics --table1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* word : {"thickness", "width", "length", "S2/S1", "departs", "Findings",
                           "Thickness departs most", "not stated"})
    EXPECT_NE(r.out.find(word), std::string::npos) << word << "\n" << r.out;
  EXPECT_EQ(r.out.find("Exact Eq. (11)"), std::string::npos) << r.out;
}

TEST_F(Cli, PhysicsTable1RejectsOptionsThatDoNotApply) {
  for (const char* option : {"--terms", "--voltage"}) {
    const auto r = Run(std::string("physics --table1 ") + option + " 3");
    EXPECT_EQ(r.exit_code, 2) << option;
    EXPECT_NE(r.err.find(option), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
}

}  // namespace
}  // namespace flexid

namespace flexid {
namespace {

// flexid diagnose on a shipped concealed recording: the DESIGN.md JSON, the report, the
// augmented model file, and simulate applying the augmentation.
TEST_F(Cli, DiagnoseGivesTheContractJsonReportAndAugmentedModel) {
  const std::string rec = kExamples + "/concealed/rec-06.csv";
  const auto report = scratch_.path() / "report.html";
  const auto augmented = scratch_.path() / "augmented.json";
  auto r = Run("diagnose " + rec + " --model " + kExamples + "/seed-8V.json --json --report " +
               report.string() + " --out " + augmented.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  for (const char* key : {"verdict", "baseline", "findings"}) EXPECT_TRUE(j.contains(key)) << key;
  for (const char* key : {"fit_percent", "rmse_mm", "heldout_rmse_mm"})
    EXPECT_TRUE(j["baseline"][key].is_number()) << key;
  ASSERT_FALSE(j["findings"].empty());
  const auto& f = j["findings"][0];
  EXPECT_EQ(f["effect"], j["verdict"]);
  for (const char* key :
       {"explanation", "where", "params", "heldout_rmse_before_mm", "heldout_rmse_after_mm"})
    EXPECT_TRUE(f.contains(key)) << key;
  EXPECT_LT(f["heldout_rmse_after_mm"].get<double>(), f["heldout_rmse_before_mm"].get<double>());
  ASSERT_TRUE(std::filesystem::exists(report));
  // The augmented model predicts the recording better than the model alone.
  auto fit_of = [&](const std::string& model) {
    const auto s = Run("simulate --model " + model + " " + rec + " --out " +
                       (scratch_.path() / "pred.csv").string());
    EXPECT_EQ(s.exit_code, 0) << s.err;
    const size_t at = s.out.find("RMSE ");
    return std::stod(s.out.substr(at + 5));
  };
  EXPECT_LT(fit_of(augmented.string()), fit_of(kExamples + "/seed-8V.json"));

  // An augmentation flexid does not know is bad input, named.
  WriteFile(scratch_.path() / "odd.json",
            R"({"format": "flexid.model/1", "kind": "tf", "num": [1], "den": [1, 1],
                "augmentations": [{"effect": "gremlins"}]})");
  r = Run("diagnose " + rec + " --model " + (scratch_.path() / "odd.json").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("gremlins"), std::string::npos) << r.err;
  r = Run("diagnose " + (scratch_.path() / "missing.csv").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("missing.csv"), std::string::npos) << r.err;
}

// Several recordings of one actuator: one diagnosis, spans that name their recording, one
// report with a chart set per recording; a bad one among them is named.
TEST_F(Cli, DiagnoseSeveralRecordingsTogether) {
  const std::string a = kExamples + "/concealed/rec-06.csv";
  const std::string b = kExamples + "/concealed/rec-01.csv";
  const auto report = scratch_.path() / "both.html";
  auto r = Run("diagnose " + a + " " + b + " --model " + kExamples +
               "/seed-8V.json --json --report " + report.string());
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["recordings"].size(), 2u);
  EXPECT_EQ(j["recordings"][0], a);
  bool in[2] = {false, false};
  for (const auto& span : j["heldout"]) {
    ASSERT_TRUE(span["recording"].is_number_integer()) << span;
    const int index = span["recording"].get<int>();
    ASSERT_TRUE(index == 0 || index == 1) << span;
    in[index] = true;
  }
  EXPECT_TRUE(in[0] && in[1]);
  std::ifstream file(report);
  const std::string html((std::istreambuf_iterator<char>(file)), std::istreambuf_iterator<char>());
  EXPECT_NE(html.find("rec-06.csv"), std::string::npos);
  EXPECT_NE(html.find("rec-01.csv"), std::string::npos);
  r = Run("diagnose " + a + " " + b + " --model " + kExamples + "/seed-8V.json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("diagnosis of " + a + " + " + b), std::string::npos) << r.out;

  r = Run("diagnose " + a + " " + (scratch_.path() / "gone.csv").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("gone.csv"), std::string::npos) << r.err;
  r = Run("diagnose " + a + " --recent 2");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--recent"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace flexid

namespace flexid {
namespace {

TEST_F(Cli, PlotWritesSvgChartsAndRefusesWhatItCannotDo) {
  const std::string rec = kExamples + "/concealed/rec-02.csv";
  auto svg_of = [&](const std::string& args, const std::string& file) {
    const auto r = Run("plot " + args + " --out " + (scratch_.path() / file).string());
    EXPECT_EQ(r.exit_code, 0) << args << ": " << r.err;
    std::ifstream in(scratch_.path() / file);
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  auto count = [](const std::string& text, const std::string& what) {
    size_t n = 0;
    for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
    return n;
  };
  // fit: two charts (deflection with measured and predicted, voltage); residual: one.
  const std::string fit = svg_of("fit --model " + kExamples + "/seed-8V.json " + rec, "fit.svg");
  EXPECT_EQ(fit.rfind("<svg", 0), 0u);
  EXPECT_EQ(count(fit, "<svg"), 3u);
  EXPECT_NE(fit.find("predicted"), std::string::npos);
  EXPECT_EQ(
      count(svg_of("residual --model " + kExamples + "/seed-8V.json " + rec, "r.svg"), "<svg"), 2u);
  // bode of the two-rule T-S model: one magnitude and one phase series per rule.
  const std::string bode = svg_of("bode --model " + kExamples + "/seed-ts.json", "bode.svg");
  EXPECT_EQ(count(bode, "<svg"), 3u);
  EXPECT_GE(count(bode, "<path"), 4u);
  const std::string mem =
      svg_of("memberships --model " + kExamples + "/seed-ts.json", "memberships.svg");
  EXPECT_NE(mem.find("8 V"), std::string::npos);

  // PNG by the extension (tests/cli_report_test.cc checks the image); others are refused.
  EXPECT_EQ(
      svg_of("fit --model " + kExamples + "/seed-8V.json " + rec, "fit.png").rfind("\x89PNG", 0),
      0u);
  auto r = Run("plot fit --model " + kExamples + "/seed-8V.json " + rec + " --out x.gif");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find(".svg or .png"), std::string::npos) << r.err;
  r = Run("plot bode --model " + kExamples + "/seed-8V.json " + rec + " --out x.svg");
  EXPECT_EQ(r.exit_code, 2);
  r = Run("plot bode --model " + (scratch_.path() / "missing.json").string() + " --out x.svg");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("missing.json"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace flexid
