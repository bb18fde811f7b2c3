// The mismatch diagnosis's pipeline (diagnose.h): Diagnose and its stages (Diagnoser).
// Its parts: the effect catalogue (effects.h), the evidence and the fits
// (diagnose_fit.h), locating and explaining (diagnose_explain.h), the JSON
// (diagnosis_json.cc).
#include "model/diagnose/diagnose.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <numeric>
#include <optional>
#include <stdexcept>
#include <tuple>

#include "model/core/errors.h"
#include "model/core/metrics.h"
#include "model/diagnose/diagnose_explain.h"
#include "model/diagnose/diagnose_fit.h"
#include "model/identify/identify_global.h"

namespace flexid::model {

using namespace diagnosis;  // NOLINT(google-build-using-namespace): the diagnosis's own parts

namespace {

// Step-timing nuisance regressors at most (Diagnose): bounds their matrix to 64 doubles a
// sample (39 MB for 77,000 samples).
constexpr size_t kMaxTimedSteps = 64;
// A held-out error of the final model beyond this many noise deviations is reported as an
// unexplained misfit (Diagnoser::ReportWhatIsLeft).
constexpr double kLeftOverToNoise = 3.0;

}  // namespace

std::vector<double> SimulateAugmented(const TsModel& baseline, const Recording& recording,
                                      const std::vector<Effect>& effects) {
  for (const Effect& e : effects)
    if (e.params.size() != EffectParameterNames(e.kind).size())
      throw std::invalid_argument(std::string("effect ") + EffectName(e.kind) + " needs " +
                                  std::to_string(EffectParameterNames(e.kind).size()) +
                                  " parameters");
  Data data;
  data.rec = &recording;
  return Predict(data, Augmented{&baseline, effects, nullptr});
}

// -----------------------------------------------------------------------------------------
// Diagnose
// -----------------------------------------------------------------------------------------

namespace {

// One diagnosis (Diagnose, diagnose.h): its stages, in order, share the evidence (data),
// the result being built and the model every candidate is tested against (current).
struct Diagnoser {
  const DiagnoseOptions& options;
  const std::optional<TsModel>& trusted_model;
  Data data;            // first: rec's initialiser fills data.starts
  const Recording rec;  // the recordings laid end to end (data.starts)
  const size_t n;
  Diagnosis result;
  // Without a trusted model: the baseline with one more pole and zero under the physics
  // chain's prior, its held-out RMSE and its held-out likelihood ratio against the
  // baseline: what model order alone gains there, which a back-relaxation must exceed
  // (Baseline, Judge). When every such fit falls back (or none can be made), the
  // baseline's own: 0.
  double more_order_heldout_mm = std::numeric_limits<double>::infinity();
  double more_order_heldout_lr = std::numeric_limits<double>::infinity();
  std::string model_words;
  std::vector<EffectKind> kinds;  // the candidates tried
  double test_level = 0.0;        // of every test: 1 - false-alarm rate / tests
  double n_train = 0.0;
  FitResult current;  // the model to beat: the baseline, then with the findings
  std::vector<EffectKind> chosen;
  std::vector<CandidateReport> round_reports;

  // What the final model (the baseline with the findings) leaves on the held-out samples:
  // beyond kLeftOverToNoise times the noise, an unexplained misfit that no entry of the
  // catalogue resembles. A verdict "none" beside a held-out error many times the noise
  // would read as "the model is fine".
  void ReportWhatIsLeft() {
    const double left_mm = RmsOver(Residual(rec.deflection_mm, current.prediction), data.heldout);
    if (!(left_mm > kLeftOverToNoise * data.noise_mm)) return;
    Misfit misfit;
    misfit.rms_mm = std::sqrt(left_mm * left_mm - data.noise_mm * data.noise_mm);
    misfit.where = result.heldout;
    misfit.explanation =
        model_words + (result.findings.empty() ? "" : " with what was found") +
        " predicts the held-out samples at " + Mm(left_mm) +
        Format(", %.1f times the sensor noise", left_mm / data.noise_mm) +
        ", and no effect of the catalogue explains the rest (" + Mm(misfit.rms_mm) +
        " beyond the noise): " +
        (trusted_model ? "the model itself is off there"
                       : "the fitted samples did not determine a model that carries over to "
                         "them") +
        ", or the actuator shows physics the catalogue does not hold";
    result.unexplained.push_back(std::move(misfit));
  }

