// Control with the identified model (issue 17): the model predictive controller, the
// SIMC-tuned PI and open-loop model inversion (model/control/controller.h, the code
// flexid-control runs) against two plants, in one run:
//   rig       flexid-rig's plant (clients/rig/closed_loop.h: the seed's T-S model, 0.02 mm
//             sensor noise), controlled with a model identified as flexidd does
//             (IdentifyGlobalTs) from the rig's 2 V and 8 V square waves, as in deploy/demo;
//   ts_plant  the independent T-S test plant (tests/ts_plant.h, its own RK4 integrator and
//             smoothstep memberships on the delayed voltage), controlled with a model
//             identified from its 1-8-1 V staircase (80 s per level);
// through tests/control_harness.h (the loop: u_k applied at t_k, y_k measured, u_{k+1}
// decided). References, in mm, on the "5 V scale" of each plant's identified model
// (y_ss(V): its steady state under V volts):
//   multilevel  random levels y_ss(1..5 V), 100-200 s each, 1200 s
//                 (the rig's random protocol, read in mm, as flexid-control reads it);
//   sine F      y_ss(2.5 V) + A sin(2 pi F t), F = 0.01, 0.05, 0.2 Hz, where A is what a
//               2 V swing reaches at F on the frozen model at 2.5 V (the plants pass almost
//               nothing at 0.2 Hz: the amplitude follows), for max(600 s, 6 periods).
// Limits: -8 .. 8 V, 5 V/s, 1200 V s per 220 s (the defaults).
// Per run: the tracking RMSE of the noise-free deflection against the reference (mm, and
// in % of the reference's standard deviation), the RMS voltage, the charge (integral of
// |u| dt) and the largest charge in any 220 s window. Then, per plant and reference, the
// model-based controller's RMSE over the PI's. For the sines, what each run's error and
// voltage are made of: the mean, the component at F (its RMS) and the rest (RMS), scored
// after the lead-in, and the same of the controller's own model driven by the run's
// voltages. Deterministic (fixed seeds).
//
//   build/bench/control_bench [--svg PATH] [--ts-seed N] [--ts-sweep]
//                             [--move-weight W] [--effort-weight W] [--replan S]
//                             [--mismatch-time-constant S]
//     --svg      the rig's multilevel run: reference, measured and voltage, predictive and PI
//     --ts-seed  draw the T-S test plant from seed N (default 7): other draws, other plants
//     --ts-sweep identify the T-S plant's model from its staircase and a square-wave sweep
//                (0.5 / 4.5 V, 0.01 to 0.4 Hz, 3 cycles each), not the staircase alone
//     --move-weight, --effort-weight  the predictive and open-loop runs' penalties,
//                mm^2 per V^2 (model/control/mpc.h; default the controller's)
//     --replan, --mismatch-time-constant  their replan period (the plan's shortest block)
//                and the mismatch filter's time constant tau_d, s (mpc.h; default the
//                controller's)
#include <chrono>
#include <cmath>
#include <complex>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <fstream>
#include <memory>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "clients/cli/svg_plot.h"
#include "clients/control/reference_input.h"
#include "clients/rig/closed_loop.h"
#include "clients/rig/protocol.h"
#include "clients/rig/rig.h"
#include "control_harness.h"
#include "model/core/presets.h"
#include "model/identify/identify_global.h"

namespace flexid {
namespace {

using model::control::Controller;
using model::control::ControllerKind;
using model::control::ControllerOptions;
using model::control::Reference;

constexpr double kNoise_mm = 0.02;

// flexid-rig's plant in the harness's loop.
class RigLoopPlant : public testing::LoopPlant {
 public:
  explicit RigLoopPlant(uint64_t seed) : plant_(model::SeedTsModel(), {}, Options(seed)) {}
  double Sample(double voltage_V) override { return plant_.Next(voltage_V).deflection_mm; }
  double clean_mm() const override { return plant_.clean_mm(); }

