// flexid report (REC.csv | --trial N) [--model M.json | --actuator ID [--version V]]
//               --out REPORT.html [--no-diagnosis] [--json]
// One self-contained HTML page on a model and a recording (inline CSS and SVG, no scripts,
// no external resources): the header (recording, model, date), the fit (measured and
// predicted deflection, fit %, RMSE), the Bode plot of each local model, the T-S
// memberships, the residual tests (whiteness and input cross-correlation, with the
// residual and its correlations as charts), and the mismatch diagnosis with the model as
// the trusted baseline (diagnosis_report.h, as `flexid diagnose --model`). Without a model
// one is identified on the recording first, as `flexid identify` does, and the diagnosis
// identifies its own baseline on the training samples, as `flexid diagnose` does.
#include <algorithm>
#include <cmath>
#include <ctime>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/diagnosis_report.h"
#include "clients/cli/format.h"
#include "clients/cli/model_charts.h"
#include "clients/cli/svg_plot.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"
#include "model/core/text_file.h"
#include "model/core/transfer_function.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify.h"
#include "model/identify/identify_ts.h"

namespace flexid::cli {
namespace {

constexpr int kWidthPx = 960, kBodeWidthPx = 480;
constexpr int kCorrelationLags = 25;

struct ReportArgs {
  std::string recording_path;
  std::optional<int64_t> trial;
  ModelChoice model;
  std::string out_path;
  bool no_diagnosis = false;
  bool json = false;
};

std::string Html(const std::string& text) { return EscapeXml(text); }

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char buffer[64];
  std::strftime(buffer, sizeof buffer, "%Y-%m-%d %H:%M UTC", &utc);
  return buffer;
}

std::string Row(const std::string& name, const std::string& value_html) {
  return "<tr><th>" + name + "</th><td class=\"num\">" + value_html + "</td></tr>\n";
}

std::string Svg(Chart chart, int width_px, int height_px, bool keep_title = false) {
  if (!keep_title) chart.title.clear();
  return RenderSvg(chart, width_px, height_px) + "\n";
}

// A model identified on the recording, as `flexid identify REC.csv` does.
LoadedModel IdentifyOn(const LoadedRecording& rec) {
  const model::TsEstimate estimate = model::IdentifyTsModel({rec.recording});
  LoadedModel out;
  out.doc = estimate.local.size() == 1 ? model::FromTransferFunction(estimate.model.rules[0].tf)
                                       : model::FromTsModel(estimate.model);
  out.name = "identified on " + rec.name;
  return out;
}

std::string HeaderSection(const LoadedRecording& rec, const LoadedModel& model,
                          const model::TsModel& ts, bool identified) {
  const size_t rules = ts.rules.size();
  std::string html = RecordingSummaryHtml(rec.recording);
  html += "<table>\n";
  html += "<tr><th>recording</th><td>" + Html(rec.name) +
          (rec.actuator.empty() ? "" : " (actuator " + Html(rec.actuator) + ")") + "</td></tr>\n";
  html += "<tr><th>model</th><td>" + Html(model.name) + ": " +
          (model.doc.kind == model::ModelDocument::Kind::kTsFuzzy
               ? "T-S fuzzy model of " + std::to_string(rules) + " local models"
               : std::string("one transfer function")) +
          (model.doc.augmentations.empty()
               ? ""
               : ", " + std::to_string(model.doc.augmentations.size()) + " augmentation(s)") +
          "</td></tr>\n";
  html += "<tr><th>generated</th><td>" + Html(UtcNow()) + "</td></tr>\n</table>\n";
  if (identified)
    html +=
        "<p><strong>No model was given:</strong> this report identified one on the recording "
        "first, as <code>flexid identify</code> does (one transfer function with dead time per "
        "voltage level, blended by T-S memberships when there are several levels). Its fit is "
        "therefore an in-sample figure.</p>\n";
  html +=
      "<nav><ul><li><a href=\"#fit\">Fit</a></li><li><a href=\"#bode\">Bode plots</a></li>"
      "<li><a href=\"#memberships\">Memberships</a></li><li><a href=\"#residual\">Residual "
      "tests</a></li><li><a href=\"#diagnosis\">Diagnosis</a></li></ul></nav>\n";
  return html;
}

std::string FitSection(const LoadedRecording& rec, const std::vector<double>& predicted,
                       const model::FitFigures& fit) {
  std::string html = "<h2 id=\"fit\">Fit</h2>\n<table>\n";
  html += Row("fit (%)", Html(FormatNumber(fit.fit_percent, 4)));
  html += Row("RMSE (mm)", Html(FormatNumber(fit.rmse_mm, 4)));
  html += Row("samples", std::to_string(fit.samples));
  html += "</table>\n";
  std::vector<Chart> charts = FitCharts(rec.recording, predicted, "");
  html += Svg(charts[0], kWidthPx, 380);
  html += Svg(charts[1], kWidthPx, 220);
  html +=
      "<p class=\"caption\">fit % = 100 (1 &minus; &Vert;y &minus; &ycirc;&Vert; / &Vert;y "
      "&minus; mean y&Vert;) over every sample of the recording, the model simulated from rest "
      "on the recorded voltage (its augmentations applied).</p>\n";
  return html;
}

std::string BodeSection(const model::TsModel& ts) {
  std::string html = "<h2 id=\"bode\">Bode plots of the local models</h2>\n";
  for (size_t r = 0; r < ts.rules.size(); ++r) {
    const model::TransferFunction& tf = ts.rules[r].tf;
    html += "<h3>" +
            (ts.rules.size() == 1
                 ? std::string("The transfer function")
                 : "Local model at " + Html(FormatNumber(ts.rules[r].level_V, 4)) + " V") +
            "</h3>\n";
    html += "<p>G(s) = e<sup>&minus;" + Html(FormatNumber(tf.delay_s, 4)) + " s</sup> (" +
            Html(FormatPolynomial(tf.num)) + ") / (" + Html(FormatPolynomial(tf.den)) +
            "); DC gain " + Html(FormatNumber(tf.num.back() / tf.den.back(), 4)) + " mm/V.</p>\n";
    std::vector<Chart> charts = BodeCharts(ts, "", r);
    charts[0].title = "magnitude";
    charts[1].title = "phase (dead time included)";
    html += "<div class=\"bode\">\n" + Svg(charts[0], kBodeWidthPx, 300, true) +
            Svg(charts[1], kBodeWidthPx, 300, true) + "</div>\n";
  }
  return html;
}

std::string MembershipSection(const model::ModelDocument& doc, const model::TsModel& ts) {
  std::string html = "<h2 id=\"memberships\">Memberships</h2>\n";
  if (doc.kind != model::ModelDocument::Kind::kTsFuzzy)
    return html + "<p>Not a T-S model: one transfer function applies at every voltage.</p>\n";
  html += Svg(MembershipChart(ts, ""), kWidthPx, 300);
  html +=
      "<p class=\"caption\">Each rule's normalised weight against the scheduling value; the "
      "prediction is the weighted blend of the local models' outputs.</p>\n";
  return html;
}

Chart CorrelationChart(const std::string& title, const std::string& x_label,
                       const std::vector<double>& lags, const std::vector<double>& values,
                       double bound) {
  Chart chart;
  chart.title = title;
  chart.x_label = x_label;
  chart.y_label = "correlation";
  chart.series.push_back({"correlation", lags, values, "#1f77b4", false, false});
  if (std::isfinite(bound) && !lags.empty()) {
    const std::vector<double> ends = {lags.front(), lags.back()};
    chart.series.push_back({"95 % bound", ends, {bound, bound}, "#c62828", true, false});
    chart.series.push_back({"", ends, {-bound, -bound}, "#c62828", true, false});
  }
  return chart;
}

std::string ResidualSection(const LoadedRecording& rec, const std::vector<double>& predicted,
                            const model::FitFigures& fit) {
  std::string html = "<h2 id=\"residual\">Residual tests</h2>\n";
  html += "<p>The residual (measured &minus; predicted) over all " + std::to_string(fit.samples) +
          " samples, tested at up to " + std::to_string(kCorrelationLags) +
          " lags (Ljung, System Identification, section 16.6).</p>\n";
  html += ResidualTestsTableHtml(fit);
  html += Svg(ResidualChart(rec.recording, predicted, ""), kWidthPx, 280);
  const model::WhitenessTest& white = fit.whiteness;
  if (white.max_lag > 0) {
    std::vector<double> lags;
    for (int k = 1; k <= white.max_lag; ++k) lags.push_back(k);
    html += Svg(CorrelationChart("autocorrelation of the residual", "lag (samples)", lags,
                                 white.autocorrelation, white.bound),
                kWidthPx, 240, true);
  }
  const model::CrossCorrelationTest& cross = fit.cross_correlation;
  if (cross.max_lag > 0) {
    const std::vector<double> lags(cross.lags.begin(), cross.lags.end());
    html += Svg(CorrelationChart("input-residual cross-correlation",
                                 "lag (samples; positive: the input leads)", lags,
                                 cross.correlation, cross.bound),
                kWidthPx, 240, true);
  }
  html +=
      "<p class=\"caption\">Whiteness passes when the Ljung-Box Q is below the &chi;&sup2; "
      "quantile; the bound drawn on the autocorrelation is the pointwise one. The "
      "cross-correlation passes when every lag is within the simultaneous bound drawn.</p>\n";
  return html;
}

struct Report {
  std::string html;
  model::FitFigures fit;
  std::optional<std::string> verdict;
  std::string model_name;
};

Report BuildReport(const ReportArgs& args) {
  CheckModelChoice(args.model);
  const LoadedRecording rec = LoadRecording(args.recording_path, args.trial);
  if (rec.recording.deflection_mm.size() != rec.recording.t_s.size())
    throw UsageError(rec.name + ": the report needs a deflection_mm column");

  Progress progress("report on " + rec.name, "steps");
  const bool identified = !args.model.Given();
  LoadedModel model;
  if (identified) {
    progress.Note("no model given: identifying one on " + rec.name);
    model = IdentifyOn(rec);
  } else {
    model = LoadModel(args.model);
  }
  const model::TsModel ts = model::AsTsModel(model.doc);
  progress.Note("simulating " + model.name);
  const std::vector<double> predicted = PredictDeflection(model.doc, rec.recording, model.name);
  Report report;
  report.model_name = model.name;
  report.fit = model::FitFiguresOf(rec.recording.deflection_mm, predicted, rec.recording.voltage_V,
                                   kCorrelationLags);

  std::string& html = report.html;
  html = HtmlPageStart("flexid report: " + rec.name + " and " + model.name);
  html += HeaderSection(rec, model, ts, identified);
  html += FitSection(rec, predicted, report.fit);
  html += BodeSection(ts);
  html += MembershipSection(model.doc, ts);
  html += ResidualSection(rec, predicted, report.fit);

  html += "<h2 id=\"diagnosis\">Diagnosis</h2>\n";
  if (args.no_diagnosis) {
    html += "<p>Not run (--no-diagnosis).</p>\n";
  } else {
    progress.Note(identified ? "diagnosing " + rec.name + " (baseline identified on it)"
                             : "diagnosing " + rec.name + " against " + model.name);
    std::optional<model::TsModel> trusted;
    model::DiagnoseOptions options;
    if (!identified) {
      trusted = ts;
      options.baseline_effects = model::EffectsOf(model.doc, model.name);
      html += "<p>What the recording shows that " + Html(model.name) +
              " leaves out: the model is the trusted baseline, as <code>flexid diagnose "
              "--model</code> uses it.</p>\n";
    } else {
      html +=
          "<p>Without a trusted model the diagnosis identifies its own baseline on the "
          "training samples only (not the model above, which saw every sample), as "
          "<code>flexid diagnose</code> does.</p>\n";
    }
    const model::Diagnosis diagnosis = model::Diagnose(rec.recording, trusted, options);
    html += DiagnosisSectionsHtml({rec.recording}, diagnosis, 3);
    report.verdict = diagnosis.verdict;
  }
  html += HtmlPageEnd();
  progress.Finish();
  return report;
}

void RunReport(const ReportArgs& args) {
  if (args.recording_path.empty() && !args.trial)
    throw UsageError("report needs a recording: REC.csv or --trial N");
  if (!args.recording_path.empty() && args.trial)
    throw UsageError("report: give either REC.csv or --trial " + std::to_string(*args.trial) +
                     ", not both");
  std::string lower = args.out_path;
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (!(lower.ends_with(".html") || lower.ends_with(".htm")))
    throw UsageError("--out " + args.out_path +
                     ": the report is HTML; the file name must end in "
                     ".html or .htm");

  const Report report = BuildReport(args);
  try {
    model::WriteFileAtomically(args.out_path, report.html);
  } catch (const model::InputError& e) {
    throw OperationError(e.what());
  }
  if (args.json) {
    nlohmann::json out = {
        {"out", args.out_path},
        {"model", report.model_name},
        {"fit_percent", report.fit.fit_percent},
        {"rmse_mm", report.fit.rmse_mm},
        {"samples", report.fit.samples},
        {"whiteness_passed", report.fit.whiteness.passed},
        {"cross_correlation_passed", report.fit.cross_correlation.passed},
        {"verdict", report.verdict ? nlohmann::json(*report.verdict) : nlohmann::json(nullptr)}};
    std::cout << out.dump(2) << "\n";
    return;
  }
  std::cout << "wrote report to " << args.out_path << "\n";
  Table table({"model", "fit %", "RMSE mm", "whiteness", "input correlation", "verdict"});
  auto passed = [](int lags, bool ok) { return lags == 0 ? "-" : ok ? "pass" : "FAIL"; };
  table.AddRow({report.model_name, FormatNumber(report.fit.fit_percent, 4),
                FormatNumber(report.fit.rmse_mm, 3),
                passed(report.fit.whiteness.max_lag, report.fit.whiteness.passed),
                passed(report.fit.cross_correlation.max_lag, report.fit.cross_correlation.passed),
                report.verdict.value_or("(not run)")});
  table.Print(std::cout);
}

}  // namespace

