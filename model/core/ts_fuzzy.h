// Takagi-Sugeno fuzzy model, seed Eqs. (14)-(17) and (19).
//
// Rule i: IF z is M_i THEN x' = A_i x + B_i u. With one scheduling variable, product
// inference reduces to w_i = M_i(z) and the normalised weights are mu_i = w_i / sum_j w_j
// (Eq. 16). The global model is x' = A(mu) x + B(mu) u(t - T(mu)) (Eqs. 17, 19).
//
// How flexid blends, and why it departs from the letter of Eq. (17):
// blending the matrices A_i, B_i of any fixed realisation blends polynomial coefficients,
// and a convex combination of two stable 4th-order denominators need not be stable (it
// was not for local models identified from a 2-4-6-8 V staircase), nor need the DC gain
// stay between the local gains (in the output-derivative form the seed's own models give
// a negative DC gain at 4 V, because the numerator's constant term becomes a difference of
// numbers near 143). flexid therefore blends the frozen transfer function at mu:
//   - denominator: each local denominator is split into real factors (RealFactors:
//     quadratics s^2 + c1 s + c0 ordered slow to fast, one linear factor for odd order)
//     and corresponding factors are blended, c(mu) = sum_i mu_i c_i; stable local models
//     have c > 0, so every blend is stable;
//   - DC gain: K(mu) = sum_i mu_i K_i, monotone between neighbouring levels;
//   - zeros: the numerator shape is the blend of the gain-normalised numerators
//     num_i(s) / num_i(0) (plain coefficients when a local model has no DC gain);
//   - dead time: T(mu) = sum_i mu_i T_i.
// The frozen model is realised in the output-derivative form, whose states are the
// output and its derivatives, so a change of operating point keeps the output continuous
// and a step across a rule boundary does not ring (tests/ts_fuzzy_test.cc). At every
// level the blend is exactly that level's local model.
//
// Realisation. kFrozen (the default, described above) switches one frozen model with the
// operating point. kParallel runs every rule as its own linear system, driven by its share
// of the voltage, and adds their outputs:
//   y = sum_i G_i(s) [mu_i(z(t)) u(t)],   z = |u| (or u), each G_i with its dead time,
// the premise read when the voltage is applied and its share delayed with it. On a voltage
// held still both give sum_i mu_i K_i u. They differ when z moves: after a change the old
// rule's share relaxes with the old rule's dynamics while the new rule's share rises with
// its own, and the output is continuous without any re-expression of states. With equal
// dynamics in every rule it is a Hammerstein model: the static map u -> sum_i mu_i K_i u,
// then one linear system. The frozen model at z is the sum of the firing rules' transfer
// functions (all rules share one dead time), whose order is the sum of theirs.
//
// Scheduling: z(t) = |u(t)| by default (the seed's rules are on |z| <= 5 and 5 < |z| <= 8);
// z follows the applied voltage without the dead time: the operating point is set the
// moment the voltage is applied. With kAbsVoltageHeld, a voltage inside the rest band
// (|u| <= rest_band_V) keeps the operating point of the last voltage applied outside it:
// the relaxation after a 8 V pulse then follows the 8 V model, as it did in the
// recording that model was identified from (a 0 <-> 8 V square wave). With plain |u| the
// blend would switch to the lowest level's model at every return to 0 V and could not
// reproduce its own local model on that recording. Per-level identification
// (identify_ts.h) uses kAbsVoltageHeld.
//
// With kAbsVoltageDelayed, z(t) = |u(t - scheduling_delay_s)|: the operating point
// follows the voltage as it arrives after the dead time, so the rule that governs the
// response to a voltage change switches when the change reaches the actuator, and the
// relaxation after a pulse follows the rule of the rest voltage. Simulations read z at
// each sample time t_k as the voltage in force (zero-order hold) at t_k - delay. Global
// identification (identify_global.h) chooses among the three premises on held-out data.
#pragma once

