// Figures of fit used throughout flexid.
#pragma once

#include <span>

namespace flexid::model {

// fit % = 100 (1 - ||y - yhat|| / ||y - mean(y)||) (NRMSE fit; 100 is perfect, 0 is no
// better than the mean, negative is worse). Precondition: equal, non-zero lengths.
double FitPercent(std::span<const double> measured, std::span<const double> predicted);

// Root-mean-square of y - yhat, in the output's units (mm).
double Rmse(std::span<const double> measured, std::span<const double> predicted);

}  // namespace flexid::model
