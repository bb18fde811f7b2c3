#include "model/core/presets.h"

namespace flexid::model {

TransferFunction SeedModel2V() {
  return {{0.0063, 0.6381, 1.152, 1.14}, {1.0, 0.3631, 225.5, 14.98, 0.2142}, 3.67};
}

TransferFunction SeedModel8V() {
  return {{0.0085, 0.842, 1.924, 1.97}, {1.0, 0.5898, 367.2, 29.41, 0.2275}, 3.67};
}

TsModel SeedTsModel() {
  return MakeTsModelOnLevels({{2.0, SeedModel2V(), {}}, {8.0, SeedModel8V(), {}}});
}

}  // namespace flexid::model
