#include "model/control/reference.h"

#include <algorithm>
#include <cmath>
#include <sstream>
#include <stdexcept>

#include "model/core/errors.h"
#include "model/core/recording.h"

namespace flexid::model::control {

Reference::Reference(std::vector<double> t_s, std::vector<double> deflection_mm, std::string source)
    : t_s_(std::move(t_s)), deflection_mm_(std::move(deflection_mm)), source_(std::move(source)) {
  if (t_s_.empty()) throw InputError(source_ + ": the reference has no samples");
  if (t_s_.size() != deflection_mm_.size())
    throw InputError(source_ + ": the reference's time and deflection differ in length");
  for (size_t k = 0; k < t_s_.size(); ++k) {
    std::ostringstream why;
    if (!std::isfinite(t_s_[k]) || !std::isfinite(deflection_mm_[k]))
      why << "sample " << k + 1 << " is not finite";
    else if (k == 0 && t_s_[k] < 0.0)
      why << "time starts at " << t_s_[k] << " s, before 0 (t = 0 is the start of the run)";
    else if (k > 0 && !(t_s_[k] > t_s_[k - 1]))
      why << "time is not strictly increasing at sample " << k + 1 << " (" << t_s_[k] << " s after "
          << t_s_[k - 1] << " s)";
    else
      continue;
    throw InputError(source_ + ": " + why.str());
  }
}

double Reference::At(double t_s) const {
  if (t_s <= t_s_.front()) return deflection_mm_.front();
  if (t_s >= t_s_.back()) return deflection_mm_.back();
  const auto after = std::upper_bound(t_s_.begin(), t_s_.end(), t_s) - t_s_.begin();
  const auto i = static_cast<size_t>(after - 1);
  const double w = (t_s - t_s_[i]) / (t_s_[i + 1] - t_s_[i]);
  return (1.0 - w) * deflection_mm_[i] + w * deflection_mm_[i + 1];
}

Reference ReadReferenceCsv(const std::string& path) {
  CsvReadOptions options;
  options.require_voltage = false;
  Recording recording = ReadRecordingCsv(path, options);
  return Reference(std::move(recording.t_s), std::move(recording.deflection_mm), path);
}

SteadyStateMap::SteadyStateMap(const TsModel& model, double min_V, double max_V, double step_V)
    : min_V_(min_V), max_V_(max_V), step_V_(step_V) {
  std::string why;
  if (!IsValid(model, &why)) throw std::invalid_argument("SteadyStateMap: invalid model: " + why);
  if (!(std::isfinite(min_V) && std::isfinite(max_V) && min_V < max_V && step_V > 0.0))
    throw std::invalid_argument("SteadyStateMap: bad voltage range or step");
  const auto count = static_cast<size_t>(std::ceil((max_V - min_V) / step_V - 1e-9)) + 1;
  step_V_ = (max_V - min_V) / static_cast<double>(count - 1);
  deflection_mm_.reserve(count);
  for (size_t i = 0; i < count; ++i) {
    const double u_V = i + 1 == count ? max_V : min_V + static_cast<double>(i) * step_V_;
    const double gain = DcGain(FrozenModelAt(model, SchedulingValue(model, u_V)));
    deflection_mm_.push_back(u_V == 0.0 ? 0.0 : gain * u_V);
  }
  const auto [low, high] = std::minmax_element(deflection_mm_.begin(), deflection_mm_.end());
  lowest_mm_ = *low;
  highest_mm_ = *high;
  if (!std::isfinite(lowest_mm_) || !std::isfinite(highest_mm_))
    throw std::invalid_argument(
        "SteadyStateMap: the model has no finite steady state (a pole at 0)");
}

double SteadyStateMap::DeflectionAt(double voltage_V) const {
  const double position = (std::clamp(voltage_V, min_V_, max_V_) - min_V_) / step_V_;
  const auto i = std::min(static_cast<size_t>(position), deflection_mm_.size() - 2);
  const double w = position - static_cast<double>(i);
  return (1.0 - w) * deflection_mm_[i] + w * deflection_mm_[i + 1];
}

double SteadyStateMap::SlopeAt(double voltage_V) const {
  const double low = std::max(min_V_, voltage_V - step_V_);
  const double high = std::min(max_V_, voltage_V + step_V_);
  return (DeflectionAt(high) - DeflectionAt(low)) / (high - low);
}

double SteadyStateMap::VoltageFor(double deflection_mm) const {
  // Each segment [u_i, u_{i+1}] is linear: the nearest point of each, the best of all.
  double best_V = 0.0, best_distance = INFINITY;
  for (size_t i = 0; i + 1 < deflection_mm_.size(); ++i) {
    const double y0 = deflection_mm_[i], y1 = deflection_mm_[i + 1];
    const double w = y1 == y0 ? 0.0 : std::clamp((deflection_mm - y0) / (y1 - y0), 0.0, 1.0);
    const double u_V = min_V_ + (static_cast<double>(i) + w) * step_V_;
    const double distance = std::abs(y0 + w * (y1 - y0) - deflection_mm);
    if (distance < best_distance - 1e-12 ||
        (distance <= best_distance + 1e-12 && std::abs(u_V) < std::abs(best_V))) {
      best_distance = distance;
      best_V = u_V;
    }
  }
  return best_V;
}

std::string ReachabilityProblem(const Reference& reference, const SteadyStateMap& map) {
  constexpr double kTolerance_mm = 1e-9;
  for (size_t k = 0; k < reference.t_s().size(); ++k) {
    const double y = reference.deflection_mm()[k];
    if (y >= map.lowest_mm() - kTolerance_mm && y <= map.highest_mm() + kTolerance_mm) continue;
    std::ostringstream why;
    why.precision(4);
    why << "the reference is " << y << " mm at t = " << reference.t_s()[k]
        << " s, outside what the model reaches in steady state within " << map.min_V() << " .. "
        << map.max_V() << " V (" << map.lowest_mm() << " .. " << map.highest_mm() << " mm)";
    return why.str();
  }
  return "";
}

}  // namespace flexid::model::control
