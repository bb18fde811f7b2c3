// flexid plot fit|residual (REC.csv | --trial N) [--model M.json | --actuator ID [--version V]]
//                          --out FILE.svg|png [--width PX] [--height PX]
// flexid plot bode|memberships (--model M.json | --actuator ID [--version V]) --out FILE.svg|png
// Charts of a model and a recording (model_charts.h) as one image: SVG (svg_plot.h) or
// PNG (png_plot.h), chosen by the extension of --out, charts stacked top to bottom. The
// recording is a CSV file or a stored trial, the model a file or a stored model (source.h:
// flexidd, or the --db file). fit and residual on a trial with no model given use the
// active model of the trial's actuator. A model file's augmentations are applied for fit
// and residual, as in `flexid simulate`.
#include <algorithm>
#include <cctype>
#include <iostream>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include "clients/cli/command.h"
#include "clients/cli/model_charts.h"
#include "clients/cli/png_plot.h"
#include "clients/cli/svg_plot.h"
#include "model/core/errors.h"
#include "model/core/text_file.h"

namespace flexid::cli {
namespace {

constexpr int kDefaultWidthPx = 900, kDefaultChartHeightPx = 320;
constexpr int kMinChartPx = 200, kMaxImagePx = 10000;

enum class ImageFormat { kSvg, kPng };

struct PlotArgs {
  std::string what;
  std::string recording_path;
  std::optional<int64_t> trial;
  ModelChoice model;
  std::string out_path;
  std::optional<int> width_px, height_px;
};

// The format named by the extension of --out (case-insensitive).
ImageFormat FormatOf(const std::string& path) {
  std::string extension = path.size() >= 4 ? path.substr(path.size() - 4) : "";
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".svg") return ImageFormat::kSvg;
  if (extension == ".png") return ImageFormat::kPng;
  throw UsageError("--out " + path +
                   ": unknown image type; the file name must end in .svg or .png");
}

// Charts stacked vertically in one SVG document.
std::string StackSvg(const std::vector<Chart>& charts, int width_px, int chart_height_px) {
  std::string body;
  for (size_t i = 0; i < charts.size(); ++i) {
    std::string svg = RenderSvg(charts[i], width_px, chart_height_px);
    // The nested chart keeps its own coordinates; only its position changes.
    svg.insert(4, " y=\"" + std::to_string(static_cast<int>(i) * chart_height_px) + "\"");
    body += svg;
  }
  return "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + std::to_string(width_px) +
         "\" height=\"" + std::to_string(chart_height_px * static_cast<int>(charts.size())) +
         "\">" + body + "</svg>\n";
}

void CheckArguments(const PlotArgs& args, bool needs_recording) {
  CheckModelChoice(args.model);
  if (needs_recording) {
    if (args.recording_path.empty() && !args.trial)
      throw UsageError("plot " + args.what +
                       " needs a recording: REC.csv or --trial N (e.g. flexid plot " + args.what +
                       " --model MODEL.json REC.csv --out FILE.svg)");
    if (!args.recording_path.empty() && args.trial)
      throw UsageError("plot " + args.what + ": give either REC.csv or --trial " +
                       std::to_string(*args.trial) + ", not both");
    if (!args.recording_path.empty() && !args.model.Given())
      throw UsageError("plot " + args.what +
                       " of a CSV recording needs a model: --model M.json or --actuator ID");
  } else if (!args.model.Given()) {
    throw UsageError("plot " + args.what + " needs a model: --model M.json or --actuator ID");
  }
  if (args.width_px && (*args.width_px < kMinChartPx || *args.width_px > kMaxImagePx))
    throw UsageError("--width must be between " + std::to_string(kMinChartPx) + " and " +
                     std::to_string(kMaxImagePx) + " px, got " + std::to_string(*args.width_px));
}

void RunPlot(const PlotArgs& args) {
  const ImageFormat format = FormatOf(args.out_path);
  const bool needs_recording = args.what == "fit" || args.what == "residual";
  CheckArguments(args, needs_recording);
  const int chart_count = args.what == "residual" || args.what == "memberships" ? 1 : 2;
  const int width_px = args.width_px.value_or(kDefaultWidthPx);
  const int height_px = args.height_px.value_or(kDefaultChartHeightPx * chart_count);
  if (height_px < kMinChartPx * chart_count || height_px > kMaxImagePx)
    throw UsageError("--height must be between " + std::to_string(kMinChartPx * chart_count) +
                     " and " + std::to_string(kMaxImagePx) + " px for plot " + args.what + " (" +
                     std::to_string(chart_count) + " charts of at least " +
                     std::to_string(kMinChartPx) + " px), got " + std::to_string(height_px));

  std::vector<Chart> charts;
  if (needs_recording) {
    const LoadedRecording rec = LoadRecording(args.recording_path, args.trial);
    ModelChoice choice = args.model;
    if (!choice.Given()) choice.actuator = rec.actuator;  // a trial: its actuator's model
    const LoadedModel model = LoadModel(choice);
    const std::vector<double> predicted = PredictDeflection(model.doc, rec.recording, model.name);
    if (args.what == "fit")
      charts =
          FitCharts(rec.recording, predicted, "deflection: " + rec.name + " and " + model.name);
    else
      charts = {ResidualChart(rec.recording, predicted,
                              "residual (measured - predicted): " + rec.name + ", " + model.name)};
  } else {
    const LoadedModel model = LoadModel(args.model);
    const model::TsModel ts = model::AsTsModel(model.doc);
    if (args.what == "bode")
      charts = BodeCharts(ts, model.name);
    else
      charts = {MembershipChart(ts, model.name)};
  }

  const int chart_height_px = height_px / chart_count;
  std::string bytes;
  if (format == ImageFormat::kSvg) {
    bytes = StackSvg(charts, width_px, chart_height_px);
  } else {
    try {
      bytes = RenderPng(charts, width_px, chart_height_px);
    } catch (const std::runtime_error& e) {
      throw OperationError(args.out_path + ": " + e.what());
    }
  }
  try {
    model::WriteFileAtomically(args.out_path, bytes);
  } catch (const model::InputError& e) {
    throw OperationError(e.what());
  }
  std::cout << "wrote " << args.what << " plot to " << args.out_path << " ("
            << (format == ImageFormat::kSvg ? "SVG" : "PNG") << ", " << width_px << " x "
            << chart_height_px * chart_count << " px)\n";
}

}  // namespace

