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

namespace freeform::gpu_bench {

struct BenchCase {
    std::string name;
    Scene scene;
    Heightmap surface;
    RaySet rays;
    PathParams params;
    HeightOverlay move;                   // a move as the annealer proposes them: a 5 × 5 vertex patch
    std::vector<std::int32_t> move_rays;  // the rays that enter the move's cells from above
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

double median(std::vector<double> v);

}  // namespace freeform::gpu_bench
