#pragma once
// The kernel of a window of moves evaluated together (trace/window.hpp): one ray of one
// proposal, retraced through that proposal's overlay. In its own header, which the CUDA
// tracer (cuda/trace_cuda.cuh) includes as well, so that the device runs this very code.
#include <cstdint>

#include "../core/hd.hpp"
#include "../surface/overlay.hpp"
#include "heightfield_kernel.hpp"
#include "path.hpp"

namespace freeform {

// Pair k's ray, retraced through its proposal's view: records[k]. The same functor runs
// under every execution policy (it reads only the arrays it is given).
template <class View>
struct WindowRetraceKernel {
    const View* views;  // one per proposal
    PathParams pp;
    const Vec3* origin;  // the ray set's
    const Vec3* direction;
    const std::int32_t* proposal;  // per pair: which proposal
    const std::int32_t* ray;       // per pair: which ray
    RayRecord* records;            // per pair: the ray's record after its proposal's move

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t id = ray[k];
        records[k] = trace_heightfield_ray(views[proposal[k]], pp, origin[id], direction[id], NoCellVisitor{});
    }
};

}  // namespace freeform