void RegisterReportCommand(CLI::App& app) {
  auto args = std::make_shared<ReportArgs>();
  CLI::App* cmd = app.add_subcommand(
      "report",
      "One self-contained HTML page: fit, Bode plots, memberships, residual tests, diagnosis");
  cmd->add_option("RECORDING", args->recording_path, "Recording CSV (t_s,voltage_V,deflection_mm)");
  cmd->add_option("--trial", args->trial, "A stored trial instead of a CSV recording");
  cmd->add_option("--model", args->model.path,
                  "Model file; without --model or --actuator one is identified on the recording");
  cmd->add_option("--actuator", args->model.actuator, "Use this actuator's stored model");
  cmd->add_option("--version", args->model.version,
                  "Stored model version with --actuator (default: the active one)");
  cmd->add_option("--out", args->out_path, "HTML file to write")->required();
  cmd->add_flag("--no-diagnosis", args->no_diagnosis, "Leave out the (slower) mismatch diagnosis");
  cmd->add_flag("--json", args->json, "Print the report's figures as one JSON document");
  cmd->footer(
      "Examples:\n"
      "  flexid report examples/concealed/rec-04.csv --model examples/seed-8V.json --out "
      "rec-04.html\n"
      "  flexid report --trial 3 --actuator S1 --out trial-3.html --no-diagnosis\n"
      "  flexid --db var/flexid.db report --trial 3 --out trial-3.html");
  cmd->callback([args] { RunReport(*args); });
}

}  // namespace flexid::cli
