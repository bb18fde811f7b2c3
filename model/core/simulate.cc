#include "model/core/simulate.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <deque>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "model/core/discretise.h"
#include "model/core/state_space.h"

namespace flexid::model {
namespace {

void CheckModel(const TsModel& model) {
  std::string why;
  if (!IsValid(model, &why)) throw std::invalid_argument("invalid model: " + why);
}

void CheckSeries(std::span<const double> t_s, std::span<const double> voltage_V) {
  if (t_s.size() != voltage_V.size())
    throw std::invalid_argument("time and voltage series differ in length (" +
                                std::to_string(t_s.size()) + " vs " +
                                std::to_string(voltage_V.size()) + ")");
  for (size_t k = 0; k < t_s.size(); ++k) {
    if (!std::isfinite(t_s[k]) || !std::isfinite(voltage_V[k]))
      throw std::invalid_argument("non-finite time or voltage at sample " + std::to_string(k));
    if (k > 0 && !(t_s[k] > t_s[k - 1]))
      throw std::invalid_argument("time not strictly increasing at sample " + std::to_string(k));
  }
}

// What is computed per operating point (a discretisation, memberships), cached by
// q = round(z / resolution): the operating point is z = q * resolution (OperatingZ). A
// continuously varying input (a chirp in kV) moves q on most samples, so the slot is found
// by indexing a flat table over q in [-q_max, q_max] when the input's range is known and
// the table is small next to the samples simulated; by hashing otherwise. At most
// kMaxOperatingPoints entries (about 8 MB of discretisations): then it starts afresh, and
// pointers from earlier calls of At are invalid.
constexpr size_t kMaxOperatingPoints = 32768;

template <typename Entry>
class OperatingPointCache {
 public:
  // max_abs_z_V < 0: the range is unknown (hashing only).
  OperatingPointCache(double resolution_V, double max_abs_z_V, size_t samples)
      : resolution_V_(resolution_V) {
    if (!(max_abs_z_V >= 0.0)) return;
    const double q_max = std::ceil(max_abs_z_V / resolution_V) + 1.0;
    const double slots = 2.0 * q_max + 1.0;
    if (slots > static_cast<double>(std::min(kMaxOperatingPoints, samples + 1024))) return;
    q_max_ = static_cast<long>(q_max);
    table_.assign(static_cast<size_t>(slots), nullptr);
  }

  // The entry for the operating point q (a whole number), made by make(z) if new.
  template <typename Make>
  const Entry& At(double q, const Make& make) {
    if (q_max_ >= 0 && std::abs(q) <= static_cast<double>(q_max_)) {
      Entry*& slot = table_[static_cast<size_t>(static_cast<long>(q) + q_max_)];
      if (slot == nullptr) slot = &Insert(q, make);
      return *slot;
    }
    const auto it = map_.find(std::bit_cast<uint64_t>(q));
    return it != map_.end() ? it->second : Insert(q, make);
  }

 private:
  template <typename Make>
  Entry& Insert(double q, const Make& make) {
    if (map_.size() >= kMaxOperatingPoints) {
      map_.clear();
      std::fill(table_.begin(), table_.end(), nullptr);
    }
    return map_.emplace(std::bit_cast<uint64_t>(q), make(q * resolution_V_)).first->second;
  }

