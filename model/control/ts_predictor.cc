#include "model/control/ts_predictor.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "model/core/discretise.h"
#include "model/core/state_space.h"

namespace flexid::model::control {

struct TsPredictor::Entry {
  Eigen::MatrixXd Phi;
  Eigen::VectorXd Gamma0, Gamma1;
  double D = 0.0;
  long delay_samples = 0;
  bool fractional = false;
  // Markov parameters h_0..h_{n-1}: the state is re-expressed with them at a change of
  // operating point so that the output and its derivatives stay continuous (simulate.cc).
  Eigen::VectorXd remap;
  Eigen::VectorXd steady_per_V;  // the state under 1 V held forever (zero with a pole at 0)
};

struct TsPredictor::Channel {
  std::shared_ptr<const Entry> entry;  // null until the first sample (kFrozen)
  Eigen::VectorXd x;
  std::vector<double> inputs;  // ring: the input of sample j at j mod size

  double Input(long j) const {
    const auto size = static_cast<long>(inputs.size());
    return inputs[static_cast<size_t>(((j % size) + size) % size)];
  }
  void SetInput(long j, double value) {
    const auto size = static_cast<long>(inputs.size());
    inputs[static_cast<size_t>(((j % size) + size) % size)] = value;
  }
  // The input the dead time delivers at sample k: u_{k-d}, or u_{k-d-1} with a fraction.
  double Delayed(const Entry& e, long k) const {
    return Input(e.fractional ? k - e.delay_samples - 1 : k - e.delay_samples);
  }
  // y_k, then x_{k+1} (the header's equations).
  double Advance(long k) {
    const Entry& e = *entry;
    const double u_now = Input(k - e.delay_samples), u_prev = Input(k - e.delay_samples - 1);
    const double y = (x.size() > 0 ? x(0) : 0.0) + e.D * (e.fractional ? u_prev : u_now);
    if (x.size() > 0) x = e.Phi * x + e.Gamma0 * u_now + e.Gamma1 * u_prev;
    return y;
  }
};

struct TsPredictor::Shared {
  TsModel model;
  PreparedRules prepared;
  double resolution_V = 0.0;
  long premise_delay = 0;  // kAbsVoltageDelayed: samples between a voltage and its premise
  std::unordered_map<uint64_t, std::shared_ptr<const Entry>> frozen;  // by rounded z
  std::unordered_map<uint64_t, std::vector<double>> memberships;      // by rounded z
};

std::shared_ptr<const TsPredictor::Entry> TsPredictor::MakeEntry(const TransferFunction& tf,
                                                                 double dt_s) {
  auto entry = std::make_shared<Entry>();
  const StateSpace ss = RealiseOutputDerivativeForm(tf);
  const DiscreteModel dm = DiscretiseZoh(ss, dt_s);
  entry->Phi = dm.Phi;
  entry->Gamma0 = dm.Gamma0;
  entry->Gamma1 = dm.Gamma1;
  entry->D = dm.D;
  entry->delay_samples = dm.delay_samples;
  entry->fractional = dm.delay_fraction > 0.0;
  entry->remap = MarkovParameters(tf).head(ss.A.rows());
  entry->steady_per_V = Eigen::VectorXd::Zero(ss.A.rows());
  if (ss.A.rows() > 0) {
    Eigen::FullPivLU<Eigen::MatrixXd> lu(ss.A);
    if (lu.isInvertible()) entry->steady_per_V = lu.solve(-ss.B);
  }
  return entry;
}

TsPredictor::TsPredictor(const TsModel& model, double sample_period_s, double initial_voltage_V,
                         double resolution_V)
    : shared_(std::make_shared<Shared>()),
      scheduler_(shared_->model),
      sample_period_s_(sample_period_s),
      last_voltage_V_(initial_voltage_V) {
  std::string why;
  if (!IsValid(model, &why)) throw std::invalid_argument("TsPredictor: invalid model: " + why);
  if (!(sample_period_s > 0.0 && std::isfinite(sample_period_s)))
    throw std::invalid_argument("TsPredictor: the sample period must be finite and > 0 s");
  if (!(resolution_V > 0.0 && std::isfinite(resolution_V)) || !std::isfinite(initial_voltage_V))
    throw std::invalid_argument("TsPredictor: bad resolution or initial voltage");
  shared_->model = model;
  shared_->prepared = PrepareRules(shared_->model);
  shared_->resolution_V = resolution_V;
  if (model.scheduling == SchedulingVariable::kAbsVoltageDelayed)
    shared_->premise_delay =
        static_cast<long>(std::ceil(model.scheduling_delay_s / sample_period_s - 1e-9));
  const long ring =
      static_cast<long>(std::ceil(max_delay_s() / sample_period_s)) + shared_->premise_delay + 3;
  premise_V_.assign(static_cast<size_t>(shared_->premise_delay + 1), initial_voltage_V);

  const double z_before = RoundedZ(initial_voltage_V);
  if (model.realisation == TsRealisation::kParallel) {
    const std::vector<double> before = MembershipsAt(z_before);
    for (size_t i = 0; i < model.rules.size(); ++i) {
      const double share_V = before[i] * initial_voltage_V;
      Channel channel;
      channel.entry = MakeEntry(FrozenModelAt(SingleRule(model.rules[i].tf), 0.0), sample_period_s);
      channel.x = channel.entry->steady_per_V * share_V;
      channel.inputs.assign(static_cast<size_t>(ring), share_V);
      channels_.push_back(std::move(channel));
    }
    return;
  }
  Channel channel;
  channel.x = FrozenEntryAt(z_before)->steady_per_V * initial_voltage_V;
  channel.inputs.assign(static_cast<size_t>(ring), initial_voltage_V);
  channels_.push_back(std::move(channel));
}

TsPredictor::TsPredictor(const TsPredictor&) = default;
TsPredictor& TsPredictor::operator=(const TsPredictor&) = default;
TsPredictor::TsPredictor(TsPredictor&&) noexcept = default;
TsPredictor& TsPredictor::operator=(TsPredictor&&) noexcept = default;
TsPredictor::~TsPredictor() = default;

double TsPredictor::max_delay_s() const {
  double delay_s = 0.0;
  for (const LocalModel& rule : shared_->model.rules) delay_s = std::max(delay_s, rule.tf.delay_s);
  return delay_s;
}

double TsPredictor::RoundedZ(double premise_V) {
  const double resolution_V = shared_->resolution_V;
  return std::round(scheduler_.Next(premise_V) / resolution_V) * resolution_V;
}

std::shared_ptr<const TsPredictor::Entry> TsPredictor::FrozenEntryAt(double z) const {
  const uint64_t key = std::bit_cast<uint64_t>(z);
  auto it = shared_->frozen.find(key);
  if (it != shared_->frozen.end()) return it->second;
  std::vector<double> mu;
  NormalisedMemberships(shared_->model, z, &mu);
  const TransferFunction frozen = BlendedTransferFunction(shared_->model, shared_->prepared, mu);
  return shared_->frozen.emplace(key, MakeEntry(frozen, sample_period_s_)).first->second;
}

const std::vector<double>& TsPredictor::MembershipsAt(double z) const {
  const uint64_t key = std::bit_cast<uint64_t>(z);
  auto it = shared_->memberships.find(key);
  if (it == shared_->memberships.end()) {
    std::vector<double> mu;
    NormalisedMemberships(shared_->model, z, &mu);
    it = shared_->memberships.emplace(key, std::move(mu)).first;
  }
  return it->second;
}

double TsPredictor::Step(double voltage_V) {
  if (!std::isfinite(voltage_V)) throw std::invalid_argument("TsPredictor: non-finite voltage");
  const double y = shared_->model.realisation == TsRealisation::kParallel ? StepParallel(voltage_V)
                                                                          : StepFrozen(voltage_V);
  last_voltage_V_ = voltage_V;
  ++k_;
  return y;
}

double TsPredictor::StepFrozen(double voltage_V) {
  Channel& channel = channels_.front();
  const long k = k_;
  channel.SetInput(k, voltage_V);
  // The premise: u_k, or for kAbsVoltageDelayed u_{k - premise_delay}.
  const auto premise_size = static_cast<long>(premise_V_.size());
  premise_V_[static_cast<size_t>(k % premise_size)] = voltage_V;
  const double premise_V = premise_V_[static_cast<size_t>((k + 1) % premise_size)];
  const bool single = shared_->model.rules.size() == 1;
  if (channel.entry == nullptr || (!single && premise_V != last_premise_V_)) {
    const uint64_t key = single ? 0 : std::bit_cast<uint64_t>(RoundedZ(premise_V));
    if (key != last_key_) {
      const bool switching = channel.entry != nullptr && channel.x.size() > 0;
      if (switching) channel.x += channel.entry->remap * channel.Delayed(*channel.entry, k);
      channel.entry = FrozenEntryAt(std::bit_cast<double>(key));
      if (switching) channel.x -= channel.entry->remap * channel.Delayed(*channel.entry, k);
      last_key_ = key;
    }
  }
  last_premise_V_ = premise_V;
  return channel.Advance(k);
}

double TsPredictor::StepParallel(double voltage_V) {
  const std::vector<double>& mu = MembershipsAt(RoundedZ(voltage_V));
  double y = 0.0;
  for (size_t i = 0; i < channels_.size(); ++i) {
    channels_[i].SetInput(k_, mu[i] * voltage_V);
    y += channels_[i].Advance(k_);
  }
  return y;
}

}  // namespace flexid::model::control