void RegisterPlotCommand(CLI::App& app) {
  CLI::App* plot =
      app.add_subcommand("plot", "Charts of a model and a recording as SVG or PNG images");
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
    cmd->add_option("--model", args->model.path, "Model file (flexid.model/1 JSON)");
    cmd->add_option("--actuator", args->model.actuator,
                    kind.recording ? "Use this actuator's stored model (default with --trial: the "
                                     "trial's actuator's active model)"
                                   : "Use this actuator's stored model");
    cmd->add_option("--version", args->model.version,
                    "Stored model version with --actuator (default: the active one)");
    if (kind.recording) {
      cmd->add_option("RECORDING", args->recording_path,
                      "Recording CSV (t_s,voltage_V,deflection_mm)");
      cmd->add_option("--trial", args->trial, "A stored trial instead of a CSV recording");
    }
    cmd->add_option("--out", args->out_path, "Image to write: FILE.svg or FILE.png")->required();
    cmd->add_option("--width", args->width_px, "Image width in px (default 900)");
    cmd->add_option("--height", args->height_px,
                    "Image height in px (default 320 per chart; fit and bode draw 2 charts)");
    if (kind.recording)
      cmd->footer(std::string("Examples:\n  flexid plot ") + kind.name +
                  " --model examples/seed-8V.json run.csv --out " + kind.name +
                  ".svg\n  flexid plot " + kind.name + " --trial 3 --out " + kind.name +
                  ".png\n  flexid --db var/flexid.db plot " + kind.name +
                  " --trial 3 --actuator S1 --version 2 --out " + kind.name + ".png");
    else
      cmd->footer(std::string("Examples:\n  flexid plot ") + kind.name +
                  " --model examples/seed-ts.json --out " + kind.name + ".svg\n  flexid plot " +
                  kind.name + " --actuator S1 --version 2 --out " + kind.name + ".png");
    cmd->callback([args] { RunPlot(*args); });
  }
}

}  // namespace flexid::cli
