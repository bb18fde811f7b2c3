// Takagi-Sugeno fuzzy model, seed Eqs. (14)-(17) and (19).
//
// Rule i: IF z is M_i THEN x' = A_i x + B_i u. With one scheduling variable, product
// inference reduces to w_i = M_i(z) and the normalised weights are mu_i = w_i / sum_j w_j
// (Eq. 16). The global model is x' = A(mu) x + B(mu) u(t - T(mu)) (Eqs. 17, 19).
//
// How flexid blends, and why it departs from the letter of Eq. (17):
// every local model is realised in the output-derivative form (state_space.h), whose
// A_i differ only in the companion row holding the denominator coefficients, so
// A(mu) = sum_i mu_i A_i holds exactly. For the input vector flexid does NOT use
// sum_i mu_i B_i: in that form B_i are Markov parameters, and blending them linearly
// makes the numerator's constant term a difference of large numbers. With the seed's
// coefficients the literal blend has a negative DC gain at 4 V (between two local models
// of gain +5.3 and +8.7). In the observable companion form Eq. (17) is linear in the
// coefficients but a voltage step across a rule boundary rings the lightly damped mode.
// flexid therefore blends the transfer-function coefficients,
//   num(mu) = sum_i mu_i num_i,  den(mu) = sum_i mu_i den_i (each den monic),
//   T(mu) = sum_i mu_i T_i,
// and realises that blend in the output-derivative form: A(mu) is exactly Eq. (17)'s,
// B(mu) is the blend's Markov parameters, the DC gain moves monotonically between the
// local gains, and the states keep their meaning (output and derivatives) across a switch.
//
// Scheduling: z(t) = |u(t)| by default (the seed's rules are on |z| <= 5 and 5 < |z| <= 8);
// z follows the applied voltage without the dead time: the operating point is set the
// moment the voltage is applied.
#pragma once

#include <string>
#include <vector>

#include "model/transfer_function.h"

namespace flexid::model {

enum class MembershipShape { kTriangular, kTrapezoidal, kGaussian, kSigmoid };

// Membership function on the scheduling variable (V):
//   triangular  {a, b, c}:     0 at a, 1 at b, 0 at c
//   trapezoidal {a, b, c, d}:  0 at a, 1 on [b, c], 0 at d; a = b = -inf or c = d = +inf
//                              make a shoulder that stays at 1 to that side
//   gaussian    {centre, sigma}
//   sigmoid     {centre, slope}: 1 / (1 + exp(-slope (z - centre))); slope in 1/V
struct Membership {
  MembershipShape shape = MembershipShape::kTriangular;
  std::vector<double> params;
  double Evaluate(double z) const;
};
bool IsValid(const Membership& membership, std::string* error);
const char* MembershipShapeName(MembershipShape shape);
bool ParseMembershipShape(const std::string& name, MembershipShape* shape);

enum class SchedulingVariable { kAbsVoltage, kVoltage };
const char* SchedulingVariableName(SchedulingVariable variable);
bool ParseSchedulingVariable(const std::string& name, SchedulingVariable* variable);

struct LocalModel {
  double level_V = 0.0;  // voltage level at which the local model was identified
  TransferFunction tf;
  Membership membership;
};

struct TsModel {
  SchedulingVariable scheduling = SchedulingVariable::kAbsVoltage;
  std::vector<LocalModel> rules;
};

// At least one rule; every local model valid and of the same order; memberships valid.
bool IsValid(const TsModel& model, std::string* error);

double SchedulingValue(const TsModel& model, double voltage_V);

// Eq. (16): normalised firing strengths mu (size = number of rules, sum 1). Where no
// membership fires (z beyond every support), the rule whose level is nearest takes it all.
void NormalisedMemberships(const TsModel& model, double z, std::vector<double>* mu);

// Memberships placed on the identified levels (sorted ascending): trapezoidal shoulders
// below the first and above the last level, linear interpolation between neighbours, so
// that exactly the two neighbouring rules fire between two levels and each local model
// is used alone at its own level.
TsModel MakeTsModelOnLevels(std::vector<LocalModel> local_models,
                            SchedulingVariable scheduling = SchedulingVariable::kAbsVoltage);

// The frozen model at memberships mu (the blend described above). Precondition:
// IsValid(model), mu.size() == rules.size(), sum mu == 1.
TransferFunction BlendedTransferFunction(const TsModel& model, const std::vector<double>& mu);

// The frozen model at scheduling value z.
TransferFunction FrozenModelAt(const TsModel& model, double z);

// A T-S model with one rule that is the given transfer function everywhere.
TsModel SingleRule(const TransferFunction& tf);

}  // namespace flexid::model
