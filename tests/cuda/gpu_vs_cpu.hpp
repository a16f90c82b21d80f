#pragma once
// Shared by the two halves of the GPU-against-CPU test: gpu_vs_cpu_host.cpp (compiled by
// the host compiler, as the library's CPU build is) builds the scenes and traces them
// with HeightfieldTracer; gpu_vs_cpu.cu traces them on the GPU and compares.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <freeform/scene/rays.hpp>
#include <freeform/scene/scene.hpp>
#include <freeform/surface/overlay.hpp>
#include <freeform/trace/path.hpp>
#include <freeform/trace/tracer.hpp>
#include <freeform/trace/index_kernel.hpp>
#include <freeform/trace/window_backend.hpp>
#include <freeform/trace/window_kernel.hpp>

namespace freeform::gpu_test {

struct Case {
    std::string name;
    Scene scene;
    Heightmap surface;
    RaySet rays;
};

struct Reference {
    Histogram histogram;
    TraceTotals totals;
};

// Flat mirror, paraboloid, point light, lens, interreflecting bumps under a disk light.
std::vector<Case> make_cases();

// HeightfieldTracer on the CPU (exec::seq).
Reference cpu_trace_all(const Case& c);
std::vector<RayRecord> cpu_trace(const Case& c, std::span<const std::int32_t> ids);
// Through a proposed move, without changing c.surface.
std::vector<RayRecord> cpu_trace(const Case& c, std::span<const std::int32_t> ids, const HeightOverlay& o);

// A window of moves evaluated on the host by WindowEvaluation's kernel forms (select_flat
// over a slotted index, sum_atomic) under exec::seq, with what a device needs to evaluate
// the same window (cuda::DeviceWindowEvaluation); then the window's first move accepted
// (its change, as the device's commit() takes it) and the other moves evaluated against
// the state it leaves.
struct WindowResult {
    std::vector<WindowPatch> patches;
    std::vector<std::int32_t> slot_proposal, proposals, rays;
    std::vector<WindowChange> changes;
};
struct WindowReference {
    SlottedRayCellIndex index;
    std::vector<RayRecord> maintained;
    float pad = 0;
    WindowResult before, after;
    std::vector<std::int32_t> commit_rays, commit_begin;
    std::vector<RayRecord> commit_records;
    std::vector<CellCrossing> commit_cells;
};
WindowReference cpu_window(const Case& c, std::span<const HeightOverlay> moves);

// The device's window backend (cuda::DeviceWindowBackend), made by the CUDA half.
std::unique_ptr<WindowBackend> make_device_backend(const Heightmap& surface, const RaySet& rays,
                                                   const PathParams& params);

// A short design of the case (annealing at fixed iterations, speculative windows of 8)
// with its windows evaluated on the device, against the same design with its moves
// evaluated one by one on the CPU: the same heights, energy and acceptances, bit for bit.
// Returns what differed, a line each (none: equal).
std::vector<std::string> design_checks(const Case& c);

// A move in the middle of the surface, as the annealer proposes them.
HeightOverlay bump_overlay(const Heightmap& hm);

}  // namespace freeform::gpu_test