  Diagnoser(const std::vector<Recording>& recordings, const std::optional<TsModel>& trusted,
            const DiagnoseOptions& diagnose_options)
      : options(diagnose_options),
        trusted_model(trusted),
        rec(JoinRecordings(recordings, &data.starts, &data.shift_s)),
        n(rec.t_s.size()),
        model_words(trusted ? "the model" : "the identified model") {
    result.trusted_model = trusted_model.has_value();
    for (const Recording& r : recordings) result.recordings.push_back(r.source);
    data.rec = &rec;
    data.duration_s = rec.t_s.back() - rec.t_s.front();
  }

  // The sample period, the voltage levels and plateaus, the scheduling resolution.
  void ReadLevels() {
    {
      std::vector<double> steps;
      for (size_t k = 1; k < n; ++k) steps.push_back(rec.t_s[k] - rec.t_s[k - 1]);
      std::nth_element(steps.begin(), steps.begin() + static_cast<long>(steps.size() / 2),
                       steps.end());
      data.dt_s = steps[steps.size() / 2];
    }
    for (double v : rec.voltage_V) data.max_abs_V = std::max(data.max_abs_V, std::abs(v));
    if (data.max_abs_V == 0.0) throw InputError(rec.source + ": the voltage is 0 throughout");
    try {
      data.levels = DetectLevels(rec.t_s, rec.voltage_V);
    } catch (const InputError&) {
      // E.g. a level held from the first sample, never entered: diagnosis only needs the
      // plateaus and levels, so they are found again with that check relaxed (a recording
      // starts at rest, so its first sample is a step from 0 V).
      const size_t pad = static_cast<size_t>(std::ceil(5.0 / data.dt_s));  // 5 s at rest
      Recording padded;
      for (size_t i = pad; i > 0; --i) {
        padded.t_s.push_back(rec.t_s.front() - static_cast<double>(i) * data.dt_s);
        padded.voltage_V.push_back(0.0);
      }
      padded.t_s.insert(padded.t_s.end(), rec.t_s.begin(), rec.t_s.end());
      padded.voltage_V.insert(padded.voltage_V.end(), rec.voltage_V.begin(), rec.voltage_V.end());
      data.levels = DetectLevels(padded.t_s, padded.voltage_V);
      std::erase_if(data.levels.plateaus, [pad](const Plateau& p) { return p.end <= pad; });
      for (Plateau& p : data.levels.plateaus) {
        p.begin = p.begin > pad ? p.begin - pad : 0;
        p.end -= pad;
      }
    }
    data.rest_band_V = std::max(data.levels.rest_band_V, 0.02 * data.max_abs_V);
    for (const VoltageLevel& level : data.levels.levels) {
      const double a = std::abs(level.level_V);
      if (a <= data.rest_band_V) continue;
      bool merged = false;
      for (double& known : data.abs_levels_V)
        if (std::abs(known - a) <= std::max(data.levels.tolerance_V, 0.05 * a)) merged = true;
      if (!merged) data.abs_levels_V.push_back(a);
    }
    std::sort(data.abs_levels_V.begin(), data.abs_levels_V.end());
    data.resolution_V = SchedulingResolutionFor(data.max_abs_V, data.levels.plateau_input);
    if (!data.levels.plateau_input) {
      // A continuous input: its spread of |u| stands in for the levels.
      std::vector<double> a;
      for (double v : rec.voltage_V)
        if (std::abs(v) > data.rest_band_V) a.push_back(std::abs(v));
      std::sort(a.begin(), a.end());
      data.abs_levels_V.clear();
      if (!a.empty()) {
        const double p10 = a[a.size() / 10], p90 = a[a.size() * 9 / 10];
        data.abs_levels_V.push_back(p10);
        if (p90 > 1.3 * p10) data.abs_levels_V.push_back(p90);
      }
    }
  }

  // 1. Held-out blocks (block j ends at j / K of the duration) and the noise.
  void HoldOut() {
    const double t0 = rec.t_s.front();
    const double block = options.heldout_fraction * data.duration_s / options.heldout_blocks;
    for (int j = 1; j <= options.heldout_blocks; ++j) {
      const double end = t0 + data.duration_s * j / options.heldout_blocks;
      result.heldout.push_back({end - block, end});
    }
    for (size_t k = 0; k < n; ++k) {
      bool held = false;
      for (const TimeSpan& s : result.heldout)
        held |= rec.t_s[k] >= s.t_start_s && rec.t_s[k] <= s.t_end_s;
      (held ? data.heldout : data.train).push_back(k);
    }
    data.noise_mm = NoiseFromSecondDifferences(rec.deflection_mm);
    {
      double peak = 0.0;
      for (double y : rec.deflection_mm) peak = std::max(peak, std::abs(y));
      data.noise_mm = std::max(data.noise_mm, 1e-4 * peak);  // noise-free data
    }
    result.noise_std_mm = data.noise_mm;
  }