 private:
  static rig::RigOptions Options(uint64_t seed) {
    rig::RigOptions options;
    options.noise_mm = kNoise_mm;
    options.seed = seed;
    return options;
  }
  rig::ClosedLoopPlant plant_;
};

// A rig recording of a protocol (open loop), as flexid-rig --out writes it.
model::Recording RigRecording(const std::string& spec, uint64_t seed) {
  rig::RigOptions options;
  options.noise_mm = kNoise_mm;
  options.seed = seed;
  rig::Rig rig(model::SeedTsModel(), rig::ParseProtocol(spec), {}, options);
  model::Recording recording;
  rig::RigSample sample;
  while (rig.Next(&sample)) {
    recording.t_s.push_back(sample.t_s);
    recording.voltage_V.push_back(sample.voltage_V);
    recording.deflection_mm.push_back(sample.deflection_mm);
  }
  return recording;
}

struct PlantCase {
  std::string name;
  model::TsModel model;  // identified
  double noise_mm;       // the plant's sensor noise (sigma)
  std::function<std::unique_ptr<testing::LoopPlant>()> make;
  // The plant's own T-S model where it has one (the rig's: the seed's), to print its gain
  // at each sine's frequency beside the identified model's.
  std::optional<model::TsModel> truth = std::nullopt;
};

struct ReferenceCase {
  std::string name;
  Reference reference;
  double frequency_Hz = 0.0;  // a sine's F; 0 for the multilevel reference
};

// The lead-in: the reference's first value held for kLeadIn_s before it, so that every
// controller starts from the same settled state; runs are scored after it.
constexpr double kLeadIn_s = 300.0;

Reference WithLeadIn(const Reference& reference) {
  std::vector<double> t_s = {0.0}, y_mm = {reference.deflection_mm().front()};
  for (size_t k = 0; k < reference.t_s().size(); ++k) {
    t_s.push_back(reference.t_s()[k] + kLeadIn_s);
    y_mm.push_back(reference.deflection_mm()[k]);
  }
  return Reference(t_s, y_mm, reference.source());
}

// A square wave between 0.5 and 4.5 V at 0.01, 0.02, 0.05, 0.1, 0.2 and 0.4 Hz, three
// cycles each, after 10 s at 0 V and before 60 s at 0 V: what a lab records to know the
// actuator at the frequencies it wants to follow (--ts-sweep).
testing::TsProtocol SquareSweep() {
  testing::TsProtocol protocol;
  size_t at = testing::TsSamplesIn(10.0);
  for (double frequency_Hz : {0.01, 0.02, 0.05, 0.1, 0.2, 0.4}) {
    const size_t half = testing::TsSamplesIn(0.5 / frequency_Hz);
    for (int edge = 0; edge < 6; ++edge, at += half)
      protocol.holds.push_back({at, edge % 2 == 0 ? 4.5 : 0.5});
  }
  protocol.holds.push_back({at, 0.0});
  protocol.samples = at + testing::TsSamplesIn(60.0) + 1;
  return protocol;
}

std::vector<ReferenceCase> References(const PlantCase& plant) {
  const model::TsModel& model = plant.model;
  const model::control::SteadyStateMap steady(model, -8.0, 8.0);
  std::string levels;
  for (int volts = 1; volts <= 5; ++volts) {
    char text[32];
    std::snprintf(text, sizeof text, "%s%.3f", volts > 1 ? "/" : "", steady.DeflectionAt(volts));
    levels += text;
  }
  std::vector<ReferenceCase> cases;
  cases.push_back(
      {"multilevel",
       WithLeadIn(control::ReferenceFromProtocol(
           "random:levels=" + levels + ",dwell_min=100,dwell_max=200,duration=1200,seed=3", 0.1))});
  const model::TransferFunction frozen = model::FrozenModelAt(model, 2.5);
  for (double frequency_Hz : {0.01, 0.05, 0.2}) {
    const double swing_V = 2.0;
    const double gain_mm_per_V =
        std::abs(model::FrequencyResponse(frozen, 2.0 * std::numbers::pi * frequency_Hz));
    const double amplitude_mm = swing_V * gain_mm_per_V;
    // What the actuator can reach at F at all: the largest swing around 2.5 V within the
    // default limits (8 V is 5.5 V above 2.5 V; a swing a at F moves at 2 pi F a <= 5 V/s),
    // through the model's gain at F. Printed beside the sensor's 0.02 mm noise: below it,
    // no reference at F means anything.
    const double reach_V = std::min(5.5, 5.0 / (2.0 * std::numbers::pi * frequency_Hz));
    std::printf(
        "%-9s sine %g Hz: gain %.4g mm/V (static %.3g); reference +-%.4g mm; within "
        "the limits +-%.2f V reaches +-%.4g mm (sensor noise %.2g mm)\n",
        plant.name.c_str(), frequency_Hz, gain_mm_per_V,
        std::abs(model::FrequencyResponse(frozen, 0.0)), amplitude_mm, reach_V,
        reach_V * gain_mm_per_V, plant.noise_mm);
    if (plant.truth) {
      const double w = 2.0 * std::numbers::pi * frequency_Hz;
      const std::complex<double> g_model = model::FrequencyResponse(frozen, w);
      const std::complex<double> g_plant =
          model::FrequencyResponse(model::FrozenModelAt(*plant.truth, 2.5), w);
      std::printf(
          "%-9s sine %g Hz: the plant's own gain there %.4g mm/V, %.1f degrees from "
          "the model's phase\n",
          plant.name.c_str(), frequency_Hz, std::abs(g_plant),
          std::arg(g_plant / g_model) * 180.0 / std::numbers::pi);
    }
    const double duration_s = std::max(600.0, 6.0 / frequency_Hz);
    char spec[160];
    std::snprintf(spec, sizeof spec, "sine:level=%.4f,amplitude=%.5f,frequency=%g,duration=%g",
                  steady.DeflectionAt(2.5), amplitude_mm, frequency_Hz, duration_s);
    char name[32];
    std::snprintf(name, sizeof name, "sine %g Hz", frequency_Hz);
    cases.push_back({name, WithLeadIn(control::ReferenceFromProtocol(spec, 0.1)), frequency_Hz});
  }
  return cases;
}

// A series x(t) split into its mean, its component at F (amplitude, projected on cos and
// sin: least squares over whole periods) and the RMS of what is left.
struct AtFrequency {
  double mean = 0.0, amplitude = 0.0, rest_rms = 0.0;
};

AtFrequency SplitAt(const std::vector<double>& t_s, const std::vector<double>& x,
                    double frequency_Hz) {
  AtFrequency split;
  const double n = static_cast<double>(x.size());
  for (double v : x) split.mean += v / n;
  const double w = 2.0 * std::numbers::pi * frequency_Hz;
  double c = 0.0, s = 0.0;
  for (size_t k = 0; k < x.size(); ++k) {
    c += 2.0 / n * (x[k] - split.mean) * std::cos(w * t_s[k]);
    s += 2.0 / n * (x[k] - split.mean) * std::sin(w * t_s[k]);
  }
  split.amplitude = std::hypot(c, s);
  double rest = 0.0;
  for (size_t k = 0; k < x.size(); ++k) {
    const double left = x[k] - split.mean - c * std::cos(w * t_s[k]) - s * std::sin(w * t_s[k]);
    rest += left * left / n;
  }
  split.rest_rms = std::sqrt(rest);
  return split;
}

double StandardDeviation(const std::vector<double>& values) {
  double mean = 0.0, squares = 0.0;
  for (double v : values) mean += v;
  mean /= static_cast<double>(values.size());
  for (double v : values) squares += (v - mean) * (v - mean);
  return std::sqrt(squares / static_cast<double>(values.size()));
}

void WritePlot(const std::string& path, const testing::LoopResult& predictive,
               const testing::LoopResult& pi) {
  cli::Chart deflection{
      "rig, multilevel reference: deflection", "time (s)", "deflection (mm)", {}, {}};
  deflection.series.push_back(
      {"reference", predictive.t_s, predictive.reference_mm, "#000000", true, false});
  deflection.series.push_back(
      {"measured, predictive", predictive.t_s, predictive.measured_mm, "#1f77b4", false, false});
  deflection.series.push_back({"measured, PI", pi.t_s, pi.measured_mm, "#d62728", false, false});
  cli::Chart voltage{"voltage", "time (s)", "voltage (V)", {}, {}};
  voltage.series.push_back(
      {"predictive", predictive.t_s, predictive.voltage_V, "#1f77b4", false, true});
  voltage.series.push_back({"PI", pi.t_s, pi.voltage_V, "#d62728", false, true});
  std::string lower = cli::RenderSvg(voltage, 900, 300);
  lower.replace(lower.find("<svg "), 5, "<svg y=\"420\" ");
  std::ofstream out(path, std::ios::trunc);
  out << "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"900\" height=\"720\">\n"
      << cli::RenderSvg(deflection, 900, 420) << lower << "</svg>\n";
}

}  // namespace
}  // namespace flexid

