// Figures of fit used throughout flexid: fit %, RMSE, noise, and the validation figures
// (FitFigures) every identification and diagnosis reports.
#pragma once

#include <cstddef>
#include <span>
#include <vector>

#include "model/core/residual_tests.h"

namespace flexid::model {

// fit % = 100 (1 - ||y - yhat|| / ||y - mean(y)||) (NRMSE fit; 100 is perfect, 0 is no
// better than the mean, negative is worse). Precondition: equal, non-zero lengths.
double FitPercent(std::span<const double> measured, std::span<const double> predicted);

// Root-mean-square of y - yhat, in the output's units (mm).
double Rmse(std::span<const double> measured, std::span<const double> predicted);

// Robust standard deviation 1.4826 * median(|v - median(v)|) (the MAD scaled to a normal
// distribution); 0 for no values.
double RobustSpread(std::vector<double> values);

// Sensor noise of a measured signal from the data alone: sigma = RobustSpread(d2 y) /
// sqrt(6), with d2 y_k = y_k - 2 y_{k-1} + y_{k-2} (white noise of variance sigma^2 gives
// d2 y of variance 6 sigma^2; a slow, smooth response contributes little and the few
// steps are outliers to the median). 0 for fewer than 3 samples.
double NoiseFromSecondDifferences(std::span<const double> y);

// The figures every validation reports: fit %, RMSE (mm) and the residual tests.
struct FitFigures {
  size_t samples = 0;
  double fit_percent = 0.0;
  double rmse_mm = 0.0;
  WhitenessTest whiteness;
  CrossCorrelationTest cross_correlation;
};

// Fit %, RMSE and the residual tests of predictions against measurements (the tests are
// left empty when the residual or the input has no variance, e.g. a perfect fit).
FitFigures FitFiguresOf(std::span<const double> measured, std::span<const double> predicted,
                        std::span<const double> input, int correlation_lags = 25);

}  // namespace flexid::model
