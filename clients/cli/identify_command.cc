// flexid identify REC.csv [REC2.csv ...] [--out MODEL.json] [--json] [--validate VAL.csv]
// flexid identify --actuator ID [--trials 3,4 | --latest N] [--json] [--out MODEL.json]
//                 [--timeout S]                      (in flexidd: stores a new active version)
// flexid --db PATH identify (--trials 3,4 | --actuator ID [--latest N]) [...]
//                                                    (here, on stored trials; nothing stored)
//
// Fits the whole T-S model at once, its structure chosen on held-out data
// (model/identify/identify_global.h); or, with --method time, finds the voltage levels, fits one
// local transfer function with dead time per level and assembles the T-S model
// (model/identify/identify_ts.h); or, with --structure physics, fits
// the physics chain's parameters (model/physics/greybox.h); or, with --method frequency, fits the
// rational model to frequency responses estimated from square waves
// (model/identify/frequency_response.h). --json prints the model file document itself, with its
// fit figures; --out writes it.
#include <cmath>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "flexid/version.h"
#include "model/core/errors.h"
#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/simulate.h"
#include "model/identify/frequency_response.h"
#include "model/identify/identify_global.h"
#include "model/identify/identify_ts.h"
#include "model/physics/greybox.h"
#include "model/physics/physics.h"