namespace {

int Run(int argc, char** argv) {
  using namespace flexid;
  std::string svg_path;
  uint64_t ts_seed = 7;
  bool ts_sweep = false;
  // < 0: the controller's defaults (model/control/mpc.h)
  double move_weight = -1.0, effort_weight = -1.0, replan_s = -1.0, mismatch_tau_s = -1.0;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--svg") == 0 && i + 1 < argc) {
      svg_path = argv[++i];
    } else if (std::strcmp(argv[i], "--ts-sweep") == 0) {
      ts_sweep = true;
    } else if ((std::strcmp(argv[i], "--move-weight") == 0 ||
                std::strcmp(argv[i], "--effort-weight") == 0 ||
                std::strcmp(argv[i], "--replan") == 0 ||
                std::strcmp(argv[i], "--mismatch-time-constant") == 0) &&
               i + 1 < argc) {
      // Checked here for a number >= 0; the controller checks the rest (MpcOptions::IsValid).
      const char* option = argv[i];
      const char* text = argv[++i];
      char* end = nullptr;
      const double value = std::strtod(text, &end);
      if (end == text || *end != '\0' || !std::isfinite(value) || value < 0.0) {
        std::fprintf(stderr, "control_bench: %s \"%s\": not a finite number >= 0\n", option, text);
        return 2;
      }
      double* target = std::strcmp(option, "--move-weight") == 0     ? &move_weight
                       : std::strcmp(option, "--effort-weight") == 0 ? &effort_weight
                       : std::strcmp(option, "--replan") == 0        ? &replan_s
                                                                     : &mismatch_tau_s;
      *target = value;
    } else if (std::strcmp(argv[i], "--ts-seed") == 0 && i + 1 < argc) {
      const char* text = argv[++i];
      char* end = nullptr;
      ts_seed = std::strtoull(text, &end, 10);
      if (end == text || *end != '\0' || text[0] == '-') {
        std::fprintf(stderr, "control_bench: --ts-seed \"%s\": not a seed (a whole number >= 0)\n",
                     text);
        return 2;
      }
    } else {
      std::fprintf(stderr,
                   "usage: control_bench [--svg PATH] [--ts-seed N] [--ts-sweep] "
                   "[--move-weight W] [--effort-weight W] [--replan S] "
                   "[--mismatch-time-constant S]\n");
      return 2;
    }
  }
  const auto clock_start = std::chrono::steady_clock::now();
  std::vector<PlantCase> plants;
  {
    const model::GlobalEstimate rig_model =
        model::IdentifyGlobalTs({RigRecording("square:level=2,period=220,cycles=2", 11),
                                 RigRecording("square:level=8,period=220,cycles=2", 12)});
    plants.push_back({"rig", rig_model.model, kNoise_mm,
                      [] { return std::make_unique<RigLoopPlant>(21); }, model::SeedTsModel()});
    std::printf("rig: model identified from 2 V and 8 V square waves: %s\n",
                rig_model.structure.Describe().c_str());
  }
  {
    const testing::TsPlant plant = testing::DrawTsPlant(ts_seed);
    const testing::TsRecording staircase =
        testing::RecordTsPlant(plant, testing::TsStaircase(80.0), 71);
    std::vector<model::Recording> recordings = {staircase.recording};
    if (ts_sweep) recordings.push_back(testing::RecordTsPlant(plant, SquareSweep(), 73).recording);
    const model::GlobalEstimate ts_model = model::IdentifyGlobalTs(recordings);
    plants.push_back({"ts_plant", ts_model.model, plant.noise_std_mm,
                      [plant] { return std::make_unique<testing::TsPlantLoop>(plant, 72); }});
    std::printf(
        "ts_plant (seed %llu, %zu rules, dead time %.2f s): model identified from its "
        "staircase%s: %s\n",
        static_cast<unsigned long long>(ts_seed), plant.rules.size(), plant.delay_s,
        ts_sweep ? " and a square-wave sweep" : "", ts_model.structure.Describe().c_str());
  }
  std::printf("\n%-9s %-12s %-11s %9s %8s %9s %10s %12s\n", "plant", "reference", "controller",
              "RMSE mm", "RMSE %", "V rms", "charge Vs", "peak Vs/220s");
  std::vector<std::string> ratios;
  for (const PlantCase& plant : plants) {
    for (const ReferenceCase& reference : References(plant)) {
      std::vector<double> scored;
      for (size_t k = 0; k < reference.reference.t_s().size(); ++k)
        if (reference.reference.t_s()[k] >= kLeadIn_s)
          scored.push_back(reference.reference.deflection_mm()[k]);
      const double spread = StandardDeviation(scored);
      testing::LoopResult results[3];
      const ControllerKind kinds[3] = {ControllerKind::kPredictive, ControllerKind::kPi,
                                       ControllerKind::kOpenLoop};
      for (int i = 0; i < 3; ++i) {
        ControllerOptions options;
        options.kind = kinds[i];
        if (move_weight >= 0.0) options.mpc.move_weight = move_weight;
        if (effort_weight >= 0.0) options.mpc.effort_weight = effort_weight;
        if (replan_s >= 0.0) options.mpc.replan_s = replan_s;
        if (mismatch_tau_s >= 0.0) options.mpc.disturbance_time_constant_s = mismatch_tau_s;
        Controller controller(plant.model, reference.reference, options);
        const std::unique_ptr<testing::LoopPlant> loop_plant = plant.make();
        results[i] = testing::RunLoop(controller, *loop_plant, kLeadIn_s);
        const testing::LoopResult& r = results[i];
        std::printf("%-9s %-12s %-11s %9.4f %8.1f %9.2f %10.0f %12.0f\n", plant.name.c_str(),
                    reference.name.c_str(), model::control::ControllerKindName(kinds[i]), r.rmse_mm,
                    100.0 * r.rmse_mm / spread, r.voltage_rms_V, r.charge_Vs,
                    r.peak_window_charge_Vs);
      }
      if (reference.frequency_Hz > 0.0)
        for (int i = 0; i < 3; ++i) {
          const testing::LoopResult& r = results[i];
          std::vector<double> t_s, error_mm, model_error_mm, voltage_V;
          for (size_t k = 0; k < r.t_s.size(); ++k)
            if (r.t_s[k] >= kLeadIn_s) {
              t_s.push_back(r.t_s[k]);
              error_mm.push_back(r.clean_mm[k] - r.reference_mm[k]);
              model_error_mm.push_back(r.model_mm[k] - r.reference_mm[k]);
              voltage_V.push_back(r.voltage_V[k]);
            }
          const AtFrequency e = SplitAt(t_s, error_mm, reference.frequency_Hz);
          const AtFrequency u = SplitAt(t_s, voltage_V, reference.frequency_Hz);
          std::printf(
              "%-9s %-12s %-11s   error: mean %+.4f mm, at F %.4f mm RMS, rest %.4f mm RMS; "
              "voltage: mean %.3f V, at F +-%.3f V, rest %.3f V RMS",
              plant.name.c_str(), reference.name.c_str(),
              model::control::ControllerKindName(kinds[i]), e.mean, e.amplitude / std::sqrt(2.0),
              e.rest_rms, u.mean, u.amplitude, u.rest_rms);
          // The controller's own model driven by the same voltages (not for the PI).
          if (std::isfinite(model_error_mm.front())) {
            const AtFrequency m = SplitAt(t_s, model_error_mm, reference.frequency_Hz);
            std::printf("; its model's error: mean %+.4f mm, at F %.4f mm RMS", m.mean,
                        m.amplitude / std::sqrt(2.0));
          }
          std::printf("\n");
        }
      char line[160];
      std::snprintf(line, sizeof line, "%-9s %-12s predictive / PI RMSE = %.2f", plant.name.c_str(),
                    reference.name.c_str(), results[0].rmse_mm / results[1].rmse_mm);
      ratios.push_back(line);
      if (!svg_path.empty() && plant.name == "rig" && reference.name == "multilevel")
        WritePlot(svg_path, results[0], results[1]);
    }
  }
  std::printf("\n");
  for (const std::string& line : ratios) std::printf("%s\n", line.c_str());
  std::printf(
      "\n%.0f s in all\n",
      std::chrono::duration<double>(std::chrono::steady_clock::now() - clock_start).count());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return Run(argc, argv);
  } catch (const std::exception& e) {  // an option the controller refuses, a failed fit
    std::fprintf(stderr, "control_bench: %s\n", e.what());
    return 2;
  }
}
