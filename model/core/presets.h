// The seed paper's identified models for actuator S1 (section 4, Eq. 18). The paper
// gives each coefficient as a range between its 2 V and 8 V identifications; flexid takes
// the lower ends as the 2 V model and the upper ends as the 8 V model (the DESIGN.md
// example file, "the seed's 8 V coefficients", is the upper ends). beta = -3.67 is a
// dead time of 3.67 s. The output unit of Eq. 18 is not stated (SEED-NOTES.md).
#pragma once

#include "model/core/transfer_function.h"
#include "model/core/ts_fuzzy.h"

namespace flexid::model {

TransferFunction SeedModel2V();
TransferFunction SeedModel8V();

// The seed's two-rule T-S model (section 4): rule 1 "|z| <= 5" with the 2 V model, rule 2
// "5 < |z| <= 8" with the 8 V model. The paper's membership functions (Figure 8b) are
// not given numerically; flexid places trapezoidal memberships on the identified levels
// (MakeTsModelOnLevels): rule 1 alone up to 2 V, rule 2 alone from 8 V, linear between,
// crossing at mu = 0.5 at the seed's rule boundary of 5 V.
TsModel SeedTsModel();

}  // namespace flexid::model
