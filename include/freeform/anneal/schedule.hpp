#pragma once
// Cooling schedules for the annealer.
//
// A run is a sequence of passes. A pass starts at an initial temperature t0 and cools in
// steps: the temperature is held for `iterations_per_temperature` iterations, then the
// schedule gives the next one. A re-heat ends the pass and starts a new one at a lower
// t0 (reference §3.1: after N iterations without improvement, start again from β·t0).
//
// A schedule is a pure function of (t0, cooling, step). Nothing is carried from one
// iteration to the next, so the annealer can compute the temperature of any iteration
// ahead of time, which speculative evaluation relies on (every proposal of a window must
// see the temperature the serial run would give it).
#include <algorithm>
#include <cmath>
#include <concepts>
#include <cstdint>

namespace freeform {

// What the annealer needs from a schedule:
//   temperature(t0, cooling, step): temperature of the step-th temperature step of a
//     pass that started at t0 (step 0 gives t0). `cooling` is AnnealOptions::cooling,
//     in (0, 1]. Must be deterministic and ≥ 0; 0 means only non-worsening moves pass.
// Optional:
//   reheat(t0, reheat_factor): initial temperature of the pass that follows a pass
//     started at t0 (default reheat_factor · t0).
template <class S>
concept CoolingSchedule =
    std::copy_constructible<S> && requires(const S& s, double t0, double cooling, std::int64_t step) {
        { s.temperature(t0, cooling, step) } -> std::convertible_to<double>;
    };

// The initial temperature of the next pass, using the schedule's own rule when it has one.
template <CoolingSchedule S>
double reheat_temperature(const S& schedule, double t0, double reheat_factor) {
    if constexpr (requires { { schedule.reheat(t0, reheat_factor) } -> std::convertible_to<double>; }) {
        return static_cast<double>(schedule.reheat(t0, reheat_factor));
    } else {
        return reheat_factor * t0;
    }
}

// T_k = t0 · a^k (reference eq. 3.2). The default: the acceptance of a given uphill step
// falls off at the same relative rate in every pass, whatever t0 is.
struct GeometricSchedule {
    double temperature(double t0, double cooling, std::int64_t step) const {
        // pow of an exact integer exponent rather than repeated multiplication, so the
        // value does not depend on how the caller walked to this step.
        return t0 * std::pow(cooling, static_cast<double>(step));
    }
};

// T_k = t0 · max(0, 1 − k·(1 − a)): the same first step as the geometric schedule with
// the same a, then straight down to 0 after 1/(1 − a) steps, where the pass becomes a
// greedy descent until a re-heat or a stop rule ends it. a = 1 holds t0 for ever.
struct LinearSchedule {
    double temperature(double t0, double cooling, std::int64_t step) const {
        return t0 * std::max(0.0, 1.0 - static_cast<double>(step) * (1.0 - cooling));
    }
};

static_assert(CoolingSchedule<GeometricSchedule>);
static_assert(CoolingSchedule<LinearSchedule>);

// The schedule a design anneals each stage with (the scene file's "optimise" keys of the
// same names; docs/scene.md). The designer turns them into AnnealOptions per stage
// (design/designer.hpp): a stage's t0 is calibrated so that `initial_acceptance` of its
// uphill moves pass, then scaled by `initial_temperature_scale`.
struct ScheduleOptions {
    double initial_acceptance = 0.03;          // of uphill moves at the start of each stage
    double refine_initial_acceptance = 0.001;  // ... at most, after a transport start
    double initial_temperature_scale = 1;      // multiplies every stage's calibrated t0
    double cooling = 0.95;
    int temperature_steps = 120;               // cooling steps per stage
    double reheat_factor = 0.5;
    double patience_fraction = 0.08;  // re-heat after this fraction of a stage without a new best
};

}  // namespace freeform