  // 2. The baseline: the trusted model, or one identified on the training samples, and its
  // prediction; without a trusted model also the bar back-relaxation and creep must clear
  // (MoreOrder).
  void Baseline() {
    std::optional<GlobalEstimate> estimate;
    if (trusted_model) {
      result.baseline_model = *trusted_model;
      for (const Effect& e : options.baseline_effects)
        if (e.params.size() != EffectParameterNames(e.kind).size())
          throw std::invalid_argument(std::string("effect ") + EffectName(e.kind) +
                                      ": wrong parameter count");
      data.given = options.baseline_effects;
    } else {
      estimate = IdentifyBaseline(rec, data, &result);
      result.baseline_model = estimate->model;
    }
    result.baseline_mm = Predict(data, Augmented{&result.baseline_model, {}, nullptr});
    for (double y : result.baseline_mm)
      if (!std::isfinite(y))
        throw InputError(rec.source + ": the baseline model's prediction is not finite");
    if (estimate && estimate->structure.num_poles < 6) MoreOrder(*estimate);
  }

  // The physics chain's step response cannot fall back (Eqs. 11-13), and the identified
  // baseline is held to that. A back-relaxation on top of it adds a slow pole-zero pair
  // that falls back; what may help is the extra order alone (a clean square wave on a
  // plant with more slow modes than the baseline was flagged). So it is named only where
  // it predicts the held-out samples better than the baseline with one more pole and zero
  // that does not fall back (Judge).
  void MoreOrder(const GlobalEstimate& estimate) {
    try {
      const GlobalEstimate more = IdentifyBaseline(rec, data, &result, &estimate);
      const std::vector<double> r =
          NuisanceFreeResidual(data, Predict(data, Augmented{&more.model, {}, nullptr}));
      const std::vector<double> r0 = NuisanceFreeResidual(data, result.baseline_mm);
      more_order_heldout_mm = RmsOver(r, data.heldout);
      more_order_heldout_lr =
          std::max(0.0, EffectiveSamples(r, data.heldout) *
                            std::log(SumSquares(r0, data.heldout) /
                                     std::max(SumSquares(r, data.heldout), 1e-300)));
      result.notes.push_back(
          "back-relaxation: to be named, it must predict the held-out samples better than one "
          "more pole and zero that does not fall back (" +
          more.structure.Describe() + ": " + Mm(more_order_heldout_mm) + ")");
    } catch (const InputError& e) {
      // Every fit of one more pole and zero fell back (or failed): under the prior the
      // baseline is the best model of its kind, and the bar is the baseline's.
      more_order_heldout_mm =
          RmsOver(Residual(rec.deflection_mm, result.baseline_mm), data.heldout);
      more_order_heldout_lr = 0.0;
      result.notes.push_back(
          std::string("back-relaxation: no model of one more pole and zero that does not fall "
                      "back (") +
          e.what() + "): it must predict the held-out samples better than the baseline");
    }
  }

  // Step-timing nuisance (Data::edges_*): one regressor per sample where the voltage
  // steps, the baseline's response to the previous sample's voltage moving halfway to the
  // new one. Continuous inputs (more than one step per 50 samples) get none.
  void StepTimingNuisance() {
    const TsModel& baseline = result.baseline_model;
    {
      const double step_V = std::max(5.0 * data.levels.tolerance_V, 0.05 * data.max_abs_V);
      std::vector<size_t> edges;
      for (size_t k = 1; k < n; ++k)
        if (std::abs(rec.voltage_V[k] - rec.voltage_V[k - 1]) > step_V &&
            std::find(data.starts.begin(), data.starts.end(), k) == data.starts.end())
          edges.push_back(k);
      // An identified baseline has none: it is refitted with every effect on these samples,
      // its dead time placed within a sample, and regressors with free coefficients would
      // let the step timing absorb slow trends in the training samples that the held-out
      // samples then lack (measured: 16 of 24 effects named without them, 9 with).
      // At most kMaxTimedSteps of them (memory: n of them per sample); a recording with more
      // steps is treated as continuous.
      if (trusted_model && !edges.empty() && edges.size() <= std::min(n / 50, kMaxTimedSteps)) {
        Eigen::MatrixXd g(static_cast<long>(n), static_cast<long>(edges.size()));
        for (size_t e = 0; e < edges.size(); ++e) {
          std::vector<double> u = rec.voltage_V;
          u[edges[e] - 1] += 0.5 * (u[edges[e]] - u[edges[e] - 1]);
          const std::vector<double> y = data.SimulateFromRest(baseline, u);
          for (size_t k = 0; k < n; ++k)
            g(static_cast<long>(k), static_cast<long>(e)) = y[k] - result.baseline_mm[k];
        }
        auto basis = [&](const std::vector<size_t>& index) {
          Eigen::MatrixXd rows(static_cast<long>(index.size()), g.cols());
          for (size_t i = 0; i < index.size(); ++i)
            rows.row(static_cast<long>(i)) = g.row(static_cast<long>(index[i]));
          Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(rows);
          qr.setThreshold(1e-6);
          const long rank = qr.rank();
          Eigen::MatrixXd q = qr.householderQ() * Eigen::MatrixXd::Identity(rows.rows(), rank);
          return q;
        };
        data.edges_train = basis(data.train);
      }
    }
  }