  double resolution_V_;
  long q_max_ = -1;
  std::vector<Entry*> table_;
  std::unordered_map<uint64_t, Entry> map_;  // node-based: entries stay where they are
};

// The operating point's index q for a scheduling value (z = q * resolution).
double OperatingIndex(Scheduler& scheduler, double voltage_V, double resolution_V) {
  return std::round(scheduler.Next(voltage_V) / resolution_V);
}

// Scheduling value used to pick the operating point (see kSchedulingResolution_V).
double OperatingZ(Scheduler& scheduler, double voltage_V, double resolution_V) {
  return OperatingIndex(scheduler, voltage_V, resolution_V) * resolution_V;
}

// Largest |u| of an input and of the voltage before it: what bounds |z|.
double MaxAbs(std::span<const double> u, double before_V) {
  double top = std::abs(before_V);
  for (double v : u) top = std::max(top, std::abs(v));
  return top;
}

// kAbsVoltageDelayed: the premise at sample time t_k is the voltage in force at
// t_k - delay, i.e. sample k - ceil(delay / dt) on a uniform grid.
long PremiseDelaySamples(const TsModel& model, double dt_s) {
  if (model.scheduling != SchedulingVariable::kAbsVoltageDelayed) return 0;
  return static_cast<long>(std::ceil(model.scheduling_delay_s / dt_s - 1e-9));
}

// Every value of a voltage series finite, else std::invalid_argument naming what and the
// sample. The vectorised test first (an identification simulates the same input thousands
// of times): v - v is 0 for every finite v and NaN otherwise, and Eigen sums in packets
// (allFinite() compiles to a scalar loop); the loop only to name the sample.
void CheckFinite(std::span<const double> series_V, const char* what) {
  const Eigen::Map<const Eigen::ArrayXd> v(series_V.data(),
                                           static_cast<Eigen::Index>(series_V.size()));
  if ((v - v).sum() == 0.0) return;
  for (size_t k = 0; k < series_V.size(); ++k)
    if (!std::isfinite(series_V[k]))
      throw std::invalid_argument(std::string("non-finite ") + what + " at sample " +
                                  std::to_string(k));
}

// The scheduling resolution, and a premise series (SimulationOptions::premise_V) as long
// as the voltage (samples) and finite.
void CheckOptions(const SimulationOptions& options, size_t samples) {
  if (!(options.scheduling_resolution_V > 0.0) || !std::isfinite(options.scheduling_resolution_V))
    throw std::invalid_argument("scheduling resolution must be finite and > 0");
  if (options.premise_V.empty()) return;
  if (options.premise_V.size() != samples)
    throw std::invalid_argument("premise voltage has " + std::to_string(options.premise_V.size()) +
                                " samples, the voltage " + std::to_string(samples));
  CheckFinite(options.premise_V, "premise voltage");
}

// The frozen model at one scheduling value, realised (state_space.h).
struct OperatingPoint {
  std::vector<double> mu;
  StateSpace ss;
  // Markov parameters h0..h_{n-1}: state i is y^(i) - h_i u while the input holds still.
  Eigen::VectorXd remap;
};

OperatingPoint OperatingPointAt(const TsModel& model, const PreparedRules& prepared, double z) {
  OperatingPoint op;
  NormalisedMemberships(model, z, &op.mu);
  const TransferFunction frozen = BlendedTransferFunction(model, prepared, op.mu);
  op.ss = RealiseOutputDerivativeForm(frozen);
  op.remap = MarkovParameters(frozen).head(op.ss.A.rows());
  return op;
}

// At a change of operating point the state is re-expressed so that the output and its
// derivatives stay continuous: with the input held, x_i = y^(i) - h_i u_d in each frozen
// model, so x_new = x_old + h_old u_d,old - h_new u_d,new (u_d: the delayed input each
// model sees now). Without this, local models whose Markov parameters differ would make
// the implied derivatives jump at every switch. Applied in two halves (leave the old
// point, enter the new one) so that no reference to the old point is needed after the
// new one is looked up.
template <typename Vec>
void AddMarkovTerm(const Eigen::VectorXd& h, double u_delayed, double sign, Vec* x) {
  for (Eigen::Index i = 0; i < x->size(); ++i) (*x)(i) += sign * h(i) * u_delayed;
}

// State under a voltage u0 held forever: A x + B u0 = 0.
Eigen::VectorXd InitialState(const StateSpace& ss, double u0) {
  const Eigen::Index n = ss.A.rows();
  if (n == 0 || u0 == 0.0) return Eigen::VectorXd::Zero(n);
  Eigen::FullPivLU<Eigen::MatrixXd> lu(ss.A);
  if (!lu.isInvertible())
    throw std::invalid_argument("start_in_steady_state: the model has a pole at s = 0");
  return lu.solve(-ss.B * u0);
}

// ---------------------------------------------------------------------------------------
// Uniform grid: x[k+1] = Phi x[k] + Gamma0 u[k-d] + Gamma1 u[k-d-1] (discretise.h), with
// Phi, Gamma and d computed exactly for the frozen model at z_k, which is constant over
// the interval because z follows the held voltage. Discretisations are cached per
// scheduling value: lab inputs (steps, square waves, staircases, DAQ-quantised voltages)
// take few distinct values.
// ---------------------------------------------------------------------------------------

template <int N>
struct UniformEntry {
  using Mat = Eigen::Matrix<double, N, N>;
  using Vec = Eigen::Matrix<double, N, 1>;
  Mat Phi;
  Vec G0, G1;
  double D = 0.0;
  long delay_samples = 0;
  bool fractional = false;
  std::vector<double> mu;
  Eigen::VectorXd remap;
};

template <int N>
UniformEntry<N> MakeUniformEntry(const TsModel& model, const PreparedRules& prepared, double z,
                                 double dt_s) {
  OperatingPoint op = OperatingPointAt(model, prepared, z);
  const DiscreteModel dm = DiscretiseZoh(op.ss, dt_s);
  UniformEntry<N> e;
  e.Phi = dm.Phi;
  e.G0 = dm.Gamma0;
  e.G1 = dm.Gamma1;
  e.D = dm.D;
  e.delay_samples = dm.delay_samples;
  e.fractional = dm.delay_fraction > 0.0;
  e.mu = std::move(op.mu);
  e.remap = std::move(op.remap);
  return e;
}

// Output sample x(0) of the output-derivative form (zero for a pure gain).
template <int N, typename Vec>
double FirstState(const Vec& x) {
  if constexpr (N == 0) {
    return 0.0;
  } else {
    return x(0);
  }
}

// y is __restrict: the state x has its address taken (AddMarkovTerm), and without the
// promise that y does not alias it every store to y[k] made the loop reload x from memory
// (a one-rule simulation 16 % slower).
template <int N>
void RunUniform(const TsModel& model, double dt_s, std::span<const double> u,
                const SimulationOptions& options, double* __restrict y,
                std::vector<double>* memberships) {
  using Vec = typename UniformEntry<N>::Vec;
  const size_t m = model.rules.size();
  const double u_before = options.start_in_steady_state ? u.front() : options.initial_voltage_V;

  // The input is padded in front with the pre-start voltage, so that u[k - d] for the
  // largest dead time of any rule is up[k - d] without a branch.
  double max_delay_s = 0.0;
  for (const LocalModel& rule : model.rules) max_delay_s = std::max(max_delay_s, rule.tf.delay_s);
  const long premise_delay = PremiseDelaySamples(model, dt_s);
  const long pad = std::max(static_cast<long>(std::ceil(max_delay_s / dt_s)), premise_delay) + 2;
  const double resolution_V = options.scheduling_resolution_V;
  std::vector<double> padded(static_cast<size_t>(pad), u_before);
  padded.insert(padded.end(), u.begin(), u.end());
  const double* up = padded.data() + pad;
  // The operating point's voltage (SimulationOptions::premise_V), padded alike.
  const std::span<const double> premise = options.premise_V.empty() ? u : options.premise_V;
  const double premise_before =
      options.start_in_steady_state ? premise.front() : options.initial_voltage_V;
  std::vector<double> premise_padded;
  const double* pp = up;
  if (!options.premise_V.empty()) {
    premise_padded.assign(static_cast<size_t>(pad), premise_before);
    premise_padded.insert(premise_padded.end(), premise.begin(), premise.end());
    pp = premise_padded.data() + pad;
  }

  const PreparedRules prepared = PrepareRules(model);
  auto make_entry = [&](double z) { return MakeUniformEntry<N>(model, prepared, z, dt_s); };

  Scheduler scheduler(model);
  Vec x = InitialState(
      OperatingPointAt(model, prepared, OperatingZ(scheduler, premise_before, resolution_V)).ss,
      u_before);
  const long count = static_cast<long>(u.size());
  if (memberships) memberships->resize(u.size() * m);

  if (m == 1) {
    // One rule: one discretisation, the tightest loop.
    const UniformEntry<N> e = make_entry(0.0);  // one rule: every z gives the same model
    const long d = e.delay_samples;
    for (long k = 0; k < count; ++k) {
      const double u_now = up[k - d], u_prev = up[k - d - 1];
      y[k] = FirstState<N>(x) + e.D * (e.fractional ? u_prev : u_now);
      x = e.Phi * x + e.G0 * u_now + e.G1 * u_prev;
    }
    if (memberships) std::fill(memberships->begin(), memberships->end(), 1.0);
    return;
  }
  OperatingPointCache<UniformEntry<N>> cache(resolution_V, MaxAbs(premise, premise_before),
                                             u.size());
  double last_q = std::numeric_limits<double>::quiet_NaN();
  const UniformEntry<N>* e = nullptr;
  // The scheduler gives the same z for a repeated voltage (held |u| included), and lab
  // inputs hold each voltage for many samples: z is computed only when the voltage moves.
  double last_raw_V = std::numeric_limits<double>::quiet_NaN();
  for (long k = 0; k < count; ++k) {
    const double raw_V = pp[k - premise_delay];
    const bool moved = e == nullptr || raw_V != last_raw_V;
    last_raw_V = raw_V;
    const double q = moved ? OperatingIndex(scheduler, raw_V, resolution_V) : last_q;
    if (!(q == last_q)) {
      auto delayed = [&](const UniformEntry<N>* p) {
        return p->fractional ? up[k - p->delay_samples - 1] : up[k - p->delay_samples];
      };
      const bool switching = e != nullptr && N != 0;
      if (switching) AddMarkovTerm(e->remap, delayed(e), +1.0, &x);
      e = &cache.At(q, make_entry);
      if (switching) AddMarkovTerm(e->remap, delayed(e), -1.0, &x);
      last_q = q;
    }
    const long d = e->delay_samples;
    const double u_now = up[k - d], u_prev = up[k - d - 1];
    y[k] = FirstState<N>(x) + e->D * (e->fractional ? u_prev : u_now);
    x = e->Phi * x + e->G0 * u_now + e->G1 * u_prev;
    if (memberships)
      std::copy(e->mu.begin(), e->mu.end(), memberships->begin() + static_cast<long>(k * m));
  }
}

void DispatchUniform(const TsModel& model, double dt_s, std::span<const double> u,
                     const SimulationOptions& options, double* y,
                     std::vector<double>* memberships) {
  switch (Order(model.rules.front().tf)) {
    case 0:
      return RunUniform<0>(model, dt_s, u, options, y, memberships);
    case 1:
      return RunUniform<1>(model, dt_s, u, options, y, memberships);
    case 2:
      return RunUniform<2>(model, dt_s, u, options, y, memberships);
    case 3:
      return RunUniform<3>(model, dt_s, u, options, y, memberships);
    case 4:
      return RunUniform<4>(model, dt_s, u, options, y, memberships);
    case 5:
      return RunUniform<5>(model, dt_s, u, options, y, memberships);
    case 6:
      return RunUniform<6>(model, dt_s, u, options, y, memberships);
    default:
      return RunUniform<Eigen::Dynamic>(model, dt_s, u, options, y, memberships);
  }
}

// kParallel (ts_fuzzy.h): every rule simulated alone on its share mu_i(z) u of the
// voltage, the outputs added. The share is a held voltage like any other, so each rule's
// simulation is the exact single-model one, dead time included.
class ParallelShares {
 public:
  // max_abs_V, samples: the input's largest |u| and length when known (OperatingPointCache).
  ParallelShares(const TsModel& model, double resolution_V, double max_abs_V = -1.0,
                 size_t samples = 0)
      : model_(model),
        scheduler_(model),
        resolution_V_(resolution_V),
        cache_(resolution_V, max_abs_V, samples) {}

