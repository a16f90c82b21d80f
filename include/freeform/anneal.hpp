#pragma once
// The annealing module: the generic annealer (Metropolis, cooling schedules, re-heat,
// stop rules, callbacks, speculative parallel evaluation). It does not depend on the
// optics; any type that fits AnnealProblem can be annealed.
#include "anneal/annealer.hpp"
#include "anneal/schedule.hpp"
