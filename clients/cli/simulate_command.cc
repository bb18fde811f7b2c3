// flexid simulate (--model MODEL.json | --actuator ID [--version V]) (REC.csv | --trial N)
//                 [--out PRED.csv]
// Predicted deflection for the recording's voltage column (DESIGN.md). Without --out the
// CSV goes to stdout; with it, a summary (and the fit when the recording has a deflection
// column) is printed. The model can be a stored version of an actuator and the recording
// a stored trial, from flexidd or (with the global --db PATH) from a database file.
#include <cmath>
#include <iostream>
#include <sstream>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/source.h"
#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/simulate.h"
#include "model/core/text_file.h"
#include "model/diagnose/diagnose.h"

namespace flexid::cli {
namespace {

struct SimulateArgs {
  std::string model_path;
  std::string actuator;
  int version = 0;
  std::string recording_path;
  int64_t trial = 0;
  std::string out_path;
  bool steady_start = false;
};

void RunSimulate(const SimulateArgs& args) {
  if (args.model_path.empty() == args.actuator.empty())
    throw UsageError(args.model_path.empty()
                         ? "a model is needed: --model MODEL.json or --actuator ID [--version V]"
                         : "--model and --actuator exclude each other: give one model");
  if (args.version < 0) throw UsageError("--version: expected a model version >= 1");
  if (args.version != 0 && args.actuator.empty())
    throw UsageError("--version: names a stored model of --actuator ID");
  if (args.recording_path.empty() == (args.trial == 0))
    throw UsageError(args.recording_path.empty()
                         ? "a recording is needed: REC.csv or --trial N"
                         : "REC.csv and --trial exclude each other: give one recording");
  if (args.trial < 0) throw UsageError("--trial: expected a trial id >= 1");
  // A stored model is named "S1 model v3" in messages.
  const model::ModelDocument doc = args.actuator.empty() ? model::ReadModelFile(args.model_path)
                                                         : StoredModel(args.actuator, args.version);
  const std::string model_name =
      args.actuator.empty()
          ? args.model_path
          : args.actuator + " model" +
                (args.version != 0 ? " v" + std::to_string(args.version) : " (active)");
  model::Recording rec;
  if (args.trial != 0) {
    Progress progress("load trial " + std::to_string(args.trial));
    rec = RecordingOf(LoadTrial(
        args.trial, [&progress](int64_t done, int64_t total) { progress.Update(done, total); }));
  } else {
    rec = model::ReadRecordingCsv(args.recording_path, {.require_deflection = false});
  }
  // A model file's augmentations (effects added by `flexid diagnose --out`) are part of the
  // model: they are applied on top of it.
  const std::vector<model::Effect> effects = model::EffectsOf(doc, model_name);
  if (!effects.empty() && args.steady_start)
    throw UsageError("--steady-start: " + model_name +
                     " has augmentations, which are simulated from rest only");
  const std::vector<double> predicted_mm =
      effects.empty() ? model::Simulate(model::AsTsModel(doc), rec.t_s, rec.voltage_V,
                                        {.start_in_steady_state = args.steady_start})
                      : model::SimulateAugmented(model::AsTsModel(doc), rec, effects);
  for (size_t k = 0; k < predicted_mm.size(); ++k)
    if (!std::isfinite(predicted_mm[k]))
      throw OperationError(model_name + ": the prediction diverges at t = " +
                           FormatNumber(rec.t_s[k]) + " s (is the model stable?)");
  if (args.out_path.empty()) {
    model::WritePredictionCsv(std::cout, rec.t_s, rec.voltage_V, predicted_mm);
    return;
  }
  // Written beside the target and renamed, so a failure never leaves a partial file.
  std::ostringstream csv;
  model::WritePredictionCsv(csv, rec.t_s, rec.voltage_V, predicted_mm);
  try {
    model::WriteFileAtomically(args.out_path, csv.str());
  } catch (const model::InputError& error) {
    // The message already starts with the path: "PRED.csv: cannot write: REASON".
    throw OperationError(error.what());
  }
  std::cout << "wrote " << rec.t_s.size() << " predictions (" << FormatNumber(rec.t_s.front())
            << " .. " << FormatNumber(rec.t_s.back()) << " s) to " << args.out_path << "\n";
  if (!rec.deflection_mm.empty())
    std::cout << "fit " << FormatNumber(model::FitPercent(rec.deflection_mm, predicted_mm), 4)
              << " %, RMSE " << FormatNumber(model::Rmse(rec.deflection_mm, predicted_mm), 4)
              << " mm against the recording's deflection\n";
}

}  // namespace

void RegisterSimulateCommand(CLI::App& app) {
  auto args = std::make_shared<SimulateArgs>();
  CLI::App* cmd = app.add_subcommand(
      "simulate", "Predict the deflection for a recording's voltage with a model file");
  cmd->add_option("--model", args->model_path, "Model file (flexid.model/1 JSON)");
  cmd->add_option("--actuator", args->actuator,
                  "Use a stored model of this actuator instead of --model");
  cmd->add_option("--version", args->version,
                  "With --actuator: the stored model version (default: the active one)");
  cmd->add_option("RECORDING", args->recording_path,
                  "Recording CSV (t_s,voltage_V[,deflection_mm])");
  cmd->add_option("--trial", args->trial,
                  "Use a stored trial's voltage (and deflection, for the fit) instead of a CSV");
  cmd->add_option("--out", args->out_path,
                  "Write t_s,voltage_V,predicted_mm here instead of stdout");
  cmd->add_flag("--steady-start", args->steady_start,
                "Start in steady state under the first voltage instead of at rest");
  cmd->footer(
      "Stored models and trials come from flexidd, or from a database file with --db PATH.\n"
      "Examples:\n  flexid simulate --model examples/seed-8V.json run.csv --out pred.csv\n"
      "  flexid simulate --actuator S1 --trial 4 --out pred.csv\n"
      "  flexid --db var/flexid.db simulate --actuator S1 --version 2 run.csv");
  cmd->callback([args] { RunSimulate(*args); });
}

}  // namespace flexid::cli