  // mu(z) for the voltage u (cached by z; the scheduler gives the same z for a repeated
  // voltage, held |u| included).
  const std::vector<double>& Memberships(double voltage_V) {
    if (last_ != nullptr && voltage_V == last_voltage_V_) return *last_;
    const double q = OperatingIndex(scheduler_, voltage_V, resolution_V_);
    last_voltage_V_ = voltage_V;
    last_ = &cache_.At(q, [this](double z) {
      std::vector<double> mu;
      NormalisedMemberships(model_, z, &mu);
      return mu;
    });
    return *last_;
  }

 private:
  const TsModel& model_;
  Scheduler scheduler_;
  double resolution_V_;
  OperatingPointCache<std::vector<double>> cache_;
  double last_voltage_V_ = 0.0;
  const std::vector<double>* last_ = nullptr;
};

// Options for rule i's simulation: the state before the first sample is its share of
// the voltage before it.
SimulationOptions RuleOptions(const SimulationOptions& options, double share) {
  SimulationOptions rule = options;
  rule.initial_voltage_V = share * options.initial_voltage_V;
  return rule;
}

void ParallelUniform(const TsModel& model, double dt_s, std::span<const double> u,
                     const SimulationOptions& options, double* y,
                     std::vector<double>* memberships) {
  const size_t m = model.rules.size(), n = u.size();
  const std::span<const double> premise = options.premise_V.empty() ? u : options.premise_V;
  ParallelShares shares(model, options.scheduling_resolution_V,
                        MaxAbs(premise, options.initial_voltage_V), n);
  const std::vector<double> before = shares.Memberships(options.initial_voltage_V);
  std::vector<std::vector<double>> drive(m, std::vector<double>(n));
  if (memberships) memberships->resize(n * m);
  for (size_t k = 0; k < n; ++k) {
    const std::vector<double>& mu = shares.Memberships(premise[k]);
    for (size_t i = 0; i < m; ++i) drive[i][k] = mu[i] * u[k];
    if (memberships)
      std::copy(mu.begin(), mu.end(), memberships->begin() + static_cast<long>(k * m));
  }
  // Rules with the same dynamics (equal denominators and dead times, proportional
  // numerators: G_j = c G_i) are one linear system: G_i [drive_i + c drive_j]. A global fit
  // whose dynamics change at few knots has many such rules.
  std::vector<double> initial(m);
  for (size_t i = 0; i < m; ++i) initial[i] = before[i] * options.initial_voltage_V;
  std::vector<bool> merged(m, false);
  for (size_t i = 0; i < m; ++i) {
    if (merged[i]) continue;
    const TransferFunction& gi = model.rules[i].tf;
    for (size_t j = i + 1; j < m; ++j) {
      const TransferFunction& gj = model.rules[j].tf;
      if (merged[j] || gj.den != gi.den || gj.delay_s != gi.delay_s ||
          gj.num.size() != gi.num.size() || gi.num.back() == 0.0)
        continue;
      const double c = gj.num.back() / gi.num.back();
      bool proportional = true;
      for (size_t q = 0; q < gi.num.size() && proportional; ++q)
        proportional = std::abs(gj.num[q] - c * gi.num[q]) <=
                       1e-12 * std::max(std::abs(gj.num[q]), std::abs(c * gi.num[q]));
      if (!proportional) continue;
      for (size_t k = 0; k < n; ++k) drive[i][k] += c * drive[j][k];
      initial[i] += c * initial[j];
      merged[j] = true;
    }
  }
  std::fill(y, y + n, 0.0);
  std::vector<double> part(n);
  for (size_t i = 0; i < m; ++i) {
    if (merged[i]) continue;
    if (std::all_of(drive[i].begin(), drive[i].end(), [](double v) { return v == 0.0; }) &&
        initial[i] == 0.0)
      continue;  // a rule that never fires adds nothing
    SimulationOptions rule = options;
    rule.initial_voltage_V = initial[i];
    rule.premise_V = {};
    DispatchUniform(SingleRule(model.rules[i].tf), dt_s, drive[i], rule, part.data(), nullptr);
    for (size_t k = 0; k < n; ++k) y[k] += part[k];
  }
}

}  // namespace

// -----------------------------------------------------------------------------------------
// Any grid: event-driven exact propagation. Between events the frozen model and the
// delayed input are constant, so x(t + h) = E x(t) + F u with [E, F] from one matrix
// exponential (discretise.h). Events are the sample times (the voltage, and so the
// operating point, change) and the sample times shifted by the dead time in force.
// -----------------------------------------------------------------------------------------

struct StreamingSimulator::Impl {
  // kParallel: one single-model simulator per rule, driven by its share.
  std::vector<StreamingSimulator> rules;
  std::unique_ptr<ParallelShares> shares;
  std::vector<double> mu;