  // The model every candidate is tested against. An identified baseline is refitted here
  // as it will be with each effect (its rules' coefficients, from the identified values):
  // a candidate's gain is then the effect's, not that of one more refit of the baseline
  // (which can lower the held-out error by itself and carry a bystander effect with it).
  FitResult Reference() const {
    const TsModel& baseline = result.baseline_model;
    FitProblem reference_problem;
    reference_problem.fixed = Augmented{&baseline, {}, nullptr};
    if (!trusted_model) {
      reference_problem.refit_from = std::make_shared<const TsModel>(baseline);
      reference_problem.specs = CoefficientSpecs(baseline);
    }
    return FitParameters(data, reference_problem, &result.baseline_mm);
  }

  // 3. Locate: the baseline's fit figures and its residual by operating condition.
  void Localise() {
    const TsModel& baseline = result.baseline_model;
    const std::vector<double> r0 = Residual(rec.deflection_mm, result.baseline_mm);
    {
      std::vector<double> measured, predicted, input;
      for (size_t k : data.train) {
        measured.push_back(rec.deflection_mm[k]);
        predicted.push_back(result.baseline_mm[k]);
        input.push_back(rec.voltage_V[k]);
      }
      result.localisation.baseline_fit = FitFiguresOf(measured, predicted, input);
      result.baseline_fit_percent = result.localisation.baseline_fit.fit_percent;
      result.baseline_rmse_mm = result.localisation.baseline_fit.rmse_mm;
    }
    result.baseline_heldout_rmse_mm = RmsOver(r0, data.heldout);
    double dead_time = 0.0;
    for (const LocalModel& rule : baseline.rules) dead_time = std::max(dead_time, rule.tf.delay_s);
    result.localisation.groups = GroupResiduals(data, r0, result.baseline_mm, dead_time + 10.0);
  }

  // The candidates the recording can show (the others are reported, not tried), and the
  // level of every test (Bonferroni over them).
  void Candidates() {
    for (EffectKind kind : AllEffects()) {
      if (kind == EffectKind::kCreep) continue;  // fitted together with back-relaxation
      std::string reason;
      if (Applicable(kind, data, &reason)) {
        kinds.push_back(kind);
      } else {
        CandidateReport report;
        report.kind = kind;
        report.name = EffectName(kind);
        report.reason = "not tried: " + reason;
        result.candidates.push_back(std::move(report));
      }
    }
    const double tests = static_cast<double>(kinds.size() + 1);
    test_level = 1.0 - options.false_alarm_rate / tests;
    n_train = static_cast<double>(data.train.size());
  }

