#pragma once
// Cell means: the irradiance a camera or a light meter with the receiver's pixels records,
// and the error reported as `error_physical` (docs/measures.md).
//
// A target pixel is the mean irradiance wanted over its receiver cell, so the design is
// judged by the mean over each cell: every ray's whole weight in the cell it lands in
// (nearest deposit), with rays enough that the figure no longer depends on them. Rays
// come in batches, each a stratified set of its own jitter; the batches double until
// doubling them changes the error by less than `tolerance` (or the ray cap is reached),
// so memory stays that of one batch whatever the count.
#include <cmath>
#include <cstdint>

#include "../core/histogram.hpp"
#include "../core/rng.hpp"
#include "../objective/target.hpp"
#include "../objective/trace_setup.hpp"
#include "../scene/scene.hpp"
#include "../trace/tracer.hpp"

namespace freeform {

struct CellMeanOptions {
    double rays_per_cell = 64;         // rays per receiver cell in each batch
    double tolerance = 0.001;          // stop when doubling the rays changes the error by less
    double max_rays_per_cell = 1024;   // in all batches together
    std::uint64_t seed = 0;            // batch b uses hash_combine(seed, b + 1)
};

struct CellMeans {
    Histogram histogram;  // nearest deposit, every batch added
    TraceTotals totals;
    Target target;        // the target scaled to the histogram's rays (empty without one)
    double error = -1;    // cell-mean error to the target; -1 without a target
    double change_on_doubling = -1;  // |error − error with half the batches|; -1: one batch only
    double rays_per_cell = 0;        // in all batches together
    std::int64_t rays = 0;
    int batches = 0;
    bool converged = false;  // change_on_doubling < tolerance (false: stopped at the cap)
};

// Traces batches of rays until the cell-mean error converges. trace(scene, batch, hist,
// totals) traces one batch (its rays and path parameters: make_trace_setup) into hist
// (deposits) and totals (where the weight went), as a tracer's trace_all does; it is
// given `scene` with receiver.deposit = nearest and light.rays_per_cell = one batch's, for
// what a tracer needs beyond the set-up (meshes, the light's direction).
// `grid` places the rays (the aperture and top of the surface, scene/rays.hpp). Without
// a target one batch of max_rays_per_cell is traced.
template <class Trace>
CellMeans converged_cell_means(const Scene& scene, const Heightmap& grid, const ImageD* target,
                               const CellMeanOptions& o, Trace&& trace) {
    Scene s = scene;
    s.receiver.deposit = Deposit::nearest;
    s.light.rays = 0;
    s.light.rays_per_cell = target ? o.rays_per_cell : o.max_rays_per_cell;
    CellMeans out;
    out.histogram = Histogram(s.receiver.width, s.receiver.height);
    Fixed total = 0;    // the target's: what a flat surface would deliver (trace/setup.hpp)
    Fixed emitted = 0;  // the light's, so energy() is the share delivered, as the design's
    double previous = -1;
    while (true) {
        const TraceSetup batch =
            make_trace_setup(s, grid, nullptr, hash_combine(o.seed, std::uint64_t(out.batches) + 1));
        Histogram hist = batch.empty_histogram();
        TraceTotals batch_totals;
        trace(static_cast<const Scene&>(s), batch, hist, batch_totals);
        for (std::size_t k = 0; k < hist.cells.size(); ++k) out.histogram.cells[k] += hist.cells[k];
        out.totals.merge(batch_totals);
        emitted += batch_totals.emitted;
        total += target_total(batch.rays, batch.params);  // the target's: Fresnel included
        out.rays += batch.rays.size();
        ++out.batches;
        out.rays_per_cell = double(out.rays) / double(s.receiver.cells());
        if (!target) break;
        if ((out.batches & (out.batches - 1)) != 0) continue;  // judge at 1, 2, 4, 8, ... batches
        out.target = make_target(*target, s.receiver.width, s.receiver.height, total);
        out.error = l1_error(out.histogram, out.target);
        if (previous >= 0) {
            out.change_on_doubling = std::abs(out.error - previous);
            if (out.change_on_doubling < o.tolerance) {
                out.converged = true;
                break;
            }
        }
        previous = out.error;
        if (2.0 * out.batches * o.rays_per_cell > o.max_rays_per_cell) break;
    }
    out.totals.emitted = emitted;
    return out;
}

}  // namespace freeform
