#include "model/core/metrics.h"

#include <algorithm>
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

double RobustSpread(std::vector<double> values) {
  if (values.empty()) return 0.0;
  auto median = [](std::vector<double>& v) {
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  const double centre = median(values);
  for (double& v : values) v = std::abs(v - centre);
  return 1.4826 * median(values);
}

double NoiseFromSecondDifferences(std::span<const double> y) {
  std::vector<double> second;
  for (size_t k = 2; k < y.size(); ++k) second.push_back(y[k] - 2.0 * y[k - 1] + y[k - 2]);
  return RobustSpread(std::move(second)) / std::sqrt(6.0);
}

FitFigures FitFiguresOf(std::span<const double> measured, std::span<const double> predicted,
                        std::span<const double> input, int correlation_lags) {
  FitFigures fit;
  fit.samples = measured.size();
  fit.fit_percent = FitPercent(measured, predicted);
  fit.rmse_mm = Rmse(measured, predicted);
  std::vector<double> residual(measured.size());
  double residual_spread = 0.0, input_spread = 0.0;
  for (size_t k = 0; k < residual.size(); ++k) {
    residual[k] = measured[k] - predicted[k];
    residual_spread = std::max(residual_spread, std::abs(residual[k] - residual.front()));
    input_spread = std::max(input_spread, std::abs(input[k] - input.front()));
  }
  const int lags = std::min<int>(correlation_lags, static_cast<int>(residual.size() / 4));
  if (lags >= 1 && residual_spread > 0.0) {
    fit.whiteness = TestWhiteness(residual, lags);
    if (input_spread > 0.0)
      fit.cross_correlation = TestInputResidualCorrelation(input, residual, lags);
  }
  return fit;
}

}  // namespace flexid::model