  // Every candidate not chosen yet (from round 1 on: only those claimed on their own)
  // fitted on top of the current model.
  std::vector<std::tuple<EffectKind, FitResult>> FitCandidates(int round) const {
    const TsModel& baseline = result.baseline_model;
    const bool refit_baseline = !trusted_model;
    std::vector<std::tuple<EffectKind, FitResult>> fitted;
    for (EffectKind kind : kinds) {
      if (std::find(chosen.begin(), chosen.end(), kind) != chosen.end()) continue;
      if (round > 0) {
        // Only effects that stood on their own against the baseline are combined.
        bool was_claimed = false;
        for (const CandidateReport& c : round_reports)
          was_claimed |= c.claimed && (c.kind == kind || (kind == EffectKind::kBackRelaxation &&
                                                          c.kind == EffectKind::kCreep));
        if (!was_claimed) continue;
      }
      // Back-relaxation and creep share one model with opposite signs: fit both, keep
      // the better.
      std::vector<EffectKind> variants = {kind};
      if (kind == EffectKind::kBackRelaxation) variants.push_back(EffectKind::kCreep);
      FitResult fit;
      EffectKind fitted_kind = kind;
      for (EffectKind variant : variants) {
        FitProblem problem;
        problem.fixed = current.model;
        // Without a trusted model, the identified baseline is refitted with the effects:
        // a free fit may have bent itself towards the effect, and the effect is only
        // tested fairly against the best baseline that has it.
        problem.fixed.refit = nullptr;
        if (refit_baseline) {
          problem.refit_from =
              current.model.refit ? current.model.refit : std::make_shared<const TsModel>(baseline);
          problem.specs = CoefficientSpecs(*problem.refit_from);
        }
        // Effects chosen so far are refitted together with the new one.
        problem.fixed.effects.clear();
        for (const Effect& e : current.model.effects) {
          problem.kinds.push_back(e.kind);
          std::vector<ParameterSpec> specs = SpecsFor(e.kind, data);
          for (size_t j = 0; j < specs.size(); ++j) specs[j].starts = {e.params[j]};
          problem.specs.insert(problem.specs.end(), specs.begin(), specs.end());
        }
        problem.kinds.push_back(variant);
        const std::vector<ParameterSpec> specs = SpecsFor(variant, data);
        problem.specs.insert(problem.specs.end(), specs.begin(), specs.end());
        if (problem.refit_from) {
          // The effects' starting values from a fit with the baseline held (cheap: one
          // simulation per evaluation at most), then everything together from there.
          FitProblem held = problem;
          held.refit_from = nullptr;
          held.fixed.refit = current.model.refit;
          held.specs.erase(
              held.specs.begin(),
              held.specs.begin() + static_cast<long>(CoefficientSpecs(baseline).size()));
          FitResult start =
              FitParameters(data, held, current.model.refit ? nullptr : &result.baseline_mm);
          // The joint refit follows whether or not the effect shows with the baseline
          // held: fitted alone, the baseline has already bent towards the effect (a smooth
          // rule's gain, a slow mode), so it need not show (gated on that, 12 of 24
          // effects were named rather than 16).
          const size_t coefficients = CoefficientSpecs(baseline).size();
          for (size_t j = 0; j < start.theta.size(); ++j)
            problem.specs[coefficients + j].starts = {start.theta[j]};
        }
        FitResult f = FitParameters(data, problem, &result.baseline_mm);
        if (f.train_sse < fit.train_sse) {
          fit = std::move(f);
          fitted_kind = variant;
        }
      }
      fitted.emplace_back(fitted_kind, std::move(fit));
    }
    return fitted;
  }

  // The model to beat. A refitted baseline is a local optimum: a candidate's refit can
  // land in a better one, and its gain would then be the optimiser's, not the effect's.
  // So each candidate's refit without its effect is a model to beat too, and the best of
  // them on the training samples becomes the reference (and what the next round builds
  // on). (A dozen refitted coefficients, raw polynomial ones, are far from convex.)
  void BeatTheRefits(const std::vector<std::tuple<EffectKind, FitResult>>& fitted) {
    if (!trusted_model) {
      for (const auto& [fitted_kind, fit] : fitted) {
        FitResult without;
        without.model = fit.model;
        without.model.effects.pop_back();
        without.prediction = Predict(data, without.model);
        without.train_sse = SumSquares(NuisanceFreeResidual(data, without.prediction), data.train);
        if (without.train_sse < current.train_sse) current = std::move(without);
      }
    }
  }

  // Why a candidate that passed every test of the evidence is not a named effect ("" if
  // it is one). With a trusted model, the 95 % interval of how much of it there is must
  // exclude none (SizeDetermined). Without one, the likelihood ratio against the refitted
  // baseline was the profile test of that, and the effect must also explain at least
  // DiagnoseOptions::min_share_of_misfit of what the model misses on the held-out samples
  // beyond the noise: next to a misfit many times its size, an effect's small gain may be
  // that misfit taking its shape (on a HASEL recording whose baseline misses by 30 times
  // the noise, a "drift" whose every parameter's interval included 0 explained 7 %).
  std::string Undetermined(const FitResult& fit, const std::vector<double>& current_r,
                           const CandidateReport& report) const {
    std::string why;
    if (trusted_model) {
      std::string size;
      if (!SizeDetermined(fit.model.effects.back(), fit.covariance, fit.null_space, data.duration_s,
                          data.abs_levels_V.empty() ? data.max_abs_V : data.abs_levels_V.back(),
                          &size))
        why = "its size is not determined (" + size + ")";
      return why;
    }
    const double before_mm = RmsOver(current_r, data.heldout);
    const double misfit = before_mm * before_mm - data.noise_mm * data.noise_mm;
    const double gained = before_mm * before_mm - report.heldout_rmse_mm * report.heldout_rmse_mm;
    if (misfit > 0.0 && gained < options.min_share_of_misfit * misfit)
      why = Format("it explains %.0f %% of the held-out misfit beyond the noise",
                   100.0 * gained / misfit) +
            Format(" (%.0f %% needed)", 100.0 * options.min_share_of_misfit);
    return why;
  }

