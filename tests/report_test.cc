// The SVG chart writer (clients/cli/svg_plot.h) and the HTML diagnosis report
// (clients/cli/diagnosis_report.h), on hand-built charts and a hand-built Diagnosis.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <string>
#include <vector>

#include "clients/cli/diagnosis_report.h"
#include "clients/cli/svg_plot.h"

namespace flexid::cli {
namespace {

size_t Count(const std::string& text, const std::string& needle) {
  size_t count = 0;
  for (size_t at = text.find(needle); at != std::string::npos; at = text.find(needle, at + 1))
    ++count;
  return count;
}

bool EndsWith(const std::string& text, const std::string& suffix) {
  return text.size() >= suffix.size() &&
         text.compare(text.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// The d attribute of the index-th <path>.
std::string PathData(const std::string& svg, size_t index) {
  size_t at = 0;
  for (size_t i = 0; i <= index; ++i) {
    at = svg.find("<path d=\"", at);
    if (at == std::string::npos) return "";
    at += 9;
  }
  return svg.substr(at, svg.find('"', at) - at);
}

Chart TwoSeriesChart() {
  Chart chart;
  chart.title = "Step response";
  chart.x_label = "time (s)";
  chart.y_label = "deflection (mm)";
  Series a{.name = "measured", .x = {}, .y = {}};
  Series b{.name = "predicted", .x = {}, .y = {}, .colour = "#d95f02", .dashed = true};
  for (int i = 0; i <= 100; ++i) {
    const double t = 0.1 * i;
    a.x.push_back(t);
    a.y.push_back(1.0 - std::exp(-t));
    b.x.push_back(t);
    b.y.push_back(1.0 - std::exp(-1.1 * t));
  }
  chart.series = {a, b};
  chart.spans = {{.x_start = 2.0, .x_end = 4.0, .label = "held out"}};
  return chart;
}

TEST(SvgPlot, WellFormedBasics) {
  const std::string svg = RenderSvg(TwoSeriesChart(), 800, 400);
  EXPECT_EQ(svg.rfind("<svg", 0), 0u);
  EXPECT_TRUE(EndsWith(svg, "</svg>"));
  EXPECT_EQ(Count(svg, "<svg"), 1u);
  EXPECT_EQ(Count(svg, "<path"), 2u);             // one per series
  EXPECT_EQ(Count(svg, "stroke-dasharray"), 2u);  // the dashed series and its legend line
  EXPECT_NE(svg.find(">measured</text>"), std::string::npos);
  EXPECT_NE(svg.find(">held out</text>"), std::string::npos);
  EXPECT_NE(svg.find(">deflection (mm)</text>"), std::string::npos);
  // Every element that is opened is closed (self-closing or with an end tag).
  for (const std::string tag : {"text", "svg"})
    EXPECT_EQ(Count(svg, "<" + tag + " "), Count(svg, "</" + tag + ">")) << tag;
}

TEST(SvgPlot, Deterministic) {
  EXPECT_EQ(RenderSvg(TwoSeriesChart(), 800, 400), RenderSvg(TwoSeriesChart(), 800, 400));
}

TEST(SvgPlot, EscapesText) {
  Chart chart = TwoSeriesChart();
  chart.title = "a<b & \"c\" 'd'>";
  chart.series[0].name = "<script>x</script>";
  const std::string svg = RenderSvg(chart, 600, 300);
  EXPECT_NE(svg.find("a&lt;b &amp; &quot;c&quot; &#39;d&#39;&gt;"), std::string::npos);
  EXPECT_NE(svg.find("&lt;script&gt;x&lt;/script&gt;"), std::string::npos);
  EXPECT_EQ(svg.find("<script"), std::string::npos);
  EXPECT_EQ(svg.find("a<b"), std::string::npos);
  EXPECT_EQ(EscapeXml("&<>\"'ok"), "&amp;&lt;&gt;&quot;&#39;ok");
}

// Ticks are k * step with step in {1, 2, 5} x 10^n, and the first and last cover the range.
void ExpectNiceTicks(double low, double high) {
  SCOPED_TRACE(::testing::Message() << "range [" << low << ", " << high << "]");
  const std::vector<double> ticks = NiceTicks(low, high);
  ASSERT_GE(ticks.size(), 2u);
  ASSERT_LE(ticks.size(), 14u);
  EXPECT_LE(ticks.front(), low);
  EXPECT_GE(ticks.back(), high);
  const double step = ticks[1] - ticks[0];
  const double mantissa = step / std::pow(10.0, std::floor(std::log10(step)));
  const bool one_two_five = std::abs(mantissa - 1.0) < 1e-9 || std::abs(mantissa - 2.0) < 1e-9 ||
                            std::abs(mantissa - 5.0) < 1e-9 || std::abs(mantissa - 10.0) < 1e-9;
  EXPECT_TRUE(one_two_five) << "step " << step;
  for (size_t i = 0; i < ticks.size(); ++i) {
    const double multiple = ticks[i] / step;
    EXPECT_NEAR(multiple, std::round(multiple), 1e-9) << ticks[i];
    if (i > 0) {
      EXPECT_NEAR(ticks[i] - ticks[i - 1], step, 1e-9 * step);
    }
  }
}

TEST(SvgPlot, NiceTicksAreOneTwoFiveMultiplesCoveringTheRange) {
  ExpectNiceTicks(0.0, 1.0);
  ExpectNiceTicks(0.0, 97.3);
  ExpectNiceTicks(-3.2, 7.9);
  ExpectNiceTicks(0.013, 0.0171);
  ExpectNiceTicks(-2.5e-5, -1.1e-5);
  ExpectNiceTicks(1234.0, 98765.0);
  ExpectNiceTicks(5.0, 5.0);  // empty range: widened
  ExpectNiceTicks(0.0, 0.0);
  const std::vector<double> ticks = NiceTicks(0.0, 10.0);
  EXPECT_EQ(ticks, (std::vector<double>{0, 2, 4, 6, 8, 10}));
}

TEST(SvgPlot, DecimationKeepsTheSpikeAndBoundsThePoints) {
  const size_t n = 100000, spike = 54321, dip = 7777;
  std::vector<double> x(n), y(n);
  for (size_t i = 0; i < n; ++i) {
    x[i] = 0.01 * static_cast<double>(i);
    y[i] = 0.1 * std::sin(0.001 * static_cast<double>(i));
  }
  y[spike] = 50.0;
  y[dip] = -50.0;
  const std::vector<size_t> kept = DecimateMinMax(x, y, 2000);
  EXPECT_LE(kept.size(), 2000u);
  EXPECT_GE(kept.size(), 1000u);
  EXPECT_TRUE(std::is_sorted(kept.begin(), kept.end()));
  EXPECT_TRUE(std::binary_search(kept.begin(), kept.end(), spike));
  EXPECT_TRUE(std::binary_search(kept.begin(), kept.end(), dip));

  // Short series are kept whole.
  EXPECT_EQ(DecimateMinMax(std::vector<double>{0, 1, 2}, std::vector<double>{3, 4, 5}).size(), 3u);

  // In the SVG: about kMaxPointsPerSeries points, and the spike reaches the top of the
  // y axis (the largest tick is at or above 50, so the spike is the smallest y pixel).
  Chart chart;
  chart.series.push_back({.name = "long", .x = x, .y = y});
  const std::string d = PathData(RenderSvg(chart, 900, 400), 0);
  EXPECT_LE(Count(d, "L") + Count(d, "M"), kMaxPointsPerSeries);
  EXPECT_GE(Count(d, "L"), kMaxPointsPerSeries / 2);
}

TEST(SvgPlot, NonFiniteValuesAreSkipped) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  Chart chart;
  chart.series.push_back({.name = "gappy", .x = {0, 1, 2, 3, 4, 5}, .y = {0, 1, nan, 3, inf, 5}});
  const std::string svg = RenderSvg(chart, 600, 300);
  EXPECT_EQ(svg.find("nan"), std::string::npos);
  EXPECT_EQ(svg.find("inf"), std::string::npos);
  // Points 0-1, then 3 alone, then 5 alone: three subpaths, one line segment.
  const std::string d = PathData(svg, 0);
  EXPECT_EQ(Count(d, "M"), 3u) << d;
  EXPECT_EQ(Count(d, "L"), 1u) << d;
  // Every drawn coordinate lies inside the 600 x 300 canvas.
  std::string numbers = d;
  std::replace_if(
      numbers.begin(), numbers.end(), [](char c) { return c == 'M' || c == 'L'; }, ' ');
  std::istringstream in(numbers);
  for (double value; in >> value;) {
    EXPECT_GE(value, 0.0);
    EXPECT_LE(value, 600.0);
  }

  // A series with no finite value still renders a well-formed chart.
  Chart empty;
  empty.series.push_back({.name = "nothing", .x = {nan, 1.0}, .y = {1.0, nan}});
  const std::string empty_svg = RenderSvg(empty, 300, 200);
  EXPECT_TRUE(EndsWith(empty_svg, "</svg>"));
  EXPECT_EQ(PathData(empty_svg, 0), "");
}

TEST(SvgPlot, StepSeriesHoldsEachValue) {
  Chart chart;
  chart.series.push_back({.name = "voltage", .x = {0, 1, 2}, .y = {0, 2, 1}, .step = true});
  const std::string d = PathData(RenderSvg(chart, 600, 300), 0);
  // (0,0) (1,0) (1,2) (2,2) (2,1): four line segments, each horizontal or vertical.
  EXPECT_EQ(Count(d, "L"), 4u) << d;
}

model::ParameterEstimate Param(const std::string& name, double value, double half_width) {
  model::ParameterEstimate p;
  p.name = name;
  p.value = value;
  p.half_width_95 = half_width;
  return p;
}

struct Example {
  model::Recording recording;
  model::Diagnosis diagnosis;
};

// A 100 s recording at 10 Hz with 5 V steps; the baseline misses a slow relaxation that
// the augmented model captures.
Example BackRelaxationExample() {
  Example e;
  auto& r = e.recording;
  auto& d = e.diagnosis;
  r.source = "bench <script>alert(1)</script>.csv";
  for (int i = 0; i < 1000; ++i) {
    const double t = 0.1 * i;
    const bool on = static_cast<int>(t / 20.0) % 2 == 0;
    const double relax = on ? 0.3 * (1.0 - std::exp(-std::fmod(t, 20.0) / 8.0)) : 0.0;
    r.t_s.push_back(t);
    r.voltage_V.push_back(on ? 5.0 : 0.0);
    d.baseline_mm.push_back(on ? 2.0 : 0.0);
    d.augmented_mm.push_back((on ? 2.0 : 0.0) - relax);
    r.deflection_mm.push_back((on ? 2.0 : 0.0) - relax + 0.01 * std::sin(7.0 * t));
  }
  d.verdict = "back_relaxation";
  d.trusted_model = true;
  d.baseline_fit_percent = 91.2;
  d.baseline_rmse_mm = 0.123;
  d.baseline_heldout_rmse_mm = 0.141;
  d.noise_std_mm = 0.0071;
  d.heldout = {{10.0, 20.0}, {50.0, 60.0}, {90.0, 99.9}};

  model::Finding finding;
  finding.effect = "back_relaxation";
  finding.explanation = "Under sustained voltage the deflection relaxes back by 15 % with tau 8 s.";
  finding.where = {{0.0, 20.0}, {40.0, 60.0}};
  finding.params = {Param("fraction", 0.1537, 0.0123), Param("tau_s", 8.04, 0.91)};
  finding.heldout_rmse_before_mm = 0.141;
  finding.heldout_rmse_after_mm = 0.0123;
  finding.model.kind = model::EffectKind::kBackRelaxation;
  finding.model.params = {0.1537, 8.04};
  d.findings.push_back(finding);

  model::CandidateReport claimed;
  claimed.kind = model::EffectKind::kBackRelaxation;
  claimed.name = "back_relaxation";
  claimed.params = finding.params;
  claimed.train_rmse_mm = 0.011;
  claimed.heldout_rmse_mm = 0.0123;
  claimed.effective_samples = 412.5;
  claimed.likelihood_ratio = 1934.2;
  claimed.heldout_likelihood_ratio = 240.1;
  claimed.bic = -3871.6;
  claimed.effect_rms_mm = 0.21;
  claimed.claimed = true;
  claimed.reason = "LR 1934 > 17.3; held-out RMSE 0.141 -> 0.0123; effect 30 x noise";
  model::CandidateReport rejected;
  rejected.kind = model::EffectKind::kSensorDrift;
  rejected.name = "sensor_drift";
  rejected.params = {Param("rate_mm_per_s", 1e-5, std::numeric_limits<double>::infinity())};
  rejected.reason = "held-out RMSE not lower <script>evil()</script>";
  model::CandidateReport untried;
  untried.kind = model::EffectKind::kPolarityAsymmetry;
  untried.name = "polarity_asymmetry";
  untried.reason = "not tried: the recording does not drive both polarities";
  d.candidates = {claimed, rejected, untried};

  d.localisation.groups = {{"condition", "held", 600, -0.18, 0.2},
                           {"condition", "rest", 400, 0.001, 0.01}};
  d.localisation.baseline_fit.samples = 700;
  d.localisation.baseline_fit.fit_percent = 91.2;
  d.localisation.baseline_fit.rmse_mm = 0.123;
  d.localisation.baseline_fit.whiteness.max_lag = 25;
  d.localisation.baseline_fit.whiteness.ljung_box_q = 8123.4;
  d.localisation.baseline_fit.whiteness.chi2_threshold = 37.65;
  d.localisation.baseline_fit.cross_correlation.max_lag = 25;
  d.localisation.baseline_fit.cross_correlation.max_abs = 0.61;
  d.localisation.baseline_fit.cross_correlation.bound = 0.12;
  d.notes = {"note with & ampersand", "<b>not bold</b>"};
  return e;
}

TEST(DiagnosisReport, ContainsVerdictExplanationAndFigures) {
  const Example e = BackRelaxationExample();
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "Diagnosis of bench 7");
  EXPECT_EQ(html.rfind("<!DOCTYPE html>", 0), 0u);
  EXPECT_NE(html.find("</html>"), std::string::npos);
  EXPECT_NE(html.find("<title>Diagnosis of bench 7</title>"), std::string::npos);
  EXPECT_NE(html.find("Verdict: back_relaxation"), std::string::npos);
  EXPECT_NE(html.find("relaxes back by 15 % with tau 8 s."), std::string::npos);
  EXPECT_NE(html.find("trusted model"), std::string::npos);
  EXPECT_NE(html.find(">91.2<"), std::string::npos);    // fit %
  EXPECT_NE(html.find(">0.141<"), std::string::npos);   // held-out RMSE
  EXPECT_NE(html.find(">0.0071<"), std::string::npos);  // noise
  EXPECT_NE(html.find("sensor_drift"), std::string::npos);
  EXPECT_NE(html.find("not determined"), std::string::npos);  // infinite half-width
  EXPECT_NE(html.find("-3872"), std::string::npos);           // BIC without exponent
  EXPECT_NE(html.find("not white"), std::string::npos);
  EXPECT_NE(html.find("Q = 8123"), std::string::npos);
  EXPECT_NE(html.find("note with &amp; ampersand"), std::string::npos);
  // A candidate that was not tried shows its reason and no figures.
  const size_t untried = html.find("<td>polarity_asymmetry</td>");
  ASSERT_NE(untried, std::string::npos);
  const std::string row = html.substr(untried, html.find("</tr>", untried) - untried);
  EXPECT_NE(row.find("does not drive both polarities"), std::string::npos);
  EXPECT_EQ(row.find(">0<"), std::string::npos) << row;
}

TEST(DiagnosisReport, ShowsUnexplainedMisfitsOnlyWhenThereAreSome) {
  Example e = BackRelaxationExample();
  EXPECT_EQ(DiagnosisReportHtml({e.recording}, e.diagnosis, "r").find("Unexplained misfits"),
            std::string::npos);
  model::Misfit misfit;
  misfit.resembles = "electrolysis_saturation";
  misfit.rms_mm = 0.0789;
  misfit.where = {{345.6, 524.5}};
  misfit.explanation = "its size is not determined <i>";
  e.diagnosis.unexplained.push_back(misfit);
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "r");
  EXPECT_NE(html.find("Unexplained misfits"), std::string::npos);
  EXPECT_NE(html.find("<td>electrolysis_saturation</td>"), std::string::npos);
  EXPECT_NE(html.find("not determined &lt;i&gt;"), std::string::npos);
  // What the final model leaves on the held-out samples resembles no effect.
  misfit.resembles.clear();
  e.diagnosis.unexplained.push_back(misfit);
  EXPECT_NE(DiagnosisReportHtml({e.recording}, e.diagnosis, "r")
                .find("<td>nothing in the catalogue</td>"),
            std::string::npos);
}

TEST(DiagnosisReport, ParameterTableShowsValueAndHalfWidth) {
  const Example e = BackRelaxationExample();
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "report");
  EXPECT_NE(html.find("0.154 &plusmn; 0.0123"), std::string::npos);
  EXPECT_NE(html.find("8.04 &plusmn; 0.91"), std::string::npos);
  EXPECT_NE(html.find("0.141 &rarr; 0.0123"), std::string::npos);  // held-out RMSE
}

