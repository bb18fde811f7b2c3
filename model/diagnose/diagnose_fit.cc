#include "model/diagnose/diagnose_fit.h"

#include <ceres/ceres.h>

#include <algorithm>
#include <cmath>
#include <numeric>

#include "model/core/errors.h"
#include "model/core/secant_lm.h"

namespace flexid::model::diagnosis {

// -----------------------------------------------------------------------------------------
// Statistics
// -----------------------------------------------------------------------------------------

double SumSquares(std::span<const double> r, const std::vector<size_t>& index) {
  double sum = 0.0;
  for (size_t k : index) sum += r[k] * r[k];
  return sum;
}

double EffectiveSamples(std::span<const double> r, const std::vector<size_t>& index) {
  double mean = 0.0;
  for (size_t k : index) mean += r[k];
  mean /= static_cast<double>(std::max<size_t>(index.size(), 1));
  double c0 = 0.0, c1 = 0.0;
  for (size_t i = 0; i < index.size(); ++i) {
    const double a = r[index[i]] - mean;
    c0 += a * a;
    if (i + 1 < index.size() && index[i + 1] == index[i] + 1) c1 += a * (r[index[i + 1]] - mean);
  }
  const double rho = c0 > 0 ? std::clamp(c1 / c0, 0.0, 0.995) : 0.0;
  return static_cast<double>(index.size()) * (1.0 - rho) / (1.0 + rho);
}

std::vector<double> Residual(std::span<const double> y, std::span<const double> yhat) {
  std::vector<double> r(y.size());
  for (size_t k = 0; k < y.size(); ++k) r[k] = y[k] - yhat[k];
  return r;
}

double RmsOver(std::span<const double> r, const std::vector<size_t>& index) {
  return index.empty() ? 0.0 : std::sqrt(SumSquares(r, index) / static_cast<double>(index.size()));
}

// -----------------------------------------------------------------------------------------
// The recording as the diagnosis sees it
// -----------------------------------------------------------------------------------------

std::vector<double> Data::SimulateFromRest(const TsModel& model, const std::vector<double>& u,
                                           const std::vector<double>& premise) const {
  SimulationOptions options = Simulation();
  options.premise_V = premise;
  if (Recordings() == 1) return Simulate(model, rec->t_s, u, options);
  std::vector<double> y;
  y.reserve(u.size());
  const std::span<const double> t(rec->t_s), v(u), p(premise);
  for (size_t j = 0; j < Recordings(); ++j) {
    if (!premise.empty()) options.premise_V = p.subspan(Begin(j), End(j) - Begin(j));
    const std::vector<double> part = Simulate(model, t.subspan(Begin(j), End(j) - Begin(j)),
                                              v.subspan(Begin(j), End(j) - Begin(j)), options);
    y.insert(y.end(), part.begin(), part.end());
  }
  return y;
}

void Data::ApplyOutput(const Effect& e, std::vector<double>* y_mm) const {
  if (Recordings() == 1 || e.kind == EffectKind::kSensorDrift)
    return ApplyOutputEffect(e, rec->t_s, y_mm);
  const std::span<const double> t(rec->t_s);
  for (size_t j = 0; j < Recordings(); ++j) {
    const auto first = y_mm->begin() + static_cast<long>(Begin(j));
    const auto last = y_mm->begin() + static_cast<long>(End(j));
    std::vector<double> part(first, last);
    ApplyOutputEffect(e, t.subspan(Begin(j), End(j) - Begin(j)), &part);
    std::copy(part.begin(), part.end(), first);
  }
}

std::vector<double> NuisanceFreeResidual(const Data& data, std::span<const double> predicted) {
  std::vector<double> r = Residual(data.rec->deflection_mm, predicted);
  auto project = [&r](const std::vector<size_t>& index, const Eigen::MatrixXd& q) {
    if (q.cols() == 0) return;
    Eigen::VectorXd v(static_cast<long>(index.size()));
    for (size_t i = 0; i < index.size(); ++i) v(static_cast<long>(i)) = r[index[i]];
    v -= q * (q.transpose() * v);
    for (size_t i = 0; i < index.size(); ++i) r[index[i]] = v(static_cast<long>(i));
  };
  project(data.train, data.edges_train);
  return r;
}

namespace {

// Every number of a model, its enumerations included: two models with the same numbers
// simulate alike.
std::vector<double> ModelNumbers(const TsModel& model) {
  std::vector<double> n = {static_cast<double>(model.scheduling),
                           static_cast<double>(model.realisation), model.rest_band_V,
                           model.scheduling_delay_s, static_cast<double>(model.rules.size())};
  for (const LocalModel& rule : model.rules) {
    n.insert(n.end(),
             {rule.level_V, rule.tf.delay_s, static_cast<double>(rule.tf.num.size()),
              static_cast<double>(rule.tf.den.size()), static_cast<double>(rule.membership.shape),
              static_cast<double>(rule.membership.params.size())});
    n.insert(n.end(), rule.tf.num.begin(), rule.tf.num.end());
    n.insert(n.end(), rule.tf.den.begin(), rule.tf.den.end());
    n.insert(n.end(), rule.membership.params.begin(), rule.membership.params.end());
  }
  return n;
}

}  // namespace

std::vector<double> SimulationMemo::Simulate(const Data& data, const TsModel& model,
                                             const std::vector<double>& u,
                                             const std::vector<double>& premise) {
  std::vector<double> numbers = ModelNumbers(model);
  for (auto it = entries_.rbegin(); it != entries_.rend(); ++it)
    if (it->model == numbers && it->u == u && it->premise == premise) return it->y;
  if (entries_.size() == kEntries) entries_.erase(entries_.begin());
  entries_.push_back({std::move(numbers), u, premise, data.SimulateFromRest(model, u, premise)});
  ++simulations_;
  return entries_.back().y;
}

std::vector<double> Predict(const Data& data, const Augmented& a, const std::vector<double>* cache,
                            SimulationMemo* memo) {
  const Recording& rec = *data.rec;
  bool any_input = false;
  for (const Effect& e : a.effects) any_input |= IsInputEffect(e.kind);
  // The voltage the gel responds to. Input effects act on the recordings in order, as one
  // actuator lived them (a degradation's charge accumulates from one to the next). A gain
  // effect leaves the operating point to the voltage before it (premise, once one acts).
  std::vector<double> u = rec.voltage_V, premise;
  for (const auto* list : {&data.given, &a.effects})
    for (const Effect& e : *list) {
      if (!IsInputEffect(e.kind)) continue;
      if (IsGainEffect(e.kind) && premise.empty()) premise = u;
      if (!premise.empty() && !IsGainEffect(e.kind)) ApplyInputEffect(e, rec.t_s, &premise);
      ApplyInputEffect(e, rec.t_s, &u);
    }
  auto output_effect = [&](const Effect& e, std::vector<double>* y) {
    if (!IsInputEffect(e.kind)) data.ApplyOutput(e, y);
  };
  std::vector<double> y;
  if (!any_input && cache && !a.refit) {
    y = *cache;  // the baseline with the given effects
  } else {
    y = memo ? memo->Simulate(data, a.Baseline(), u, premise)
             : data.SimulateFromRest(a.Baseline(), u, premise);
    for (const Effect& e : data.given) output_effect(e, &y);
  }
  for (const Effect& e : a.effects) output_effect(e, &y);
  return y;
}

// -----------------------------------------------------------------------------------------
// Fitting effect parameters (Ceres, numeric derivatives through the simulation)
// -----------------------------------------------------------------------------------------

std::vector<ParameterSpec> CoefficientSpecs(const TsModel& model) {
  std::vector<ParameterSpec> specs;
  for (const LocalModel& rule : model.rules) {
    const TransferFunction& tf = rule.tf;
    for (double c : tf.num) specs.push_back({-kInf, kInf, {c}});
    for (size_t i = 1; i < tf.den.size(); ++i) specs.push_back({-kInf, kInf, {tf.den[i]}});
  }
  return specs;
}

std::vector<double> CovarianceOf(const Eigen::MatrixXd& j, double sigma2,
                                 Eigen::MatrixXd* covariance_out, Eigen::MatrixXd* null_space_out) {
  const long q = j.cols();
  std::vector<double> half_width(static_cast<size_t>(q), kInf);
  covariance_out->resize(0, 0);
  null_space_out->resize(0, 0);
  // A parameter the residuals do not move at all (a saturation's onset anywhere between
  // two visited levels) is held: the others' intervals are then given it, and its own
  // is "not determined".
  const Eigen::MatrixXd jtj = j.transpose() * j;
  if (q == 0) return half_width;
  const double largest = jtj.diagonal().cwiseAbs().maxCoeff();
  std::vector<long> moved;
  for (long i = 0; i < q; ++i)
    if (jtj(i, i) > 1e-14 * largest) moved.push_back(i);
  const long p = static_cast<long>(moved.size());
  if (p == 0) return half_width;
  Eigen::MatrixXd sub(p, p);
  for (long a = 0; a < p; ++a)
    for (long b = 0; b < p; ++b) sub(a, b) = jtj(moved[a], moved[b]);
  // Parameters that trade off exactly (a saturation's onset and slope seen at one level
  // above the onset) leave a combination determined: the pseudo-inverse gives its
  // variance (SizeDetermined checks that its size is such a combination); a parameter
  // not determined alone gets no interval.
  const Eigen::VectorXd scale = sub.diagonal().cwiseSqrt().cwiseInverse();
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(scale.asDiagonal() * sub * scale.asDiagonal(),
                                        Eigen::ComputeFullU | Eigen::ComputeFullV);
  const Eigen::VectorXd sv = svd.singularValues();
  Eigen::VectorXd inverse = Eigen::VectorXd::Zero(p);
  Eigen::MatrixXd null_space(p, 0);
  for (long i = 0; i < p; ++i) {
    if (sv(i) > 1e-12 * sv(0)) {
      inverse(i) = 1.0 / sv(i);
    } else {
      null_space.conservativeResize(Eigen::NoChange, null_space.cols() + 1);
      null_space.col(null_space.cols() - 1) = svd.matrixV().col(i);
    }
  }
  const Eigen::MatrixXd covariance = sigma2 * scale.asDiagonal() * svd.matrixV() *
                                     inverse.asDiagonal() * svd.matrixU().transpose() *
                                     scale.asDiagonal();
  *covariance_out = Eigen::MatrixXd::Constant(q, q, kInf);
  *null_space_out = Eigen::MatrixXd::Zero(q, null_space.cols());
  for (long a = 0; a < p; ++a) {
    // Alone, a parameter is determined unless it has a share in an undetermined
    // direction (directions in scaled coordinates).
    const bool alone = null_space.cols() == 0 || null_space.row(a).norm() < 1e-6;
    if (alone)
      half_width[static_cast<size_t>(moved[a])] = 1.96 * std::sqrt(std::max(0.0, covariance(a, a)));
    for (long b = 0; b < p; ++b) (*covariance_out)(moved[a], moved[b]) = covariance(a, b);
    null_space_out->row(moved[a]) = null_space.row(a) * scale(a);
  }
  return half_width;
}

namespace {

Augmented Assemble(const FitProblem& p, const double* theta) {
  Augmented a = p.fixed;
  size_t i = 0;
  if (p.refit_from) {
    auto model = std::make_shared<TsModel>(*p.refit_from);
    for (LocalModel& rule : model->rules) {
      TransferFunction& tf = rule.tf;
      for (double& c : tf.num) c = theta[i++];
      for (size_t j = 1; j < tf.den.size(); ++j) tf.den[j] = theta[i++];
    }
    a.refit = std::move(model);
  }
  for (EffectKind kind : p.kinds) {
    Effect e{kind, {}};
    for (size_t j = 0; j < EffectParameterNames(kind).size(); ++j) e.params.push_back(theta[i++]);
    a.effects.push_back(std::move(e));
  }
  return a;
}

class EffectCost {
 public:
  EffectCost(const Data& data, const FitProblem& problem, const std::vector<double>* baseline)
      : data_(data), problem_(problem), baseline_(baseline) {
    // A refitted baseline stays under the physics chain's prior it was identified under
    // (Eqs. 11-13: a step response that rises without falling back; kBaselineFallBack, or
    // what the baseline it starts from already falls back): free, its coefficients would
    // absorb a back-relaxation, leaving nothing to the effect that models it.
    if (problem_.refit_from)
      max_fall_back_ = std::max(kBaselineFallBack, LargestFallBack(*problem_.refit_from));
  }
  bool operator()(double const* const* parameters, double* residuals) const {
    const Augmented model = Assemble(problem_, parameters[0]);
    if (model.refit && max_fall_back_ > 0.0 &&
        LargestFallBack(*model.refit) > max_fall_back_ * (1.0 + 1e-9)) {
      std::fill(residuals, residuals + data_.train.size(), 1e6);
      return true;
    }
    // Ceres evaluates a step's cost, then, the step taken, the residuals again at the
    // same point as the base of the Jacobian's differences: the memo keeps both to one
    // simulation.
    const std::vector<double> y = Predict(data_, model, baseline_, &memo_);
    const std::vector<double> projected = NuisanceFreeResidual(data_, y);
    for (size_t i = 0; i < data_.train.size(); ++i) {
      const double r = projected[data_.train[i]];
      residuals[i] = std::isfinite(r) ? r : 1e6;
    }
    return true;
  }

