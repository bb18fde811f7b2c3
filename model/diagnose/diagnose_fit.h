// The diagnosis's evidence and its fits (internal to model/diagnose*.cc): the recordings as
// the diagnosis sees them (Data: joined recordings, held-out split, noise, levels), one
// prediction of a baseline with effects (Augmented, Predict), the residual statistics
// every test uses, and the least-squares fit of effect parameters, alone or with the
// identified baseline's coefficients (FitParameters).
#pragma once

#include <Eigen/Dense>
#include <cstddef>
#include <limits>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "model/core/levels.h"
#include "model/core/simulate.h"
#include "model/diagnose/diagnose.h"
#include "model/identify/identify_global.h"

namespace flexid::model::diagnosis {

inline constexpr double kInf = std::numeric_limits<double>::infinity();

double SumSquares(std::span<const double> r, const std::vector<size_t>& index);

// Lag-1 autocorrelation of r over consecutive members of `index` (pairs that straddle a
// gap are skipped), clamped to [0, 0.995]; n_eff = n (1 - rho) / (1 + rho).
double EffectiveSamples(std::span<const double> r, const std::vector<size_t>& index);

std::vector<double> Residual(std::span<const double> y, std::span<const double> yhat);

double RmsOver(std::span<const double> r, const std::vector<size_t>& index);

struct Data {
  // The recordings laid end to end (JoinRecordings): recording j is samples
  // [starts[j], starts[j + 1]), its times shifted by shift_s[j]. Empty starts: one.
  const Recording* rec = nullptr;
  std::vector<size_t> starts;
  std::vector<double> shift_s;
  size_t Recordings() const { return starts.empty() ? 1 : starts.size() - 1; }
  size_t Begin(size_t j) const { return starts.empty() ? 0 : starts[j]; }
  size_t End(size_t j) const { return starts.empty() ? rec->t_s.size() : starts[j + 1]; }
  // The model driven by u from rest in every recording (each starts at rest: the state
  // never carries from one recording into the next).
  // premise: the voltage the operating point follows (SimulationOptions::premise_V;
  // empty: u).
  std::vector<double> SimulateFromRest(const TsModel& model, const std::vector<double>& u,
                                       const std::vector<double>& premise = {}) const;
  // An output effect: a relaxation or a hysteresis state starts afresh in each recording
  // (each starts at rest); a sensor drift runs through them in order (one sensor over a
  // session: its warm-up happens once, and the gaps between recordings do not count).
  void ApplyOutput(const Effect& e, std::vector<double>* y_mm) const;
  // The voltage column is sampled: where the voltage really stepped between two samples is
  // unknown, and a step's timing error leaves an error that the slow modes carry for
  // minutes. Every fit and training test therefore works after projecting out the
  // baseline's response to moving each recorded step by up to half a sample (nuisance
  // regressors; an orthonormal basis over the training samples, empty: none). Held-out
  // samples are never fitted, nuisance included: their figures are raw.
  Eigen::MatrixXd edges_train;
  std::vector<Effect> given;  // part of the baseline
  std::vector<size_t> train, heldout;
  std::vector<TimeSpan> heldout_spans;
  double noise_mm = 0.0;
  double max_abs_V = 0.0;
  double rest_band_V = 0.0;
  double resolution_V = kSchedulingResolution_V;  // scheduling (SchedulingResolutionFor)
  SimulationOptions Simulation() const {
    SimulationOptions options;
    options.scheduling_resolution_V = resolution_V;
    return options;
  }
  LevelAnalysis levels;
  std::vector<double> abs_levels_V;  // distinct |level|, ascending
  double duration_s = 0.0;
  double dt_s = 0.0;  // median sample period
};

// The baseline plus a list of effects: one prediction.
struct Augmented {
  const TsModel* baseline = nullptr;
  std::vector<Effect> effects;
  // Without a trusted model the baseline is refitted with the effects (its one transfer
  // function's coefficients); then this is the refitted baseline, used instead.
  std::shared_ptr<const TsModel> refit;
  const TsModel& Baseline() const { return refit ? *refit : *baseline; }
};

struct ParameterSpec {
  double lower, upper;
  std::vector<double> starts;  // candidate starting values (all combinations are tried)
};

struct FitProblem {
  Augmented fixed;                   // baseline and effects already chosen
  std::vector<EffectKind> kinds;     // effects whose parameters are fitted (appended)
  std::vector<ParameterSpec> specs;  // for every fitted parameter: the baseline's, if
                                     // refitted, then effect by effect
  // Refit this single-rule baseline's coefficients too (num, then den after its leading 1),
  // from their values in it; the result replaces Augmented::refit.
  std::shared_ptr<const TsModel> refit_from;
};

struct FitResult {
  Augmented model;
  std::vector<double> theta;  // fitted parameters
  std::vector<double> half_width;
  Eigen::MatrixXd covariance;  // of theta (a pseudo-inverse); empty when not determined
  Eigen::MatrixXd null_space;  // directions of theta the data do not determine (columns)
  std::vector<double> prediction;
  double train_sse = kInf;
};

// measured - predicted, with the step-timing nuisance projected out of the training
// samples (Data::edges_train): what every fit and training test works on.
std::vector<double> NuisanceFreeResidual(const Data& data, std::span<const double> predicted);

// The last few simulations of one fit, by their exact inputs (every number of the model,
// the drive and the premise). A parameter that does not move the drive leaves the
// simulation as it was: a saturation's slope while its onset is above every sample, a
// dead zone's threshold moved by a central difference between two plateaus. On the HASEL
// mixed recording's diagnosis, a tenth of every sample simulated was such a repeat.
class SimulationMemo {
 public:
  // The simulation of `model` under u with `premise` (Data::SimulateFromRest), from the
  // memo or made and kept.
  std::vector<double> Simulate(const Data& data, const TsModel& model, const std::vector<double>& u,
                               const std::vector<double>& premise);
  size_t simulations() const { return simulations_; }  // made, not found