namespace flexid::cli {
namespace {

using nlohmann::json;

struct IdentifyArgs {
  std::vector<std::string> recordings;
  std::vector<std::string> validate;
  std::string out;
  bool as_json = false;
  int zeros = 3, poles = 4;
  double max_delay_s = 10.0;
  std::optional<double> delay_s;
  std::string structure = "free";
  std::string method = "global";
  std::string geometry_mm = "40x8x2";
  std::string predict_geometry_mm;
  // Stored trials instead of CSV files.
  std::string actuator;
  std::string trials_text;
  std::optional<int> latest;
  double timeout_s = 300.0;
  CLI::App* command = nullptr;  // to see which options were given
  // What the recordings are called in the model file's identified_from.
  std::vector<std::string> names;
  std::vector<int64_t> trial_ids;
};

std::string Passed(bool tested, bool passed) { return !tested ? "-" : passed ? "pass" : "FAIL"; }

void PrintFit(const std::string& label, const model::FitFigures& fit) {
  std::cout << "  " << label << ": fit " << FormatNumber(fit.fit_percent, 4) << " %, RMSE "
            << FormatNumber(fit.rmse_mm, 4) << " mm, " << fit.samples
            << " samples; residual whiteness "
            << Passed(fit.whiteness.max_lag > 0, fit.whiteness.passed)
            << ", input-residual correlation "
            << Passed(fit.cross_correlation.max_lag > 0, fit.cross_correlation.passed) << "\n";
}

void PrintEstimate(const model::TfEstimate& e) {
  Table table({"parameter", "value", "+- 95 %"});
  for (const auto& c : e.coefficients)
    table.AddRow({c.name, FormatNumber(c.value, 6), FormatNumber(c.half_width_95, 3)});
  table.AddRow(
      {"DC gain", FormatNumber(e.dc_gain.value, 6), FormatNumber(e.dc_gain.half_width_95, 3)});
  table.Print(std::cout, "    ");
  std::cout << "    poles:";
  for (const auto& p : e.poles) std::cout << "  " << FormatComplex({p.re, p.im}, 4);
  std::cout << "\n";
}

std::vector<model::Recording> ReadAll(const std::vector<std::string>& paths,
                                      bool require_deflection) {
  std::vector<model::Recording> out;
  for (const std::string& path : paths)
    out.push_back(model::ReadRecordingCsv(path, {.require_deflection = require_deflection}));
  return out;
}

// A whole recording as one segment on a uniform grid (starting at rest).
model::DataSegment WholeRecording(const model::Recording& rec) {
  model::DataSegment seg;
  if (!model::IsUniformGrid(rec.t_s, &seg.dt_s))
    throw UsageError(rec.source + ": this method needs a uniform sample period");
  seg.voltage_V = rec.voltage_V;
  seg.deflection_mm = rec.deflection_mm;
  return seg;
}

// "LxWxh" in mm -> the same parameters for a beam of that geometry (C_dl scaled with the
// face area, model/physics/physics.h).
model::PhysicalParameters WithGeometryText(const model::PhysicalParameters& reference,
                                           const std::string& option, const std::string& text) {
  double l = 0, w = 0, h = 0;
  char x1 = 0, x2 = 0;
  std::istringstream in(text);
  if (!(in >> l >> x1 >> w >> x2 >> h) || x1 != 'x' || x2 != 'x' || !(l > 0 && w > 0 && h > 0) ||
      !std::isfinite(l + w + h) || !in.eof())
    throw UsageError(option + ": expected LxWxh in mm, e.g. 40x8x2, got \"" + text + "\"");
  return model::WithGeometry(reference, l * 1e-3, w * 1e-3, h * 1e-3);
}

void Emit(const IdentifyArgs& args, const model::ModelDocument& doc) {
  if (!args.out.empty()) model::WriteModelFile(args.out, doc);
  if (args.as_json)
    std::cout << model::ModelToJson(doc).dump(2) << "\n";
  else if (!args.out.empty())
    std::cout << "wrote " << args.out << "\n";
}

void AddValidation(const IdentifyArgs& args, const model::TsModel& model,
                   model::ModelDocument* doc) {
  if (args.validate.empty()) return;
  const model::FitFigures validation = model::EvaluateTsFit(model, ReadAll(args.validate, true));
  doc->extra["validation"] = model::FitFiguresToJson(validation);
  doc->extra["validation"]["recordings"] = args.validate;
  if (!args.as_json) PrintFit("validation", validation);
}

void RunFree(const IdentifyArgs& args, model::ModelDocument* doc,
             const std::vector<model::Recording>& recordings) {
  model::TsIdentifyOptions options;
  options.local.num_zeros = args.zeros;
  options.local.num_poles = args.poles;
  options.local.max_delay_s = args.max_delay_s;
  if (args.delay_s) {
    options.local.estimate_delay = false;
    options.local.fixed_delay_s = *args.delay_s;
  }
  const model::TsEstimate estimate = model::IdentifyTsModel(recordings, options);
  *doc = model::ToModelDocument(estimate);
  if (!args.as_json) {
    std::cout << estimate.local.size()
              << (estimate.local.size() == 1 ? " voltage level" : " voltage levels")
              << (estimate.plateau_input ? "" : " (no plateaus: one level for the whole input)")
              << "\n";
    for (const auto& local : estimate.local) {
      std::cout << "\nlocal model at " << FormatNumber(local.level_V, 4) << " V (" << local.segments
                << (local.segments == 1 ? " segment" : " segments") << ")\n";
      PrintFit("fit", local.estimate.fit);
      PrintEstimate(local.estimate);
    }
    std::cout << "\n";
    PrintFit(estimate.local.size() == 1 ? "model" : "T-S blend", estimate.fit);
    if (!estimate.leave_one_level_out.empty()) {
      std::cout << "  leave one level out (RMSE mm, blend of the other levels vs full blend):\n";
      Table table({"level V", "left out", "in sample"});
      for (const auto& r : estimate.leave_one_level_out)
        table.AddRow({FormatNumber(r.level_V, 4), FormatNumber(r.left_out_rmse_mm, 4),
                      FormatNumber(r.in_sample_rmse_mm, 4)});
      table.Print(std::cout, "    ");
    }
    for (const auto& note : estimate.notes) std::cout << "  note: " << note << "\n";
  }
  AddValidation(args, estimate.model, doc);
}

// --method global: the global T-S fit (model/identify/identify_global.h), the structure chosen on
// held-out data unless --zeros/--poles fix the orders.
void RunGlobal(const IdentifyArgs& args, model::ModelDocument* doc,
               const std::vector<model::Recording>& recordings) {
  model::GlobalIdentifyOptions options;
  if (args.command->count("--zeros") > 0 || args.command->count("--poles") > 0) {
    options.num_zeros = args.zeros;
    options.num_poles = args.poles;
  }
  options.max_delay_s = args.max_delay_s;
  options.fixed_delay_s = args.delay_s;
  Progress progress("identify");
  progress.Note("fitting the T-S model on " + std::to_string(recordings.size()) +
                (recordings.size() == 1 ? " recording" : " recordings") +
                " and choosing its structure on held-out data ...");
  const model::GlobalEstimate e = model::IdentifyGlobalTs(recordings, options);
  progress.Finish();
  *doc = model::ToModelDocument(e);
  if (!args.as_json) {
    std::cout << "structure: " << e.structure.Describe() << "\n  " << e.reason << "\n";
    PrintFit("fit", e.fit);
    std::cout << "  held-out RMSE " << FormatNumber(e.held_out_rmse_mm, 4) << " mm; noise estimate "
              << FormatNumber(e.noise_std_mm, 4) << " mm; dead time "
              << FormatNumber(e.delay_s.value, 4) << " +- "
              << FormatNumber(e.delay_s.half_width_95, 3) << " s\n";
    Table table({"rule V", "DC gain mm/V", "+- 95 %", "poles"});
    for (size_t i = 0; i < e.rules.size(); ++i) {
      std::string poles;
      for (const auto& p : e.rules[i].poles)
        poles += (poles.empty() ? "" : "  ") + FormatComplex(p, 4);
      table.AddRow({FormatNumber(e.rules[i].knot_V, 4), FormatNumber(e.rules[i].dc_gain.value, 5),
                    FormatNumber(e.rules[i].dc_gain.half_width_95, 3), poles});
    }
    table.Print(std::cout, "    ");
    for (const auto& w : e.warnings) std::cout << "  warning: " << w << "\n";
    for (const auto& note : e.notes) std::cout << "  note: " << note << "\n";
  }
  AddValidation(args, e.model, doc);
}

void RunPhysics(const IdentifyArgs& args, model::ModelDocument* doc,
                const std::vector<model::Recording>& recordings) {
  const model::PhysicalParameters start =
      WithGeometryText(model::SeedS1Parameters(), "--geometry", args.geometry_mm);
  if (!args.predict_geometry_mm.empty())  // checked before the fit
    WithGeometryText(start, "--predict-geometry", args.predict_geometry_mm);
  std::vector<model::DataSegment> segments;
  for (const auto& rec : recordings) segments.push_back(WholeRecording(rec));
  model::GreyBoxOptions options;
  options.max_delay_s = args.max_delay_s;
  const model::GreyBoxEstimate e = model::IdentifyPhysics(segments, start, options);
  // The model file holds the small-bending linearisation y = K L^2 / 2 (mm); the physical
  // parameters are kept beside it.
  model::TransferFunction deflection = e.curvature_tf;
  for (double& c : deflection.num) c *= 0.5 * start.L_m * start.L_m * 1000.0;
  *doc = model::FromTransferFunction(deflection);
  doc->extra["structure"] = "physics";
  doc->extra["physical_parameters"] = model::ParameterEstimatesToJson(e.estimates);
  doc->extra["identifiable_combinations"] = model::ParameterEstimatesToJson(e.combinations);
  doc->extra["geometry_mm"] = {
      {"L", start.L_m * 1e3}, {"W", start.W_m * 1e3}, {"h", start.h_m * 1e3}};
  doc->extra["fit"] = model::FitFiguresToJson(e.fit);
  doc->extra["note"] =
      "num/den: small-bending linearisation (deflection = curvature L^2/2) of the fitted chain";
  if (!args.as_json) {
    std::cout << "physics chain fitted (geometry " << args.geometry_mm << " mm, C_dl and E held)\n";
    PrintFit("fit", e.fit);
    Table table({"parameter", "value", "+- 95 %"});
    for (const auto& p : e.estimates)
      table.AddRow({p.name, FormatNumber(p.value, 5), FormatNumber(p.half_width_95, 3)});
    for (const auto& p : e.combinations)
      table.AddRow({p.name, FormatNumber(p.value, 5), FormatNumber(p.half_width_95, 3)});
    table.Print(std::cout, "    ");
    std::cout << "  (intervals wider than the value mean the data do not determine that parameter; "
                 "model/physics/greybox.h)\n";
  }
  if (!args.predict_geometry_mm.empty()) {
    // Another beam of the same material: the fitted parameters at its geometry, driven by
    // the first recording's voltage.
    const model::PhysicalParameters other =
        WithGeometryText(e.parameters, "--predict-geometry", args.predict_geometry_mm);
    const std::vector<double> y =
        model::PredictDeflection_mm(other, e.delay_s, options.terms, segments.front());
    const std::vector<double> y_here =
        model::PredictDeflection_mm(e.parameters, e.delay_s, options.terms, segments.front());
    auto peak = [](const std::vector<double>& v) {
      double p = 0.0;
      for (double x : v) p = std::max(p, std::abs(x));
      return p;
    };
    doc->extra["prediction"] = {{"geometry_mm", args.predict_geometry_mm},
                                {"recording", args.names.front()},
                                {"peak_deflection_mm", peak(y)},
                                {"peak_deflection_fitted_geometry_mm", peak(y_here)}};
    if (!args.as_json)
      std::cout << "  prediction for " << args.predict_geometry_mm << " mm under "
                << args.names.front() << "'s voltage: peak deflection " << FormatNumber(peak(y), 4)
                << " mm (fitted beam: " << FormatNumber(peak(y_here), 4) << " mm)\n";
  }
  AddValidation(args, model::SingleRule(deflection), doc);
}

void RunFrequency(const IdentifyArgs& args, model::ModelDocument* doc,
                  const std::vector<model::Recording>& recordings) {
  std::vector<model::DataSegment> segments;
  for (const auto& rec : recordings) segments.push_back(WholeRecording(rec));
  model::FrequencyFitOptions options;
  options.num_zeros = args.zeros;
  options.num_poles = args.poles;
  options.max_delay_s = args.max_delay_s;
  const model::FrequencyFit fit = model::IdentifyFromSquareWaves(segments, options);
  *doc = model::FromTransferFunction(fit.tf);
  json points = json::array();
  for (const auto& p : fit.points)
    points.push_back({{"frequency_Hz", p.frequency_Hz},
                      {"gain", std::abs(p.response)},
                      {"phase_rad", std::arg(p.response)},
                      {"gain_half_width_95", p.gain_half_width_95},
                      {"harmonic", p.harmonic}});
  doc->extra["method"] = "frequency";
  doc->extra["frequency_points"] = points;
  doc->extra["intervals"] = model::ParameterEstimatesToJson(fit.coefficients);
  doc->extra["weighted_rms_error"] = fit.weighted_rms_error;
  doc->extra["report"] = fit.method_report;
  if (!args.as_json) {
    std::cout << "frequency response from " << fit.points.size() << " points; " << fit.method_report
              << "\n";
    Table table({"f Hz", "gain", "phase deg", "+- gain"});
    for (const auto& p : fit.points)
      table.AddRow({FormatNumber(p.frequency_Hz, 4), FormatNumber(std::abs(p.response), 4),
                    FormatNumber(std::arg(p.response) * 180.0 / M_PI, 4),
                    FormatNumber(p.gain_half_width_95, 3)});
    table.Print(std::cout, "    ");
    std::cout << "  G(s) = e^(-" << FormatNumber(fit.tf.delay_s, 4) << " s) ("
              << FormatPolynomial(fit.tf.num) << ") / (" << FormatPolynomial(fit.tf.den) << ")\n";
  }
  AddValidation(args, model::SingleRule(fit.tf), doc);
}

void CheckOptions(const IdentifyArgs& args) {
  if (args.structure != "free" && args.structure != "physics")
    throw UsageError("--structure: expected free or physics, got \"" + args.structure + "\"");
  if (args.method != "time" && args.method != "global" && args.method != "frequency")
    throw UsageError("--method: expected time, global or frequency, got \"" + args.method + "\"");
  if (args.structure == "physics" && args.method == "frequency")
    throw UsageError("--structure physics fits in the time domain; drop --method frequency");
  if (!(args.max_delay_s >= 0.0) || !std::isfinite(args.max_delay_s))
    throw UsageError("--max-delay must be finite and >= 0");
  if (args.delay_s && (!(*args.delay_s >= 0.0) || !std::isfinite(*args.delay_s)))
    throw UsageError("--delay must be finite and >= 0");
  if (args.poles < 1 || args.poles > 8 || args.zeros < 0 || args.zeros >= args.poles)
    throw UsageError("orders: need 1 <= --poles <= 8 and 0 <= --zeros < --poles");
}

// Identification here, on recordings (CSV files or stored trials).
void RunLocal(const IdentifyArgs& args, const std::vector<model::Recording>& recordings) {
  model::ModelDocument doc;
  if (args.structure == "physics")
    RunPhysics(args, &doc, recordings);
  else if (args.method == "frequency")
    RunFrequency(args, &doc, recordings);
  else if (args.method == "global")
    RunGlobal(args, &doc, recordings);
  else
    RunFree(args, &doc, recordings);
  doc.extra["identified_from"] = args.names;
  if (!args.trial_ids.empty()) doc.extra["identified_from_trials"] = args.trial_ids;
  doc.extra["flexid_version"] = kVersion;
  Emit(args, doc);
}

// "3,4" -> {3, 4}.
std::vector<int64_t> ParseTrialIds(const std::string& text) {
  std::vector<int64_t> ids;
  size_t start = 0;
  while (true) {
    const size_t comma = text.find(',', start);
    const std::string item = text.substr(start, comma == std::string::npos ? comma : comma - start);
    const bool digits = !item.empty() && item.size() <= 18 &&
                        item.find_first_not_of("0123456789") == std::string::npos;
    if (!digits || std::stoll(item) < 1)
      throw UsageError("--trials: expected trial ids such as 3,4, got \"" + text + "\"");
    ids.push_back(std::stoll(item));
    if (comma == std::string::npos) break;
    start = comma + 1;
  }
  return ids;
}

// Offline: the latest `count` finished trials of an actuator with enough samples.
std::vector<int64_t> LatestTrials(const std::string& actuator, int count) {
  std::vector<int64_t> ids;
  for (const json& t : Query("trials", {{"actuator", actuator}, {"limit", 1000}})) {
    if (t.value("state", "") == "recording" || t.value("samples", int64_t{0}) < 100) continue;
    ids.push_back(t.value("id", int64_t{0}));
    if (static_cast<int>(ids.size()) == count) break;
  }
  if (ids.empty())
    throw UsageError(actuator + " has no finished trial long enough to identify from in " +
                     DbPath());
  return ids;
}

std::string JoinIds(const std::vector<int64_t>& ids) {
  std::string text;
  for (int64_t id : ids) text += (text.empty() ? "" : ", ") + std::to_string(id);
  return text;
}

// Online: flexidd identifies on its stored trials and stores the result as a new active
// version; the reply (sent when the fit ends) is the stored record with the model.
void RunInDaemon(IdentifyArgs args) {
  for (const char* option : {"--validate", "--zeros", "--poles", "--max-delay", "--delay",
                             "--structure", "--method", "--geometry", "--predict-geometry"})
    if (args.command->count(option) > 0)
      throw UsageError(std::string(option) +
                       " applies to identification here (REC.csv files, or --db); flexidd "
                       "identifies with the orders of its configuration");
  json request = {{"actuator", args.actuator}};
  std::string which;
  if (!args.trial_ids.empty()) {
    request["trials"] = args.trial_ids;
    which = "trials " + JoinIds(args.trial_ids);
  } else {
    if (args.latest) request["latest"] = *args.latest;
    which = args.latest ? "the latest " + std::to_string(*args.latest) + " trials"
                        : "its latest trials";
  }
  Progress progress("identify");
  progress.Note("identifying " + args.actuator + " in flexidd on " + which + " ...");
  const json reply = CallOnline("identify", request, args.timeout_s);
  progress.Finish();
  const std::string name =
      args.actuator + " model v" + std::to_string(reply.value("version", int64_t{0}));
  const model::ModelDocument doc = model::ParseModelJson(reply.at("model").dump(), name);
  if (!args.out.empty()) {
    try {
      model::WriteModelFile(args.out, doc);
    } catch (const model::InputError& e) {
      throw OperationError(e.what());
    }
  }
  if (args.as_json) {
    std::cout << reply.dump(2) << "\n";
    return;
  }
  std::vector<int64_t> used;
  for (const json& id : reply.value("trials", json::array())) used.push_back(id.get<int64_t>());
  std::cout << name << " identified in flexidd from trials " << JoinIds(used)
            << " and made active\n";
  const json fit = reply.value("fit", json());
  auto number = [](const json& object, const char* key) {
    return object.is_object() && object.contains(key) && object[key].is_number()
               ? object[key].get<double>()
               : NAN;
  };
  auto cell = [](double value, int significant) {
    return std::isfinite(value) ? FormatNumber(value, significant) : std::string("-");
  };
  std::cout << "  " << (doc.kind == model::ModelDocument::Kind::kTsFuzzy ? "T-S blend" : "model")
            << ": fit " << cell(number(fit, "fit_percent"), 4) << " %, RMSE "
            << cell(number(fit, "rmse_mm"), 4) << " mm on " << cell(number(fit, "samples"), 9)
            << " samples\n";
  Table table({"level V", "fit %", "RMSE mm", "DC gain mm/V", "dead time s"});
  if (doc.kind == model::ModelDocument::Kind::kTsFuzzy) {
    for (size_t i = 0; i < doc.ts.rules.size(); ++i) {
      const json local_fit = i < doc.local_extra.size() && doc.local_extra[i].is_object()
                                 ? doc.local_extra[i].value("fit", json())
                                 : json();
      const model::TransferFunction& tf = doc.ts.rules[i].tf;
      table.AddRow(
          {FormatNumber(doc.ts.rules[i].level_V, 4), cell(number(local_fit, "fit_percent"), 4),
           cell(number(local_fit, "rmse_mm"), 4), cell(model::DcGain(tf), 5), cell(tf.delay_s, 4)});
    }
  } else {
    table.AddRow({cell(number(doc.extra, "level_V"), 4), cell(number(fit, "fit_percent"), 4),
                  cell(number(fit, "rmse_mm"), 4), cell(model::DcGain(doc.tf), 5),
                  cell(doc.tf.delay_s, 4)});
  }
  table.Print(std::cout);
  std::cout << "  (flexid models show --actuator " << args.actuator << " --version "
            << reply.value("version", int64_t{0}) << " for the poles and zeros)\n";
  if (!args.out.empty()) std::cout << "wrote " << args.out << "\n";
}

void RunIdentify(IdentifyArgs args) {
  if (!args.recordings.empty()) {
    if (!args.actuator.empty() || !args.trials_text.empty() || args.latest)
      throw UsageError(
          "REC.csv files cannot be combined with --actuator, --trials or --latest: "
          "identify either the files or stored trials");
    CheckOptions(args);
    args.names = args.recordings;
    RunLocal(args, ReadAll(args.recordings, true));
    return;
  }
  if (!args.trials_text.empty()) args.trial_ids = ParseTrialIds(args.trials_text);
  if (!args.trial_ids.empty() && args.latest)
    throw UsageError("--trials and --latest exclude each other");
  if (args.latest && (*args.latest < 1 || *args.latest > 100))
    throw UsageError("--latest: expected 1-100 trials, got " + std::to_string(*args.latest));
  if (!(args.timeout_s > 0.0) || !std::isfinite(args.timeout_s))
    throw UsageError("--timeout: expected a positive number of seconds");
  if (!Offline()) {
    if (args.actuator.empty())
      throw UsageError(args.trial_ids.empty()
                           ? "nothing to identify: give REC.csv files, or --actuator ID to "
                             "identify in flexidd (or --db PATH --trials 3,4 to identify here)"
                           : "--trials: identification in flexidd needs --actuator ID");
    RunInDaemon(args);
    return;
  }
  // Offline: stored trials identified here, exactly as CSV files would be.
  CheckOptions(args);
  if (args.trial_ids.empty()) {
    if (args.actuator.empty())
      throw UsageError("--db: name the trials (--trials 3,4) or the actuator (--actuator ID)");
    args.trial_ids = LatestTrials(args.actuator, args.latest.value_or(2));
  }
  std::vector<model::Recording> recordings;
  for (int64_t id : args.trial_ids) {
    Progress progress("load trial " + std::to_string(id));
    const StoredTrial trial =
        LoadTrial(id, [&progress](int64_t done, int64_t total) { progress.Update(done, total); });
    const std::string owner = trial.trial.value("actuator", "");
    if (!args.actuator.empty() && owner != args.actuator)
      throw UsageError("--trials: trial " + std::to_string(id) + " belongs to " + owner + ", not " +
                       args.actuator);
    recordings.push_back(RecordingOf(trial, 100));
    args.names.push_back(recordings.back().source);
  }
  RunLocal(args, recordings);
}

}  // namespace

void RegisterIdentifyCommand(CLI::App& app) {
  auto args = std::make_shared<IdentifyArgs>();
  CLI::App* cmd =
      app.add_subcommand("identify", "Identify per-voltage transfer functions and their T-S blend");
  cmd->add_option("RECORDING", args->recordings, "Recording CSVs (t_s,voltage_V,deflection_mm)");
  cmd->add_option("--actuator", args->actuator,
                  "Identify this actuator in flexidd on its stored trials (a new active version)");
  cmd->add_option("--trials", args->trials_text, "Stored trial ids, e.g. 3,4");
  cmd->add_option("--latest", args->latest,
                  "Use the latest N finished trials (flexidd's default: its configuration)");
  cmd->add_option("--timeout", args->timeout_s,
                  "Seconds to wait for flexidd's identification (default 300)");
  cmd->add_option("--out", args->out, "Write the model file here");
  cmd->add_flag("--json", args->as_json, "Print the model file document (with fit figures)");
  cmd->add_option("--validate", args->validate, "Recordings to validate on (not fitted)");
  cmd->add_option("--zeros", args->zeros,
                  "Numerator order (global: chosen on held-out data unless given; time and "
                  "frequency: default 3)");
  cmd->add_option("--poles", args->poles,
                  "Denominator order (global: chosen on held-out data unless given; time and "
                  "frequency: default 4)");
  cmd->add_option("--max-delay", args->max_delay_s, "Largest dead time searched, s (default 10)");
  cmd->add_option("--delay", args->delay_s, "Fix the dead time, s, instead of estimating it");
  cmd->add_option("--structure", args->structure,
                  "free (Eq. 18 coefficients) or physics (Eqs. 1-13 parameters)");
  cmd->add_option("--method", args->method,
                  "global (default: the whole T-S model in one output-error fit, its structure "
                  "chosen on held-out data), time (a transfer function per level, blended) or "
                  "frequency (square-wave frequency responses)");
  cmd->add_option("--geometry", args->geometry_mm,
                  "Beam LxWxh in mm for --structure physics (default 40x8x2)");
  cmd->add_option(
      "--predict-geometry", args->predict_geometry_mm,
      "With --structure physics: predict a beam of this LxWxh (mm) of the same material");
  cmd->footer(
      "Stored trials: with --actuator (no --db) flexidd identifies and stores the result as a\n"
      "new active model version. With --db PATH the trials are read from the file and\n"
      "identified here, exactly like CSV files; the model is NOT stored in the database (use\n"
      "--out to keep it).\n"
      "Examples:\n"
      "  flexid identify run-2V.csv run-8V.csv --out s1.json --validate check.csv\n"
      "  flexid identify --actuator S1 --latest 2\n"
      "  flexid --db var/flexid.db identify --trials 3,4 --out s1.json\n"
      "  flexid identify staircase.csv --json > model.json\n"
      "  flexid identify square-5V.csv --structure physics --geometry 40x8x2 --predict-geometry "
      "20x8x2");
  args->command = cmd;
  cmd->callback([args] { RunIdentify(*args); });
}

}  // namespace flexid::cli