 private:
  const Data& data_;
  const FitProblem& problem_;
  const std::vector<double>* baseline_;
  double max_fall_back_ = 0.0;   // of a refitted baseline's rules; 0: not refitted
  mutable SimulationMemo memo_;  // operator() is const for Ceres; one fit, one thread
};

// Every combination of the parameters' starting values, each clamped to its bounds.
std::vector<std::vector<double>> StartCombinations(const std::vector<ParameterSpec>& specs) {
  std::vector<std::vector<double>> starts = {{}};
  for (const ParameterSpec& spec : specs) {
    std::vector<std::vector<double>> next;
    for (const auto& partial : starts)
      for (double v : spec.starts) {
        auto extended = partial;
        extended.push_back(std::clamp(v, spec.lower, spec.upper));
        next.push_back(std::move(extended));
      }
    starts = std::move(next);
  }
  return starts;
}

}  // namespace

FitResult FitParameters(const Data& data, const FitProblem& problem,
                        const std::vector<double>* baseline) {
  const std::vector<ParameterSpec>& specs = problem.specs;
  const size_t q = specs.size();
  FitResult best;
  if (q == 0) {
    best.model = problem.fixed;
    best.prediction = Predict(data, best.model, baseline);
    best.train_sse = SumSquares(NuisanceFreeResidual(data, best.prediction), data.train);
    return best;
  }
  // solve: Levenberg-Marquardt from theta (in place) for at most `iterations`; returns the
  // SSE and, if asked, the 95 % half-widths.
  const EffectCost cost_function(data, problem, baseline);
  const size_t m = data.train.size();
  // 95 % half-widths from the Jacobian j (m x q) at the end point, with the residual
  // variance inflated by n / n_eff for correlated residuals.
  auto half_widths = [&](const Eigen::MatrixXd& j, const std::vector<double>& residuals, double sse,
                         std::vector<double>* half_width) {
    std::vector<size_t> all(residuals.size());
    std::iota(all.begin(), all.end(), size_t{0});
    const double n = static_cast<double>(residuals.size());
    const double n_eff = std::max(EffectiveSamples(residuals, all), 1.0);
    const double sigma2 = sse / std::max(1.0, n - static_cast<double>(q)) * n / n_eff;
    *half_width = CovarianceOf(j, sigma2, &best.covariance, &best.null_space);
  };
  // A refitted baseline adds a dozen or more coefficients, each difference a simulation of
  // the whole recording: the secant L-M (secant_lm.h, two simulations an iteration, as the
  // global fit uses) rather than central differences at every iteration.
  auto solve_secant = [&](std::vector<double>* theta, int iterations,
                          std::vector<double>* half_width) {
    std::vector<double> lower(q), upper(q);
    for (size_t j = 0; j < q; ++j) {
      lower[j] = specs[j].lower;
      upper[j] = specs[j].upper;
    }
    auto residuals = [&](const double* x, double* r) {
      const double* blocks[] = {x};
      cost_function(blocks, r);
      for (size_t i = 0; i < m; ++i)
        if (r[i] == 1e6) return false;
      return true;
    };
    SecantLmOptions options;
    options.max_iterations = iterations;
    const SecantLmResult solved = SolveSecantLm(residuals, m, *theta, lower, upper, options);
    *theta = solved.x;
    if (half_width) {
      std::vector<double> r0(m), r1(m);
      residuals(theta->data(), r0.data());
      Eigen::MatrixXd j(static_cast<long>(m), static_cast<long>(q));
      for (size_t c = 0; c < q; ++c) {
        std::vector<double> x = *theta;
        double h = 1e-6 * std::max(std::abs(x[c]), 1e-3);
        if (x[c] + h > upper[c]) h = -h;
        x[c] += h;
        if (!residuals(x.data(), r1.data())) {  // across the prior's bound: the other side
          h = -h;
          x[c] = (*theta)[c] + h;
          residuals(x.data(), r1.data());
        }
        for (size_t i = 0; i < m; ++i)
          j(static_cast<long>(i), static_cast<long>(c)) = (r1[i] - r0[i]) / h;
      }
      half_widths(j, r0, solved.sum_of_squares, half_width);
    }
    return solved.sum_of_squares;
  };
  auto solve = [&](std::vector<double>* theta, int iterations, std::vector<double>* half_width) {
    if (problem.refit_from) return solve_secant(theta, 4 * iterations, half_width);
    ceres::Problem ceres_problem;
    auto* cost = new ceres::DynamicNumericDiffCostFunction<EffectCost, ceres::CENTRAL>(
        new EffectCost(data, problem, baseline));
    cost->AddParameterBlock(static_cast<int>(q));
    cost->SetNumResiduals(static_cast<int>(data.train.size()));
    ceres_problem.AddResidualBlock(cost, nullptr, theta->data());
    for (size_t j = 0; j < q; ++j) {
      ceres_problem.SetParameterLowerBound(theta->data(), static_cast<int>(j), specs[j].lower);
      ceres_problem.SetParameterUpperBound(theta->data(), static_cast<int>(j), specs[j].upper);
    }
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = iterations;
    options.function_tolerance = 1e-8;
    options.logging_type = ceres::SILENT;
    options.num_threads = 1;
    ceres::Solver::Summary summary;
    ceres::Solve(options, &ceres_problem, &summary);
    if (half_width) {
      ceres::CRSMatrix jacobian;
      std::vector<double> residuals;
      ceres_problem.Evaluate(ceres::Problem::EvaluateOptions(), nullptr, &residuals, nullptr,
                             &jacobian);
      Eigen::MatrixXd j = Eigen::MatrixXd::Zero(jacobian.num_rows, jacobian.num_cols);
      for (int r = 0; r < jacobian.num_rows; ++r)
        for (int i = jacobian.rows[static_cast<size_t>(r)];
             i < jacobian.rows[static_cast<size_t>(r) + 1]; ++i)
          j(r, jacobian.cols[static_cast<size_t>(i)]) = jacobian.values[static_cast<size_t>(i)];
      half_widths(j, residuals, 2.0 * summary.final_cost, half_width);
    }
    return 2.0 * summary.final_cost;
  };
  // Every combination of the starting values, a few iterations each; the best goes on.
  const std::vector<std::vector<double>> starts = StartCombinations(specs);
  std::vector<double> theta = starts.front();
  if (starts.size() > 1) {
    double best_sse = kInf;
    for (std::vector<double> start : starts) {
      const double sse = solve(&start, 4, nullptr);
      if (sse < best_sse) {
        best_sse = sse;
        theta = start;
      }
    }
  }
  solve(&theta, problem.refit_from ? 15 : 40, &best.half_width);
  best.theta = theta;
  best.model = Assemble(problem, best.theta.data());
  best.prediction = Predict(data, best.model, baseline);
  best.train_sse = SumSquares(NuisanceFreeResidual(data, best.prediction), data.train);
  return best;
}

std::vector<double> WhatTheLastEffectAdds(const Data& data, const FitResult& fit) {
  Augmented without = fit.model;
  without.effects.pop_back();
  const std::vector<double> y = Predict(data, without);
  std::vector<double> delta(y.size());
  for (size_t k = 0; k < y.size(); ++k) delta[k] = fit.prediction[k] - y[k];
  return delta;
}

std::vector<ParameterSpec> SpecsFor(EffectKind kind, const Data& data) {
  const double D = data.duration_s, dt = data.dt_s;
  const double top = data.abs_levels_V.empty() ? data.max_abs_V : data.abs_levels_V.back();
  const double low = data.abs_levels_V.empty() ? 0.0 : data.abs_levels_V.front();
  double range_mm = 0.0;
  {
    const auto [lo, hi] =
        std::minmax_element(data.rec->deflection_mm.begin(), data.rec->deflection_mm.end());
    range_mm = *hi - *lo;
  }
  // A relaxation is at least a second (5 samples when coarser): faster ones are the
  // actuator's own charging dynamics (the seed's fast modes).
  // A relaxation slower than half the recording completes neither within a hold nor
  // between holds: over the recording it is a trend, which a sensor drift explains as
  // well (with up to 3 times the duration allowed, drifts were read as creep).
  const double tau_lo = std::max(5.0 * dt, 1.0), tau_hi = std::max(0.5 * D, tau_lo * 2);
  auto taus = [&] {
    std::vector<double> v;
    for (double t : {20.0, 80.0, 300.0})
      if (t < tau_hi && t > tau_lo) v.push_back(t);
    if (v.empty()) v.push_back(std::sqrt(tau_lo * tau_hi));
    return v;
  };
  switch (kind) {
    case EffectKind::kBackRelaxation:
    case EffectKind::kCreep:
      return {{0.0, kind == EffectKind::kBackRelaxation ? 0.95 : 2.0, {0.03, 0.2}},
              {tau_lo, tau_hi, taus()}};
    case EffectKind::kCycleDegradation:
      // Degradation only: a gain that grows with use is not this effect. Its exponent from
      // a steady loss per charge (1, the start) down to wear nearly done at first (0.2),
      // never accelerating: up to 3, a late loss took the place of a faint saturation on
      // levels that rose late in a recording (independent simulator, faint set).
      return {{0.0, 0.95, {0.01, 0.1}}, {0.2, 1.0, {1.0}}};
    case EffectKind::kHysteresis:
      return {{0.0, 0.5 * range_mm + 1e-9, {std::max(2.0 * data.noise_mm, 1e-6)}},
              {1e-3 * range_mm + 1e-9,
               range_mm + 1e-9,
               {0.01 * range_mm + 1e-9, 0.1 * range_mm + 1e-9}}};
    case EffectKind::kElectrolysisSaturation: {
      std::vector<double> onsets;
      for (size_t i = 0; i + 1 < data.abs_levels_V.size(); ++i)
        onsets.push_back(0.5 * (data.abs_levels_V[i] + data.abs_levels_V[i + 1]));
      if (onsets.empty()) onsets.push_back(0.5 * top);
      return {{0.5 * low, top, onsets}, {0.0, 1.0, {0.5}}};
    }
    case EffectKind::kDeadZone: {
      // The threshold may lie above the lowest levels (they then move nothing): starts
      // below the lowest level and between the lowest few.
      std::vector<double> starts = {0.1 * low, 0.5 * low};
      for (size_t i = 0; i + 1 < data.abs_levels_V.size() && i < 3; ++i)
        starts.push_back(0.5 * (data.abs_levels_V[i] + data.abs_levels_V[i + 1]));
      return {{0.0, 0.9 * std::max(top, 1e-9), starts}};
    }
    case EffectKind::kSensorDrift:
      // A sensor's zero moves slowly: a warm-up within the first twentieth of the
      // recording is a start-up offset that the first motion's friction or the model's
      // own transient explain as well (fitted free, 6.8 s warm-ups took the place of
      // hysteresis).
      return {{-kInf, kInf, {0.0}},
              {-kInf, kInf, {0.0}},
              {std::max(tau_lo, 0.05 * D), 5.0 * D, {0.1 * D, 0.5 * D}}};
    case EffectKind::kPolarityAsymmetry:
      return {{0.05, 3.0, {0.8, 1.2}}};
  }
  return {};
}

bool Applicable(EffectKind kind, const Data& data, std::string* why) {
  const auto& u = data.rec->voltage_V;
  size_t positive = 0, negative = 0;
  for (double v : u) {
    if (v > data.rest_band_V) ++positive;
    if (v < -data.rest_band_V) ++negative;
  }
  switch (kind) {
    case EffectKind::kPolarityAsymmetry:
      if (std::min(positive, negative) < std::max<size_t>(20, (positive + negative) / 20)) {
        *why = "the recording does not drive both polarities";
        return false;
      }
      return true;
    case EffectKind::kElectrolysisSaturation:
    case EffectKind::kDeadZone:
      if (data.abs_levels_V.size() < 2) {
        *why = "needs two or more voltage levels (one level cannot tell it from a gain error)";
        return false;
      }
      return true;
    default:
      return true;
  }
}

// The recordings laid end to end, in the order given, as one: recording j > 0 starts one
// sample period (its predecessor's last) after its predecessor ends. *starts receives the
// first sample of each, then the total; *shift_s what was added to each one's times.
Recording JoinRecordings(const std::vector<Recording>& recordings, std::vector<size_t>* starts,
                         std::vector<double>* shift_s) {
  if (recordings.empty()) throw InputError("diagnosis needs at least one recording");
  if (recordings.size() > static_cast<size_t>(kMaxDiagnosedRecordings))
    throw InputError(std::to_string(recordings.size()) +
                     " recordings; one diagnosis takes at most " +
                     std::to_string(kMaxDiagnosedRecordings));
  Recording joined;
  for (const Recording& r : recordings) {
    const size_t n = r.t_s.size();
    if (r.deflection_mm.size() != n || r.voltage_V.size() != n)
      throw InputError(r.source + ": diagnosis needs time, voltage and deflection columns");
    if (n < 2) throw InputError(r.source + ": " + std::to_string(n) + " samples; need at least 2");
    double shift = 0.0;
    if (!joined.t_s.empty()) {
      const size_t m = joined.t_s.size();
      const double gap_s = m >= 2 ? joined.t_s[m - 1] - joined.t_s[m - 2] : r.t_s[1] - r.t_s[0];
      shift = joined.t_s.back() + gap_s - r.t_s.front();
      joined.source += " + ";
    }
    starts->push_back(joined.t_s.size());
    shift_s->push_back(shift);
    joined.source += r.source;
    for (double t : r.t_s) joined.t_s.push_back(t + shift);
    joined.voltage_V.insert(joined.voltage_V.end(), r.voltage_V.begin(), r.voltage_V.end());
    joined.deflection_mm.insert(joined.deflection_mm.end(), r.deflection_mm.begin(),
                                r.deflection_mm.end());
  }
  starts->push_back(joined.t_s.size());
  return joined;
}

std::vector<TimeSpan> OnRecordings(const Data& data, const std::vector<TimeSpan>& joined) {
  std::vector<TimeSpan> out;
  for (const TimeSpan& s : joined)
    for (size_t j = 0; j < data.Recordings(); ++j) {
      const double first = std::max(s.t_start_s, data.rec->t_s[data.Begin(j)]);
      const double last = std::min(s.t_end_s, data.rec->t_s[data.End(j) - 1]);
      if (first <= last)
        out.push_back({first - data.shift_s[j], last - data.shift_s[j], static_cast<int>(j)});
    }
  return out;
}

GlobalEstimate IdentifyBaseline(const Recording& rec, const Data& data, Diagnosis* result,
                                const GlobalEstimate* higher_than) {
  const size_t n = rec.t_s.size();
  // The held-out deflection never reaches the identification: the samples there are
  // excluded from every fit (they are simulated through, so the state carries over) and
  // replaced by a straight line between their training neighbours, so that no estimate
  // taken from the raw data (noise, levels) reads them either.
  Recording training = rec;
  for (const TimeSpan& s : result->heldout) {
    size_t a = 0;
    while (a < n && rec.t_s[a] < s.t_start_s) ++a;
    size_t b = a;
    while (b < n && rec.t_s[b] <= s.t_end_s) ++b;
    const double left = a > 0 ? rec.deflection_mm[a - 1] : (b < n ? rec.deflection_mm[b] : 0.0);
    const double right = b < n ? rec.deflection_mm[b] : left;
    for (size_t k = a; k < b; ++k) {
      const double w = static_cast<double>(k - a + 1) / static_cast<double>(b - a + 1);
      training.deflection_mm[k] = (1 - w) * left + w * right;
    }
  }
  GlobalIdentifyOptions identify;
  // The seed's blend: one rule, or two handing over smoothly (Eq. 19), never a gain per
  // level (identify_global.h, rules_at_most).
  identify.rules_at_most = 2;
  // The physics chain's step response cannot fall back (Eqs. 11-13): a baseline that
  // does has absorbed back-relaxation, and the effect is then never seen.
  identify.max_fall_back = higher_than ? kMoreOrderFallBack : kBaselineFallBack;
  // One more pole and zero than the baseline, everything else kept and its dead time
  // fixed: the question is the slow dynamics, and one fit from where the baseline ended
  // answers it (a second selection would cost as much as the first).
  identify.raise_order_of = higher_than;
  for (const TimeSpan& s : result->heldout)
    identify.excluded_spans_s.emplace_back(s.t_start_s, s.t_end_s + 0.5 * data.dt_s);
  std::vector<Recording> parts;
  for (size_t j = 0; j < data.Recordings(); ++j) {
    const auto first = static_cast<long>(data.Begin(j)), last = static_cast<long>(data.End(j));
    Recording part;
    part.source = training.source;
    part.t_s.assign(training.t_s.begin() + first, training.t_s.begin() + last);
    part.voltage_V.assign(training.voltage_V.begin() + first, training.voltage_V.begin() + last);
    part.deflection_mm.assign(training.deflection_mm.begin() + first,
                              training.deflection_mm.begin() + last);
    parts.push_back(std::move(part));
  }
  GlobalEstimate estimate;
  try {
    estimate = IdentifyGlobalTs(parts, identify);
  } catch (const InputError& e) {
    if (higher_than) throw InputError(std::string("no baseline could be identified: ") + e.what());
    // No structure met the prior (a drift can make every fit fall back a little): the
    // baseline without it, said so, rather than no diagnosis at all.
    identify.max_fall_back = 0.0;
    try {
      estimate = IdentifyGlobalTs(parts, identify);
    } catch (const InputError& again) {
      throw InputError(std::string("no baseline could be identified: ") + again.what());
    }
    result->notes.push_back(std::string("baseline: identified without the physics chain's prior "
                                        "(no structure met it: ") +
                            e.what() + ")");
  }
  if (higher_than) return estimate;
  result->notes.push_back("baseline: " + estimate.structure.Describe() + " (" + estimate.reason +
                          ")");
  for (const std::string& w : estimate.warnings) result->notes.push_back("baseline: " + w);
  return estimate;
}

}  // namespace flexid::model::diagnosis
