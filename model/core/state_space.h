// State-space realisation used for simulation and for blending local models (Eq. 17).
//
//   x' = A x + B u(t - T),   y = C x + D u(t - T)
//
// flexid uses one canonical form everywhere: the observability form whose states are
// the output and its derivatives, built from the Markov parameters h_k of
// G(s) = h0 + h1 s^-1 + h2 s^-2 + ... (delay excluded):
//
//       [ 0    1    0  ...  0  ]        [ h1 ]
//   A = [ 0    0    1  ...  0  ],   B = [ h2 ],   C = [1 0 ... 0],   D = h0,
//       [ ...                  ]        [ .. ]
//       [-a_n -a_{n-1} ... -a_1]        [ hn ]
//
// with den = s^n + a1 s^{n-1} + ... + a_n and h_k = b_k - sum_{i=1..k} a_i h_{k-i}.
// x1 = y - h0 u, x2 = x1' - h1 u, ...: every state is the output or one of its
// (input-corrected) derivatives, so local models of equal order share the meaning of
// their states. That is what lets a T-S blend switch between rules without a bump
// (SEED-NOTES.md; tests/ts_fuzzy_test.cc steps across the rule boundary).
#pragma once

#include <Eigen/Dense>

#include "model/core/transfer_function.h"

namespace flexid::model {

struct StateSpace {
  Eigen::MatrixXd A;
  Eigen::VectorXd B;
  Eigen::RowVectorXd C;
  double D = 0.0;
  double delay_s = 0.0;  // input dead time T
};

// Precondition: IsValid(tf). A zero-order model yields n = 0 states (pure gain).
StateSpace RealiseOutputDerivativeForm(const TransferFunction& tf);

// Markov parameters h0..h_n of the rational part.
Eigen::VectorXd MarkovParameters(const TransferFunction& tf);

}  // namespace flexid::model
