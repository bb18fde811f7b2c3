#include "clients/cli/diagnosis_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string_view>
#include <utility>
#include <vector>

#include "clients/cli/format.h"
#include "clients/cli/svg_plot.h"
#include "flexid/version.h"

namespace flexid::cli {
namespace {

constexpr int kChartWidthPx = 960;
constexpr const char* kMeasuredColour = "#222222";
constexpr const char* kBaselineColour = "#1f77b4";
constexpr const char* kAugmentedColour = "#d95f02";
constexpr const char* kHeldOutColour = "#9e9e9e";
constexpr const char* kEffectColour = "#fd8d3c";

constexpr const char* kStyle = R"(
body { font-family: sans-serif; color: #222; max-width: 1040px; margin: 1.5em auto;
       padding: 0 1em; line-height: 1.4; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
h2 { font-size: 1.2em; margin-top: 1.8em; border-bottom: 1px solid #ccc; }
.meta, .caption { color: #555; font-size: 0.92em; }
.verdict { border-left: 6px solid #d95f02; background: #fff4ec; padding: 0.6em 1em; }
.verdict.none { border-left-color: #2e7d32; background: #eef7ee; }
.verdict h2, .verdict h3 { border: none; margin-top: 0.2em; }
h3 { font-size: 1.05em; margin-top: 1.4em; }
nav ul { margin: 0.3em 0; padding-left: 1.2em; }
.bode { display: flex; flex-wrap: wrap; gap: 0 16px; }
.bode svg { flex: 1 1 440px; }
table { border-collapse: collapse; margin: 0.6em 0; font-size: 0.92em; }
th, td { border: 1px solid #ccc; padding: 0.25em 0.55em; vertical-align: top; }
th { background: #f2f2f2; text-align: left; }
td.num { text-align: right; white-space: nowrap; font-variant-numeric: tabular-nums; }
tr.claimed td { background: #fff4ec; }
tr.untried td { color: #777; }
.pass { color: #2e7d32; font-weight: bold; }
.fail { color: #c62828; font-weight: bold; }
.bar { display: inline-block; height: 0.8em; background: #1f77b4; }
svg { display: block; max-width: 100%; height: auto; margin: 0.4em 0; }
)";

std::string Html(std::string_view text) { return EscapeXml(text); }

// About three significant digits; plain integers from 1000 up to 10^7 (BIC, likelihood
// ratios) rather than exponent notation.
std::string Number(double value) {
  if (std::isfinite(value) && std::abs(value) >= 1000.0 && std::abs(value) < 1e7) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%.0f", value);
    return buffer;
  }
  return FormatNumber(value, 3);
}

std::string Estimate(const model::ParameterEstimate& estimate) {
  if (!std::isfinite(estimate.half_width_95))
    return Number(estimate.value) + " &plusmn; (not determined by the data)";
  return Number(estimate.value) + " &plusmn; " + Number(estimate.half_width_95);
}

std::string Estimates(const std::vector<model::ParameterEstimate>& estimates) {
  std::string out;
  for (const auto& e : estimates) {
    if (!out.empty()) out += "<br>";
    out += Html(e.name) + " = " + Estimate(e);
  }
  return out.empty() ? "&ndash;" : out;
}

std::string Cell(const std::string& html) { return "<td>" + html + "</td>"; }
std::string NumberCell(const std::string& html) { return "<td class=\"num\">" + html + "</td>"; }

std::string HeaderRow(const std::vector<std::string>& headers) {
  std::string row = "<tr>";
  for (const auto& h : headers) row += "<th>" + h + "</th>";
  return row + "</tr>\n";
}

std::string PassFail(bool passed, const char* pass_text, const char* fail_text) {
  return passed ? std::string("<span class=\"pass\">") + pass_text + "</span>"
                : std::string("<span class=\"fail\">") + fail_text + "</span>";
}

// "12&ndash;30 s, ...", each span prefixed with its recording's name when the diagnosis
// covered several.
std::string Spans(const std::vector<model::TimeSpan>& spans, const model::Diagnosis& diagnosis) {
  std::string out;
  for (const auto& s : spans) {
    if (!out.empty()) out += ", ";
    if (diagnosis.recordings.size() > 1 && s.recording >= 0 &&
        static_cast<size_t>(s.recording) < diagnosis.recordings.size())
      out += "<code>" + Html(diagnosis.recordings[static_cast<size_t>(s.recording)]) + "</code> ";
    out += Number(s.t_start_s) + "&ndash;" + Number(s.t_end_s) + " s";
  }
  return out.empty() ? "none" : out;
}

// A series over the recording's time axis, for as many samples as both cover.
Series TimeSeries(const std::string& name, const std::vector<double>& t_s,
                  const std::vector<double>& values, const char* colour, bool dashed = false) {
  const size_t n = std::min(t_s.size(), values.size());
  Series series;
  series.name = name;
  series.x.assign(t_s.begin(), t_s.begin() + static_cast<ptrdiff_t>(n));
  series.y.assign(values.begin(), values.begin() + static_cast<ptrdiff_t>(n));
  series.colour = colour;
  series.dashed = dashed;
  return series;
}

std::vector<double> Difference(const std::vector<double>& a, const std::vector<double>& b) {
  std::vector<double> out(std::min(a.size(), b.size()));
  for (size_t i = 0; i < out.size(); ++i) out[i] = a[i] - b[i];
  return out;
}

// The held-out blocks of recording `recording` (its index among the diagnosed ones).
void AddHeldOutSpans(const model::Diagnosis& diagnosis, int recording, Chart* chart) {
  for (const auto& s : diagnosis.heldout)
    if (s.recording == recording)
      chart->spans.push_back(
          {s.t_start_s, s.t_end_s, kHeldOutColour, 0.35, "held out (no fit saw these samples)"});
}

void AddEffectSpans(const model::Diagnosis& diagnosis, int recording, Chart* chart) {
  if (diagnosis.findings.empty()) return;
  const model::Finding& verdict = diagnosis.findings.front();
  for (const auto& s : verdict.where)
    if (s.recording == recording)
      chart->spans.push_back(
          {s.t_start_s, s.t_end_s, kEffectColour, 0.22, "where " + verdict.effect + " acts"});
}

std::string Headline(const model::Diagnosis& diagnosis) {
  std::string html;
  const bool found = !diagnosis.findings.empty();
  html += found ? "<section class=\"verdict\">\n" : "<section class=\"verdict none\">\n";
  html += "<h2>Verdict: " + Html(diagnosis.verdict) + "</h2>\n";
  for (const auto& finding : diagnosis.findings) {
    html +=
        "<p><strong>" + Html(finding.effect) + "</strong>: " + Html(finding.explanation) + "</p>\n";
    if (finding.rivals.empty()) continue;
    std::string rivals;
    for (const model::Rival& r : finding.rivals)
      rivals += (rivals.empty() ? "" : ", ") + Html(r.effect) + " (held-out RMSE " +
                FormatNumber(r.heldout_rmse_mm, 3) + " mm)";
    html += "<p>Also claimed on its own against the same model: " + rivals + "; " +
            Html(finding.effect) + " chosen by " + Html(finding.chosen_by) + ".</p>\n";
  }
  if (!found)
    html +=
        "<p>No effect of the catalogue passed all three tests (training likelihood ratio, "
        "held-out improvement, size against the noise); the candidate table says why each "
        "was not claimed.</p>\n";
  html += "</section>\n";

  html += "<h2>Baseline</h2>\n<p>";
  if (diagnosis.trusted_model) {
    html += "The baseline is the <strong>trusted model</strong>, as given.";
  } else {
    const size_t rules = diagnosis.baseline_model.rules.size();
    html +=
        "The baseline was <strong>identified on this recording</strong> (training samples "
        "only; ";
    html += rules > 1 ? "a T-S blend of " + std::to_string(rules) + " local models)."
                      : std::string("one local model).");
  }
  html += "</p>\n<table>\n";
  auto figure = [&](const std::string& name, const std::string& value) {
    html += "<tr><th>" + name + "</th>" + NumberCell(value) + "</tr>\n";
  };
  figure("fit, training samples (%)", Number(diagnosis.baseline_fit_percent));
  figure("RMSE, training samples (mm)", Number(diagnosis.baseline_rmse_mm));
  figure("RMSE, held-out samples (mm)", Number(diagnosis.baseline_heldout_rmse_mm));
  if (found)  // the findings are added in order; the last one's figure is the augmented model's
    figure("RMSE, held-out samples, with the findings (mm)",
           Number(diagnosis.findings.back().heldout_rmse_after_mm));
  figure("noise estimate, standard deviation (mm)", Number(diagnosis.noise_std_mm));
  html += "<tr><th>held-out blocks</th>" + Cell(Spans(diagnosis.heldout, diagnosis)) + "</tr>\n";
  html += "</table>\n";
  return html;
}

// The charts of one recording; `offset`: its first sample in the diagnosis's predictions
// (which run through the recordings in order).
std::string RecordingPlots(const model::Recording& recording, size_t offset, int index,
                           const model::Diagnosis& diagnosis) {
  const bool found = !diagnosis.findings.empty();
  const auto& t = recording.t_s;
  auto slice = [&](const std::vector<double>& all) {
    const size_t first = std::min(offset, all.size());
    const size_t last = std::min(offset + t.size(), all.size());
    return std::vector<double>(all.begin() + static_cast<ptrdiff_t>(first),
                               all.begin() + static_cast<ptrdiff_t>(last));
  };
  const std::vector<double> baseline_mm = slice(diagnosis.baseline_mm);
  const std::vector<double> augmented_mm = slice(diagnosis.augmented_mm);
  std::string html = "<h2>Measured and predicted deflection";
  if (diagnosis.recordings.size() > 1) html += ": <code>" + Html(recording.source) + "</code>";
  html += "</h2>\n";

  Chart deflection;
  deflection.x_label = "time (s)";
  deflection.y_label = "deflection (mm)";
  AddHeldOutSpans(diagnosis, index, &deflection);
  AddEffectSpans(diagnosis, index, &deflection);
  deflection.series.push_back(TimeSeries("measured", t, recording.deflection_mm, kMeasuredColour));
  deflection.series.push_back(TimeSeries("baseline prediction", t, baseline_mm, kBaselineColour));
  if (found)
    deflection.series.push_back(
        TimeSeries("augmented prediction", t, augmented_mm, kAugmentedColour, true));
  html += RenderSvg(deflection, kChartWidthPx, 400) + "\n";

  Chart voltage;
  voltage.x_label = "time (s)";
  voltage.y_label = "voltage (V)";
  AddHeldOutSpans(diagnosis, index, &voltage);
  Series applied = TimeSeries("applied voltage", t, recording.voltage_V, "#555555");
  applied.step = true;
  voltage.series.push_back(std::move(applied));
  html += RenderSvg(voltage, kChartWidthPx, 220) + "\n";
  html +=
      "<p class=\"caption\">Grey bands: held-out blocks, which no fit has seen; the figures "
      "on them are predictions.";
  if (found) html += " Orange bands: where the verdict's effect acts.";
  html += "</p>\n";

  html += "<h2>Residual";
  if (diagnosis.recordings.size() > 1) html += ": <code>" + Html(recording.source) + "</code>";
  html += "</h2>\n";
  Chart residual;
  residual.x_label = "time (s)";
  residual.y_label = "measured \u2212 predicted (mm)";
  AddHeldOutSpans(diagnosis, index, &residual);
  AddEffectSpans(diagnosis, index, &residual);
  residual.series.push_back(TimeSeries(
      "before (baseline)", t, Difference(recording.deflection_mm, baseline_mm), kBaselineColour));
  if (found)
    residual.series.push_back(TimeSeries("after (augmented)", t,
                                         Difference(recording.deflection_mm, augmented_mm),
                                         kAugmentedColour));
  html += RenderSvg(residual, kChartWidthPx, 320) + "\n";
  html +=
      "<p class=\"caption\">A model that explains the physics leaves a residual like noise: "
      "no steps, slopes or shapes that repeat with the input.</p>\n";
  return html;
}

std::string Plots(const std::vector<model::Recording>& recordings,
                  const model::Diagnosis& diagnosis) {
  std::string html;
  size_t offset = 0;
  for (size_t j = 0; j < recordings.size(); ++j) {
    html += RecordingPlots(recordings[j], offset, static_cast<int>(j), diagnosis);
    offset += recordings[j].t_s.size();
  }
  return html;
}

std::string FindingsTable(const model::Diagnosis& diagnosis) {
  std::string html = "<h2>Findings</h2>\n";
  if (diagnosis.findings.empty()) return html + "<p>None claimed.</p>\n";
  html += "<table>\n" + HeaderRow({"effect", "parameter", "value &plusmn; 95 % half-width",
                                   "held-out RMSE before &rarr; after (mm)"});
  for (const auto& finding : diagnosis.findings) {
    const size_t rows = std::max<size_t>(1, finding.params.size());
    const std::string span = " rowspan=\"" + std::to_string(rows) + "\"";
    const std::string effect = "<td" + span + ">" + Html(finding.effect) + "</td>";
    const std::string rmse = "<td class=\"num\"" + span + ">" +
                             Number(finding.heldout_rmse_before_mm) + " &rarr; " +
                             Number(finding.heldout_rmse_after_mm) + "</td>";
    if (finding.params.empty()) {
      html += "<tr>" + effect + Cell("&ndash;") + Cell("&ndash;") + rmse + "</tr>\n";
      continue;
    }
    for (size_t i = 0; i < finding.params.size(); ++i) {
      const auto& p = finding.params[i];
      html += "<tr>" + (i == 0 ? effect : std::string()) + Cell(Html(p.name)) +
              NumberCell(Estimate(p)) + (i == 0 ? rmse : std::string()) + "</tr>\n";
    }
  }
  return html + "</table>\n";
}

std::string CandidateTable(const model::Diagnosis& diagnosis) {
  std::string html = "<h2>Candidates tried</h2>\n";
  if (diagnosis.candidates.empty()) return html + "<p>None tried.</p>\n";
  html += "<table>\n" + HeaderRow({"candidate", "parameters (&plusmn; 95 %)", "training RMSE (mm)",
                                   "held-out RMSE (mm)", "n<sub>eff</sub>", "likelihood ratio",
                                   "held-out LR", "BIC", "effect RMS (mm)", "claimed", "reason"});
  for (const auto& c : diagnosis.candidates) {
    // A candidate the recording cannot show is listed with its reason but no figures.
    const bool tried = c.effective_samples > 0.0 || !c.params.empty();
    auto figure = [&](double value) { return NumberCell(tried ? Number(value) : "&ndash;"); };
    html += c.claimed ? "<tr class=\"claimed\">" : tried ? "<tr>" : "<tr class=\"untried\">";
    html += Cell(Html(c.name)) + Cell(Estimates(c.params)) + figure(c.train_rmse_mm) +
            figure(c.heldout_rmse_mm) + figure(c.effective_samples) + figure(c.likelihood_ratio) +
            figure(c.heldout_likelihood_ratio) + figure(c.bic) + figure(c.effect_rms_mm) +
            Cell(c.claimed ? "yes" : "no") + Cell(Html(c.reason)) + "</tr>\n";
  }
  return html + "</table>\n";
}

std::string LocalisationSection(const model::Diagnosis& diagnosis) {
  const model::Localisation& where = diagnosis.localisation;
  std::string html = "<h2>Where the baseline residual is</h2>\n";
  if (where.groups.empty()) {
    html += "<p>No breakdown.</p>\n";
  } else {
    double largest_rms_mm = 0.0;
    for (const auto& g : where.groups)
      if (std::isfinite(g.rms_mm)) largest_rms_mm = std::max(largest_rms_mm, g.rms_mm);
    html += "<table>\n" + HeaderRow({"dimension", "group", "samples", "mean (mm)", "RMS (mm)", ""});
    for (const auto& g : where.groups) {
      std::string bar;
      if (largest_rms_mm > 0.0 && std::isfinite(g.rms_mm)) {
        char width[32];
        std::snprintf(width, sizeof width, "%.0f", 120.0 * g.rms_mm / largest_rms_mm);
        bar = "<span class=\"bar\" style=\"width: " + std::string(width) + "px\"></span>";
      }
      html += "<tr>" + Cell(Html(g.dimension)) + Cell(Html(g.group)) +
              NumberCell(std::to_string(g.samples)) + NumberCell(Number(g.mean_mm)) +
              NumberCell(Number(g.rms_mm)) + Cell(bar) + "</tr>\n";
    }
    html += "</table>\n";
  }

  const model::FitFigures& fit = where.baseline_fit;
  html += "<h2>Residual tests (baseline, training samples)</h2>\n";
  html += "<p>" + std::to_string(fit.samples) + " samples, fit " + Number(fit.fit_percent) +
          " %, RMSE " + Number(fit.rmse_mm) + " mm.</p>\n";
  return html + ResidualTestsTableHtml(fit);
}

}  // namespace

std::string ResidualTestsTableHtml(const model::FitFigures& fit) {
  std::string html = "<table>\n" + HeaderRow({"test", "statistic", "threshold", "result"});
  const model::WhitenessTest& white = fit.whiteness;
  if (white.max_lag > 0) {
    html +=
        "<tr>" + Cell("whiteness (Ljung-Box, lags 1&ndash;" + std::to_string(white.max_lag) + ")") +
        NumberCell("Q = " + Number(white.ljung_box_q)) +
        NumberCell("&chi;&sup2; = " + Number(white.chi2_threshold)) +
        Cell(PassFail(white.passed, "white", "not white: structure the model misses")) + "</tr>\n";
  } else {
    html += "<tr>" + Cell("whiteness") + Cell("&ndash;") + Cell("&ndash;") + Cell("not computed") +
            "</tr>\n";
  }
  const model::CrossCorrelationTest& cross = fit.cross_correlation;
  if (cross.max_lag > 0) {
    html +=
        "<tr>" +
        Cell("input&ndash;residual correlation (lags &plusmn;" + std::to_string(cross.max_lag) +
             ")") +
        NumberCell("max |r| = " + Number(cross.max_abs)) +
        NumberCell("bound = " + Number(cross.bound)) +
        Cell(PassFail(cross.passed, "independent", "correlated: the residual follows the input")) +
        "</tr>\n";
  } else {
    html += "<tr>" + Cell("input&ndash;residual correlation") + Cell("&ndash;") + Cell("&ndash;") +
            Cell("not computed") + "</tr>\n";
  }
  return html + "</table>\n";
}

namespace {

std::string AbsorbedSection(const model::Diagnosis& diagnosis) {
  std::string html = "<h2>What a free fit absorbed</h2>\n";
  if (diagnosis.absorbed.empty()) {
    if (diagnosis.trusted_model)
      return html + "<p>Not applicable: the baseline is the trusted model.</p>\n";
    return html +
           "<p>Nothing reported: no slow mode of the identified baseline contradicts the "
           "physics chain.</p>\n";
  }
  html += "<table>\n" + HeaderRow({"effect", "level (V)", "&tau; (s)", "fall-back (share of step)",
                                   "explanation"});
  for (const auto& a : diagnosis.absorbed)
    html += "<tr>" + Cell(Html(a.effect)) + NumberCell(Number(a.level_V)) +
            NumberCell(Number(a.tau_s)) + NumberCell(Number(a.fall_back)) +
            Cell(Html(a.explanation)) + "</tr>\n";
  return html + "</table>\n";
}

// Misfits a candidate would explain but whose size the data do not determine, and what the
// final model leaves on the held-out samples (resembling nothing): never named.
std::string UnexplainedSection(const model::Diagnosis& diagnosis) {
  if (diagnosis.unexplained.empty()) return "";
  std::string html = "<h2>Unexplained misfits</h2>\n<table>\n" +
                     HeaderRow({"resembles", "RMS (mm)", "where", "explanation"});
  for (const auto& m : diagnosis.unexplained)
    html += "<tr>" + Cell(Html(m.resembles.empty() ? "nothing in the catalogue" : m.resembles)) +
            NumberCell(Number(m.rms_mm)) + Cell(Spans(m.where, diagnosis)) +
            Cell(Html(m.explanation)) + "</tr>\n";
  return html + "</table>\n";
}

std::string NotesSection(const model::Diagnosis& diagnosis) {
  std::string html = "<h2>Notes</h2>\n";
  if (diagnosis.notes.empty()) return html + "<p>None.</p>\n";
  html += "<ul>\n";
  for (const auto& note : diagnosis.notes) html += "<li>" + Html(note) + "</li>\n";
  return html + "</ul>\n";
}

std::string RecordingSummary(const model::Recording& recording) {
  std::string html = "<p class=\"meta\">Recording <code>" + Html(recording.source) +
                     "</code>: " + std::to_string(recording.t_s.size()) + " samples";
  if (recording.t_s.size() >= 2)
    html += " over " + Number(recording.t_s.back() - recording.t_s.front()) + " s";
  if (!recording.voltage_V.empty()) {
    const auto [low, high] =
        std::minmax_element(recording.voltage_V.begin(), recording.voltage_V.end());
    html += ", voltage " + Number(*low) + " to " + Number(*high) + " V";
  }
  return html + ".</p>\n";
}

}  // namespace

std::string HtmlPageStart(const std::string& title) {
  std::string html;
  html += "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n";
  html += "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n";
  html += "<title>" + Html(title) + "</title>\n<style>" + kStyle + "</style>\n</head>\n<body>\n";
  html += "<h1>" + Html(title) + "</h1>\n";
  return html;
}

std::string HtmlPageEnd() {
  return "<p class=\"meta\">flexid " + Html(kVersion) + "</p>\n</body>\n</html>\n";
}

std::string RecordingSummaryHtml(const model::Recording& recording) {
  return RecordingSummary(recording);
}

std::string DiagnosisSectionsHtml(const std::vector<model::Recording>& recordings,
                                  const model::Diagnosis& diagnosis, int heading_level) {
  std::string html;
  html += Headline(diagnosis);
  html += Plots(recordings, diagnosis);
  html += FindingsTable(diagnosis);
  html += CandidateTable(diagnosis);
  html += UnexplainedSection(diagnosis);
  html += LocalisationSection(diagnosis);
  html += AbsorbedSection(diagnosis);
  html += NotesSection(diagnosis);
  if (heading_level != 2) {
    // The sections write <h2>; every text inside is escaped, so these tags are ours.
    const std::string level = std::to_string(std::clamp(heading_level, 1, 6));
    for (const auto& [from, to] : {std::pair<std::string, std::string>{"<h2>", "<h" + level + ">"},
                                   {"</h2>", "</h" + level + ">"}}) {
      for (size_t at = html.find(from); at != std::string::npos;
           at = html.find(from, at + to.size()))
        html.replace(at, from.size(), to);
    }
  }
  return html;
}

std::string DiagnosisReportHtml(const std::vector<model::Recording>& recordings,
                                const model::Diagnosis& diagnosis, const std::string& title) {
  std::string summaries;
  for (const model::Recording& r : recordings) summaries += RecordingSummary(r);
  return HtmlPageStart(title) + summaries + DiagnosisSectionsHtml(recordings, diagnosis) +
         HtmlPageEnd();
}

}  // namespace flexid::cli
