#pragma once
// The transport start without its reweighted second solve, for the tests (kept apart from
// support.hpp, which does not pull in the design module).
#include <cstdint>
#include <utility>

#include <freeform/design/start.hpp>

namespace freeform::testing {

// make_design_start's first solve alone. Tests of the first solve's geometry (aims,
// edges, walls, stretches) and tests that need any transport surface use it; the second
// solve, kept only when the exact tracer finds it better, has cases of its own
// (test_transport), and leaving it out elsewhere halves those tests' time under the
// sanitizers.
inline DesignStart first_solve_start(const Scene& s, Heightmap initial, const ImageD& target, std::uint64_t seed,
                                     int threads) {
    return make_design_start(s, std::move(initial), target, seed, threads, min_start_grid, no_second_solves);
}

}  // namespace freeform::testing