  double StepParallel(double t_s, double voltage_V, double premise_V) {
    mu = shares->Memberships(premise_V);
    double y = 0.0;
    for (size_t i = 0; i < rules.size(); ++i) y += rules[i].Step(t_s, mu[i] * voltage_V);
    return y;
  }

  TsModel model;
  SimulationOptions options;
  Scheduler scheduler{model};
  bool started = false;
  double t_now_s = 0.0;
  double u_before_V = 0.0;
  Eigen::VectorXd x;
  double max_delay_s = 0.0;
  // Operating points cached by scheduling value; propagators by (operating point, step).
  struct Point {
    OperatingPoint op;
    std::unordered_map<uint64_t, ZohStep> steps;
  };
  std::unordered_map<uint64_t, Point> points;
  std::optional<PreparedRules> prepared;  // the model's rules, once (PrepareRules)
  Point* point = nullptr;                 // in force since the last sample
  // (t_j, u_j), increasing t_j, and the premise's voltage p_j (premise_V) beside it.
  struct Past {
    double t_s, u_V, premise_V;
  };
  std::deque<Past> history;
  double premise_before_V = 0.0;

  // Step quantised to 2^-40 s (about 1e-12 s) so that equal steps on a float grid share
  // one cached propagator; the propagation uses the quantised step.
  static double Quantise(double h_s) { return std::ldexp(std::round(std::ldexp(h_s, 40)), -40); }