  static constexpr size_t kEntries = 3;

 private:
  struct Entry {
    std::vector<double> model, u, premise, y;
  };
  std::vector<Entry> entries_;  // the most recent last
  size_t simulations_ = 0;
};

// `cache`: the baseline's own prediction, if known (output-side effects then need no
// simulation). `memo`: simulations to reuse and keep (one fit's).
std::vector<double> Predict(const Data& data, const Augmented& a,
                            const std::vector<double>* cache = nullptr,
                            SimulationMemo* memo = nullptr);

// Bounds and starts of a refitted baseline's coefficients: free, from their values.
std::vector<ParameterSpec> CoefficientSpecs(const TsModel& model);

// The covariance of parameters estimated by least squares with Jacobian j (m x q) and
// residual variance sigma2, as a pseudo-inverse: *covariance (q x q, infinite for a
// parameter the residuals do not move), *null_space (q x c: the directions the data do not
// determine). Returns each parameter's 95 % half-width (infinite when not determined alone).
std::vector<double> CovarianceOf(const Eigen::MatrixXd& j, double sigma2,
                                 Eigen::MatrixXd* covariance_out, Eigen::MatrixXd* null_space_out);

// The problem's parameters fitted on the training samples (the nuisance projected out):
// every combination of their starting values a few iterations, the best to convergence
// (Ceres L-M with the baseline held, the secant L-M when it is refitted), with the
// covariance at the end point. `baseline`: the baseline's own prediction, if known.
FitResult FitParameters(const Data& data, const FitProblem& problem,
                        const std::vector<double>* baseline);

// The fitted model's prediction minus the same model without its last effect (the
// baseline as refitted with it, the earlier effects kept).
std::vector<double> WhatTheLastEffectAdds(const Data& data, const FitResult& fit);

// Bounds and starting values of one effect's parameters for this recording.
std::vector<ParameterSpec> SpecsFor(EffectKind kind, const Data& data);

// Can the recording show the effect at all?
bool Applicable(EffectKind kind, const Data& data, std::string* why);

// The identified baseline may fall back by at most this share of a step (identify_global.h,
// max_fall_back): the 1 % below which ReadAgainstPhysics reads no fall-back.
constexpr double kBaselineFallBack = 0.01;
// The model of one more pole and zero that back-relaxation must beat (Diagnoser::MoreOrder)
// may fall back by at most this share: the baseline's 1 % is slack for a model that should
// not fall back at all, and a higher order that gains by spending it (a slow pole and zero
// that fall back 0.8 %) is a back-relaxation by another name, not model order.
constexpr double kMoreOrderFallBack = 0.002;

// Without a trusted model: the whole T-S model identified on the training samples by the
// global fit (identify_global.h, the path `flexid identify` and flexidd take), its
// structure chosen on held-out blocks of the training samples. Notes go to result->notes.
// `higher_than`: a baseline already identified; its structure with one more pole and zero,
// premise, realisation and dead time as chosen (for the back-relaxation test below); notes
// are then not added; it is held to the physics chain's prior like the baseline.
GlobalEstimate IdentifyBaseline(const Recording& rec, const Data& data, Diagnosis* result,
                                const GlobalEstimate* higher_than = nullptr);

// The recordings laid end to end, in the order given, as one: recording j > 0 starts one
// sample period (its predecessor's last) after its predecessor ends. *starts receives the
// first sample of each, then the total; *shift_s what was added to each one's times.
Recording JoinRecordings(const std::vector<Recording>& recordings, std::vector<size_t>* starts,
                         std::vector<double>* shift_s);

// Spans on the joined time axis as spans of the recordings, on their own times (a span
// across the end of one recording becomes one in each).
std::vector<TimeSpan> OnRecordings(const Data& data, const std::vector<TimeSpan>& joined);

}  // namespace flexid::model::diagnosis
