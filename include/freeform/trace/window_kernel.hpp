#pragma once
// The kernel of a window of moves evaluated together (trace/window.hpp): one ray of one
// proposal, retraced through that proposal's overlay. In its own header, which the CUDA
// tracer (cuda/trace_cuda.cuh) includes as well, so that the device runs this very code.
#include <cstdint>
#include <span>
#include <vector>

#include "../core/hd.hpp"
#include "../surface/overlay.hpp"
#include "heightfield_kernel.hpp"
#include "path.hpp"

namespace freeform {

// The kernels' views of a window's moves over `base` (host memory), one per move.
inline void overlay_views(const Heightmap& base, std::span<const HeightOverlay> moves, std::vector<OverlayView>& out) {
    out.resize(moves.size());
    for (std::size_t p = 0; p < moves.size(); ++p) out[p] = overlay_view(base, moves[p]);
}

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

// What one pair's ray does to its proposal: its old deposit taken away and its new one
// added (four cells each, splat of trace/path.hpp; zero amounts where a record left the
// receiver), and the weights it delivered before and now. Plain data.
struct PairChange {
    std::int64_t cell[8];
    Fixed amount[8];
    Fixed weight, before, now;  // the ray's weight; what it delivered before and now
    RayStatus status_before, status_now;
    bool moved;  // its record changed (nothing else is set otherwise)
};

// Pair k's change against the maintained records: out[k]. The per-ray half of
// IncrementalTrace::account, the same integers, summed per proposal afterwards.
struct WindowAccountKernel {
    ReceiverView receiver;
    const std::int32_t* ray;      // per pair
    const RayRecord* records;     // per pair: after its proposal's move
    const RayRecord* maintained;  // per ray: before any move (IncrementalTrace::records)
    const Fixed* weight;          // per ray
    PairChange* out;              // per pair

    FREEFORM_HD void operator()(std::int64_t k) const {
        PairChange& c = out[k];
        const RayRecord& before = maintained[ray[k]];
        const RayRecord& now = records[k];
        c.moved = !(now == before);
        if (!c.moved) return;
        c.weight = weight[ray[k]];
        c.before = delivered_weight(before, c.weight), c.now = delivered_weight(now, c.weight);
        c.status_before = before.status, c.status_now = now.status;
        const Splat a =
            before.status == RayStatus::receiver ? splat(receiver, before.px, before.py, c.before) : Splat{};
        const Splat b = now.status == RayStatus::receiver ? splat(receiver, now.px, now.py, c.now) : Splat{};
        for (int j = 0; j < 4; ++j) {
            c.cell[j] = a.cell[j], c.amount[j] = -a.amount[j];
            c.cell[4 + j] = b.cell[j], c.amount[4 + j] = b.amount[j];
        }
    }
};

}  // namespace freeform
