#pragma once
// Incremental evaluation with the Embree tracer (docs/architecture.md §4 for both tracers).
//
// Embree must see a move before it can trace it: the backend writes the move's heights
// into the height map, refits only the Embree tiles the patch touches, retraces the
// affected rays, then puts the heights back and refits again. The state after delta()
// is the state before it, bit for bit, but the heights are briefly shared, so deltas
// are evaluated one at a time (no speculative parallelism with this backend).
#include "../trace/embree.hpp"
#include "../trace/incremental.hpp"
#include "problem.hpp"

namespace freeform {

struct EmbreeBackend {
    static constexpr bool concurrent_deltas = false;
    static constexpr const char* name = "embree";

    EmbreeTracer* tracer = nullptr;
    Heightmap* surface = nullptr;

    Histogram rebuild(IncrementalTrace& trace) const {
        return trace.rebuild_with([&](std::int32_t id, CellCollector& visit) { return tracer->trace_one(id, visit); });
    }

    void evaluate(const IncrementalTrace& trace, const HeightOverlay& o, TraceChange& change) const {
        const auto retrace = [&](std::int32_t id, CellCollector& visit) { return tracer->trace_one(id, visit); };
        if (o.empty()) {
            trace.evaluate_with(o, change, retrace);
            return;
        }
        const HeightSnapshot before = surface->snapshot(o.patch);
        o.commit(*surface);
        tracer->surface_changed(o.patch);
        trace.evaluate_with(o, change, retrace);
        surface->restore(before);
        tracer->surface_changed(o.patch);
    }

    void committed(const Patch& p) { tracer->surface_changed(p); }
};

using EmbreeSurfaceProblem = BasicSurfaceProblem<EmbreeBackend>;

}  // namespace freeform
