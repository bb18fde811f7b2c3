// flexid diagnose REC.csv [REC2.csv ...] [--model MODEL.json] [--json] [--report REPORT.html]
//                         [--out AUGMENTED.json]
// flexid diagnose --actuator ID [--trial N ... | --recent K] [--no-model] [--json]
//                 [--timeout S]                       (in flexidd, on stored trials)
// flexid [--db PATH] diagnose --trial N ... [--actuator ID] [--model M.json | --no-model]
//                             [--json] [--report R.html] [--out AUGMENTED.json]
//                                                     (here, on stored trials)
// Several recordings (or trials) of one actuator make one diagnosis from the evidence of
// all of them (model/diagnose/diagnose.h).
// Where a model and a recording disagree, which physics the model leaves out, a model of
// it, and the held-out improvement (model/diagnose/diagnose.h; JSON format in DESIGN.md).
//
// Every form prints the same human output from the diagnosis JSON (PrintHuman), so the
// answer of flexidd and a diagnosis run here read alike. The report and the augmented
// model need the diagnosis itself (model::Diagnosis), which flexidd does not send: with
// --report or --out (or --model, or --db) a stored trial is loaded and diagnosed here.
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "clients/cli/command.h"
#include "clients/cli/diagnosis_report.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/text_file.h"
#include "model/diagnose/diagnose.h"

