#pragma once
// The kernels of the GPU height-field tracer (trace_cuda.cuh), in a header that any C++20
// compiler accepts: they are FREEFORM_HD functors over plain views, so for_each runs the
// very same code under exec::seq and exec::omp over host memory as under exec::cuda over
// device memory. The CPU tests check these functors, not copies of them, against
// HeightfieldTracer (tests/test_exec.cpp); the GPU test checks them on the device.
#include <cstddef>
#include <cstdint>
#include <span>

#include "../core/atomic.hpp"
#include "../core/fixed_point.hpp"
#include "../core/hd.hpp"
#include "../scene/rays.hpp"
#include "../trace/heightfield_kernel.hpp"
#include "../trace/path.hpp"
#include "../trace/tracer.hpp"

namespace freeform::cuda {

// Where a trace's weight went, accumulated per ray with atomics. Each lane is a copy of
// the counters; ray k adds to lane k % totals_lanes, so the threads of a warp spread over
// different addresses instead of queueing on one.
inline constexpr int totals_lanes = 32;
inline constexpr int totals_slots = 8;  // weight by slot (RayStatus 0..5, Fresnel 6), rays on the receiver
inline constexpr int totals_hits_slot = 7;

// The deposit target of `deposit`: one fixed-point histogram cell per index.
struct AtomicCells {
    unsigned long long* cells;
    FREEFORM_HD void operator()(std::int64_t c, Fixed amount) const {
        if (amount != 0) atomic_add(cells + c, static_cast<unsigned long long>(amount));
    }
};

// Ray k of the ray set: traced, counted in the totals and deposited. The same functor
// runs under for_each(exec::cuda, ...) over device pointers and under exec::seq/omp over
// host pointers.
template <class View>
struct TraceDepositKernel {
    View hf;
    PathParams pp;
    const Vec3* origin;
    const Vec3* direction;
    const Fixed* weight;
    unsigned long long* cells;   // receiver width * height, zeroed
    unsigned long long* totals;  // totals_lanes * totals_slots, zeroed

    FREEFORM_HD void operator()(std::int64_t k) const {
        const RayRecord rec = trace_heightfield_ray(hf, pp, origin[k], direction[k], NoCellVisitor{});
        const Fixed w = weight[k], delivered = delivered_weight(rec, w);
        unsigned long long* lane = totals + (k % totals_lanes) * totals_slots;
        atomic_add(lane + int(rec.status), static_cast<unsigned long long>(delivered));
        if (delivered != w) atomic_add(lane + int(fresnel_reflected_slot), static_cast<unsigned long long>(w - delivered));
        if (rec.status != RayStatus::receiver) return;
        atomic_add(lane + totals_hits_slot, 1ull);
        deposit(pp.receiver, rec.px, rec.py, delivered, AtomicCells{cells});
    }
};

// The record of ray ids[k] into records[k].
template <class View>
struct TraceRecordsKernel {
    View hf;
    PathParams pp;
    const Vec3* origin;
    const Vec3* direction;
    const std::int32_t* ids;
    RayRecord* records;

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t id = ids[k];
        records[k] = trace_heightfield_ray(hf, pp, origin[id], direction[id], NoCellVisitor{});
    }
};

// Folds the lanes of a totals buffer into TraceTotals (emitted is left to the caller).
inline TraceTotals fold_totals(std::span<const unsigned long long> lanes, std::int64_t rays) {
    TraceTotals t;
    t.rays = rays;
    for (int l = 0; l < totals_lanes; ++l) {
        const unsigned long long* lane = lanes.data() + std::size_t(l) * totals_slots;
        for (std::size_t s = 0; s < t.weight_by_status.size(); ++s)
            t.weight_by_status[s] = Fixed(std::uint64_t(t.weight_by_status[s]) + lane[s]);
        t.rays_hit_receiver += std::int64_t(lane[totals_hits_slot]);
    }
    return t;
}

}  // namespace freeform::cuda