  // 5. The tests of one fitted candidate against the current model: claimed, or why not.
  // A candidate that passes all but the size test is also an unexplained misfit.
  CandidateReport Judge(EffectKind fitted_kind, const FitResult& fit, int round) {
    const std::vector<double> current_r = Residual(rec.deflection_mm, current.prediction);
    const double sse0 = current.train_sse;
    const std::vector<double> current_w = NuisanceFreeResidual(data, current.prediction);
    const double sse0_h = SumSquares(current_w, data.heldout);
    CandidateReport report;
    report.kind = fitted_kind;
    report.name = EffectName(fitted_kind);
    const std::vector<double> r1 = Residual(rec.deflection_mm, fit.prediction);
    const Effect& added = fit.model.effects.back();
    const size_t offset = fit.theta.size() - added.params.size();
    for (size_t j = 0; j < added.params.size(); ++j)
      report.params.push_back({EffectParameterNames(fitted_kind)[j], added.params[j],
                               fit.half_width.empty() ? kInf : fit.half_width[offset + j]});
    report.train_rmse_mm = std::sqrt(fit.train_sse / n_train);
    report.heldout_rmse_mm = RmsOver(r1, data.heldout);
    const std::vector<double> w1 = NuisanceFreeResidual(data, fit.prediction);
    report.effective_samples = EffectiveSamples(w1, data.train);
    const int k = static_cast<int>(added.params.size());
    report.likelihood_ratio =
        report.effective_samples * std::log(sse0 / std::max(fit.train_sse, 1e-300));
    const double sse1_h = SumSquares(w1, data.heldout);
    const double n_eff_h = EffectiveSamples(w1, data.heldout);
    report.heldout_likelihood_ratio = n_eff_h * std::log(sse0_h / std::max(sse1_h, 1e-300));
    report.bic = report.effective_samples * std::log(fit.train_sse / n_train) +
                 static_cast<double>(fit.theta.size()) * std::log(report.effective_samples);
    // What it adds, over the samples it touches.
    const std::vector<double> delta = WhatTheLastEffectAdds(data, fit);
    double peak = 0.0;
    for (double d : delta) peak = std::max(peak, std::abs(d));
    double sum = 0.0;
    size_t touched = 0;
    for (double d : delta)
      if (std::abs(d) > 0.05 * peak) {
        sum += d * d;
        ++touched;
      }
    report.effect_rms_mm = touched ? std::sqrt(sum / static_cast<double>(touched)) : 0.0;
    const double lr_threshold = ChiSquareQuantile(test_level, k);
    const double heldout_threshold = ChiSquareQuantile(test_level, 1);
    // Without a trusted model the held-out samples also test the identified baseline's
    // extrapolation: a refit that moves it there without explaining the fitted samples
    // is a better baseline, not an effect. The training evidence must then stand alone
    // (a clean 2-4-6-8 V staircase was flagged "creep" on held-out evidence alone:
    // likelihood ratio 5.8 in training, 295 held out).
    const double evidence = report.likelihood_ratio +
                            (trusted_model ? std::max(report.heldout_likelihood_ratio, 0.0) : 0.0);
    if (!(evidence > lr_threshold)) {
      report.reason =
          Format(trusted_model ? "evidence too weak (training plus held-out likelihood ratio %.1f"
                               : "evidence too weak (training likelihood ratio %.1f",
                 evidence) +
          Format(" <= %.1f)", lr_threshold);
    } else if (!(report.heldout_likelihood_ratio > heldout_threshold)) {
      report.reason = Format("does not predict the held-out samples better (likelihood ratio %.1f",
                             report.heldout_likelihood_ratio) +
                      Format(" <= %.1f)", heldout_threshold);
    } else if (!(report.heldout_rmse_mm < RmsOver(current_r, data.heldout))) {
      report.reason = "the held-out RMSE does not fall (" + Mm(RmsOver(current_r, data.heldout)) +
                      " -> " + Mm(report.heldout_rmse_mm) + ")";
    } else if (!trusted_model &&
               (fitted_kind == EffectKind::kBackRelaxation || fitted_kind == EffectKind::kCreep) &&
               !(report.heldout_likelihood_ratio - more_order_heldout_lr > heldout_threshold)) {
      report.reason =
          "one more pole and zero that does not fall back gains as much on the held-out "
          "samples (" +
          Mm(more_order_heldout_mm) +
          Format(", likelihood ratio %.1f against the baseline; ", more_order_heldout_lr) +
          report.name + Format(" %.1f", report.heldout_likelihood_ratio) +
          Format(", at least %.1f more needed): model order, not ", heldout_threshold) +
          report.name;
    } else if (report.effect_rms_mm < options.min_effect_to_noise * data.noise_mm) {
      report.reason = "real but negligible: adds " + Mm(report.effect_rms_mm) +
                      Format(", under %.2g times the noise", options.min_effect_to_noise);
    } else if (const std::string undetermined = Undetermined(fit, current_r, report);
               !undetermined.empty()) {
      // It explains the data, but not as this effect: an unexplained misfit, where it is.
      report.reason = undetermined + ": an unexplained misfit, not a named effect";
      Misfit misfit;
      misfit.resembles = report.name;
      misfit.rms_mm = report.effect_rms_mm;
      misfit.where = WhereItActs(data, delta, report.kind);
      misfit.explanation = "a misfit of " + Mm(report.effect_rms_mm) + " that " + report.name +
                           " would explain, but " + undetermined;
      result.unexplained.push_back(std::move(misfit));
    } else {
      report.claimed = true;
      report.reason = "claimed";
    }
    report.round = round;
    return report;
  }

