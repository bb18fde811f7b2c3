// The helpers the `flexid trials` subcommands share (trials_common.h).
#include "clients/cli/trials_common.h"

#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "bus/ids.h"
#include "clients/cli/command.h"
#include "storage/database.h"

namespace flexid::cli::trials {
namespace {

storage::TrialState StateOf(const std::string& name) {
  if (name == "complete") return storage::TrialState::kComplete;
  if (name == "interrupted") return storage::TrialState::kInterrupted;
  return storage::TrialState::kRecording;
}

}  // namespace

void CheckActuatorId(const std::string& id) {
  if (!bus::IsValidId(id))
    throw UsageError(std::string("--actuator must be ") + bus::kIdRule + " (got \"" + id + "\")");
}

void CheckTrialId(int64_t id) {
  if (id < 1)
    throw UsageError("ID: a trial id is a positive integer (got " + std::to_string(id) + ")");
}

storage::Trial TrialFromJson(const nlohmann::json& j) {
  storage::Trial t;
  t.id = j.value("id", int64_t{0});
  t.actuator_id = j.value("actuator", "");
  t.protocol = j.value("protocol", "");
  t.start_utime = j.value("start_utime", int64_t{0});
  t.end_utime = j.value("end_utime", int64_t{0});
  t.state = StateOf(j.value("state", ""));
  t.samples = j.value("samples", int64_t{0});
  return t;
}

void PrintJson(const nlohmann::json& j) { std::cout << j.dump(2) << "\n"; }

}  // namespace flexid::cli::trials
