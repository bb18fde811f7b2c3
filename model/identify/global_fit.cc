// The global T-S fit itself (identify_global.h, "Fit"): the output error of a model on the
// fitted samples, the bounded secant Levenberg-Marquardt fit of a layout's parameters,
// fits over a grid of dead times, the coarse grid the structure is chosen on, and the
// plausibility checks a fitted model must pass (switching, fall-back, frozen poles).
#include "model/identify/global_fit.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "model/core/errors.h"
#include "model/core/secant_lm.h"
#include "model/core/simulate.h"

namespace flexid::model::global_fit {

size_t Count(const Mask& mask) {
  size_t n = 0;
  for (const auto& m : mask) n += static_cast<size_t>(std::count(m.begin(), m.end(), 1));
  return n;
}

// ---------------------------------------------------------------------------------------
// Simulation and the output-error fit
// ---------------------------------------------------------------------------------------

namespace {

// Calls visit(e) with the output error e of every masked sample, in series order.
template <typename Visit>
void VisitOutputErrors(const Problem& problem, const TsModel& model, const Mask& mask,
                       Visit&& visit) {
  SimulationOptions options;
  options.scheduling_resolution_V = problem.resolution_V;
  for (size_t r = 0; r < problem.series.size(); ++r) {
    const auto& m = mask[r];
    const auto last = std::find(m.rbegin(), m.rend(), 1);
    if (last == m.rend()) continue;
    const size_t end = static_cast<size_t>(m.rend() - last);
    const Series& s = problem.series[r];
    const std::vector<double> yhat =
        SimulateUniform(model, problem.dt_s, std::span(s.u).first(end), options);
    for (size_t k = 0; k < end; ++k)
      if (m[k]) visit(s.y[k] - yhat[k]);
  }
}

}  // namespace

double OutputError(const Problem& problem, const TsModel& model, const Mask& mask) {
  double ssr = 0.0;
  VisitOutputErrors(problem, model, mask, [&ssr](double e) { ssr += e * e; });
  return ssr;
}

// The fit's residual function (the solver forms the sum of squares itself).
void OutputResiduals(const Problem& problem, const TsModel& model, const Mask& mask,
                     double* residuals) {
  size_t i = 0;
  VisitOutputErrors(problem, model, mask, [residuals, &i](double e) { residuals[i++] = e; });
}

FitResult Fit(const Problem& problem, const Layout& layout, const Mask& mask,
              std::vector<double> theta) {
  FitResult result;
  result.samples = Count(mask);
  const int p = layout.Size();
  if (result.samples < static_cast<size_t>(2 * p))
    throw InputError("too few samples (" + std::to_string(result.samples) + ") for " +
                     std::to_string(p) + " parameters");
  std::vector<double> lo, hi;
  layout.Bounds(problem, &lo, &hi);
  if (problem.fixed_delay_s) lo[0] = hi[0] = *problem.fixed_delay_s;
  for (int j = 0; j < p; ++j)
    theta[static_cast<size_t>(j)] = std::clamp(
        theta[static_cast<size_t>(j)], lo[static_cast<size_t>(j)], hi[static_cast<size_t>(j)]);
  // The output error at a trial point; a point the simulator refuses is not admissible
  // (the solver then shrinks the step).
  auto residuals = [&](const double* at, double* out) {
    try {
      OutputResiduals(problem, layout.Model(at, problem.rest_band_V), mask, out);
      return true;
    } catch (const std::invalid_argument&) {
      return false;
    }
  };
  SecantLmOptions options;
  options.max_iterations = problem.max_iterations;
  SecantLmResult solved;
  try {
    solved = SolveSecantLm(residuals, result.samples, std::move(theta), lo, hi, options);
  } catch (const std::invalid_argument& e) {
    throw InputError(std::string("the fit could not start: ") + e.what());
  }
  result.theta = std::move(solved.x);
  result.ssr = solved.sum_of_squares;
  result.iterations = solved.iterations;
  if (!std::isfinite(result.ssr)) throw InputError("the fit diverged");
  return result;
}

std::vector<FitResult> FitsOverDelays(const Problem& problem, const Layout& layout,
                                      const Mask& mask, const std::vector<double>& start,
                                      const std::vector<double>& delays_s, int iterations,
                                      int* fits) {
  Problem fixed = problem;
  fixed.max_iterations = std::min(problem.max_iterations, iterations);
  std::vector<FitResult> out(delays_s.size());
  if (delays_s.empty()) return out;
  std::vector<size_t> order(delays_s.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(),
            [&](size_t a, size_t b) { return delays_s[a] < delays_s[b]; });
  size_t nearest = 0;
  for (size_t i = 1; i < order.size(); ++i)
    if (std::abs(delays_s[order[i]] - start[0]) < std::abs(delays_s[order[nearest]] - start[0]))
      nearest = i;
  auto walk = [&](long from, long to, long step) {
    std::vector<double> from_theta = start;
    for (long i = from; i != to; i += step) {
      const size_t index = order[static_cast<size_t>(i)];
      fixed.fixed_delay_s = std::clamp(delays_s[index], 0.0, problem.max_delay_s);
      std::vector<double> theta = from_theta;
      theta[0] = *fixed.fixed_delay_s;
      try {
        out[index] = Fit(fixed, layout, mask, std::move(theta));
        ++*fits;
        from_theta = out[index].theta;
      } catch (const InputError&) {
      }
    }
  };
  walk(static_cast<long>(nearest), static_cast<long>(order.size()), 1);
  walk(static_cast<long>(nearest) - 1, -1, -1);
  return out;
}

FitResult BestOverDelays(const Problem& problem, const Layout& layout, const Mask& mask,
                         const std::vector<double>& start, const std::vector<double>& delays_s,
                         int iterations, int* fits) {
  FitResult best;
  for (FitResult& fit : FitsOverDelays(problem, layout, mask, start, delays_s, iterations, fits))
    if (fit.ssr < best.ssr) best = std::move(fit);
  return best;
}

std::vector<double> DelayGrid(double centre_s, double half_width_s, double step_s, double dt_s) {
  std::vector<double> grid;
  const double base = (std::floor(centre_s / dt_s) + 0.5) * dt_s;
  const int count = static_cast<int>(std::ceil(half_width_s / step_s - 1e-9));
  for (int m = -count; m <= count; ++m)
    if (m != 0 || std::abs(base - centre_s) > 1e-9) grid.push_back(base + m * step_s);
  return grid;
}

void Decimate(int factor, Problem* problem, Mask* mask) {
  if (factor <= 1) return;
  auto keep = [factor](auto& v) {
    size_t j = 0;
    for (size_t k = 0; k < v.size(); k += static_cast<size_t>(factor)) v[j++] = v[k];
    v.resize(j);
  };
  for (Series& s : problem->series) {
    // The input over each coarse interval is the mean of the samples it holds, so that a
    // step between two kept samples acts (to first order in the coarse period over the
    // time constants) when it happened rather than at the next kept sample.
    for (size_t k = 0; k < s.u.size(); k += static_cast<size_t>(factor)) {
      const size_t end = std::min(s.u.size(), k + static_cast<size_t>(factor));
      s.u[k] = std::accumulate(s.u.begin() + static_cast<long>(k),
                               s.u.begin() + static_cast<long>(end), 0.0) /
               static_cast<double>(end - k);
    }
    keep(s.t_s);
    keep(s.u);
    keep(s.y);
  }
  for (auto& m : *mask) keep(m);
  problem->dt_s *= factor;
  problem->w_max = 0.8 * M_PI / problem->dt_s;
}

// ---------------------------------------------------------------------------------------
// Plausibility
// ---------------------------------------------------------------------------------------

std::string SwitchingProblem(const TsModel& model, const Problem& problem,
                             std::vector<double> levels_V, double noise_mm) {
  // Parallel rules do not switch: each is a stable linear system driven by a bounded
  // share of the voltage, and a jump moves shares from one to the other.
  if (model.realisation == TsRealisation::kParallel) return "";
  levels_V.push_back(0.0);
  std::sort(levels_V.begin(), levels_V.end());
  levels_V.erase(std::unique(levels_V.begin(), levels_V.end()), levels_V.end());
  if (levels_V.size() < 2 || model.rules.size() < 2) return "";
  std::vector<double> gain;  // frozen DC gain at each level, mm/V
  double slowest_s = 0.0;
  for (double v : levels_V) {
    const TransferFunction frozen = FrozenModelAt(model, v);
    gain.push_back(DcGain(frozen));
    for (const auto& pole : Poles(frozen))
      if (pole.real() < 0.0) slowest_s = std::max(slowest_s, -1.0 / pole.real());
  }
  const size_t n =
      static_cast<size_t>(std::clamp(std::ceil(5.0 * slowest_s / problem.dt_s), 100.0, 20000.0));
  SimulationOptions options;
  options.start_in_steady_state = true;
  options.scheduling_resolution_V = problem.resolution_V;
  auto excursion = [](const std::vector<double>& y, double from, double to) {
    const auto [lo, hi] = std::minmax_element(y.begin(), y.end());
    return std::max({0.0, *hi - std::max(from, to), std::min(from, to) - *lo});
  };
  // A frozen model is linear: its swing on a step, as a fraction of the step, is the
  // same from every start. One unit step per level.
  std::vector<double> frozen_swing(levels_V.size());
  for (size_t j = 0; j < levels_V.size(); ++j) {
    std::vector<double> unit(n, 1.0);
    unit[0] = 0.0;
    const TsModel alone =
        MakeTsModelOnLevels({{levels_V[j], FrozenModelAt(model, levels_V[j]), {}}});
    frozen_swing[j] = excursion(SimulateUniform(alone, problem.dt_s, unit, options), 0.0, gain[j]) /
                      std::max(std::abs(gain[j]), 1e-12);
  }
  double worst = 0.0;
  std::string text;
  for (size_t i = 0; i < levels_V.size(); ++i)
    for (size_t j = 0; j < levels_V.size(); ++j) {
      if (i == j) continue;
      const double a = levels_V[i], b = levels_V[j];
      std::vector<double> u(n, b);
      u[0] = a;
      const double ya = gain[i] * a, yb = gain[j] * b;
      const double allowed = (frozen_swing[j] + 0.25) * std::abs(yb - ya) + 3.0 * noise_mm;
      const double swing = excursion(SimulateUniform(model, problem.dt_s, u, options), ya, yb);
      if (swing > allowed && swing - allowed > worst) {
        worst = swing - allowed;
        text = "a jump from " + Volts(a) + " to " + Volts(b) + " V swings " + Volts(swing) +
               " mm beyond its start and end values (" + Volts(ya) + " and " + Volts(yb) +
               " mm), where its frozen models allow " + Volts(allowed) + " mm";
      }
    }
  return text;
}

std::string FallBackProblem(const TsModel& model, double limit) {
  if (!(limit > 0.0)) return "";
  for (const LocalModel& rule : model.rules) {
    const FallBack fall = StepFallBack(rule.tf);
    if (fall.share > limit)
      return "its model at " + Volts(rule.level_V) + " V falls back by " +
             Volts(100.0 * fall.share) + " % of its final value (" + Volts(fall.tau_s) +
             " s), which the physics chain's step response cannot";
  }
  return "";
}

double FastestFrozenPole(const TsModel& model, double top_V) {
  double fastest = 0.0;
  // Parallel rules: every frozen model's poles are those of the rules that fire (the sum
  // of eight rules' transfer functions, as one polynomial, is too ill-conditioned to root).
  if (model.realisation == TsRealisation::kParallel) {
    for (const LocalModel& rule : model.rules)
      for (const auto& p : Poles(rule.tf)) {
        if (!(p.real() < 0.0)) return kInf;
        fastest = std::max(fastest, std::abs(p));
      }
    return fastest;
  }
  for (int i = 0; i <= 200; ++i) {
    const double z = 1.25 * top_V * i / 200.0;
    for (const auto& p : Poles(FrozenModelAt(model, z))) {
      if (!(p.real() < 0.0)) return kInf;
      fastest = std::max(fastest, std::abs(p));
    }
  }
  return fastest;
}

}  // namespace flexid::model::global_fit
