#pragma once
// Shared by the two halves of the GPU tracing benchmark (benchmarks/gpu/run.sh):
// trace_bench_host.cpp, compiled by the host compiler as the library's CPU build is, loads
// a scene file, makes its transport start on the final mesh (a designed-like surface, not
// a flat one) and times the CPU tracer; trace_bench.cu times the GPU tracer on the same
// surface and rays and checks that both give the same histogram bit for bit.
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <freeform/scene/rays.hpp>
#include <freeform/scene/scene.hpp>
#include <freeform/surface/overlay.hpp>
#include <freeform/trace/path.hpp>
#include <freeform/trace/tracer.hpp>
#include <freeform/trace/index_kernel.hpp>
#include <freeform/trace/window_kernel.hpp>

namespace freeform::gpu_bench {

struct BenchCase {
    std::string name;
    Scene scene;
    Heightmap surface;
    RaySet rays;
    PathParams params;
    HeightOverlay move;                   // a move as the annealer proposes them: a 5 × 5 vertex patch
    std::vector<std::int32_t> move_rays;  // the rays that enter the move's cells from above
    std::vector<HeightOverlay> window;    // a window of such moves spread over the surface (trace/window.hpp)
};

// `resolution` > 0 overrides the receiver's resolution (square); `threads` is used for
// the start.
BenchCase make_case(const std::string& scene_file, int resolution, int threads);

struct CpuTiming {
    Histogram histogram;
    TraceTotals totals;
    double full_seconds = 0;  // one trace_all, the median of `repeats`
    double move_seconds = 0;  // tracing one move's rays through its overlay, the median
    std::vector<RayRecord> move_records;
};

// HeightfieldTracer on `threads` OpenMP threads (1: exec::seq).
CpuTiming time_cpu(const BenchCase& c, int threads, int repeats);

// The window's moves evaluated against the case's surface (IncrementalTrace): one after
// another with IncrementalTrace::evaluate, as the annealer does on one thread, and
// together with WindowEvaluation on 2 threads, whose three steps are timed apart, in their
// host forms and their kernel forms. The pairs, their records and the changes are kept
// for the GPU's evaluation of the same window.
struct WindowTiming {
    double per_move_seconds = 0;  // the window's moves evaluated one by one, the median
    double window_seconds = 0;    // WindowEvaluation::evaluate on 2 threads, the median
    double select_seconds = 0, retrace_seconds = 0, sum_seconds = 0;  // its steps, medians
    bool same_changes = false;                                        // every move's change equal to evaluate()'s
    // The kernel forms on 2 threads (select_flat, sum_atomic), the medians, and whether
    // they gave the host forms' pairs and changes.
    double flat_select_seconds = 0, atomic_sum_seconds = 0;
    double flatten_seconds = 0;  // flatten() of the index (what a commit costs while the device copy is redone whole)
    bool same_kernel_forms = false;
    std::vector<std::int32_t> proposals, rays;
    std::vector<RayRecord> records;
    // What the device's whole window needs (cuda::DeviceWindowEvaluation), and the host's
    // changes to compare with.
    FlatRayCellIndex index;
    SlottedRayCellIndex slotted;                               // the device's form of it
    std::vector<std::int32_t> slotted_proposals, slotted_rays;  // the pairs selected from it
    std::vector<RayRecord> maintained;
    // The first move's change, as cuda::DeviceWindowEvaluation::commit takes it.
    std::vector<std::int32_t> commit_rays, commit_begin;
    std::vector<RayRecord> commit_records;
    std::vector<CellCrossing> commit_cells;
    std::vector<WindowPatch> patches;
    std::vector<std::int32_t> slot_proposal;
    float pad = 0;
    std::vector<WindowChange> changes;
};
WindowTiming time_window_cpu(const BenchCase& c, int repeats);

double median(std::vector<double> v);

}  // namespace freeform::gpu_bench
