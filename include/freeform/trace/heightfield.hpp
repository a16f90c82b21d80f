#pragma once
// HeightfieldTracer: the exact, BVH-free tracer for a scene made of one height field.
// It handles mirrors (interreflections on the height field included, up to max_depth)
// and lenses (front face = the height field, flat back face), with Phong correction.
#include <algorithm>
#include <cstdint>
#include <span>
#include <string_view>
#include <vector>

#include "../core/exec.hpp"
#include "heightfield_kernel.hpp"
#include "packet.hpp"
#include "tracer.hpp"

namespace freeform {

// The tile height ranges of a height field (TileView; the walk's block skip,
// heightfield_kernel.hpp): each tile's lowest and highest vertex, the vertices on its
// borders included. One pass over the heights, made for each plain trace.
struct TileRanges {
    std::vector<float> lo, hi;
    int tiles_x = 0;

    explicit TileRanges(const HeightfieldView& hf) {
        constexpr int cells = 1 << hf_detail::tile_shift;
        const int cx = hf.nx - 1, cy = hf.ny - 1;
        tiles_x = (cx + cells - 1) / cells;
        const int tiles_y = (cy + cells - 1) / cells;
        lo.assign(std::size_t(tiles_x) * std::size_t(tiles_y), INFINITY);
        hi.assign(lo.size(), -INFINITY);
        for (int j = 0; j < hf.ny; ++j) {
            // A vertex on a tile border belongs to the tiles on both sides.
            const int tj0 = std::max(0, (j - 1) >> hf_detail::tile_shift);
            const int tj1 = std::min(tiles_y - 1, j >> hf_detail::tile_shift);
            for (int i = 0; i < hf.nx; ++i) {
                const float h = hf.height(i, j);
                const int ti0 = std::max(0, (i - 1) >> hf_detail::tile_shift);
                const int ti1 = std::min(tiles_x - 1, i >> hf_detail::tile_shift);
                for (int tj = tj0; tj <= tj1; ++tj)
                    for (int ti = ti0; ti <= ti1; ++ti) {
                        const std::size_t k = std::size_t(tj) * std::size_t(tiles_x) + std::size_t(ti);
                        lo[k] = std::min(lo[k], h), hi[k] = std::max(hi[k], h);
                    }
            }
        }
    }
    // `hf` with these tiles.
    HeightfieldView attach(HeightfieldView hf) const {
        hf.tiles = {lo.data(), hi.data(), tiles_x};
        return hf;
    }
};

class HeightfieldTracer {
public:
    HeightfieldTracer(const Heightmap& surface, const RaySet& rays, const PathParams& params)
        : surface_(&surface), rays_(&rays), params_(params) {}

    static constexpr std::string_view name() { return "heightfield"; }
    const RaySet& rays() const { return *rays_; }
    const PathParams& params() const { return params_; }
    const Heightmap& surface() const { return *surface_; }

    // Height changes need no acceleration update: the traversal reads the heights.
    void surface_changed(const Patch&) {}

    // Traces every ray and deposits it; `totals` receives where the weight went.
    template <HostPolicy P>
    void trace_all(P policy, Histogram& out, TraceTotals& totals) const {
        const int chunks = thread_count(policy);
        std::vector<Histogram> partial(std::size_t(chunks), Histogram(out.width, out.height));
        std::vector<TraceTotals> partial_totals(static_cast<std::size_t>(chunks));
        const TileRanges tiles(surface_->view());
        const HeightfieldView hf = tiles.attach(surface_->view());
        const RaySet& r = *rays_;
        for_each_chunk(policy, r.size(), chunks, [&](int c, std::int64_t begin, std::int64_t end) {
            Histogram& h = partial[std::size_t(c)];
            TraceTotals& t = partial_totals[std::size_t(c)];
#if !defined(__CUDACC__)
            if (packet::use_packets(params_)) {
                const hf_detail::Grid g = hf_detail::grid_of(hf);
                packet::NoLaneVisitor none;
                RayRecord rec[packet::width];
                for (std::int64_t k0 = begin; k0 < end; k0 += packet::width) {
                    const int n = int(std::min<std::int64_t>(packet::width, end - k0));
                    packet::trace_rays(hf, g, params_, r.origin.data() + k0, r.direction.data() + k0, n, rec, none);
                    for (int l = 0; l < n; ++l) {
                        const Fixed w = r.weight[std::size_t(k0 + l)];
                        t.add(rec[l], w);
                        deposit_record(params_.receiver, rec[l], w, h.cells);
                    }
                }
                return;
            }
#endif
            for (std::int64_t k = begin; k < end; ++k) {
                const RayRecord rec = trace_heightfield_ray(hf, params_, r.origin[std::size_t(k)],
                                                            r.direction[std::size_t(k)], NoCellVisitor{});
                const Fixed w = r.weight[std::size_t(k)];
                t.add(rec, w);
                deposit_record(params_.receiver, rec, w, h.cells);
            }
        });
        totals.emitted = r.total;
        merge_partials(partial, partial_totals, out, totals);
    }

    // Traces the rays `ids` into `records` (records[k] belongs to ids[k]).
    template <HostPolicy P>
    void trace(P policy, std::span<const std::int32_t> ids, std::span<RayRecord> records) const {
        const HeightfieldView hf = surface_->view();
#if !defined(__CUDACC__)
        if (packet::use_packets(params_)) {
            const hf_detail::Grid g = hf_detail::grid_of(hf);
            const std::int64_t packets = (std::int64_t(ids.size()) + packet::width - 1) / packet::width;
            for_each(policy, packets, [&](std::int64_t p) {
                const std::size_t k0 = std::size_t(p) * packet::width;
                const int n = int(std::min<std::size_t>(packet::width, ids.size() - k0));
                Vec3 o[packet::width], d[packet::width];
                for (int l = 0; l < n; ++l) {
                    const auto id = std::size_t(ids[k0 + std::size_t(l)]);
                    o[l] = rays_->origin[id], d[l] = rays_->direction[id];
                }
                packet::NoLaneVisitor none;
                packet::trace_rays(hf, g, params_, o, d, n, records.data() + k0, none);
            });
            return;
        }
#endif
        for_each(policy, std::int64_t(ids.size()), [&](std::int64_t k) {
            const auto id = std::size_t(ids[std::size_t(k)]);
            records[std::size_t(k)] =
                trace_heightfield_ray(hf, params_, rays_->origin[id], rays_->direction[id], NoCellVisitor{});
        });
    }

    // Traces one ray, reporting every surface cell its path crosses inside the slab.
    template <class Visitor>
    RayRecord trace_one(std::int32_t id, Visitor&& visit) const {
        return trace_heightfield_ray(surface_->view(), params_, rays_->origin[std::size_t(id)],
                                     rays_->direction[std::size_t(id)], visit);
    }

private:
    const Heightmap* surface_;
    const RaySet* rays_;
    PathParams params_;
};

static_assert(Tracer<HeightfieldTracer>, "HeightfieldTracer must satisfy the Tracer concept");

}  // namespace freeform