  // The verdict of a round among its claimed candidates, added to the findings; it
  // becomes the current model.
  void AddFinding(std::vector<std::pair<CandidateReport, FitResult>>* claimed_in) {
    auto& claimed = *claimed_in;
    const std::vector<double> current_r = Residual(rec.deflection_mm, current.prediction);
    // The verdict of this round: among the claimed candidates (each beat the baseline on
    // both sets of samples), with a trusted model the lowest information criterion on the
    // training samples. Without one, each candidate brings its own refit of a dozen
    // baseline coefficients, and the training samples alone favour the refit that bends
    // most; the held-out samples alone favour whichever candidate's refit extrapolates
    // best to the few conditions they hold (a final rest the training samples lack). The
    // one with the least squared error over every sample wins. (On the independent
    // simulator's recordings without a model: by the information criterion 33 of 48
    // effects were named together with the lab plant's; by the held-out error 16 of 24 on
    // the simulator's alone, by every sample 18, with no clean recording flagged.)
    auto score = [&](const std::pair<CandidateReport, FitResult>& c) {
      if (trusted_model) return c.first.bic;
      const std::vector<double> r = Residual(rec.deflection_mm, c.second.prediction);
      return SumSquares(r, data.train) + SumSquares(r, data.heldout);
    };
    std::vector<size_t> order(claimed.size());
    std::iota(order.begin(), order.end(), size_t{0});
    std::vector<double> scores;
    for (const auto& c : claimed) scores.push_back(score(c));
    // Stable: among equal scores, the candidate tried first wins.
    std::stable_sort(order.begin(), order.end(),
                     [&](size_t a, size_t b) { return scores[a] < scores[b]; });
    const size_t best = order.front();
    auto& [report, fit] = claimed[best];
    Finding finding;
    // The runners-up: a lab reads that the data hold them too.
    for (size_t i = 1; i < order.size(); ++i)
      finding.rivals.push_back(
          {claimed[order[i]].first.name, claimed[order[i]].first.heldout_rmse_mm});
    if (!finding.rivals.empty())
      finding.chosen_by = trusted_model ? "the lowest information criterion on the training samples"
                                        : "the least squared error over every sample";
    finding.effect = report.name;
    finding.params = report.params;
    finding.heldout_rmse_before_mm = RmsOver(current_r, data.heldout);
    finding.heldout_rmse_after_mm = report.heldout_rmse_mm;
    finding.model = fit.model.effects.back();
    const std::vector<double> delta = WhatTheLastEffectAdds(data, fit);
    finding.where = WhereItActs(data, delta, finding.model.kind);
    finding.explanation = Explain(finding.model, data, delta, finding.heldout_rmse_before_mm,
                                  finding.heldout_rmse_after_mm, model_words);
    // Parameters of earlier findings move slightly in the joint refit.
    for (size_t i = 0; i < result.findings.size(); ++i)
      result.findings[i].model = fit.model.effects[i];
    result.findings.push_back(std::move(finding));
    chosen.push_back(report.kind == EffectKind::kCreep ? EffectKind::kBackRelaxation : report.kind);
    current = std::move(fit);
  }

