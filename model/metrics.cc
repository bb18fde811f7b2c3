#include "model/metrics.h"

#include <cmath>
#include <stdexcept>

namespace flexid::model {
namespace {

void CheckLengths(std::span<const double> a, std::span<const double> b) {
  if (a.size() != b.size() || a.empty())
    throw std::invalid_argument("fit figures need two series of equal, non-zero length");
}

}  // namespace

double FitPercent(std::span<const double> measured, std::span<const double> predicted) {
  CheckLengths(measured, predicted);
  double mean = 0.0;
  for (double y : measured) mean += y;
  mean /= static_cast<double>(measured.size());
  double error = 0.0, spread = 0.0;
  for (size_t k = 0; k < measured.size(); ++k) {
    error += (measured[k] - predicted[k]) * (measured[k] - predicted[k]);
    spread += (measured[k] - mean) * (measured[k] - mean);
  }
  if (spread == 0.0) return error == 0.0 ? 100.0 : -INFINITY;
  return 100.0 * (1.0 - std::sqrt(error / spread));
}

double Rmse(std::span<const double> measured, std::span<const double> predicted) {
  CheckLengths(measured, predicted);
  double error = 0.0;
  for (size_t k = 0; k < measured.size(); ++k)
    error += (measured[k] - predicted[k]) * (measured[k] - predicted[k]);
  return std::sqrt(error / static_cast<double>(measured.size()));
}

}  // namespace flexid::model
