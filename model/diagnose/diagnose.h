// Mismatch diagnosis (`flexid diagnose`): where a model and a recording disagree, which
// physics the model leaves out, a model of it, and how much better the augmented model
// predicts samples that no fit has seen.
//
// Steps, for one recording (t_s, voltage_V, deflection_mm) and a baseline model:
//  1. Held-out blocks. Contiguous blocks of the recording (DiagnoseOptions::heldout_blocks
//     blocks of heldout_fraction / heldout_blocks of the duration each, spread over the
//     recording, the last one at its end) are held out from every fit: the baseline's
//     identification when there is no trusted model, and every effect's parameters. The
//     input is known everywhere, so every model is simulated over the whole recording and
//     scored on the fitted ("training") and the held-out samples separately.
//  2. Baseline. With a trusted model: that model as given (with its file's augmentations).
//     Without: the whole T-S model identified on the training samples by the global fit
//     (identify_global.h, the path `flexid identify` and flexidd take), limited to the
//     seed's blend: one rule, or two handing over smoothly (Eq. 19), never a gain per level
//     (which would absorb a static map or a gain that changes with time).
//  3. Locate. The residual r = measured - baseline, broken down by operating condition
//     (Localisation), with its whiteness and input cross-correlation tests.
//  4. Candidates. Each effect of the catalogue (EffectKind) that the recording can show
//     (e.g. polarity_asymmetry needs both polarities) is added to the baseline and its
//     parameters are fitted on the training samples (several starts for the nonlinear
//     ones). A trusted model stays as given (Levenberg-Marquardt, Ceres, numeric
//     derivatives through the simulation). An identified baseline is refitted with every
//     effect, every rule's coefficients with the effect's parameters (secant L-M,
//     secant_lm.h): fitted alone it has bent towards what it cannot express. It is tested
//     against the baseline refitted the same way without an effect, or against the best of
//     the candidates' refits with their effect removed when one of them landed in a better
//     optimum (the gain is then the optimiser's, not the effect's). Without a trusted
//     model the baseline is identified under the physics chain's prior (max_fall_back
//     1 %: no rule's step response may fall back, Eqs. 11-13), and every refit of it stays
//     under it (no more than it fell back from the start; if no structure meets the prior,
//     the baseline is identified without it, in a note). Back-relaxation and creep
//     add a slow pole-zero pair to it, and the extra order alone may be what helps (a
//     clean square wave on a plant with more slow modes than the baseline was read as
//     back-relaxation). So the baseline with one more pole and zero under a stricter prior
//     (GlobalIdentifyOptions::raise_order_of: the baseline's structure, one fit from four
//     starts, falling back at most 0.2 %: the baseline's 1 % is slack, and a higher order
//     that spends it is a back-relaxation) is fitted too, and either is named only where
//     its held-out likelihood ratio exceeds what that model gains there by the held-out
//     test's threshold (what the baseline gains, 0, when every such fit falls back).
//     With a trusted model the recorded voltage is a sampled column: where a step really
//     happened between two samples is unknown, and its timing error leaves a slow error in
//     the prediction. Its fits and tests are made after projecting out the baseline's
//     response to moving each recorded step by up to half a sample (one nuisance regressor
//     per step; none for continuous inputs: more than one step per 50 samples or more than
//     64 steps, which bounds the regressors' memory to 64 doubles a sample). An identified
//     baseline has none: it is fitted to these samples, and free nuisance coefficients let
//     the timing absorb slow trends. Held-out figures are raw.
//  5. Decide. Residuals of a slightly wrong model are not white, so samples are not
//     independent evidence: every likelihood figure uses the effective sample count
//     n_eff = n (1 - rho) / (1 + rho) of the residual (rho its lag-1 autocorrelation). A
//     candidate is claimed when
//       - its likelihood ratio n_eff ln(SSE_0 / SSE_1) exceeds the chi-square quantile for
//         its parameter count at DiagnoseOptions::false_alarm_rate (Bonferroni over the
//         candidates tried): training plus held-out (the held-out part counted only when
//         positive) with a trusted model, training alone without one (there the held-out
//         samples also test the identified baseline's extrapolation),
//       - it predicts the held-out samples better: held-out likelihood ratio above the
//         chi-square(1) quantile at the same rate, and a lower held-out RMSE,
//       - what it adds to the prediction is at least min_effect_to_noise times the noise
//         over the samples it touches, and
//       - its size is determined: with a trusted model, the 95 % interval (delta method on
//         the fit's covariance) of how much of it there is excludes none; without one, the
//         likelihood ratio against the refitted baseline is the profile test of size =
//         none, and the effect must explain at least min_share_of_misfit of the held-out
//         misfit beyond the noise (next to a misfit many times its size, a small gain may be
//         that misfit taking the effect's shape). A candidate that passes all but this is
//         an unexplained misfit (Misfit), reported where it is, never named.
//     Among claimed candidates the verdict is, with a trusted model, the one with the lowest
//     information criterion on the training samples, BIC = n_eff ln(SSE / n) + k ln(n_eff);
//     without one, the least squared error over every sample, fitted and held out (each
//     candidate brings its own refit: the fitted samples alone favour the refit that bends
//     most, the held-out ones alone the one that extrapolates best to the few conditions
//     they hold). One more
//     effect may then be added on top of it by the same tests (forward selection, at most
//     max_effects), the earlier effects refitted with it.
//     What the final model still misses on the held-out samples beyond 3 times the noise
//     is reported as an unexplained misfit that no catalogue entry resembles (a verdict
//     "none" beside it does not mean the model is right there).
//  6. Without a trusted model, the identified baseline as refitted with the findings is
//     also read against the physics chain (Eqs. 11-13: a step response that rises without
//     falling back): a fall-back is reported (Absorbed), never named: it has no held-out
//     test and no interval.
//
// Measured (README "Diagnosis", with the commands): on the independent simulator's
// batteries (../shared/data/independent/score), on the lab plant of
// tests/effect_plant.h (tests/diagnose_acceptance_test.cc; its effects and this catalogue
// share the formulas of cycle degradation and polarity asymmetry, and its drift is a
// warm-up plus a linear trend like the catalogue's), and on the effect battery of
// tests/effect_battery.h (tests/diagnose_battery_test.cc, bench/diagnose_battery), whose
// effects are formulated otherwise than any catalogue entry. One comes close: its wear, a
// loss linear in the square root of the charge, and the catalogue's degradation with
// exponent 0.5, exponential in it, differ by under 1 % of the gain while the loss is
// under 10 %.
//
// Deterministic: no random numbers; the same input gives the same findings.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "model/core/model_file.h"
#include "model/core/recording.h"
#include "model/core/ts_fuzzy.h"
#include "model/diagnose/effects.h"
#include "model/identify/identify.h"

