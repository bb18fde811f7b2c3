// Continuous-time transfer function with dead time, the seed's Eq. (13) / Eq. (18):
//
//   G(s) = e^{-T s} (a1 s^m + ... + a_{m+1}) / (b1 s^n + ... + b_{n+1}),   m <= n,
//
// where T = delay_s >= 0 is the dead time (the seed writes e^{beta s} with beta = -T).
// Input is the applied voltage in V; output is the tip deflection (mm in flexid's data).
#pragma once

#include <complex>
#include <string>
#include <vector>

namespace flexid::model {

struct TransferFunction {
  std::vector<double> num;  // numerator, highest power first
  std::vector<double> den;  // denominator, highest power first, den[0] != 0
  double delay_s = 0.0;     // dead time T in seconds (>= 0)
};

// Checks that coefficients are finite, the denominator is non-zero with a non-zero
// leading coefficient, the model is proper (deg num <= deg den) and the delay is finite
// and non-negative. On failure returns false and writes a sentence to *error.
bool IsValid(const TransferFunction& tf, std::string* error);

// Same model with den[0] == 1 and leading zeros trimmed.
TransferFunction Normalised(const TransferFunction& tf);

int Order(const TransferFunction& tf);  // degree of the denominator

std::vector<std::complex<double>> Poles(const TransferFunction& tf);
std::vector<std::complex<double>> Zeros(const TransferFunction& tf);

// Steady-state gain G(0) = num(0) / den(0) (output units per volt); +-inf with a pole at 0.
double DcGain(const TransferFunction& tf);

bool IsStable(const TransferFunction& tf);  // every pole strictly in the left half-plane

// One entry per real pole and per complex-conjugate pair (the member with Im > 0).
struct Mode {
  std::complex<double> pole;
  double natural_frequency_rad_s = 0.0;  // |p|
  double damping_ratio = 0.0;            // -Re(p)/|p|: 1 for a stable real pole
  double time_constant_s = 0.0;          // -1/Re(p): decay time of the mode's envelope
  bool oscillatory = false;              // complex pair
};
std::vector<Mode> Modes(const TransferFunction& tf);

// G(j omega) including the dead-time phase e^{-j omega T}.
std::complex<double> FrequencyResponse(const TransferFunction& tf, double omega_rad_s);

// Response to a unit step applied at t = 0 from rest, at the given times (s, >= 0,
// non-decreasing). Exact: computed with the matrix exponential, not by integration.
std::vector<double> StepResponse(const TransferFunction& tf, const std::vector<double>& t_s);

// The physics chain (Eqs. 11-13) predicts real poles and a step response that rises to
// its final value without falling back; a fitted model that falls back has a slow
// pole-zero pair (back-relaxation, or model order). Measured on the exact step response
// after the fast transients (5 time constants of every mode faster than 5 s, oscillatory
// ones included, after the dead time): the largest excess over the final value, as a
// share of it, and the time constant of the decay from the peak back to the final value
// (share 0: no fall-back, or still rising at the end).
struct FallBack {
  double share = 0.0;
  double peak_time_s = 0.0;
  double tau_s = 0.0;
};
FallBack StepFallBack(const TransferFunction& tf);

}  // namespace flexid::model
