#pragma once
// Where the kernel forms of a window run, over a copy of the incremental trace's state
// kept there (trace/window.hpp, CopiedStateWindowEvaluator): the host
// (HostKernelWindowBackend, trace/window.hpp) or a device (cuda::DeviceWindowBackend,
// cuda/window_cuda.cuh). In a header of its own, free of the incremental trace's, so that
// nvcc compiles the device backend against it: the trace is only named here.
#include <cstdint>
#include <span>

#include "../surface/heightmap.hpp"
#include "../surface/overlay.hpp"
#include "crossing.hpp"
#include "index_kernel.hpp"
#include "path.hpp"
#include "window_kernel.hpp"

namespace freeform {

class IncrementalTrace;

class WindowBackend {
public:
    virtual ~WindowBackend() = default;
    // The whole state: the slotted index, the maintained records, and the surface as the
    // trace holds it now.
    virtual void upload_state(const IncrementalTrace& trace, const SlottedRayCellIndex& index,
                              std::span<const RayRecord> records) = 0;
    // The surface's heights changed in `patch` (a committed move).
    virtual void surface_changed(const Patch& patch) = 0;
    // A window: `moves` with their slots (window_slots) and the surface's rounding
    // allowance; change(p) afterwards.
    virtual void evaluate(const IncrementalTrace& trace, std::span<const HeightOverlay> moves,
                          std::span<const WindowPatch> patches, std::span<const std::int32_t> slot_proposal,
                          float pad) = 0;
    virtual const WindowChange& change(std::size_t p) const = 0;
    // An accepted move's change (joined, pack_change); false when the copy ran out of
    // room (the evaluator then copies the state whole).
    virtual bool commit(std::span<const std::int32_t> rays, std::span<const RayRecord> records,
                        std::span<const std::int32_t> begin, std::span<const CellCrossing> crossings) = 0;
};

}  // namespace freeform
