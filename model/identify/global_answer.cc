// The global T-S fit's answer (identify_global.h): the stages of GlobalSearch
// (global_search.h) after the structure is chosen: the refit at the full rate, the fit
// figures and residuals, the intervals, what the data cannot decide in words, and the
// choice made again on every sample when the coarse grid was blind; and the estimate's
// model file document.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "model/core/errors.h"
#include "model/core/levels.h"
#include "model/core/metrics.h"
#include "model/core/simulate.h"
#include "model/identify/global_fit.h"
#include "model/identify/global_search.h"
#include "model/identify/identify_global.h"

namespace flexid::model {
namespace global_fit {

// Chosen on the coarse grid: refitted at the full rate, the dead time rescanned there
// within a coarse sample of where the coarse fit put it (a step is seen there up to
// factor - 1 samples late, and the premise's delay jumps at every full-rate sample).
void GlobalSearch::RefitAtFullRate() {
  if (factor > 1) {
    problem = full;
    usable = full_usable;
    const Layout layout{current, problem.w_min};
    int fits = 0;
    if (!options.fixed_delay_s) {
      // The rest of the model is already close: the sum of squares alone at each dead
      // time on the fine grid places it (one simulation each, not a fit each).
      double least = kInf;
      double best_s = current_all[0];
      for (const double delay_s :
           DelayGrid(current_all[0], factor * problem.dt_s, problem.dt_s, problem.dt_s)) {
        std::vector<double> theta = current_all;
        theta[0] = std::clamp(delay_s, 0.0, problem.max_delay_s);
        const double ssr =
            OutputError(problem, layout.Model(theta.data(), problem.rest_band_V), usable);
        if (ssr < least) {
          least = ssr;
          best_s = theta[0];
        }
      }
      current_all[0] = best_s;
    }
    try {
      FitResult refined = Fit(problem, layout, usable, current_all);
      ++fits;
      const TsModel model = layout.Model(refined.theta.data(), problem.rest_band_V);
      // Held to what the selection held every fit to: plausible switching and the prior.
      if (SwitchingProblem(model, problem, knots,
                           std::sqrt(refined.ssr / static_cast<double>(refined.samples)))
              .empty() &&
          FallBackProblem(model, problem.max_fall_back).empty())
        current_all = refined.theta;
    } catch (const InputError&) {
    }
    selector->CountFits(fits);
    result.notes.push_back("structure chosen on every " + std::to_string(factor) +
                           "th sample, refitted on every sample");
  }
}

// The chosen structure's fit on every usable sample.
void GlobalSearch::FinalFit() {
  const Layout layout{current, problem.w_min};
  final_fit.theta = current_all;
  final_fit.samples = Count(usable);
  final_fit.ssr =
      OutputError(problem, layout.Model(current_all.data(), problem.rest_band_V), usable);
  result.structure = current;
  result.model = layout.Model(final_fit.theta.data(), problem.rest_band_V);
  result.model.scheduling_delay_s = final_fit.theta[0];
  result.fits = selector->fits();
  result.theta = final_fit.theta;
  const double fastest = FastestFrozenPole(result.model, current.knots_V.back());
  if (!(fastest < M_PI / problem.dt_s))
    throw InputError("the fitted model has a pole beyond the Nyquist frequency (" + Volts(fastest) +
                     " rad/s at a " + Volts(problem.dt_s) +
                     " s sample period): the data cannot support this structure");

  // Fit figures over every usable sample; the residuals (NaN where not usable).
  residual_mm.resize(problem.series.size());
  {
    std::vector<double> measured, predicted, input;
    SimulationOptions sim;
    for (size_t r = 0; r < problem.series.size(); ++r) {
      const Series& s = problem.series[r];
      const std::vector<double> yhat = SimulateUniform(result.model, problem.dt_s, s.u, sim);
      residual_mm[r].assign(s.u.size(), std::numeric_limits<double>::quiet_NaN());
      for (size_t k = 0; k < s.u.size(); ++k)
        if (usable[r][k]) {
          measured.push_back(s.y[k]);
          predicted.push_back(yhat[k]);
          input.push_back(s.u[k]);
          residual_mm[r][k] = s.y[k] - yhat[k];
        }
    }
    result.fit = FitFiguresOf(measured, predicted, input, options.correlation_lags);
  }
}

// Intervals (header).
void GlobalSearch::Intervals() {
  const Layout layout{current, problem.w_min};
  const int p = layout.Size();
  const size_t n = final_fit.samples;
  result.noise_std_mm =
      std::sqrt(final_fit.ssr /
                static_cast<double>(n > static_cast<size_t>(p) ? n - static_cast<size_t>(p) : 1));
  Eigen::MatrixXd covariance = Eigen::MatrixXd::Zero(p, p);
  std::vector<bool> determined(static_cast<size_t>(p), true);
  {
    Eigen::VectorXd r0(static_cast<Eigen::Index>(n)), r1(static_cast<Eigen::Index>(n));
    Eigen::MatrixXd jac(static_cast<Eigen::Index>(n), p);
    OutputResiduals(problem, result.model, usable, r0.data());
    for (int j = 0; j < p; ++j) {
      if (j == 0 && options.fixed_delay_s) {
        jac.col(j).setZero();
        continue;
      }
      std::vector<double> theta = final_fit.theta;
      double h = 1e-6 * std::max(1.0, std::abs(theta[static_cast<size_t>(j)]));
      // The premise's delay in samples jumps at multiples of the sample period: the
      // dead time's difference stays on the side where it does not.
      auto premise_samples = [&](double t_s) { return std::ceil(t_s / problem.dt_s - 1e-9); };
      if (j == 0 && theta[0] >= h && premise_samples(theta[0] + h) != premise_samples(theta[0]))
        h = -h;
      theta[static_cast<size_t>(j)] += h;
      OutputResiduals(problem, layout.Model(theta.data(), problem.rest_band_V), usable, r1.data());
      jac.col(j) = -(r1 - r0) / h;
    }
    const Eigen::MatrixXd jtj = jac.transpose() * jac;
    const Eigen::VectorXd scale = jtj.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
    Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(scale.asDiagonal() * jtj *
                                                         scale.asDiagonal());
    const Eigen::VectorXd lambda = eigen.eigenvalues();
    const double top = lambda.maxCoeff();
    Eigen::MatrixXd inverse = Eigen::MatrixXd::Zero(p, p);
    for (int k = 0; k < p; ++k) {
      const Eigen::VectorXd v = eigen.eigenvectors().col(k);
      if (lambda(k) > 1e-9 * top) {
        inverse += v * v.transpose() / lambda(k);
        continue;
      }
      for (int j = 0; j < p; ++j)
        if (std::abs(v(j)) > 0.3 && !(j == 0 && options.fixed_delay_s))
          determined[static_cast<size_t>(j)] = false;
    }
    covariance = result.noise_std_mm * result.noise_std_mm * scale.asDiagonal() * inverse *
                 scale.asDiagonal();
  }
  auto estimate = [&](int j, const std::string& name) {
    ParameterEstimate e{name, final_fit.theta[static_cast<size_t>(j)], 0.0};
    e.half_width_95 = 1.96 * std::sqrt(std::max(0.0, covariance(j, j)));
    return e;
  };
  result.delay_s = estimate(0, "delay_s");
  if (delay_profile_s)
    result.delay_s.half_width_95 = std::max(result.delay_s.value - delay_profile_s->first,
                                            delay_profile_s->second - result.delay_s.value);
  for (int j = 0; j < p; ++j)
    if (!determined[static_cast<size_t>(j)]) result.undetermined.push_back(layout.ParameterName(j));
  for (int r = 0; r < layout.Rules(); ++r) {
    RuleReport report;
    report.knot_V = result.model.rules[static_cast<size_t>(r)].level_V;
    report.dc_gain = estimate(1 + r, "dc_gain");
    report.poles = Poles(result.model.rules[static_cast<size_t>(r)].tf);
    result.rules.push_back(std::move(report));
  }
}

// What the data cannot decide, in words.
void GlobalSearch::Explain() {
  result.reason = raising ? std::string("not chosen")
                          : "chosen on held-out data (" +
                                std::string(problem.series.size() >= 2
                                                ? "alternate tenths of every recording in turn"
                                                : "first and second half in turn") +
                                "): " + current.Describe();
  for (const std::string& r : reasons) result.reason += "; " + r;
  if (!result.undetermined.empty()) {
    std::string names;
    for (const auto& name : result.undetermined) names += (names.empty() ? "" : ", ") + name;
    result.warnings.push_back("the data do not determine: " + names);
  }
  // An interval that reaches 0 s cannot tell the dead time from none.
  if (result.delay_s.half_width_95 >= result.delay_s.value && !options.fixed_delay_s)
    result.warnings.push_back("the dead time is not determined: " + Volts(result.delay_s.value) +
                              " +- " + Volts(result.delay_s.half_width_95) + " s");
}

// What the levels visited cannot decide: a single level, unvisited gaps where the gain
// changes, jumps larger than the data show, levels held for less than the slowest mode.
void GlobalSearch::WarnAboutLevels() {
  if (result.plateau_input && !result.levels_V.empty()) {
    std::string sources;  // the recordings, named in the warnings below
    for (const Series& series : full.series)
      sources += (sources.empty() ? "" : ", ") + series.source;
    if (result.levels_V.size() == 1)
      result.warnings.push_back(sources + ": one voltage level (" + VoltList(result.levels_V) +
                                "): the model is linear, and every other voltage is "
                                "extrapolated from it");
    const auto& k = current.knots_V;
    // Smooth rules hand over between their centres, wherever the fit put the hand-over:
    // the gain is read off the model at each visited level, and a change of gain between
    // two neighbouring visited levels is where the data do not show it, unless the change
    // is spread over the levels around it too (a gain that grows with the voltage through
    // a dense staircase is traced by its levels: over twice either neighbouring gap's
    // change, it happens within the one gap).
    if (current.membership == MembershipShape::kGaussian) {
      auto gain_at = [&](double v) {
        std::vector<double> mu;
        NormalisedMemberships(result.model, v, &mu);
        double g = 0.0;
        for (size_t r = 0; r < mu.size(); ++r) g += mu[r] * DcGain(result.model.rules[r].tf);
        return g;
      };
      const std::vector<double>& levels = result.levels_V;
      std::vector<double> gains;
      for (double v : levels) gains.push_back(gain_at(v));
      auto change = [&](size_t gap) {
        return gap + 1 < gains.size() ? std::abs(gains[gap + 1] - gains[gap]) : 0.0;
      };
      for (size_t i = 0; i + 1 < levels.size(); ++i) {
        const double a = levels[i], b = levels[i + 1], ga = gains[i], gb = gains[i + 1];
        const double here = change(i);
        const double around = std::max(i > 0 ? change(i - 1) : 0.0, change(i + 1));
        if (here > 0.1 * std::max(std::abs(ga), std::abs(gb)) && here > 2.0 * around)
          result.warnings.push_back(
              "between " + Volts(a) + " and " + Volts(b) + " V the DC gain changes from " +
              Volts(ga) + " to " + Volts(gb) +
              " mm/V and no level between them was visited: where the rules hand over is not "
              "in the data");
      }
    }
    for (size_t i = 0; i + 1 < k.size() && current.membership != MembershipShape::kGaussian; ++i) {
      const bool seen = std::any_of(result.levels_V.begin(), result.levels_V.end(), [&](double v) {
        return v > k[i] + merged.tolerance_V && v < k[i + 1] - merged.tolerance_V;
      });
      // Unvisited gaps matter where the gain changes across them: where in the gap it
      // changes is not in the data.
      const double ka = final_fit.theta[1 + i], kb = final_fit.theta[2 + i];
      if (!seen && std::abs(kb - ka) > 0.1 * std::max(std::abs(ka), std::abs(kb)))
        result.warnings.push_back(
            "between " + Volts(k[i]) + " and " + Volts(k[i + 1]) + " V the DC gain changes from " +
            Volts(ka) + " to " + Volts(kb) +
            " mm/V and no level between them was visited: where the change happens is not in "
            "the data (the model interpolates linearly)");
    }
    // Jumps: the largest change of |u| from one plateau to the next (a recording starts
    // at rest). A staircase steps only between neighbouring levels; how the model
    // responds to a jump across several levels, and so across rules, is then not in the
    // data, however well it fits them.
    double largest_step_V = 0.0;
    for (size_t i = 0; i < merged.plateaus.size(); ++i) {
      const Plateau& b = merged.plateaus[i];
      const bool first = i == 0 || merged.plateaus[i - 1].recording != b.recording;
      const double before_V = first ? 0.0 : std::abs(merged.plateaus[i - 1].voltage_V);
      largest_step_V = std::max(largest_step_V, std::abs(std::abs(b.voltage_V) - before_V));
    }
    const double top_V = result.levels_V.back();
    if (current.knots_V.size() > 1 && largest_step_V < 0.5 * top_V)
      result.warnings.push_back(
          sources + ": |u| changes by at most " + Volts(largest_step_V) +
          " V from one level to the next, over levels up to " + Volts(top_V) +
          " V: the response to larger jumps, across rules, is not in the data (the model "
          "extrapolates it)");
    std::string levels_text = "levels visited: " + VoltList(result.levels_V);
    if (result.levels_V.front() > 0.25 * result.levels_V.back())
      levels_text += "; below " + Volts(result.levels_V.front()) + " V the model holds the " +
                     Volts(result.levels_V.front()) + " V behaviour unverified";
    result.notes.push_back(levels_text);
    // Excitation: time spent at each level against the slowest time constant.
    double slowest_s = 0.0;
    for (const auto& rule : result.model.rules)
      for (const auto& pole : Poles(rule.tf)) slowest_s = std::max(slowest_s, -1.0 / pole.real());
    for (const VoltageLevel& level : merged.levels) {
      double held_s = 0.0;
      std::string where;  // the recordings that hold the level
      for (const Plateau& plateau : merged.plateaus)
        if (plateau.level >= 0 &&
            std::abs(merged.levels[static_cast<size_t>(plateau.level)].level_V - level.level_V) <
                1e-12) {
          held_s += plateau.t_end_s - plateau.t_start_s;
          const std::string& source = full.series[plateau.recording].source;
          if (where.find(source) == std::string::npos)
            where += (where.empty() ? "" : ", ") + source;
        }
      if (held_s < slowest_s)
        result.warnings.push_back(where + ": level " + Volts(level.level_V) + " V is held for " +
                                  Volts(held_s) +
                                  " s in all, less than the slowest time constant (" +
                                  Volts(slowest_s) + " s): its gain there is extrapolated");
    }
  }
}

// The coarse grid is blind above its Nyquist frequency, and only there: a misfit below
// it was seen by the selection, which chose this structure with it. So the structure is
// chosen again on every sample when the residual above the coarse band (what is left
// after its moving mean over `factor` samples) exceeds, by half, what the noise (the
// white part of the data's second differences) leaves there; and then that choice is
// the answer. The coarse grid is a shortcut valid only where it sees everything: the
// in-sample fits of two structures chosen under different conditions do not compare
// (on a HASEL staircase the one kept that way flipped between 3p2z and 4p3z with
// numerical detail).
std::optional<GlobalEstimate> GlobalSearch::ChooseAgainOnEverySample() {
  if (factor > 1) {
    const size_t window = static_cast<size_t>(factor) | 1;  // odd, centred
    double squares = 0.0, above = 0.0;
    size_t count = 0, windows = 0;
    for (size_t r = 0; r < full.series.size(); ++r) {
      const std::vector<double>& y = full.series[r].y;
      const std::vector<double>& e = residual_mm[r];
      for (size_t k = 2; k < y.size(); ++k)
        if (full_usable[r][k] && full_usable[r][k - 1] && full_usable[r][k - 2]) {
          const double d2 = y[k] - 2 * y[k - 1] + y[k - 2];
          squares += d2 * d2;
          ++count;
        }
      for (size_t k = window / 2; k + window / 2 < e.size(); ++k) {
        double mean = 0.0;
        for (size_t i = k - window / 2; i <= k + window / 2; ++i) mean += e[i];
        mean /= static_cast<double>(window);
        if (std::isnan(mean)) continue;  // a sample in the window is not usable
        above += (e[k] - mean) * (e[k] - mean);
        ++windows;
      }
    }
    const double noise_mm =
        count > 0 ? std::sqrt(squares / (6.0 * static_cast<double>(count))) : 0.0;
    const double above_mm = windows > 0 ? std::sqrt(above / static_cast<double>(windows)) : 0.0;
    const double white_above_mm = noise_mm * std::sqrt(1.0 - 1.0 / static_cast<double>(window));
    // The same test fails when the coarse grid's model does not carry over to the full
    // rate: its error on every sample more than twice what it held out on the coarse one.
    const bool carried_over = result.fit.rmse_mm <= 2.0 * result.held_out_rmse_mm;
    if (above_mm > 1.5 * white_above_mm || !carried_over) {
      GlobalIdentifyOptions every = options;
      every.max_selection_factor = 1;
      GlobalEstimate fine = IdentifyGlobalTs(recordings, every);
      fine.notes.push_back(
          "structure chosen on every sample: chosen on every " + std::to_string(factor) +
          (carried_over
               ? "th, the residual above that grid's band stayed at " + Volts(above_mm) + " mm, " +
                     Volts(above_mm / white_above_mm) + " times the noise's share there"
               : "th, its model's error on every sample was " + Volts(result.fit.rmse_mm) +
                     " mm, against " + Volts(result.held_out_rmse_mm) + " mm held out"));
      fine.fits += result.fits;
      return fine;
    }
  }
  return std::nullopt;
}

}  // namespace global_fit

using namespace global_fit;  // NOLINT(google-build-using-namespace): the fit's own parts

ModelDocument ToModelDocument(const GlobalEstimate& e) {
  auto Number = [](double value) {
    return std::isfinite(value) ? nlohmann::json(value) : nlohmann::json(nullptr);
  };
  ModelDocument doc;
  if (e.model.rules.size() == 1) {
    doc = FromTransferFunction(e.model.rules.front().tf);
  } else {
    doc = FromTsModel(e.model);
    for (size_t i = 0; i < e.rules.size(); ++i)
      doc.local_extra[i] = {{"dc_gain",
                             {{"value", e.rules[i].dc_gain.value},
                              {"half_width_95", Number(e.rules[i].dc_gain.half_width_95)}}}};
  }
  nlohmann::json structure = {{"method", "global"},
                              {"num_zeros", e.structure.num_zeros},
                              {"num_poles", e.structure.num_poles},
                              {"premise", SchedulingVariableName(e.structure.premise)},
                              {"knots_V", e.structure.knots_V},
                              {"membership", MembershipShapeName(e.structure.membership)},
                              {"reason", e.reason}};
  doc.extra["structure"] = structure;
  doc.extra["fit"] = FitFiguresToJson(e.fit);
  doc.extra["held_out_rmse_mm"] = Number(e.held_out_rmse_mm);
  doc.extra["noise_std_mm"] = e.noise_std_mm;
  doc.extra["dead_time_s"] = {{"value", e.delay_s.value},
                              {"half_width_95", Number(e.delay_s.half_width_95)}};
  doc.extra["levels_V"] = e.levels_V;
  // One rule: the level it was identified at, where `flexid models diff` pairs models.
  if (e.rules.size() == 1 && e.levels_V.size() == 1) doc.extra["level_V"] = e.levels_V.front();
  if (e.rules.size() == 1)
    doc.extra["dc_gain"] = {{"value", e.rules[0].dc_gain.value},
                            {"half_width_95", Number(e.rules[0].dc_gain.half_width_95)}};
  if (!e.undetermined.empty()) doc.extra["undetermined"] = e.undetermined;
  if (!e.warnings.empty()) doc.extra["warnings"] = e.warnings;
  if (!e.notes.empty()) doc.extra["notes"] = e.notes;
  return doc;
}

}  // namespace flexid::model
