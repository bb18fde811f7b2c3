#include "model/control/mpc.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "model/control/box_qp.h"

namespace flexid::model::control {

bool MpcOptions::IsValid(std::string* error) const {
  std::ostringstream why;
  if (!(horizon_s > 0.0 && std::isfinite(horizon_s)))
    why << "the horizon must be finite and > 0 s (got " << horizon_s << ")";
  else if (!(replan_s > 0.0 && replan_s < horizon_s))
    why << "the replan period must be > 0 and shorter than the horizon (got " << replan_s << " s)";
  else if (!(move_weight >= 0.0 && effort_weight >= 0.0 && terminal_weight >= 0.0) ||
           !std::isfinite(move_weight + effort_weight + terminal_weight))
    why << "the weights must be finite and >= 0";
  else if (!(disturbance_time_constant_s >= 0.0 && std::isfinite(disturbance_time_constant_s)))
    why << "the mismatch filter's time constant must be finite and >= 0 s";
  else if (!(fine_horizon_s >= 0.0 && std::isfinite(fine_horizon_s)))
    why << "the fine horizon must be finite and >= 0 s";
  else if (!(probe_V > 0.0 && std::isfinite(probe_V)))
    why << "the probe voltage must be finite and > 0 V";
  else
    return true;
  *error = why.str();
  return false;
}

namespace {

// First samples (from 1) of the blocks, then H + 1: blocks of R samples up to sample F,
// then 2R, 2R, 4R, 4R, ... up to H.
std::vector<long> BlockStarts(long replan, long fine, long horizon) {
  std::vector<long> starts = {1};
  while (starts.back() + replan <= std::min(fine, horizon) + 1)
    starts.push_back(starts.back() + replan);
  long length = 2 * replan;
  for (int b = 0; starts.back() <= horizon; ++b) {
    starts.push_back(std::min(starts.back() + length, horizon + 1));
    if (b % 2 == 1) length *= 2;
  }
  return starts;
}

}  // namespace

PredictiveController::PredictiveController(const TsModel& model, const Reference& reference,
                                           const ControlLimits& limits, double sample_period_s,
                                           const MpcOptions& options, bool feedback)
    : reference_(reference),
      limits_(limits),
      sample_period_s_(sample_period_s),
      options_(options),
      feedback_(feedback),
      model_(model, sample_period_s),
      steady_(model, limits.min_V, limits.max_V) {
  std::string why;
  if (!options.IsValid(&why)) throw std::invalid_argument("MPC: " + why);
  if (!limits.IsValid(&why)) throw std::invalid_argument("MPC: " + why);
  if (!(options.horizon_s > model_.max_delay_s() + options.replan_s)) {
    std::ostringstream text;
    text << "MPC: the horizon (" << options.horizon_s
         << " s) must be longer than the model's dead time (" << model_.max_delay_s()
         << " s) plus the replan period (" << options.replan_s << " s)";
    throw std::invalid_argument(text.str());
  }
  horizon_ = std::lround(options.horizon_s / sample_period_s);
  const long replan = std::max(1L, std::lround(options.replan_s / sample_period_s));
  const long fine = std::lround((model_.max_delay_s() + options.fine_horizon_s) / sample_period_s);
  block_starts_ = BlockStarts(replan, fine, horizon_);
}

double PredictiveController::Next(long k, const CommandLimiter& limiter, double measured_mm,
                                  double* model_mm) {
  const double m_k = model_.Step(limiter.last_V());
  if (model_mm) *model_mm = m_k;
  if (feedback_ && std::isfinite(measured_mm)) {
    const double e_k = measured_mm - m_k;
    const double tau = options_.disturbance_time_constant_s;
    const double a = sample_period_s_ / (tau + sample_period_s_);
    mismatch_mm_ = have_mismatch_ ? mismatch_mm_ + a * (e_k - mismatch_mm_) : e_k;
    have_mismatch_ = true;
  }
  const long first_block = block_starts_[1] - block_starts_[0];
  if (plan_start_ < 0 || k - plan_start_ >= first_block) Replan(k, limiter);
  return plan_V_[static_cast<size_t>(k - plan_start_)];  // u_{k+1}: index k + 1 - plan_start_ - 1
}

std::vector<double> PredictiveController::Expand(const std::vector<double>& blocks,
                                                 const CommandLimiter& limiter) const {
  std::vector<double> voltages(static_cast<size_t>(horizon_));
  CommandLimiter ahead = limiter;
  size_t b = 0;
  for (long j = 1; j <= horizon_; ++j) {
    while (j >= block_starts_[b + 1]) ++b;
    voltages[static_cast<size_t>(j - 1)] = ahead.Apply(blocks[b]);
  }
  return voltages;
}

void PredictiveController::Bounds(const CommandLimiter& limiter, const Eigen::VectorXd& U0,
                                  Eigen::VectorXd* lo, Eigen::VectorXd* hi) const {
  const double applied_V = limiter.last_V(), dt = sample_period_s_;
  // left_after[s]: the applied charge still in the window s samples from now.
  const std::vector<double> charges = limiter.WindowCharges();
  const auto window = static_cast<long>(charges.size());
  std::vector<double> left_after(charges.size() + 1, 0.0);
  for (long s = window - 1; s >= 0; --s)
    left_after[static_cast<size_t>(s)] = left_after[static_cast<size_t>(s + 1)] + charges[s];
  for (Eigen::Index b = 0; b < U0.size(); ++b) {
    const auto a = static_cast<size_t>(b);
    const long start = block_starts_[a], end = block_starts_[a + 1] - 1;  // samples from 1
    // The limiter ramps towards the block's voltage sample by sample (Expand), so the block
    // may ask for what the rate reaches by its end; bounding it by its start held the
    // first block to a fifth of the rate limit while the plan counted on the whole of it
    // for the later blocks.
    const double reach_V = limits_.rate_V_per_s * dt * static_cast<double>(end);
    (*lo)(b) = std::max(limits_.min_V, applied_V - reach_V);
    (*hi)(b) = std::min(limits_.max_V, applied_V + reach_V);
    if (std::isinf(limits_.max_charge_Vs)) continue;
    // The window ending with the block: the applied samples still in it, the earlier
    // blocks' samples in it (at U0), and what is left for this block.
    double used_Vs = left_after[static_cast<size_t>(std::min(end, window))];
    for (size_t e = 0; e < a; ++e) {
      const long first = std::max(block_starts_[e], end - window + 1);
      const long last = block_starts_[e + 1] - 1;
      if (last >= first)
        used_Vs +=
            std::abs(U0(static_cast<Eigen::Index>(e))) * dt * static_cast<double>(last - first + 1);
    }
    const double length = static_cast<double>(std::min(end - start + 1, window));
    const double bound_V = std::max(0.0, (limits_.max_charge_Vs - used_Vs) / (length * dt));
    (*lo)(b) = std::max((*lo)(b), -bound_V);
    (*hi)(b) = std::min((*hi)(b), bound_V);
    if ((*lo)(b) > (*hi)(b)) (*lo)(b) = (*hi)(b) = std::clamp(0.0, (*lo)(b), (*hi)(b));
  }
}

std::vector<double> PredictiveController::Simulate(const std::vector<double>& voltages_V) const {
  TsPredictor ahead = model_;
  std::vector<double> y(voltages_V.size());
  for (size_t j = 0; j < voltages_V.size(); ++j) y[j] = ahead.Step(voltages_V[j]);
  return y;
}

void PredictiveController::Replan(long k, const CommandLimiter& limiter) {
  const double applied_V = limiter.last_V();
  const auto blocks = static_cast<Eigen::Index>(block_starts_.size() - 1);
  const auto H = static_cast<size_t>(horizon_);
  // U0: the previous plan at each block's start (its last value beyond it), else u_k.
  Eigen::VectorXd U0 = Eigen::VectorXd::Constant(blocks, applied_V);
  if (plan_start_ >= 0)
    for (Eigen::Index b = 0; b < blocks; ++b) {
      const long index = k + block_starts_[static_cast<size_t>(b)] - plan_start_ - 1;
      U0(b) = plan_V_[static_cast<size_t>(std::min<long>(index, horizon_ - 1))];
    }
  const std::vector<double> base =
      Simulate(Expand(std::vector<double>(U0.data(), U0.data() + blocks), limiter));
  // g(n): the response n samples after a unit step of the voltage at sample k+1.
  const double probe =
      applied_V + options_.probe_V <= limits_.max_V ? options_.probe_V : -options_.probe_V;
  const std::vector<double> free = Simulate(std::vector<double>(H, applied_V));
  const std::vector<double> probed = Simulate(std::vector<double>(H, applied_V + probe));
  auto g = [&](long n) { return n <= 0 ? 0.0 : (probed[n - 1] - free[n - 1]) / probe; };

  // Rows: the tracking every R samples, 1 terminal, the blocks' moves and efforts.
  const long stride = block_starts_[1] - block_starts_[0];
  const long tracked = horizon_ / stride;
  const Eigen::Index rows = tracked + 1 + 2 * blocks;
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(rows, blocks);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(rows);
  const double d = feedback_ ? mismatch_mm_ : 0.0;
  const double w_track = 1.0 / std::sqrt(static_cast<double>(tracked));
  for (long i = 0; i < tracked; ++i) {
    const long j = (i + 1) * stride;
    const double r = reference_.At(static_cast<double>(k + j) * sample_period_s_);
    double offset = base[static_cast<size_t>(j - 1)] + d - r;
    for (Eigen::Index b = 0; b < blocks; ++b) {
      const auto a = static_cast<size_t>(b);
      const double s = g(j - block_starts_[a] + 1) - g(j - block_starts_[a + 1] + 1);
      A(i, b) = w_track * s;
      offset -= s * U0(b);
    }
    rhs(i) = -w_track * offset;
  }
  const double w_term = std::sqrt(options_.terminal_weight);
  const double last = U0(blocks - 1), slope = steady_.SlopeAt(last);
  const double r_end = reference_.At(static_cast<double>(k + horizon_) * sample_period_s_);
  A(tracked, blocks - 1) = w_term * slope;
  rhs(tracked) = -w_term * (steady_.DeflectionAt(last) - slope * last + d - r_end);
  const double w_move = std::sqrt(options_.move_weight);
  for (Eigen::Index b = 0; b < blocks; ++b) {
    const auto a = static_cast<size_t>(b);
    const Eigen::Index row = tracked + 1 + b;
    A(row, b) = w_move;
    if (b > 0)
      A(row, b - 1) = -w_move;
    else
      rhs(row) = w_move * applied_V;
    // Effort: the voltage beyond what holds the reference where the block acts (its middle,
    // a dead time on), minus the mismatch.
    const double share =
        static_cast<double>(block_starts_[a + 1] - block_starts_[a]) / static_cast<double>(H);
    const double acts_s =
        static_cast<double>(k) * sample_period_s_ + model_.max_delay_s() +
        0.5 * static_cast<double>(block_starts_[a] + block_starts_[a + 1]) * sample_period_s_;
    const double w_effort = std::sqrt(options_.effort_weight * share);
    A(tracked + 1 + blocks + b, b) = w_effort;
    rhs(tracked + 1 + blocks + b) = w_effort * steady_.VoltageFor(reference_.At(acts_s) - d);
  }
  Eigen::VectorXd lo(blocks), hi(blocks);
  Bounds(limiter, U0, &lo, &hi);
  Eigen::MatrixXd M = A.transpose() * A;
  M.diagonal().array() += 1e-9 * std::max(1.0, M.diagonal().maxCoeff());
  const BoxQpResult solution = SolveBoxQp(M, A.transpose() * rhs, lo, hi, U0);
  const Eigen::VectorXd& U = solution.x;
  plan_V_ = Expand(std::vector<double>(U.data(), U.data() + blocks), limiter);
  plan_start_ = k;
  ++replans_;
}

}  // namespace flexid::model::control
