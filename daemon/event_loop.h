// flexidd's loop (DESIGN.md: "signals"): one thread polls LCM's file descriptor, a signal
// descriptor, a wake-up descriptor (the worker and the writer have something for the loop)
// and a 1 s timer (health and status). event_loop.cc holds the loop's part of Service.
#pragma once

#include <signal.h>

namespace flexid::daemon {

// SIGTERM and SIGINT stop the loop, SIGHUP reloads.
sigset_t HandledSignals();

}  // namespace flexid::daemon