  static bool SameTime(double a, double b) {
    return std::abs(a - b) <= 1e-9 * std::max(1.0, std::max(std::abs(a), std::abs(b)));
  }

  void SelectPoint(double voltage_V) {
    const double z = OperatingZ(scheduler, voltage_V, options.scheduling_resolution_V);
    const uint64_t key = std::bit_cast<uint64_t>(z);
    auto it = points.find(key);
    if (it == points.end()) {
      if (points.size() >= 32768) points.clear();
      if (!prepared) prepared = PrepareRules(model);
      it = points.emplace(key, Point{OperatingPointAt(model, *prepared, z), {}}).first;
    }
    point = &it->second;
  }

  // Voltage u(t - T) with the zero-order hold (right-continuous at sample times).
  double DelayedInput(double t_s) const {
    const double at_s = t_s - point->op.ss.delay_s;
    double value = u_before_V;
    for (const Past& p : history) {
      if (p.t_s > at_s && !SameTime(p.t_s, at_s)) break;
      value = p.u_V;
    }
    return value;
  }

  // First time in (t_now, t_end] at which the delayed input switches, if any.
  bool NextSwitch(double t_end_s, double* when_s) const {
    for (const Past& entry : history) {
      const double when = entry.t_s + point->op.ss.delay_s;
      if (when <= t_now_s || SameTime(when, t_now_s)) continue;
      if (when < t_end_s && !SameTime(when, t_end_s)) {
        *when_s = when;
        return true;
      }
      return false;
    }
    return false;
  }