namespace flexid::model {

// The baseline's prediction for the recording with the effects applied in order (input
// effects change the voltage the model is driven with, output effects change the
// deflection). Throws std::invalid_argument for a wrong parameter count.
std::vector<double> SimulateAugmented(const TsModel& baseline, const Recording& recording,
                                      const std::vector<Effect>& effects);

struct TimeSpan {
  double t_start_s = 0.0;
  double t_end_s = 0.0;
  int recording = 0;  // which of the diagnosed recordings, on its own times (0 with one)
};

// Residual statistics of one group of samples (all samples, held-out included).
struct ResidualGroup {
  std::string dimension;  // "condition", "level", "polarity", "cycle", "charge", "motion"
  std::string group;      // e.g. "held", "transition", "rest", "5 V", "cycle 3", "rising"
  size_t samples = 0;
  double mean_mm = 0.0;
  double rms_mm = 0.0;
};

struct Localisation {
  std::vector<ResidualGroup> groups;
  FitFigures baseline_fit;  // on the training samples: fit %, RMSE, whiteness, cross-correlation
};

struct CandidateReport {
  EffectKind kind = EffectKind::kBackRelaxation;
  std::string name;  // EffectName, or "creep" when back-relaxation's fraction is negative
  std::vector<ParameterEstimate> params;  // with 95 % half-widths
  double train_rmse_mm = 0.0;
  double heldout_rmse_mm = 0.0;
  double effective_samples = 0.0;  // n_eff of the training residual
  double likelihood_ratio = 0.0;   // training, against the model it was added to
  double heldout_likelihood_ratio = 0.0;
  double bic = 0.0;
  double effect_rms_mm = 0.0;  // RMS of what it adds, over the samples it touches
  bool claimed = false;
  std::string reason;  // why it was or was not claimed
  int round = 0;       // 0: added to the baseline; 1: added to the first finding, ...
};

// Another effect that passed every test on its own against the same model as a finding,
// and was not chosen: the data hold it too, less well by the round's choice.
struct Rival {
  std::string effect;
  double heldout_rmse_mm = 0.0;  // the model with it, on the held-out samples
};

struct Finding {
  std::string effect;
  std::string explanation;  // plain words, with numbers
  std::vector<TimeSpan> where;
  std::vector<ParameterEstimate> params;
  double heldout_rmse_before_mm = 0.0;
  double heldout_rmse_after_mm = 0.0;
  Effect model;  // the fitted effect, for the model file's augmentations
  // The other candidates claimed in the same round, best first by the round's choice
  // (chosen_by), with what each leaves on the held-out samples.
  std::vector<Rival> rivals;
  std::string chosen_by;  // how the finding was chosen among them (empty without rivals)
};

// What a free fit absorbed that the physics chain does not predict (no trusted model).
struct Absorbed {
  std::string effect;         // "back_relaxation"
  double level_V = 0.0;       // local model's level
  double tau_s = 0.0;         // time from the peak to 1/e of the excess
  double fall_back = 0.0;     // excess of the step response over its final value, share of it
  double amplitude_mm = 0.0;  // that excess at the level
  std::string explanation;
};

// Something a candidate effect would explain (it passed every test of the evidence) whose
// size the data do not determine: reported where it is, never as a named effect.
struct Misfit {
  // The effect whose model would explain it; empty for what the final model leaves on the
  // held-out samples beyond 3 times the noise, which nothing in the catalogue explains.
  std::string resembles;
  double rms_mm = 0.0;  // what that model adds, over the samples it touches
  std::vector<TimeSpan> where;
  std::string explanation;
};

struct DiagnoseOptions {
  int heldout_blocks = 3;
  double heldout_fraction = 0.3;   // of the duration, in (0, 0.5]
  double false_alarm_rate = 1e-3;  // per recording, split over the candidates
  double min_effect_to_noise = 0.25;
  // Without a trusted model: the least share of the held-out misfit beyond the noise
  // (RMSE^2 - noise^2) a named effect must explain, in [0, 1].
  double min_share_of_misfit = 0.1;
  int max_effects = 2;
  // Effects already part of the trusted model (its file's augmentations): applied to the
  // baseline as given, never refitted.
  std::vector<Effect> baseline_effects;
};

struct Diagnosis {
  std::string verdict;                  // effect name, or "none"
  std::vector<std::string> recordings;  // the diagnosed recordings' sources, in order
  bool trusted_model = false;
  TsModel baseline_model;
  // The baseline that goes with the findings' effects: baseline_model, or, without a
  // trusted model, the identified transfer function as refitted with them.
  TsModel augmented_baseline_model;
  double baseline_fit_percent = 0.0;  // training samples
  double baseline_rmse_mm = 0.0;      // training samples
  double baseline_heldout_rmse_mm = 0.0;
  double noise_std_mm = 0.0;  // robust estimate from the measured deflection
  std::vector<TimeSpan> heldout;
  std::vector<Finding> findings;  // claimed effects, the verdict first
  std::vector<CandidateReport> candidates;
  std::vector<Absorbed> absorbed;
  std::vector<Misfit> unexplained;
  Localisation localisation;
  std::vector<double> baseline_mm;   // prediction at every sample
  std::vector<double> augmented_mm;  // with the findings' effects (= baseline when none)
  std::vector<std::string> notes;
};

// Throws InputError for an unusable recording (too short, no deflection, constant
// voltage) and std::invalid_argument for invalid options or model.
Diagnosis Diagnose(const Recording& recording, const std::optional<TsModel>& trusted_model,
                   const DiagnoseOptions& options = {});
// Several recordings of one actuator (trials of different protocols, levels and holds):
// one diagnosis from the evidence of all of them. They are laid end to end in the order
// given, each simulated from rest (no state carries over), and the held-out blocks are
// spread over the whole. A relaxation and a hysteresis state start afresh in each
// recording; effects that belong to the actuator's or the sensor's history run through the
// recordings in order, the gaps between them not counted (a degradation's charge
// accumulates from one to the next; a sensor drift's warm-up happens once). An identified baseline
// is identified on all of them (they must share a sample period). Spans (held-out, where) say which
// recording they are in (TimeSpan::recording), on its own times; baseline_mm and augmented_mm run
// through the recordings in order. Errors name the recording.
constexpr int kMaxDiagnosedRecordings = 16;  // in one diagnosis (InputError beyond)
Diagnosis Diagnose(const std::vector<Recording>& recordings,
                   const std::optional<TsModel>& trusted_model,
                   const DiagnoseOptions& options = {});

// The diagnosis result of DESIGN.md ("Diagnosis result"): verdict, baseline
// {fit_percent, rmse_mm, heldout_rmse_mm} and findings [{effect, explanation, where,
// params, heldout_rmse_before_mm, heldout_rmse_after_mm}], plus what flexid adds: the noise
// estimate, the held-out spans, every candidate, the localisation and what a free fit
// absorbed. Parameters are {name: value} with their 95 % half-widths under
// "params_95" ({name: half-width}, null when not determined).
nlohmann::json DiagnosisToJson(const Diagnosis& diagnosis);

}  // namespace flexid::model
