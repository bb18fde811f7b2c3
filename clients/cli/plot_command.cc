// flexid plot fit|residual|bode|memberships --model MODEL.json [REC.csv] --out FILE.svg
// Charts of a model and a recording as self-contained SVG files (clients/cli/svg_plot.h):
//   fit          measured and predicted deflection over time, the voltage below
//   residual     measured - predicted over time
//   bode         magnitude (dB) and phase (degrees, dead time included) of every local
//                model against log10 of the angular frequency
//   memberships  each rule's normalised membership against the scheduling value
// A model file's augmentations are applied for fit and residual, as in `flexid simulate`.
#include <cmath>
#include <complex>
#include <iostream>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/format.h"
#include "clients/cli/svg_plot.h"
#include "model/diagnose.h"
#include "model/errors.h"
#include "model/model_file.h"
#include "model/recording.h"
#include "model/simulate.h"
#include "model/text_file.h"
#include "model/transfer_function.h"
#include "model/ts_fuzzy.h"

namespace flexid::cli {
namespace {

constexpr int kWidth_px = 900, kHeight_px = 320;
const char* const kColours[] = {"#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b"};

struct PlotArgs {
  std::string what;
  std::string model_path;
  std::string recording_path;
  std::string out_path;
};

// Charts stacked vertically in one SVG document.
std::string Stack(const std::vector<Chart>& charts) {
  std::string body;
  for (size_t i = 0; i < charts.size(); ++i) {
    std::string svg = RenderSvg(charts[i], kWidth_px, kHeight_px);
    // The nested chart keeps its own coordinates; only its position changes.
    svg.insert(4, " y=\"" + std::to_string(static_cast<int>(i) * kHeight_px) + "\"");
    body += svg;
  }
  return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + std::to_string(kWidth_px) +
         "\" height=\"" + std::to_string(kHeight_px * static_cast<int>(charts.size())) + "\">" +
         body + "</svg>\n";
}

std::vector<double> Predict(const model::ModelDocument& doc, const model::Recording& rec,
                            const std::string& model_path) {
  const std::vector<model::Effect> effects = model::EffectsOf(doc, model_path);
  std::vector<double> y = model::SimulateAugmented(model::AsTsModel(doc), rec, effects);
  for (size_t k = 0; k < y.size(); ++k)
    if (!std::isfinite(y[k]))
      throw OperationError(model_path + ": the prediction diverges at t = " +
                           FormatNumber(rec.t_s[k]) + " s (is the model stable?)");
  return y;
}

std::vector<Chart> FitCharts(const PlotArgs& args, const model::ModelDocument& doc) {
  const model::Recording rec = model::ReadRecordingCsv(args.recording_path);
  const std::vector<double> predicted = Predict(doc, rec, args.model_path);
  Chart deflection{"deflection: " + args.recording_path + " and " + args.model_path,
                   "time (s)",
                   "deflection (mm)",
                   {{"measured", rec.t_s, rec.deflection_mm, "#1f77b4", false, false},
                    {"predicted", rec.t_s, predicted, "#d62728", false, false}},
                   {}};
  Chart voltage{"applied voltage",
                "time (s)",
                "voltage (V)",
                {{"voltage", rec.t_s, rec.voltage_V, "#555555", false, true}},
                {}};
  if (args.what == "fit") return {deflection, voltage};
  std::vector<double> residual(predicted.size());
  for (size_t k = 0; k < residual.size(); ++k) residual[k] = rec.deflection_mm[k] - predicted[k];
  return {Chart{"residual (measured - predicted): " + args.recording_path,
                "time (s)",
                "residual (mm)",
                {{"residual", rec.t_s, residual, "#1f77b4", false, false}},
                {}}};
}

std::vector<Chart> BodeCharts(const PlotArgs& args, const model::ModelDocument& doc) {
  const model::TsModel ts = model::AsTsModel(doc);
  Chart magnitude{"Bode magnitude: " + args.model_path,
                  "log10 angular frequency (rad/s)",
                  "magnitude (dB, mm per V)",
                  {},
                  {}};
  Chart phase{"Bode phase (dead time included)",
              "log10 angular frequency (rad/s)",
              "phase (degrees)",
              {},
              {}};
  for (size_t r = 0; r < ts.rules.size(); ++r) {
    const model::TransferFunction& tf = ts.rules[r].tf;
    Series m{ts.rules.size() == 1 ? "G" : FormatNumber(ts.rules[r].level_V, 4) + " V",
             {},
             {},
             kColours[r % std::size(kColours)],
             false,
             false};
    Series p = m;
    double previous = 0.0, unwrap = 0.0;
    for (int i = 0; i <= 400; ++i) {
      const double log_w = -4.0 + 6.0 * i / 400.0;  // 1e-4 .. 1e2 rad/s
      const double w = std::pow(10.0, log_w);
      const std::complex<double> g = model::FrequencyResponse(tf, w);
      // The rational part's phase is unwrapped on the grid; the dead time's -w T is exact
      // (it turns faster than any grid resolves at high frequency).
      const std::complex<double> rational = g * std::polar(1.0, w * tf.delay_s);
      double angle = std::arg(rational) * 180.0 / std::numbers::pi;
      if (i > 0) {
        while (angle + unwrap - previous > 180.0) unwrap -= 360.0;
        while (angle + unwrap - previous < -180.0) unwrap += 360.0;
      }
      previous = angle + unwrap;
      m.x.push_back(log_w);
      m.y.push_back(20.0 * std::log10(std::abs(g)));
      p.x.push_back(log_w);
      p.y.push_back(previous - w * tf.delay_s * 180.0 / std::numbers::pi);
    }
    magnitude.series.push_back(std::move(m));
    phase.series.push_back(std::move(p));
  }
  return {magnitude, phase};
}

std::vector<Chart> MembershipCharts(const PlotArgs& args, const model::ModelDocument& doc) {
  const model::TsModel ts = model::AsTsModel(doc);
  double top = 1.0;
  for (const model::LocalModel& rule : ts.rules) top = std::max(top, std::abs(rule.level_V));
  Chart chart{"rule memberships: " + args.model_path,
              "scheduling value (V)",
              "normalised membership",
              {},
              {}};
  std::vector<double> mu;
  for (size_t r = 0; r < ts.rules.size(); ++r) {
    Series s{FormatNumber(ts.rules[r].level_V, 4) + " V", {},    {},
             kColours[r % std::size(kColours)],           false, false};
    for (int i = 0; i <= 400; ++i) {
      const double z = 1.25 * top * i / 400.0;
      model::NormalisedMemberships(ts, z, &mu);
      s.x.push_back(z);
      s.y.push_back(mu[r]);
    }
    chart.series.push_back(std::move(s));
  }
  return {chart};
}

void RunPlot(const PlotArgs& args) {
  const bool svg =
      args.out_path.size() > 4 && args.out_path.compare(args.out_path.size() - 4, 4, ".svg") == 0;
  if (!svg)
    throw UsageError("--out " + args.out_path +
                     ": plots are written as SVG (FILE.svg); PNG is not available yet");
  const bool needs_recording = args.what == "fit" || args.what == "residual";
  if (needs_recording && args.recording_path.empty())
    throw UsageError("plot " + args.what + " needs a recording: flexid plot " + args.what +
                     " --model MODEL.json REC.csv --out FILE.svg");
  if (!needs_recording && !args.recording_path.empty())
    throw UsageError("plot " + args.what + " takes no recording");
  const model::ModelDocument doc = model::ReadModelFile(args.model_path);
  std::vector<Chart> charts;
  if (needs_recording) charts = FitCharts(args, doc);
  if (args.what == "bode") charts = BodeCharts(args, doc);
  if (args.what == "memberships") charts = MembershipCharts(args, doc);
  try {
    model::WriteFileAtomically(args.out_path, Stack(charts));
  } catch (const model::InputError& e) {
    throw OperationError(e.what());
  }
  std::cout << "wrote " << args.what << " plot to " << args.out_path << "\n";
}

}  // namespace

void RegisterPlotCommand(CLI::App& app) {
  CLI::App* plot = app.add_subcommand("plot", "Charts of a model and a recording as SVG files");
  plot->require_subcommand(1);
  struct Kind {
    const char* name;
    const char* help;
    bool recording;
  };
  for (const Kind& kind : {Kind{"fit", "Measured and predicted deflection, voltage below", true},
                           Kind{"residual", "Measured - predicted deflection over time", true},
                           Kind{"bode", "Magnitude and phase of every local model", false},
                           Kind{"memberships", "Each rule's membership against |V|", false}}) {
    auto args = std::make_shared<PlotArgs>();
    args->what = kind.name;
    CLI::App* cmd = plot->add_subcommand(kind.name, kind.help);
    cmd->add_option("--model", args->model_path, "Model file (flexid.model/1 JSON)")->required();
    if (kind.recording)
      cmd->add_option("RECORDING", args->recording_path,
                      "Recording CSV (t_s,voltage_V,deflection_mm)")
          ->required();
    cmd->add_option("--out", args->out_path, "SVG file to write")->required();
    cmd->footer(std::string("Example:\n  flexid plot ") + kind.name +
                " --model examples/seed-8V.json" + (kind.recording ? " run.csv" : "") + " --out " +
                kind.name + ".svg");
    cmd->callback([args] { RunPlot(*args); });
  }
}

}  // namespace flexid::cli
