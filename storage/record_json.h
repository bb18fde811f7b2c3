// JSON views of stored records: the shapes flexidd's RPC replies carry (DESIGN.md, "Bus")
// and the offline forms of the flexid command line print, so that a command gives the
// same document whether it asked the daemon or read the database file.
//
// Units follow the records: utime in microseconds of message time, voltages in V,
// deflections in mm.
#pragma once

#include <nlohmann/json.hpp>

#include "storage/database.h"

namespace flexid::storage {

// {"id", "actuator", "protocol", "start_utime", "end_utime", "state", "samples"}
nlohmann::json TrialJson(const Trial& trial);

// {"id", "actuator", "kind", "severity", "utime", "start_utime", "end_utime",
//  "magnitude_mm", "threshold_mm", "text"} (NaN magnitudes become null)
nlohmann::json AlertJson(const AlertRecord& alert);

// A proposed version's lineage as stored (an object), or null for an identified model or
// one whose lineage does not parse.
nlohmann::json LineageJson(const ModelRecord& model);

// {"actuator", "version", "created_utime", "active", "trials", "samples_hash",
//  "flexid_version", "fit"}: everything but the model document itself.
nlohmann::json ModelSummaryJson(const ModelRecord& model);

// One page of a trial's samples, as the trial_samples request returns it: {"trial",
// "offset", "total", "utime": [...], "voltage_V": [...], "deflection_mm": [...]}.
nlohmann::json SamplesPageJson(const Trial& trial, int64_t offset, const std::vector<Sample>& page);

// {"id", "length_mm", "width_mm", "thickness_mm", "material", "electrolyte",
//  "concentration_M"}
nlohmann::json ActuatorJson(const Actuator& actuator);

}  // namespace flexid::storage