  // An accruing effect was fitted on the recordings' own scale (their charge, their
  // duration; Effect::scale 0). Fixed now at that value, the augmented model predicts the
  // same on these recordings and also on others and live. A degradation's charge is that
  // of the voltage reaching it: after the input effects before it.
  void FixScales() {
    std::vector<double> u = rec.voltage_V;
    for (const Effect& e : data.given)
      if (IsInputEffect(e.kind)) ApplyInputEffect(e, rec.t_s, &u);
    for (Finding& f : result.findings) {
      Effect& e = f.model;
      if (EffectScaleName(e.kind) && !(e.scale > 0)) e.scale = OwnScale(e.kind, rec.t_s, u);
      if (IsInputEffect(e.kind)) ApplyInputEffect(e, rec.t_s, &u);
    }
  }

  Diagnosis Run() {
    const TsModel& baseline = result.baseline_model;
    ReadLevels();
    HoldOut();
    Baseline();
    StepTimingNuisance();
    const FitResult reference = Reference();
    Localise();
    // 4-5. Candidates, forward selection.
    Candidates();
    current = reference;
    for (int round = 0; round < options.max_effects; ++round) {
      // Every candidate fitted first, then tested against one model.
      const std::vector<std::tuple<EffectKind, FitResult>> fitted = FitCandidates(round);
      BeatTheRefits(fitted);
      std::vector<std::pair<CandidateReport, FitResult>> claimed;
      for (const auto& [fitted_kind, fit] : fitted) {
        CandidateReport report = Judge(fitted_kind, fit, round);
        round_reports.push_back(report);
        if (report.claimed) claimed.emplace_back(std::move(report), fit);
      }
      if (claimed.empty()) break;
      AddFinding(&claimed);
    }
    for (CandidateReport& c : round_reports) result.candidates.push_back(std::move(c));
    // What the free fit absorbed, read on the baseline as refitted with the findings (an
    // effect the fit had bent towards is then modelled as itself). It is reported, never
    // named: a fall-back read off a fitted model has no held-out test and no interval.
    if (!trusted_model) {
      result.absorbed = ReadAgainstPhysics(
          current.model.refit ? *current.model.refit : result.baseline_model, data.noise_mm);
    }
    ReportWhatIsLeft();
    FixScales();
    result.verdict = result.findings.empty() ? "none" : result.findings.front().effect;
    result.augmented_mm = result.findings.empty() ? result.baseline_mm : current.prediction;
    result.augmented_baseline_model = current.model.refit ? *current.model.refit : baseline;
    if (data.Recordings() > 1) {
      result.heldout = OnRecordings(data, result.heldout);
      for (Finding& f : result.findings) f.where = OnRecordings(data, f.where);
      for (Misfit& m : result.unexplained) m.where = OnRecordings(data, m.where);
    }
    return std::move(result);
  }
};

}  // namespace

Diagnosis Diagnose(const Recording& recording, const std::optional<TsModel>& trusted_model,
                   const DiagnoseOptions& options) {
  return Diagnose(std::vector<Recording>{recording}, trusted_model, options);
}

Diagnosis Diagnose(const std::vector<Recording>& recordings,
                   const std::optional<TsModel>& trusted_model, const DiagnoseOptions& options) {
  if (!(options.heldout_blocks >= 1 && options.heldout_blocks <= 20 &&
        options.heldout_fraction > 0 && options.heldout_fraction <= 0.5 &&
        options.false_alarm_rate > 0 && options.false_alarm_rate < 1 &&
        options.min_effect_to_noise >= 0 && options.min_share_of_misfit >= 0 &&
        options.min_share_of_misfit <= 1 && options.max_effects >= 1))
    throw std::invalid_argument("diagnosis options out of range");
  Diagnoser diagnoser(recordings, trusted_model, options);
  if (diagnoser.n < 200)
    throw InputError(diagnoser.rec.source + ": " + std::to_string(diagnoser.n) +
                     " samples; diagnosis needs at least 200");
  std::string why;
  if (trusted_model && !IsValid(*trusted_model, &why)) throw std::invalid_argument("model: " + why);
  return diagnoser.Run();
}

}  // namespace flexid::model