  void Propagate(double h_s, double input_V) {
    h_s = Quantise(h_s);
    if (h_s <= 0.0 || x.size() == 0) return;
    const uint64_t key = std::bit_cast<uint64_t>(h_s);
    auto it = point->steps.find(key);
    if (it == point->steps.end()) {
      if (point->steps.size() >= 1024) point->steps.clear();
      it = point->steps.emplace(key, ExactZohStep(point->op.ss.A, point->op.ss.B, h_s)).first;
    }
    x = it->second.E * x + it->second.F.col(0) * input_V;
  }

  void AdvanceTo(double t_s) {
    double when_s = 0.0;
    while (NextSwitch(t_s, &when_s)) {
      Propagate(when_s - t_now_s, DelayedInput(t_now_s));
      t_now_s = when_s;
    }
    Propagate(t_s - t_now_s, DelayedInput(t_now_s));
    t_now_s = t_s;
  }

  // Drops samples no dead time can reach any more, keeping the one in force.
  void TrimHistory() {
    const double horizon_s = t_now_s - max_delay_s;
    while (history.size() >= 2 && history[1].t_s <= horizon_s &&
           !SameTime(history[1].t_s, horizon_s)) {
      u_before_V = history.front().u_V;
      premise_before_V = history.front().premise_V;
      history.pop_front();
    }
  }

