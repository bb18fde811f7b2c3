// How `flexid tf show` presents a model document (poles, zeros, DC gain, damping, time
// constants; a T-S model local model by local model), shared with `flexid models show`,
// which presents stored models the same way. Implemented in tf_command.cc.
#pragma once

#include <nlohmann/json.hpp>
#include <ostream>
#include <string>

#include "model/core/model_file.h"

namespace flexid::cli {

// The `flexid tf show --json` document: for a transfer function {"kind": "tf", num, den,
// delay_s, dc_gain, stable, poles, zeros, modes}; for a T-S model {"kind": "ts_fuzzy",
// scheduling, local_models: [same plus level_V and membership]}.
nlohmann::json ModelPresentationJson(const model::ModelDocument& doc);

// The human form, headed "NAME: transfer function" or "NAME: T-S fuzzy model, ...".
void PrintModelPresentation(const model::ModelDocument& doc, const std::string& name,
                            std::ostream& out);

}  // namespace flexid::cli
