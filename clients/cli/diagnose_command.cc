// flexid diagnose REC.csv [--model MODEL.json] [--json] [--report REPORT.html]
//                         [--out AUGMENTED.json]
// Where a model and a recording disagree, which physics the model leaves out, a model of
// it, and the held-out improvement (model/diagnose.h; JSON format in DESIGN.md).
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/diagnosis_report.h"
#include "clients/cli/format.h"
#include "model/diagnose.h"
#include "model/errors.h"
#include "model/model_file.h"
#include "model/recording.h"
#include "model/text_file.h"

namespace flexid::cli {
namespace {

struct DiagnoseArgs {
  std::string recording_path;
  std::string model_path;
  std::string report_path;
  std::string out_path;
  bool json = false;
};

std::string Spans(const std::vector<model::TimeSpan>& spans) {
  std::string text;
  for (const model::TimeSpan& s : spans) {
    if (!text.empty()) text += ", ";
    text += FormatNumber(s.t_start_s, 4) + "-" + FormatNumber(s.t_end_s, 4) + " s";
  }
  return text.empty() ? "-" : text;
}

std::string Params(const std::vector<model::ParameterEstimate>& params) {
  std::string text;
  for (const model::ParameterEstimate& p : params) {
    if (!text.empty()) text += ", ";
    text += p.name + " " + FormatNumber(p.value, 3);
    if (std::isfinite(p.half_width_95) && p.half_width_95 > 0)
      text += " +- " + FormatNumber(p.half_width_95, 2);
  }
  return text;
}

void PrintHuman(const DiagnoseArgs& args, const model::Diagnosis& d) {
  std::printf("diagnosis of %s %s\n", args.recording_path.c_str(),
              d.trusted_model
                  ? ("against " + args.model_path + " (trusted model)").c_str()
                  : "(baseline identified on the recording: 3 zeros, 4 poles, dead time)");
  std::printf(
      "  baseline: fit %s %%, RMSE %s mm on the fitted samples; held-out RMSE %s mm; "
      "sensor noise ~%s mm\n",
      FormatNumber(d.baseline_fit_percent, 4).c_str(), FormatNumber(d.baseline_rmse_mm, 3).c_str(),
      FormatNumber(d.baseline_heldout_rmse_mm, 3).c_str(), FormatNumber(d.noise_std_mm, 2).c_str());
  std::printf("  held out from every fit: %s\n", Spans(d.heldout).c_str());
  std::printf("\nverdict: %s\n", d.verdict.c_str());
  for (const model::Finding& f : d.findings) {
    std::printf("  %s: %s\n", f.effect.c_str(), f.explanation.c_str());
    std::printf("    where: %s\n", Spans(f.where).c_str());
    std::printf("    params: %s\n", Params(f.params).c_str());
    std::printf("    held-out RMSE: %s -> %s mm\n",
                FormatNumber(f.heldout_rmse_before_mm, 3).c_str(),
                FormatNumber(f.heldout_rmse_after_mm, 3).c_str());
  }
  std::printf(
      "\ncandidates (likelihood ratios use the effective sample count of correlated residuals)\n");
  std::printf("  %-24s %5s %11s %11s %10s %10s  %s\n", "effect", "round", "train mm", "held-out mm",
              "LR", "held-out LR", "decision");
  for (const model::CandidateReport& c : d.candidates) {
    if (c.reason.rfind("not tried", 0) == 0) {
      std::printf("  %-24s %5s %11s %11s %10s %10s  %s\n", c.name.c_str(), "-", "-", "-", "-", "-",
                  c.reason.c_str());
      continue;
    }
    std::printf("  %-24s %5d %11s %11s %10s %10s  %s\n", c.name.c_str(), c.round,
                FormatNumber(c.train_rmse_mm, 3).c_str(),
                FormatNumber(c.heldout_rmse_mm, 3).c_str(),
                FormatNumber(c.likelihood_ratio, 3).c_str(),
                FormatNumber(c.heldout_likelihood_ratio, 3).c_str(), c.reason.c_str());
  }
  std::printf("\nresidual of the baseline (measured - model) by operating condition\n");
  std::printf("  %-10s %-24s %8s %10s %10s\n", "dimension", "group", "samples", "mean mm",
              "RMS mm");
  for (const model::ResidualGroup& g : d.localisation.groups)
    std::printf("  %-10s %-24s %8zu %10s %10s\n", g.dimension.c_str(), g.group.c_str(), g.samples,
                FormatNumber(g.mean_mm, 3).c_str(), FormatNumber(g.rms_mm, 3).c_str());
  const auto& fit = d.localisation.baseline_fit;
  if (fit.whiteness.max_lag > 0)
    std::printf("  whiteness (Ljung-Box, %d lags): Q = %s, threshold %s: %s\n",
                fit.whiteness.max_lag, FormatNumber(fit.whiteness.ljung_box_q, 4).c_str(),
                FormatNumber(fit.whiteness.chi2_threshold, 4).c_str(),
                fit.whiteness.passed ? "white" : "not white");
  if (fit.cross_correlation.max_lag > 0)
    std::printf("  input cross-correlation: max %s, bound %s: %s\n",
                FormatNumber(fit.cross_correlation.max_abs, 3).c_str(),
                FormatNumber(fit.cross_correlation.bound, 3).c_str(),
                fit.cross_correlation.passed ? "uncorrelated" : "correlated");
  for (const std::string& note : d.notes) std::printf("note: %s\n", note.c_str());
}

void RunDiagnose(const DiagnoseArgs& args) {
  const model::Recording rec = model::ReadRecordingCsv(args.recording_path);
  std::optional<model::TsModel> trusted;
  model::DiagnoseOptions options;
  std::optional<model::ModelDocument> doc;
  if (!args.model_path.empty()) {
    doc = model::ReadModelFile(args.model_path);
    trusted = model::AsTsModel(*doc);
    options.baseline_effects = model::EffectsOf(*doc, args.model_path);
  }
  const model::Diagnosis d = model::Diagnose(rec, trusted, options);
  if (!args.report_path.empty()) {
    try {
      model::WriteFileAtomically(
          args.report_path,
          DiagnosisReportHtml(rec, d, "flexid diagnosis of " + args.recording_path));
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  if (!args.out_path.empty()) {
    // The baseline with the findings' effects as augmentations (the absorbed back-relaxation
    // of a free fit is already inside its local models).
    model::ModelDocument out;
    if (doc) {
      out = *doc;
    } else {
      const model::TsModel& m = d.augmented_baseline_model;
      if (m.rules.size() == 1) {
        out = model::FromTransferFunction(m.rules.front().tf);
      } else {
        out.kind = model::ModelDocument::Kind::kTsFuzzy;
        out.ts = m;
      }
    }
    for (const model::Finding& f : d.findings)
      if (f.heldout_rmse_after_mm < f.heldout_rmse_before_mm)
        out.augmentations.push_back(model::AugmentationOf(f.model));
    out.extra["diagnosis"] = {{"recording", args.recording_path}, {"verdict", d.verdict}};
    try {
      model::WriteModelFile(args.out_path, out);
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  if (args.json) {
    std::cout << model::DiagnosisToJson(d).dump(2) << "\n";
    return;
  }
  PrintHuman(args, d);
  if (!args.report_path.empty()) std::printf("report: %s\n", args.report_path.c_str());
  if (!args.out_path.empty()) std::printf("augmented model: %s\n", args.out_path.c_str());
}

}  // namespace

void RegisterDiagnoseCommand(CLI::App& app) {
  auto args = std::make_shared<DiagnoseArgs>();
  CLI::App* cmd = app.add_subcommand(
      "diagnose",
      "Find where a recording departs from a model, name the missing physics, model it and "
      "measure the improvement on held-out samples");
  cmd->add_option("RECORDING", args->recording_path, "Recording CSV (t_s,voltage_V,deflection_mm)")
      ->required();
  cmd->add_option("--model", args->model_path,
                  "Trusted model file; without it the seed's structure is identified on the "
                  "recording");
  cmd->add_flag("--json", args->json, "Print the diagnosis as one JSON document");
  cmd->add_option("--report", args->report_path, "Write a self-contained HTML report here");
  cmd->add_option("--out", args->out_path,
                  "Write the model with the findings as augmentations here (flexid.model/1)");
  cmd->footer(
      "Examples:\n  flexid diagnose run.csv --model examples/seed-8V.json --report run.html\n"
      "  flexid diagnose run.csv --json");
  cmd->callback([args] { RunDiagnose(*args); });
}

}  // namespace flexid::cli