TEST(DiagnosisReport, EscapesHostileStrings) {
  const Example e = BackRelaxationExample();
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "<script>t</script>");
  EXPECT_EQ(html.find("<script"), std::string::npos);
  EXPECT_EQ(html.find("<b>"), std::string::npos);
  EXPECT_NE(html.find("&lt;script&gt;evil()&lt;/script&gt;"), std::string::npos);
  EXPECT_NE(html.find("&lt;script&gt;alert(1)&lt;/script&gt;"), std::string::npos);
  EXPECT_NE(html.find("&lt;b&gt;not bold&lt;/b&gt;"), std::string::npos);
}

TEST(DiagnosisReport, SelfContained) {
  const Example e = BackRelaxationExample();
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "report");
  // The only URL is the SVG namespace, which names the vocabulary and is never fetched.
  const std::string svg_namespace = "http://www.w3.org/2000/svg";
  EXPECT_EQ(Count(html, "https://"), 0u);
  EXPECT_EQ(Count(html, "http://"), Count(html, svg_namespace));
  EXPECT_EQ(html.find("<link"), std::string::npos);
  EXPECT_EQ(html.find("@import"), std::string::npos);
  EXPECT_EQ(html.find("url("), std::string::npos);
  EXPECT_EQ(html.find("<img"), std::string::npos);
  EXPECT_GE(Count(html, "<svg"), 3u);  // deflection, voltage, residual
  EXPECT_EQ(Count(html, "<svg"), Count(html, "</svg>"));
  EXPECT_EQ(html, DiagnosisReportHtml({e.recording}, e.diagnosis, "report"));  // deterministic
}

TEST(DiagnosisReport, NoFindingAndShortSeries) {
  Example e = BackRelaxationExample();
  e.diagnosis.verdict = "none";
  e.diagnosis.findings.clear();
  e.diagnosis.trusted_model = false;
  e.diagnosis.baseline_model.rules.resize(2);
  e.diagnosis.augmented_mm.resize(10);  // shorter than the recording: drawn where it exists
  e.diagnosis.localisation = {};
  const std::string html = DiagnosisReportHtml({e.recording}, e.diagnosis, "report");
  EXPECT_NE(html.find("Verdict: none"), std::string::npos);
  EXPECT_NE(html.find("identified on this recording"), std::string::npos);
  EXPECT_NE(html.find("2 local models"), std::string::npos);
  EXPECT_NE(html.find("not computed"), std::string::npos);
  EXPECT_GE(Count(html, "<svg"), 2u);
}

}  // namespace
}  // namespace flexid::cli