  // The premise's voltage for a sample (t_s, premise_V) not yet in the history: that
  // voltage itself, or for kAbsVoltageDelayed the one in force at t_s - delay.
  double PremiseVoltage(double t_s, double premise_V) const {
    if (model.scheduling != SchedulingVariable::kAbsVoltageDelayed) return premise_V;
    const double at_s = t_s - model.scheduling_delay_s;
    if (SameTime(at_s, t_s)) return premise_V;
    double value = premise_before_V;
    for (const Past& p : history) {
      if (p.t_s > at_s && !SameTime(p.t_s, at_s)) break;
      value = p.premise_V;
    }
    return value;
  }

  double Output() const {
    const double state = x.size() > 0 ? x(0) : 0.0;
    return state + point->op.ss.D * DelayedInput(t_now_s);
  }

  double Step(double t_s, double voltage_V, double premise_V) {
    if (!std::isfinite(t_s) || !std::isfinite(voltage_V) || !std::isfinite(premise_V))
      throw std::invalid_argument("StreamingSimulator: non-finite time or voltage");
    if (!started) {
      started = true;
      t_now_s = t_s;
      u_before_V = options.start_in_steady_state ? voltage_V : options.initial_voltage_V;
      premise_before_V = options.start_in_steady_state ? premise_V : options.initial_voltage_V;
      SelectPoint(premise_before_V);
      x = InitialState(point->op.ss, u_before_V);
      SelectPoint(PremiseVoltage(t_s, premise_V));
    } else {
      if (!(t_s > t_now_s)) throw std::invalid_argument("StreamingSimulator: time not increasing");
      AdvanceTo(t_s);  // under the operating point of the previous sample
      if (x.size() > 0) AddMarkovTerm(point->op.remap, DelayedInput(t_s), +1.0, &x);
      SelectPoint(PremiseVoltage(t_s, premise_V));
      if (x.size() > 0) AddMarkovTerm(point->op.remap, DelayedInput(t_s), -1.0, &x);
    }
    history.push_back({t_s, voltage_V, premise_V});
    TrimHistory();
    return Output();
  }
};

StreamingSimulator::StreamingSimulator(const TsModel& model, const SimulationOptions& options)
    : impl_(std::make_unique<Impl>()) {
  CheckModel(model);
  if (!options.premise_V.empty())
    throw std::invalid_argument("StreamingSimulator takes the premise sample by sample (Step)");
  CheckOptions(options, 0);
  impl_->model = model;
  impl_->options = options;
  if (model.realisation == TsRealisation::kParallel) {
    impl_->shares = std::make_unique<ParallelShares>(impl_->model, options.scheduling_resolution_V);
    const std::vector<double> before = impl_->shares->Memberships(options.initial_voltage_V);
    for (size_t i = 0; i < model.rules.size(); ++i)
      impl_->rules.emplace_back(SingleRule(model.rules[i].tf), RuleOptions(options, before[i]));
    return;
  }
  for (const LocalModel& rule : model.rules)
    impl_->max_delay_s = std::max(impl_->max_delay_s, rule.tf.delay_s);
  if (model.scheduling == SchedulingVariable::kAbsVoltageDelayed)
    impl_->max_delay_s = std::max(impl_->max_delay_s, model.scheduling_delay_s);
}
StreamingSimulator::~StreamingSimulator() = default;
StreamingSimulator::StreamingSimulator(StreamingSimulator&&) noexcept = default;
StreamingSimulator& StreamingSimulator::operator=(StreamingSimulator&&) noexcept = default;

double StreamingSimulator::Step(double t_s, double voltage_V) {
  return Step(t_s, voltage_V, voltage_V);
}

double StreamingSimulator::Step(double t_s, double voltage_V, double premise_V) {
  return impl_->shares ? impl_->StepParallel(t_s, voltage_V, premise_V)
                       : impl_->Step(t_s, voltage_V, premise_V);
}

const std::vector<double>& StreamingSimulator::memberships() const {
  static const std::vector<double> kNone;
  if (impl_->shares) return impl_->mu;
  return impl_->point ? impl_->point->op.mu : kNone;
}

bool IsUniformGrid(std::span<const double> t_s, double* dt_s) {
  if (t_s.size() < 2) return false;
  const double dt = (t_s.back() - t_s.front()) / static_cast<double>(t_s.size() - 1);
  if (!(dt > 0.0)) return false;
  for (size_t k = 1; k < t_s.size(); ++k)
    if (std::abs((t_s[k] - t_s[k - 1]) - dt) > 1e-7 * dt) return false;
  *dt_s = dt;
  return true;
}

std::vector<double> SimulateUniform(const TsModel& model, double dt_s,
                                    std::span<const double> voltage_V,
                                    const SimulationOptions& options,
                                    std::vector<double>* memberships) {
  CheckModel(model);
  CheckOptions(options, voltage_V.size());
  if (!(dt_s > 0.0) || !std::isfinite(dt_s))
    throw std::invalid_argument("sample period must be finite and > 0");
  CheckFinite(voltage_V, "voltage");
  std::vector<double> y(voltage_V.size());
  if (voltage_V.empty()) return y;
  if (model.realisation == TsRealisation::kParallel) {
    ParallelUniform(model, dt_s, voltage_V, options, y.data(), memberships);
    return y;
  }
  DispatchUniform(model, dt_s, voltage_V, options, y.data(), memberships);
  return y;
}

std::vector<double> SimulateUniform(const TransferFunction& tf, double dt_s,
                                    std::span<const double> voltage_V,
                                    const SimulationOptions& options) {
  return SimulateUniform(SingleRule(tf), dt_s, voltage_V, options);
}

double SchedulingResolutionFor(double max_abs_V, bool plateau_input) {
  return plateau_input ? kSchedulingResolution_V
                       : std::max(kSchedulingResolution_V, std::abs(max_abs_V) / 256.0);
}

std::vector<double> Simulate(const TsModel& model, std::span<const double> t_s,
                             std::span<const double> voltage_V, const SimulationOptions& options,
                             std::vector<double>* memberships) {
  CheckModel(model);
  CheckSeries(t_s, voltage_V);
  double dt_s = 0.0;
  if (IsUniformGrid(t_s, &dt_s))
    return SimulateUniform(model, dt_s, voltage_V, options, memberships);
  CheckOptions(options, voltage_V.size());
  SimulationOptions streaming = options;
  streaming.premise_V = {};
  StreamingSimulator simulator(model, streaming);
  std::vector<double> y(t_s.size());
  const size_t m = model.rules.size();
  if (memberships) memberships->resize(t_s.size() * m);
  for (size_t k = 0; k < t_s.size(); ++k) {
    y[k] = simulator.Step(t_s[k], voltage_V[k],
                          options.premise_V.empty() ? voltage_V[k] : options.premise_V[k]);
    if (memberships)
      std::copy(simulator.memberships().begin(), simulator.memberships().end(),
                memberships->begin() + static_cast<long>(k * m));
  }
  return y;
}

std::vector<double> Simulate(const TransferFunction& tf, std::span<const double> t_s,
                             std::span<const double> voltage_V, const SimulationOptions& options) {
  return Simulate(SingleRule(tf), t_s, voltage_V, options);
}

}  // namespace flexid::model
