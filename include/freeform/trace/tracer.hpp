#pragma once
// What every tracer provides, and the bookkeeping shared by all of them.
#include <array>
#include <concepts>
#include <cstdint>
#include <span>
#include <string_view>

#include "../core/exec.hpp"
#include "../core/histogram.hpp"
#include "../scene/rays.hpp"
#include "../surface/heightmap.hpp"
#include "path.hpp"

namespace freeform {

// Where the weight of a trace went, in fixed point, and how many rays did what.
struct TraceTotals {
    std::int64_t rays = 0;
    std::int64_t rays_hit_receiver = 0;
    Fixed emitted = 0;                 // N: weight reaching the surface aperture
    // Indexed by RayStatus (0..5); slot fresnel_reflected_slot (6): weight reflected
    // away at refractive faces when Fresnel losses are modelled.
    std::array<Fixed, weight_slots> weight_by_status{};

    Fixed on_receiver() const { return weight_by_status[0]; }
    Fixed lost_tir() const { return weight_by_status[std::size_t(RayStatus::lost_tir)]; }
    Fixed fresnel_reflected() const { return weight_by_status[fresnel_reflected_slot]; }
    double energy() const { return emitted > 0 ? double(on_receiver()) / double(emitted) : 0.0; }

    // A traced ray of weight w: its status's slot gets what it delivers, the Fresnel slot
    // what its faces reflected away.
    void add(const RayRecord& r, Fixed w) {
        ++rays;
        if (r.status == RayStatus::receiver) ++rays_hit_receiver;
        account_weight(weight_by_status, r, w);
    }
    void merge(const TraceTotals& o) {
        rays += o.rays;
        rays_hit_receiver += o.rays_hit_receiver;
        for (std::size_t k = 0; k < weight_by_status.size(); ++k) weight_by_status[k] += o.weight_by_status[k];
    }
};

// A tracer is bound to a surface, a ray set and the scene's physics. It traces every ray
// into a histogram, or a chosen subset into per-ray records (for incremental updates),
// and is told when heights changed in a patch (so that acceleration data can be refit).
template <class T>
concept Tracer = requires(const T& ct, T& t, Histogram& hist, TraceTotals& totals,
                          std::span<const std::int32_t> ids, std::span<RayRecord> records, const Patch& patch) {
    { T::name() } -> std::convertible_to<std::string_view>;
    { ct.rays() } -> std::convertible_to<const RaySet&>;
    { ct.params() } -> std::convertible_to<const PathParams&>;
    ct.trace_all(exec::seq, hist, totals);
    ct.trace_all(exec::omp, hist, totals);
    ct.trace(exec::seq, ids, records);
    ct.trace(exec::omp, ids, records);
    t.surface_changed(patch);
};

// Adds deposits to a container of cells (a struct, not a lambda, so that nvcc sees a
// FREEFORM_HD call operator when this header is part of a CUDA translation unit).
template <class Cells>
struct AddToCells {
    Cells* cells;
    FREEFORM_HD void operator()(std::int64_t c, Fixed a) const { (*cells)[std::size_t(c)] += a; }
};

// Deposits what a record of weight w delivers (no-op unless it reached the receiver).
template <class Cells>
inline void deposit_record(const ReceiverView& rv, const RayRecord& r, Fixed w, Cells& cells) {
    if (r.status != RayStatus::receiver) return;
    deposit(rv, r.px, r.py, delivered_weight(r, w), AddToCells<Cells>{&cells});
}

// Adds up the per-thread histograms and totals of a parallel trace. The sums are exact
// integers, so the result does not depend on how the work was split.
inline void merge_partials(std::span<Histogram> partial, std::span<TraceTotals> partial_totals, Histogram& out,
                           TraceTotals& totals) {
    out.clear();
    for (const auto& h : partial)
        for (std::size_t k = 0; k < out.cells.size(); ++k) out.cells[k] += h.cells[k];
    const Fixed emitted = totals.emitted;
    totals = TraceTotals{};
    totals.emitted = emitted;
    for (const auto& t : partial_totals) totals.merge(t);
}

}  // namespace freeform