#include <string>
#include <vector>

#include "model/core/transfer_function.h"

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

enum class SchedulingVariable { kAbsVoltage, kVoltage, kAbsVoltageHeld, kAbsVoltageDelayed };
const char* SchedulingVariableName(SchedulingVariable variable);
bool ParseSchedulingVariable(const std::string& name, SchedulingVariable* variable);

enum class TsRealisation { kFrozen, kParallel };
const char* TsRealisationName(TsRealisation realisation);
bool ParseTsRealisation(const std::string& name, TsRealisation* realisation);

struct LocalModel {
  double level_V = 0.0;  // voltage level at which the local model was identified
  TransferFunction tf;
  Membership membership;
};

struct TsModel {
  SchedulingVariable scheduling = SchedulingVariable::kAbsVoltage;
  std::vector<LocalModel> rules;
  double rest_band_V = 0.0;  // kAbsVoltageHeld: |u| at or below this is rest
  // kAbsVoltageDelayed: the delay of the premise, s (finite, >= 0).
  double scheduling_delay_s = 0.0;
  // kParallel: scheduling kAbsVoltage or kVoltage, and one dead time in every rule.
  TsRealisation realisation = TsRealisation::kFrozen;
};

// The scheduling value z_k for a sequence of voltages (kAbsVoltageHeld has memory).
class Scheduler {
 public:
  explicit Scheduler(const TsModel& model) : model_(&model) {}
  double Next(double voltage_V);

 private:
  const TsModel* model_;
  double held_ = 0.0;
};

// At least one rule; every local model valid and of the same order; memberships valid.
bool IsValid(const TsModel& model, std::string* error);

// The memoryless part of the scheduling: |u| or u (kAbsVoltageHeld and
// kAbsVoltageDelayed give |u|; the simulators apply the hold and the delay).
double SchedulingValue(const TsModel& model, double voltage_V);

// The largest share by which any rule's step response falls back (StepFallBack), 0 if
// none does.
double LargestFallBack(const TsModel& model);

// Eq. (16): normalised firing strengths mu (size = number of rules, sum 1). Where no
// membership fires (z beyond every support), the rule whose level is nearest takes it all.
void NormalisedMemberships(const TsModel& model, double z, std::vector<double>* mu);

// Memberships placed on the identified levels (sorted ascending): trapezoidal shoulders
// below the first and above the last level, linear interpolation between neighbours, so
// that exactly the two neighbouring rules fire between two levels and each local model
// is used alone at its own level.
TsModel MakeTsModelOnLevels(std::vector<LocalModel> local_models,
                            SchedulingVariable scheduling = SchedulingVariable::kAbsVoltage,
                            double rest_band_V = 0.0);

// The frozen model at memberships mu (the blend described above; kParallel: the sum of
// mu_i G_i over the firing rules). Precondition:
// IsValid(model), mu.size() == rules.size(), sum mu == 1.
TransferFunction BlendedTransferFunction(const TsModel& model, const std::vector<double>& mu);

// A model's rules prepared for blending: each normalised, its denominator split into real
// factors and its DC gain taken once. A simulation blends at hundreds of operating points,
// and splitting the same rules at each one was half of a chirp's simulation time.
struct PreparedRules {
  std::vector<TransferFunction> normalised;
  std::vector<std::vector<std::vector<double>>> factors;  // RealFactors of each denominator
  std::vector<double> dc_gain;                            // 0 where the gain is infinite
};
PreparedRules PrepareRules(const TsModel& model);
// The same blend as above, from the prepared rules (bit for bit).
TransferFunction BlendedTransferFunction(const TsModel& model, const PreparedRules& prepared,
                                         const std::vector<double>& mu);

// The frozen model at scheduling value z.
TransferFunction FrozenModelAt(const TsModel& model, double z);

// A T-S model with one rule that is the given transfer function everywhere.
TsModel SingleRule(const TransferFunction& tf);

}  // namespace flexid::model
