// Importing a file into a running flexidd (internal to clients/cli/trials_*.cc): the file's
// trials are replayed onto the bus as the virtual rig sends them (bus/sample_publisher.h):
// signed trial_control2_t start on PREFIX/TRIAL, voltage_sample_t and deflection_sample_t on
// PREFIX/<ID>/VOLTAGE and /DEFLECTION, stop (PREFIX: the global --channel-prefix, default
// FLEXID). It publishes chunks of kReplayChunk deflections and lets at most kReplayWindow of
// them wait for flexidd's commit (the trial's stored count, asked over RPC) before sending
// more, so that neither the UDP socket nor flexidd's queues overflow; then it checks that
// the trial holds every sample.
#pragma once

#include <vector>

#include "clients/cli/format.h"
#include "clients/cli/trial_import.h"

namespace flexid::cli::trials {

// Plays the plan's trials to flexidd, one after the other, and returns what it stored of
// each. Refuses (UsageError) an actuator that is recording, or a plan whose times are not
// after everything stored for the actuator (flexidd takes messages in time order only).
// Throws OperationError when flexidd does not start or end a trial, stops storing, or ends
// a trial early, and on SIGINT/SIGTERM (ending the trial being played). progress may be
// null.
std::vector<StoredImport> ReplayOnBus(const ImportPlan& plan, Progress* progress);

}  // namespace flexid::cli::trials