namespace flexid::cli {
namespace {

using nlohmann::json;

struct DiagnoseArgs {
  std::vector<std::string> recording_paths;
  std::string model_path;
  std::string report_path;
  std::string out_path;
  bool json = false;
  // Stored trials instead of a CSV file.
  std::string actuator;
  std::vector<int64_t> trials;  // empty: the latest finished one (or --recent)
  int recent = 0;               // the actuator's latest K finished trials
  bool no_model = false;
  bool propose = false;  // flexidd stores the augmented model as a new inactive version
  double timeout_s = 300.0;
};

double NumberOr(const json& object, const char* key, double fallback = NAN) {
  if (!object.is_object()) return fallback;
  const auto it = object.find(key);
  return it != object.end() && it->is_number() ? it->get<double>() : fallback;
}

std::string Text(const json& object, const char* key) {
  if (!object.is_object()) return "";
  const auto it = object.find(key);
  return it != object.end() && it->is_string() ? it->get<std::string>() : "";
}

// "12-30 s, ..."; with several recordings ("recordings": their names) each span names its.
std::string Spans(const json& spans, const json& recordings) {
  std::string text;
  for (const json& s : spans) {
    if (!text.empty()) text += ", ";
    const double index = NumberOr(s, "recording", -1);
    if (recordings.is_array() && index >= 0 && index < static_cast<double>(recordings.size()) &&
        recordings[static_cast<size_t>(index)].is_string())
      text += recordings[static_cast<size_t>(index)].get<std::string>() + " ";
    text += FormatNumber(NumberOr(s, "t_start_s"), 4) + "-" +
            FormatNumber(NumberOr(s, "t_end_s"), 4) + " s";
  }
  return text.empty() ? "-" : text;
}

// "tau_s 12.3 +- 1.1, fraction 0.21" from {"params": {...}, "params_95": {...}}.
std::string Params(const json& item) {
  std::string text;
  const json params = item.value("params", json::object());
  const json widths = item.value("params_95", json::object());
  for (const auto& [name, value] : params.items()) {
    if (!text.empty()) text += ", ";
    text += name + " " + FormatNumber(value.is_number() ? value.get<double>() : NAN, 3);
    const double width = NumberOr(widths, name.c_str());
    if (std::isfinite(width) && width > 0) text += " +- " + FormatNumber(width, 2);
  }
  return text;
}

// "sensor_drift (held-out RMSE 0.0714 mm); chosen by ..." from a finding's "rivals" and
// "chosen_by"; empty without rivals.
std::string Rivals(const json& finding) {
  std::string text;
  for (const json& r : finding.value("rivals", json::array())) {
    if (!text.empty()) text += ", ";
    text += Text(r, "effect") + " (held-out RMSE " +
            FormatNumber(NumberOr(r, "heldout_rmse_mm"), 3) + " mm)";
  }
  if (!text.empty() && !Text(finding, "chosen_by").empty())
    text += "; this one chosen by " + Text(finding, "chosen_by");
  return text;
}

// The human form of a diagnosis (model::DiagnosisToJson); `subject` names the recording
// and `against` the trusted model (empty: the baseline was identified on the recording).
void PrintHuman(const std::string& subject, const std::string& against, const json& d) {
  const json baseline = d.value("baseline", json::object());
  const json recordings = d.value("recordings", json());
  std::printf("diagnosis of %s %s\n", subject.c_str(),
              !against.empty() ? ("against " + against + " (trusted model)").c_str()
                               : "(baseline identified on the recording by the global T-S fit)");
  std::printf(
      "  baseline: fit %s %%, RMSE %s mm on the fitted samples; held-out RMSE %s mm; "
      "sensor noise ~%s mm\n",
      FormatNumber(NumberOr(baseline, "fit_percent"), 4).c_str(),
      FormatNumber(NumberOr(baseline, "rmse_mm"), 3).c_str(),
      FormatNumber(NumberOr(baseline, "heldout_rmse_mm"), 3).c_str(),
      FormatNumber(NumberOr(d, "noise_std_mm"), 2).c_str());
  std::printf("  held out from every fit: %s\n",
              Spans(d.value("heldout", json::array()), recordings).c_str());
  std::printf("\nverdict: %s\n", Text(d, "verdict").c_str());
  for (const json& f : d.value("findings", json::array())) {
    std::printf("  %s: %s\n", Text(f, "effect").c_str(), Text(f, "explanation").c_str());
    std::printf("    where: %s\n", Spans(f.value("where", json::array()), recordings).c_str());
    std::printf("    params: %s\n", Params(f).c_str());
    std::printf("    held-out RMSE: %s -> %s mm\n",
                FormatNumber(NumberOr(f, "heldout_rmse_before_mm"), 3).c_str(),
                FormatNumber(NumberOr(f, "heldout_rmse_after_mm"), 3).c_str());
    if (const std::string rivals = Rivals(f); !rivals.empty())
      std::printf("    also claimed on its own: %s\n", rivals.c_str());
  }
  for (const json& m : d.value("unexplained", json::array())) {
    std::printf("  unexplained misfit: %s\n", Text(m, "explanation").c_str());
    std::printf("    where: %s\n", Spans(m.value("where", json::array()), recordings).c_str());
  }
  for (const json& a : d.value("absorbed", json::array()))
    std::printf("  absorbed by the identified model (not named): %s\n",
                Text(a, "explanation").c_str());
  std::printf(
      "\ncandidates (likelihood ratios use the effective sample count of correlated residuals)\n");
  std::printf("  %-24s %5s %11s %11s %10s %10s  %s\n", "effect", "round", "train mm", "held-out mm",
              "LR", "held-out LR", "decision");
  for (const json& c : d.value("candidates", json::array())) {
    const std::string reason = Text(c, "reason");
    if (reason.rfind("not tried", 0) == 0) {
      std::printf("  %-24s %5s %11s %11s %10s %10s  %s\n", Text(c, "effect").c_str(), "-", "-", "-",
                  "-", "-", reason.c_str());
      continue;
    }
    std::printf("  %-24s %5d %11s %11s %10s %10s  %s\n", Text(c, "effect").c_str(),
                static_cast<int>(NumberOr(c, "round", 0)),
                FormatNumber(NumberOr(c, "train_rmse_mm"), 3).c_str(),
                FormatNumber(NumberOr(c, "heldout_rmse_mm"), 3).c_str(),
                FormatNumber(NumberOr(c, "likelihood_ratio"), 3).c_str(),
                FormatNumber(NumberOr(c, "heldout_likelihood_ratio"), 3).c_str(), reason.c_str());
  }
  const json localisation = d.value("localisation", json::object());
  std::printf("\nresidual of the baseline (measured - model) by operating condition\n");
  std::printf("  %-10s %-24s %8s %10s %10s\n", "dimension", "group", "samples", "mean mm",
              "RMS mm");
  for (const json& g : localisation.value("residual_groups", json::array()))
    std::printf("  %-10s %-24s %8lld %10s %10s\n", Text(g, "dimension").c_str(),
                Text(g, "group").c_str(), static_cast<long long>(NumberOr(g, "samples", 0)),
                FormatNumber(NumberOr(g, "mean_mm"), 3).c_str(),
                FormatNumber(NumberOr(g, "rms_mm"), 3).c_str());
  const json fit = localisation.value("baseline_fit", json::object());
  if (const json w = fit.value("whiteness", json()); w.is_object())
    std::printf("  whiteness (Ljung-Box, %d lags): Q = %s, threshold %s: %s\n",
                static_cast<int>(NumberOr(w, "max_lag", 0)),
                FormatNumber(NumberOr(w, "ljung_box_q"), 4).c_str(),
                FormatNumber(NumberOr(w, "threshold_95"), 4).c_str(),
                w.value("passed", false) ? "white" : "not white");
  if (const json c = fit.value("input_residual_correlation", json()); c.is_object())
    std::printf("  input cross-correlation: max %s, bound %s: %s\n",
                FormatNumber(NumberOr(c, "max_abs"), 3).c_str(),
                FormatNumber(NumberOr(c, "bound_95"), 3).c_str(),
                c.value("passed", false) ? "uncorrelated" : "correlated");
  for (const json& note : d.value("notes", json::array()))
    if (note.is_string()) std::printf("note: %s\n", note.get<std::string>().c_str());
}

// What is diagnosed here: the recordings, the trusted model (if any) and their names.
struct LocalCase {
  std::vector<model::Recording> recordings;
  std::optional<model::ModelDocument> doc;
  std::string subject;          // "run.csv", "trial 5 of S1", "trials 4, 5 of S1"
  std::string model_name;       // "s1.json", "S1 model v2"; empty without a model
  json extra = json::object();  // members added to the JSON (trial, model_version)
};

// Diagnoses here; writes the report and the augmented model when asked; prints.
void DiagnoseHere(const DiagnoseArgs& args, const LocalCase& c) {
  std::optional<model::TsModel> trusted;
  model::DiagnoseOptions options;
  if (c.doc) {
    trusted = model::AsTsModel(*c.doc);
    options.baseline_effects = model::EffectsOf(*c.doc, c.model_name);
  }
  const model::Diagnosis d = model::Diagnose(c.recordings, trusted, options);
  if (!args.report_path.empty()) {
    try {
      model::WriteFileAtomically(
          args.report_path,
          DiagnosisReportHtml(c.recordings, d, "flexid diagnosis of " + c.subject));
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  if (!args.out_path.empty()) {
    // The baseline with the findings' effects as augmentations (the absorbed back-relaxation
    // of a free fit is already inside its local models).
    model::ModelDocument out;
    if (c.doc) {
      out = *c.doc;
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
    out.extra["diagnosis"] = {{"recording", c.subject}, {"verdict", d.verdict}};
    try {
      model::WriteModelFile(args.out_path, out);
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  json j = model::DiagnosisToJson(d);
  for (const auto& [key, value] : c.extra.items()) j[key] = value;
  if (args.json) {
    std::cout << j.dump(2) << "\n";
    return;
  }
  PrintHuman(c.subject, c.model_name, j);
  if (!args.report_path.empty()) std::printf("report: %s\n", args.report_path.c_str());
  if (!args.out_path.empty()) std::printf("augmented model: %s\n", args.out_path.c_str());
}

void RunCsv(const DiagnoseArgs& args) {
  LocalCase c;
  for (const std::string& path : args.recording_paths) {
    c.recordings.push_back(model::ReadRecordingCsv(path));
    c.subject += (c.subject.empty() ? "" : " + ") + path;
  }
  if (!args.model_path.empty()) {
    c.doc = model::ReadModelFile(args.model_path);
    c.model_name = args.model_path;
  }
  DiagnoseHere(args, c);
}

// The trials flexidd would pick: the actuator's latest `count` finished trials with at least
// 200 samples, oldest first.
std::vector<int64_t> LatestTrials(const std::string& actuator, int count) {
  std::vector<int64_t> ids;
  for (const json& t : Query("trials", {{"actuator", actuator}, {"limit", 1000}}))
    if (t.value("state", "") != "recording" && t.value("samples", int64_t{0}) >= 200 &&
        static_cast<int>(ids.size()) < count)
      ids.insert(ids.begin(), t.value("id", int64_t{0}));
  if (ids.empty()) throw UsageError(actuator + " has no finished trial to diagnose");
  return ids;
}

// "trial 5" or "trials 4, 5, 7".
std::string TrialWords(const std::vector<int64_t>& ids) {
  std::string text = ids.size() == 1 ? "trial " : "trials ";
  for (size_t i = 0; i < ids.size(); ++i) text += (i ? ", " : "") + std::to_string(ids[i]);
  return text;
}

// Stored trials diagnosed here (offline, or online with --report/--out/--model).
void RunStoredHere(const DiagnoseArgs& args) {
  const std::vector<int64_t> trial_ids =
      !args.trials.empty() ? args.trials : LatestTrials(args.actuator, std::max(args.recent, 1));
  LocalCase c;
  std::string owner;
  for (int64_t trial_id : trial_ids) {
    StoredTrial trial;
    {
      Progress progress("load trial " + std::to_string(trial_id));
      trial = LoadTrial(trial_id,
                        [&progress](int64_t done, int64_t total) { progress.Update(done, total); });
    }
    const std::string of = trial.trial.value("actuator", "");
    const std::string expected = !args.actuator.empty() ? args.actuator : owner;
    if (!expected.empty() && of != expected)
      throw UsageError("--trial: trial " + std::to_string(trial_id) + " belongs to " + of +
                       ", not " + expected + " (one diagnosis covers one actuator)");
    owner = of;
    c.recordings.push_back(RecordingOf(trial, 200));
  }
  c.subject = TrialWords(trial_ids) + " of " + owner;
  if (trial_ids.size() == 1)
    c.extra["trial"] = trial_ids.front();
  else
    c.extra["trials"] = trial_ids;
  c.extra["model_version"] = 0;
  if (!args.model_path.empty()) {
    c.doc = model::ReadModelFile(args.model_path);
    c.model_name = args.model_path;
    c.extra["model_file"] = args.model_path;
  } else if (!args.no_model) {
    // As flexidd does: the actuator's active model, or the identified baseline without one.
    int32_t active = 0;
    for (const json& m : Query("models", {{"actuator", owner}}))
      if (m.value("active", false)) active = m.value("version", 0);
    if (active != 0) {
      c.doc = StoredModel(owner, active);
      c.model_name = owner + " model v" + std::to_string(active);
      c.extra["model_version"] = active;
    }
  }
  DiagnoseHere(args, c);
}

// Online: flexidd diagnoses its stored trials; the reply is the diagnosis JSON plus
// "trial" (or "trials") and "model_version".
void RunInDaemon(const DiagnoseArgs& args) {
  json request = {{"actuator", args.actuator}, {"use_model", !args.no_model}};
  if (args.propose) request["propose"] = true;
  if (args.trials.size() == 1) request["trial"] = args.trials.front();
  if (args.trials.size() > 1) request["trials"] = args.trials;
  if (args.recent > 0) request["recent"] = args.recent;
  Progress progress("diagnose");
  progress.Note("diagnosing " + args.actuator + " " +
                (!args.trials.empty() ? TrialWords(args.trials)
                 : args.recent > 1    ? "latest " + std::to_string(args.recent) + " trials"
                                      : std::string("latest trial")) +
                " in flexidd ...");
  const json reply = CallOnline("diagnose", request, args.timeout_s);
  progress.Finish();
  if (args.json) {
    std::cout << reply.dump(2) << "\n";
    return;
  }
  const int64_t version = reply.value("model_version", int64_t{0});
  std::vector<int64_t> diagnosed;
  if (const json trials = reply.value("trials", json()); trials.is_array())
    for (const json& id : trials)
      if (id.is_number_integer()) diagnosed.push_back(id.get<int64_t>());
  if (diagnosed.empty()) diagnosed.push_back(reply.value("trial", int64_t{0}));
  PrintHuman(TrialWords(diagnosed) + " of " + args.actuator,
             version != 0 ? args.actuator + " model v" + std::to_string(version) : "", reply);
  if (!args.propose) return;
  const json proposed = reply.value("proposed_version", json());
  if (!proposed.is_number_integer()) {
    std::cout << "\nNothing proposed: the diagnosis named no effect.\n";
    return;
  }
  const std::string v = std::to_string(proposed.get<int64_t>());
  if (reply.value("adopted", false))
    std::cout << "\nProposed and adopted as " << args.actuator << " model v" << v << ".\n";
  else
    std::cout << "\nProposed as " << args.actuator << " model v" << v
              << " (inactive).\n  compare:  flexid models diff --actuator " << args.actuator << " "
              << (version != 0 ? std::to_string(version) : std::string("active")) << " " << v
              << "\n  activate: flexid models activate --actuator " << args.actuator << " " << v
              << "\n";
}

void RunDiagnose(const DiagnoseArgs& args) {
  const bool stored = !args.actuator.empty() || !args.trials.empty() || args.recent != 0;
  if (!args.recording_paths.empty()) {
    if (stored || args.no_model)
      throw UsageError(
          "a REC.csv file cannot be combined with --actuator, --trial, --recent or --no-model: "
          "diagnose either files or stored trials");
    RunCsv(args);
    return;
  }
  if (!stored)
    throw UsageError(
        "nothing to diagnose: give REC.csv files, or --actuator ID / --trial N for "
        "stored trials");
  for (int64_t id : args.trials)
    if (id < 1) throw UsageError("--trial: expected a trial id >= 1, got " + std::to_string(id));
  for (size_t i = 0; i < args.trials.size(); ++i)
    for (size_t j = 0; j < i; ++j)
      if (args.trials[i] == args.trials[j])
        throw UsageError("--trial: trial " + std::to_string(args.trials[i]) + " given twice");
  if (args.recent != 0 && (args.recent < 1 || args.recent > model::kMaxDiagnosedRecordings))
    throw UsageError("--recent: expected 1 to " + std::to_string(model::kMaxDiagnosedRecordings) +
                     " trials");
  if (args.recent != 0 && (!args.trials.empty() || args.actuator.empty()))
    throw UsageError("--recent needs --actuator and excludes --trial");
  if (args.trials.size() > static_cast<size_t>(model::kMaxDiagnosedRecordings))
    throw UsageError("--trial: at most " + std::to_string(model::kMaxDiagnosedRecordings) +
                     " trials in one diagnosis");
  if (!args.model_path.empty() && args.no_model)
    throw UsageError("--model and --no-model exclude each other");
  if (args.propose && (args.actuator.empty() || Offline() || !args.report_path.empty() ||
                       !args.out_path.empty() || !args.model_path.empty()))
    throw UsageError(
        "--propose asks flexidd to store the augmented model: it needs --actuator, and "
        "excludes --db, --report, --out and --model");
  if (!(args.timeout_s > 0.0) || !std::isfinite(args.timeout_s))
    throw UsageError("--timeout: expected a positive number of seconds");
  const bool here = Offline() || !args.report_path.empty() || !args.out_path.empty() ||
                    !args.model_path.empty() || args.actuator.empty();
  if (here)
    RunStoredHere(args);
  else
    RunInDaemon(args);
}

}  // namespace

void RegisterDiagnoseCommand(CLI::App& app) {
  auto args = std::make_shared<DiagnoseArgs>();
  CLI::App* cmd = app.add_subcommand(
      "diagnose",
      "Find where a recording departs from a model, name the missing physics, model it and "
      "measure the improvement on held-out samples");
  cmd->add_option("RECORDING", args->recording_paths,
                  "Recording CSV (t_s,voltage_V,deflection_mm); several recordings of one "
                  "actuator make one diagnosis");
  cmd->add_option("--model", args->model_path,
                  "Trusted model file; without it the seed's structure is identified on the "
                  "recording (a stored trial: the actuator's active model)");
  cmd->add_flag("--json", args->json, "Print the diagnosis as one JSON document");
  cmd->add_option("--report", args->report_path, "Write a self-contained HTML report here");
  cmd->add_option("--out", args->out_path,
                  "Write the model with the findings as augmentations here (flexid.model/1)");
  cmd->add_option(
      "--actuator", args->actuator,
      "Diagnose a stored trial of this actuator (in flexidd unless --db/--report/--out)");
  cmd->add_option("--trial", args->trials,
                  "Stored trial id; repeat for several trials of one actuator (default: the "
                  "actuator's latest finished trial)");
  cmd->add_option("--recent", args->recent,
                  "Diagnose the actuator's latest K finished trials together (1-" +
                      std::to_string(model::kMaxDiagnosedRecordings) + ")");
  cmd->add_flag("--no-model", args->no_model,
                "Stored trial: identify the baseline on the trial instead of using the "
                "actuator's active model");
  cmd->add_flag("--propose", args->propose,
                "Stored trials in flexidd: store the model with the findings as a new, inactive "
                "version with its lineage (activate it with `flexid models activate`)");
  cmd->add_option("--timeout", args->timeout_s,
                  "Seconds to wait for flexidd's diagnosis (default 300)");
  cmd->footer(
      "Stored trials: `--actuator ID` asks flexidd, which diagnoses against the active model.\n"
      "With --report or --out (which need the diagnosis itself), --model, or --db PATH, the trial\n"
      "is loaded and diagnosed here, against the trial's actuator's active model unless --model\n"
      "or --no-model says otherwise. The JSON of a stored trial adds \"trial\" and\n"
      "\"model_version\" (0: baseline identified on the trial).\n"
      "Examples:\n  flexid diagnose run.csv --model examples/seed-8V.json --report run.html\n"
      "  flexid diagnose steps.csv squares.csv --json\n"
      "  flexid diagnose --actuator S1 --recent 3\n"
      "  flexid diagnose run.csv --json\n"
      "  flexid diagnose --actuator S1 --trial 4\n"
      "  flexid diagnose --actuator S1 --trial 4 --propose\n"
      "  flexid --db var/flexid.db diagnose --trial 4 --report trial4.html");
  cmd->callback([args] { RunDiagnose(*args); });
}

}  // namespace flexid::cli
