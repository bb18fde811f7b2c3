// flexid simulate --model MODEL.json REC.csv [--out PRED.csv]: predicted deflection for
// the recording's voltage column (DESIGN.md). Without --out the CSV goes to stdout; with
// it, a summary (and the fit when the recording has a deflection column) is printed.
#include <cmath>
#include <iostream>
#include <sstream>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "model/diagnose.h"
#include "model/errors.h"
#include "model/metrics.h"
#include "model/model_file.h"
#include "model/recording.h"
#include "model/simulate.h"
#include "model/text_file.h"

namespace flexid::cli {
namespace {

struct SimulateArgs {
  std::string model_path;
  std::string recording_path;
  std::string out_path;
  bool steady_start = false;
};

void RunSimulate(const SimulateArgs& args) {
  const model::ModelDocument doc = model::ReadModelFile(args.model_path);
  const model::Recording rec =
      model::ReadRecordingCsv(args.recording_path, {.require_deflection = false});
  // A model file's augmentations (effects added by `flexid diagnose --out`) are part of the
  // model: they are applied on top of it.
  const std::vector<model::Effect> effects = model::EffectsOf(doc, args.model_path);
  if (!effects.empty() && args.steady_start)
    throw UsageError("--steady-start: " + args.model_path +
                     " has augmentations, which are simulated from rest only");
  const std::vector<double> predicted_mm =
      effects.empty() ? model::Simulate(model::AsTsModel(doc), rec.t_s, rec.voltage_V,
                                        {.start_in_steady_state = args.steady_start})
                      : model::SimulateAugmented(model::AsTsModel(doc), rec, effects);
  for (size_t k = 0; k < predicted_mm.size(); ++k)
    if (!std::isfinite(predicted_mm[k]))
      throw OperationError(args.model_path + ": the prediction diverges at t = " +
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
  cmd->add_option("--model", args->model_path, "Model file (flexid.model/1 JSON)")->required();
  cmd->add_option("RECORDING", args->recording_path,
                  "Recording CSV (t_s,voltage_V[,deflection_mm])")
      ->required();
  cmd->add_option("--out", args->out_path,
                  "Write t_s,voltage_V,predicted_mm here instead of stdout");
  cmd->add_flag("--steady-start", args->steady_start,
                "Start in steady state under the first voltage instead of at rest");
  cmd->footer("Example:\n  flexid simulate --model examples/seed-8V.json run.csv --out pred.csv");
  cmd->callback([args] { RunSimulate(*args); });
}

}  // namespace flexid::cli
