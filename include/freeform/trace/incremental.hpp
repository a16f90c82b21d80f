#pragma once
// Incremental evaluation (docs/architecture.md §4): a move changes a few heights, so only the rays
// whose paths cross the changed part of the surface can land elsewhere.
//
// For every surface cell we keep the rays whose path crosses that cell inside the height
// slab [h_min, h_max] (every segment, not only the first hit): only those rays can meet
// a triangle of that cell, whatever its heights. A move touching a patch retraces
// exactly the rays listed on the cells whose triangles change (the patch dilated by the
// normal stencil), against the surface as the move would leave it, and returns the
// change of the histogram as a sparse delta. Accepting the move writes the new records
// and updates the per-cell ray lists; rejecting it changes nothing.
//
// Invariant (tests/test_incremental.cpp): after any sequence of moves the maintained
// records and histogram equal a full retrace bit for bit.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <memory>
#include <span>
#include <vector>

#include "../core/exec.hpp"
#include "../core/task_pool.hpp"
#include "../core/histogram.hpp"
#include "../core/sparse_delta.hpp"
#include "../surface/overlay.hpp"
#include "crossing.hpp"
#include "heightfield.hpp"
#include "packet.hpp"

namespace freeform {

// Both directions of the ray <-> surface cell relation, updated in place.
class RayCellIndex {
public:
    // Empties the index for `rays` rays over `cells` cells. The per-cell lists keep their
    // memory: a rebuild of the same index (a stage putting its best state back) refills
    // them without allocating again. Under grazing light, with ~65 cells per ray, page
    // faults were about a third of a design's profile (docs/performance.md, "The
    // speed/accuracy study").
    void reset(std::int64_t rays, std::int64_t cells) {
        pool_.clear();
        slot_.assign(std::size_t(rays), Slot{});
        cell_rays_.resize(std::size_t(cells));
        for (auto& l : cell_rays_) l.clear();
        waste_ = 0;
    }

    std::span<const CellCrossing> cells_of(std::int32_t ray) const {
        const Slot& s = slot_[std::size_t(ray)];
        return {pool_.data() + s.begin, s.count};
    }
    // Hints that a ray's cells will be read soon: first where they are (its slot), then,
    // once the slot has arrived, the cells themselves.
    void prefetch_slot(std::int32_t ray) const { prefetch(slot_.data() + ray); }
    void prefetch_cells(std::int32_t ray) const { prefetch(pool_.data() + slot_[std::size_t(ray)].begin); }
    const std::vector<std::int32_t>& rays_of(std::int32_t cell) const { return cell_rays_[std::size_t(cell)]; }

    // Room for `crossings` cells in all (before a build, so the pool grows once).
    void reserve(std::size_t crossings) { pool_.reserve(crossings + 2 * slot_.size()); }

    // First assignment of a ray's cells (rays added in increasing order at build time).
    void assign(std::int32_t ray, std::span<const CellCrossing> cells) {
        store(ray, cells);
        for (const auto& c : cells) cell_rays_[std::size_t(c.cell)].push_back(ray);
    }

    // Every ray's first assignment at once: for_each_ray(f) calls f(ray, cells) for every
    // ray in increasing order. The per-cell lists are sized from a count first, so that
    // they do not grow one push_back at a time: under grazing light (some 45 cells a ray,
    // 1,400 rays a cell) each list would be copied about ten times as it doubles.
    // The lists come out as assign() makes them, bit for bit.
    template <class ForEachRay>
    void assign_all(ForEachRay&& for_each_ray) {
        std::vector<std::int32_t> count(cell_rays_.size(), 0);
        for_each_ray([&](std::int32_t, std::span<const CellCrossing> cells) {
            for (const auto& c : cells) ++count[std::size_t(c.cell)];
        });
        for (std::size_t c = 0; c < cell_rays_.size(); ++c)
            cell_rays_[c].reserve(cell_rays_[c].size() + std::size_t(count[c]));
        for_each_ray([&](std::int32_t ray, std::span<const CellCrossing> cells) { assign(ray, cells); });
    }

    // Stores a ray's new cells if they are the cells it crossed before (only the height
    // ranges differ) and returns true; otherwise changes nothing and returns false. Such an
    // update touches only the ray's own slot: distinct rays may be updated from different
    // threads at once.
    bool update_ranges(std::int32_t ray, std::span<const CellCrossing> cells) {
        const Slot& s = slot_[std::size_t(ray)];
        if (s.count != cells.size()) return false;
        CellCrossing* old = pool_.data() + s.begin;
        for (std::size_t k = 0; k < cells.size(); ++k)
            if (old[k].cell != cells[k].cell) return false;
        std::copy(cells.begin(), cells.end(), old);
        return true;
    }

    // Replaces the cells of a ray whose cells changed (update_ranges said no): moves the
    // ray between the per-cell lists that differ, then stores the cells and their ranges.
    void relist(std::int32_t ray, std::span<const CellCrossing> cells) {
        const auto old = cells_of(ray);
        const auto has = [](std::span<const CellCrossing> list, std::int32_t cell) {
            return std::find_if(list.begin(), list.end(), [&](const CellCrossing& c) { return c.cell == cell; }) !=
                   list.end();
        };
        for (const auto& c : old)
            if (!has(cells, c.cell)) {
                auto& list = cell_rays_[std::size_t(c.cell)];
                auto it = std::find(list.begin(), list.end(), ray);
                *it = list.back();
                list.pop_back();
            }
        for (const auto& c : cells)
            if (!has(old, c.cell)) cell_rays_[std::size_t(c.cell)].push_back(ray);
        store(ray, cells);
    }

    std::int64_t ray_count() const { return std::int64_t(slot_.size()); }
    std::int64_t cell_count() const { return std::int64_t(cell_rays_.size()); }
    // Ray/cell crossings listed, all rays together.
    std::int64_t crossings() const {
        std::int64_t n = 0;
        for (const Slot& s : slot_) n += s.count;
        return n;
    }

    std::size_t memory_bytes() const {
        std::size_t b = pool_.capacity() * sizeof(CellCrossing) + slot_.capacity() * sizeof(Slot);
        for (const auto& l : cell_rays_) b += l.capacity() * 4 + sizeof(l);
        return b;
    }

private:
    void store(std::int32_t ray, std::span<const CellCrossing> cells) {
        Slot& s = slot_[std::size_t(ray)];
        if (cells.size() <= s.capacity) {
            std::copy(cells.begin(), cells.end(), pool_.begin() + s.begin);
        } else {
            waste_ += s.capacity;
            s.begin = std::int64_t(pool_.size());
            s.capacity = std::uint16_t(std::min<std::size_t>(cells.size() + 2, 65535));
            // push_back's inlined path: vector::insert and resize(n, value) took their
            // general paths for these few cells (perf: 1-3 % of a move).
            for (const CellCrossing& c : cells) pool_.push_back(c);
            for (std::size_t k = cells.size(); k < s.capacity; ++k) pool_.push_back(CellCrossing{-1});
        }
        s.count = std::uint16_t(cells.size());
        if (waste_ > std::int64_t(pool_.size() / 2) && pool_.size() > 4096) compact();
    }
    void compact() {
        std::vector<CellCrossing> fresh;
        fresh.reserve(pool_.size() - std::size_t(waste_));
        for (Slot& s : slot_) {
            const std::int64_t b = std::int64_t(fresh.size());
            fresh.insert(fresh.end(), pool_.begin() + s.begin, pool_.begin() + s.begin + s.capacity);
            s.begin = b;
        }
        pool_.swap(fresh);
        waste_ = 0;
    }

    // Where a ray's cells lie in pool_ (one record per ray: one cache line to find them).
    struct Slot {
        std::int64_t begin = 0;
        std::uint16_t count = 0, capacity = 0;
    };
    std::vector<CellCrossing> pool_;
    std::vector<Slot> slot_;
    std::vector<std::vector<std::int32_t>> cell_rays_;
    std::int64_t waste_ = 0;
};

// Sorts cells[0..n) by cell and merges repeats (paths that come back over a cell) into
// one crossing with the union of their height ranges; returns the new count. The lists
// are short (one to a few cells for most rays): insertion sort.
inline std::size_t sort_merge_cells(CellCrossing* cells, std::size_t n) {
    if (n < 2) return n;
    // A path's cells come in the order it crosses them: a path running towards lower rows
    // comes in descending, the insertion sort's worst case (under grazing light, some 45
    // cells a ray, the sort was a tenth of a full trace's profile). Reversed first, it is
    // nearly sorted. Equal cells are merged by min and max: their order does not matter.
    if (cells[0].cell > cells[n - 1].cell) std::reverse(cells, cells + n);
    for (std::size_t k = 1; k < n; ++k) {
        const CellCrossing x = cells[k];
        std::size_t j = k;
        for (; j > 0 && cells[j - 1].cell > x.cell; --j) cells[j] = cells[j - 1];
        cells[j] = x;
    }
    std::size_t w = 0;
    for (std::size_t r = 1; r < n; ++r) {
        if (cells[r].cell == cells[w].cell) {
            cells[w].zlo = cells[r].zlo < cells[w].zlo ? cells[r].zlo : cells[w].zlo;
            cells[w].zhi = cells[r].zhi > cells[w].zhi ? cells[r].zhi : cells[w].zhi;
        } else {
            cells[++w] = cells[r];
        }
    }
    return w + 1;
}

// The reach envelope (docs/architecture.md §4, "The reach envelope"). Under oblique
// light a ray's path runs through the height slab over many cells (a point light 5 cm
// above a 10 cm mirror with 30 mm of height bounds: some 120 cells at 401²), yet it can
// only meet the few whose heights come near it. While every vertex stays within `margin`
// of the height it had when the trace was built, a cell's corners stay inside
// [cell_lo, cell_hi] (its vertices' limits, widened by the walk's rounding allowance);
// a crossing whose path lies wholly outside that range can then never pass the walk's
// culling test (within_reach), so the index leaves it out. Proposals are clamped to the
// vertex limits (VertexBounds), and the problem rebuilds the trace, re-centring the
// envelope, once an accepted move takes a vertex more than margin / 2 from its centre.
struct ReachView {
    const float* lo = nullptr;  // per surface cell (null: every crossing is kept)
    const float* hi = nullptr;
    FREEFORM_FORCE_INLINE bool admits(std::int32_t cell, float zlo, float zhi) const {
        return lo == nullptr || (zlo <= hi[cell] && zhi >= lo[cell]);
    }
};

struct ReachEnvelope {
    float margin = INFINITY;  // infinite: no envelope
    std::vector<float> centre, vertex_lo, vertex_hi;  // per vertex, row-major
    std::vector<float> cell_lo, cell_hi;              // per surface cell, row-major

    bool active() const { return !cell_lo.empty(); }
    ReachView view() const { return active() ? ReachView{cell_lo.data(), cell_hi.data()} : ReachView{}; }
    VertexBounds bounds() const { return active() ? VertexBounds{vertex_lo.data(), vertex_hi.data()} : VertexBounds{}; }
    void clear() {
        for (auto* v : {&centre, &vertex_lo, &vertex_hi, &cell_lo, &cell_hi}) std::vector<float>().swap(*v);
    }

    // The envelope of `surface`'s present heights.
    void centre_on(const Heightmap& surface) {
        const int nx = surface.nx(), ny = surface.ny();
        centre = surface.heights();
        vertex_lo.resize(centre.size());
        vertex_hi.resize(centre.size());
        for (std::size_t k = 0; k < centre.size(); ++k) {
            vertex_lo[k] = std::max(surface.h_min(), centre[k] - margin);
            vertex_hi[k] = std::min(surface.h_max(), centre[k] + margin);
        }
        const float pad = hf_detail::grid_of(surface.view()).z_pad;
        cell_lo.resize(std::size_t(nx - 1) * std::size_t(ny - 1));
        cell_hi.resize(cell_lo.size());
        std::size_t c = 0;
        for (int j = 0; j + 1 < ny; ++j)
            for (int i = 0; i + 1 < nx; ++i, ++c) {
                const std::size_t v = std::size_t(j) * std::size_t(nx) + std::size_t(i), up = v + std::size_t(nx);
                const auto& lo = vertex_lo;
                const auto& hi = vertex_hi;
                cell_lo[c] = std::min(std::min(lo[v], lo[v + 1]), std::min(lo[up], lo[up + 1])) - pad;
                cell_hi[c] = std::max(std::max(hi[v], hi[v + 1]), std::max(hi[up], hi[up + 1])) + pad;
            }
    }

    // Whether some vertex of `o` lies more than margin / 2 from its centre: time to
    // re-centre before the limits start to bind.
    bool spent(const HeightOverlay& o, int nx) const {
        const float half = 0.5f * margin;
        return active() && any_vertex(o, nx, [&](float h, std::size_t v) { return std::abs(h - centre[v]) > half; });
    }

    // Whether every vertex of `o` is inside its limits (a move made without them).
    bool holds(const HeightOverlay& o, int nx) const {
        return !active() ||
               !any_vertex(o, nx, [&](float h, std::size_t v) { return !(h >= vertex_lo[v] && h <= vertex_hi[v]); });
    }

private:
    // Whether pred(height, vertex) holds for some vertex of `o`'s patch (row-major ids
    // on a grid nx wide).
    template <class Pred>
    static bool any_vertex(const HeightOverlay& o, int nx, Pred&& pred) {
        std::size_t k = 0;
        for (int j = o.patch.j0; j <= o.patch.j1; ++j)
            for (int i = o.patch.i0; i <= o.patch.i1; ++i, ++k)
                if (pred(o.heights[k], std::size_t(j) * std::size_t(nx) + std::size_t(i))) return true;
        return false;
    }
};

// Collects the surface cells a traced path crosses, with the path's height range over
// each. Called for every cell of every walk, so it only merges an immediate repeat and is
// forced inline (an out-of-line call makes the walk spill its registers); finish() merges
// the remaining repeats once per ray.
struct CellCollector {
    std::vector<CellCrossing>* out;
    std::size_t first;  // where this ray's cells start in *out
    int cells_per_row;
    ReachView reach{};  // only the crossings it admits are kept (none: all)
    FREEFORM_FORCE_INLINE void operator()(int ci, int cj, float zlo, float zhi) const {
        const std::int32_t c = cj * cells_per_row + ci;
        if (!reach.admits(c, zlo, zhi)) return;
        if (out->size() > first && out->back().cell == c) {
            CellCrossing& last = out->back();
            last.zlo = zlo < last.zlo ? zlo : last.zlo;
            last.zhi = zhi > last.zhi ? zhi : last.zhi;
            return;
        }
        out->push_back(CellCrossing{c, zlo, zhi});
    }
    // A tracer that does not know the path's height over the cell (whole line: never culled).
    FREEFORM_FORCE_INLINE void operator()(int ci, int cj) const { (*this)(ci, cj, -INFINITY, INFINITY); }
    // Sorts this ray's cells and merges repeats: the union of their height ranges.
    void finish() const {
        out->resize(first + sort_merge_cells(out->data() + first, out->size() - first));
    }
};

#if !defined(__CUDACC__)
// The cells each lane of a packet crosses (trace/packet.hpp's lane visitor), in fixed
// arrays: the packet walk is inlined whole, and a call or an allocation inside it would
// make it spill its registers. A lane whose path crosses more cells than fit is marked
// in `overflow` and retraced by the scalar kernel (same record, tests/test_packet.cpp).
struct LaneCellBuffer {
    static constexpr bool active = true;
    static constexpr int capacity = 48;
    int cells_per_row = 0;
    ReachView reach{};           // only the crossings it admits are kept (none: all)
    std::uint32_t overflow = 0;  // bit l: lane l ran out of room
    int count[packet::width] = {};
    CellCrossing cell[packet::width][capacity];

    void clear() {
        overflow = 0;
        for (int& n : count) n = 0;
    }
    FREEFORM_FORCE_INLINE void operator()(int l, int ci, int cj, float zlo, float zhi) {
        const std::int32_t c = cj * cells_per_row + ci;
        if (!reach.admits(c, zlo, zhi)) return;
        int& n = count[l];
        if (n > 0 && cell[l][n - 1].cell == c) {
            CellCrossing& last = cell[l][n - 1];
            last.zlo = zlo < last.zlo ? zlo : last.zlo;
            last.zhi = zhi > last.zhi ? zhi : last.zhi;
            return;
        }
        if (n == capacity) {
            overflow |= 1u << l;
            return;
        }
        cell[l][n++] = CellCrossing{c, zlo, zhi};
    }
};
#endif

// What one thread of a ray selection and retrace produces: the rays it selected, their
// cells, the change of the histogram and of the weight per status. A TraceChange is its
// own first part; a split over threads gives the others one each (TraceChange::parts).
// The histogram change, weights and counts of the parts are added into the first; the
// rays, records and cells stay where they were made (TraceChange::part), to be
// committed there.
struct TracePart {
    std::vector<std::int32_t> rays;       // affected rays (of this part)
    std::vector<RayRecord> records;       // new records of `rays`
    std::vector<std::int32_t> cell_begin; // where each ray's cells start in `cells`, and
                                          // where the last one's end (rays.size() + 1)
    std::vector<CellCrossing> cells;      // their new cell lists, packed
    SparseDelta histogram;                // change of R
    std::array<Fixed, weight_slots> status_delta{};  // change of weight per slot (RayStatus, Fresnel)
    std::int64_t rays_moved = 0;          // rays whose record changed
    std::int64_t rays_culled = 0;         // rays listed on the move's cells that pass them out of reach
    std::vector<std::uint32_t> ray_mark;  // dedupe of affected rays (generation stamps)
    std::uint32_t generation = 0;
#if !defined(__CUDACC__)
    LaneCellBuffer lane_cells;  // scratch of the packet retrace
#endif

    // Empties the outputs and starts a new generation of marks.
    void reset_part(std::int64_t ray_count, std::int64_t receiver_cells) {
        if (std::int64_t(ray_mark.size()) != ray_count) ray_mark.assign(std::size_t(ray_count), 0), generation = 0;
        if (std::int64_t(histogram.value.size()) != receiver_cells) histogram.resize(std::size_t(receiver_cells));
        histogram.clear();
        rays.clear();
        records.clear();
        cell_begin.clear();
        cells.clear();
        status_delta.fill(0);
        rays_moved = 0;
        rays_culled = 0;
        if (++generation == 0) {
            std::fill(ray_mark.begin(), ray_mark.end(), 0u);
            generation = 1;
        }
    }
};

// The outcome of retracing the rays a move can affect; filled by evaluate(), consumed by
// commit(). Holds its own working memory so several can be evaluated concurrently.
struct TraceChange : TracePart {
    // Height ranges of the move's cells before and after it, widened as the walk's
    // culling test widens them (scratch of the ray selection).
    std::vector<CellReach> reach;
    std::vector<std::int32_t> cell_slot;  // surface cell -> its entry in reach, -1 outside the move
    std::vector<std::unique_ptr<TracePart>> parts;  // room for parts 1, 2, ... of a split
    int split = 1;  // parts that hold this change's rays: part(0) .. part(split - 1)

    // Empties the change: one part, no rays (see TracePart::reset_part).
    void reset(std::int64_t ray_count, std::int64_t receiver_cells) {
        reset_part(ray_count, receiver_cells);
        split = 1;
    }

    // Part p of the rays (0: this object), in the serial order of the selection.
    const TracePart& part(int p) const {
        return p == 0 ? static_cast<const TracePart&>(*this) : *parts[std::size_t(p - 1)];
    }
    TracePart& part(int p) { return p == 0 ? static_cast<TracePart&>(*this) : *parts[std::size_t(p - 1)]; }
    // Rays retraced, all parts together.
    std::size_t ray_count() const {
        std::size_t n = 0;
        for (int p = 0; p < split; ++p) n += part(p).rays.size();
        return n;
    }
};

// Every `stride`-th ray of a set traced as IncrementalTrace::rebuild's scalar path traces
// it, its cells collected: how many rays, in how many seconds, crossing how many cells.
// A design with a time budget asks this before it builds a trace it may not afford
// (design/designer.hpp, the level's start).
// `admitted`: the crossings a reach envelope keeps, where one is given (else all).
struct RebuildSample {
    std::int64_t rays = 0;
    double seconds = 0;
    std::int64_t crossings = 0;
    std::int64_t admitted = 0;

    // Whether the envelope is worth keeping: it leaves out at least half of the crossings
    // (under light near the normal a path crosses a cell or two anyway).
    bool envelope_pays() const { return crossings > 0 && 2 * admitted <= crossings; }
    // The crossings a trace built now would list.
    std::int64_t listed() const { return envelope_pays() ? admitted : crossings; }
};

inline RebuildSample sample_rebuild(const Heightmap& surface, const RaySet& rays, const PathParams& params,
                                    std::int64_t stride, ReachView reach = {}) {
    const auto t0 = std::chrono::steady_clock::now();
    RebuildSample s;
    std::vector<CellCrossing> cells;
    const HeightfieldView hf = surface.view();
    for (std::int64_t k = 0; k < rays.size(); k += std::max<std::int64_t>(stride, 1)) {
        cells.clear();
        CellCollector visit{&cells, 0, surface.nx() - 1};
        trace_heightfield_ray(hf, params, rays.origin[std::size_t(k)], rays.direction[std::size_t(k)], visit);
        visit.finish();
        s.crossings += std::int64_t(cells.size());
        for (const CellCrossing& c : cells) s.admitted += reach.admits(c.cell, c.zlo, c.zhi) ? 1 : 0;
        ++s.rays;
    }
    s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return s;
}

// Maintained per-ray records and ray/cell index for one height field, ray set and scene.
class IncrementalTrace {
public:
    IncrementalTrace(const Heightmap& surface, const RaySet& rays, const PathParams& params)
        : surface_(&surface), rays_(&rays), params_(params) {}

    const RaySet& rays() const { return *rays_; }
    const Heightmap& surface() const { return *surface_; }
    const PathParams& params() const { return params_; }
    const std::vector<RayRecord>& records() const { return records_; }
    const RayCellIndex& index() const { return index_; }
    // Counts the changes of the state (rebuilds and commits): a copy of the state kept
    // elsewhere (a device's, trace/window.hpp) knows from it whether it is still current.
    std::uint64_t version() const { return version_; }
    const std::array<Fixed, weight_slots>& weight_by_status() const { return status_weight_; }

    // The reach envelope's margin (metres; infinite: none, the default). Takes effect at
    // the next rebuild(), which keeps the envelope only where it leaves out at least
    // half of the crossings (a sample of every 64th ray): under light near the normal a
    // path crosses a cell or two anyway, and the limits would cost without paying.
    void set_reach_margin(float margin) { reach_.margin = margin; }
    const ReachEnvelope& reach() const { return reach_; }
    // The vertex limits proposals must keep (none when no envelope is in force).
    VertexBounds vertex_bounds() const { return reach_.bounds(); }
    int receiver_width() const { return params_.receiver.width; }
    int receiver_height() const { return params_.receiver.height; }

    // Full trace: records, index and histogram from scratch.
    template <HostPolicy P>
    Histogram rebuild(P policy) {
        centre_reach();
        const std::int64_t n = rays_->size();
        records_.assign(std::size_t(n), RayRecord{});
        index_.reset(n, cell_count());
        ++version_;
        const int chunks = std::max(1, thread_count(policy));
        std::vector<std::vector<CellCrossing>> chunk_cells(static_cast<std::size_t>(chunks));
        std::vector<std::vector<std::int64_t>> chunk_begin(static_cast<std::size_t>(chunks));
        const HeightfieldView hf = surface_->view();
        for_each_chunk(policy, n, chunks, [&](int c, std::int64_t begin, std::int64_t end) {
            auto& cells = chunk_cells[std::size_t(c)];
            auto& starts = chunk_begin[std::size_t(c)];
            starts.reserve(std::size_t(end - begin + 1));
            // Room for the chunk's cells, from the rays of its first thirty-second: the
            // vector then grows once, not by doubling (each doubling copies it and faults
            // in new pages; under grazing light the chunk holds hundreds of megabytes).
            const std::int64_t probe = begin + std::max<std::int64_t>(256, (end - begin) / 32);
            bool sized = false;
            const auto size_from_probe = [&](std::int64_t done) {
                if (sized || done < probe || done >= end) return;
                sized = true;
                cells.reserve(std::size_t(1.1 * double(cells.size()) * double(end - begin) / double(done - begin)) + 64);
            };
#if !defined(__CUDACC__)
            if (packet::use_packets(params_)) {
                auto lanes = std::make_unique<LaneCellBuffer>();
                lanes->reach = reach_.view();
                const hf_detail::Grid grid = hf_detail::grid_of(hf);
                for (std::int64_t k0 = begin; k0 < end; k0 += packet::width) {
                    const int count = int(std::min<std::int64_t>(packet::width, end - k0));
                    const Vec3* o = rays_->origin.data() + k0;
                    const Vec3* d = rays_->direction.data() + k0;
                    trace_packet(hf, grid, o, d, count, records_.data() + k0, *lanes);
                    for (int l = 0; l < count; ++l) {
                        starts.push_back(std::int64_t(cells.size()));
                        append_lane_cells(hf, *lanes, l, o[l], d[l], records_[std::size_t(k0 + l)], cells);
                    }
                    size_from_probe(k0 + count);
                }
                starts.push_back(std::int64_t(cells.size()));
                return;
            }
#endif
            for (std::int64_t k = begin; k < end; ++k) {
                starts.push_back(std::int64_t(cells.size()));
                CellCollector visit{&cells, cells.size(), surface_->nx() - 1, reach_.view()};
                records_[std::size_t(k)] = trace_heightfield_ray(hf, params_, rays_->origin[std::size_t(k)],
                                                                 rays_->direction[std::size_t(k)], visit);
                visit.finish();
                size_from_probe(k + 1);
            }
            starts.push_back(std::int64_t(cells.size()));
        });
        std::size_t crossings = 0;
        for (const auto& cells : chunk_cells) crossings += cells.size();
        index_.reserve(crossings);
        index_.assign_all([&](auto&& f) {
            for (int c = 0; c < chunks; ++c) {
                const std::int64_t begin = n * c / chunks;
                const auto& cells = chunk_cells[std::size_t(c)];
                const auto& starts = chunk_begin[std::size_t(c)];
                for (std::size_t k = 0; k + 1 < starts.size(); ++k)
                    f(std::int32_t(begin + std::int64_t(k)),
                      std::span(cells.data() + starts[k], std::size_t(starts[k + 1] - starts[k])));
            }
        });
        recount_status_weights();
        return histogram();
    }

    // Full trace with a caller-supplied tracer: retrace(id, visit) traces ray `id`,
    // calling visit(ci, cj) for every cell its path crosses inside the slab (serial).
    template <class Retrace>
    Histogram rebuild_with(Retrace&& retrace) {
        reach_.clear();  // a tracer of its own may not report the path's heights
        const std::int64_t n = rays_->size();
        records_.assign(std::size_t(n), RayRecord{});
        index_.reset(n, cell_count());
        ++version_;
        std::vector<CellCrossing> cells;
        for (std::int64_t k = 0; k < n; ++k) {
            cells.clear();
            CellCollector visit{&cells, 0, surface_->nx() - 1};
            records_[std::size_t(k)] = retrace(std::int32_t(k), visit);
            visit.finish();
            index_.assign(std::int32_t(k), cells);
        }
        recount_status_weights();
        return histogram();
    }

    // The histogram of the maintained records.
    Histogram histogram() const {
        Histogram h(params_.receiver.width, params_.receiver.height);
        for (std::size_t k = 0; k < records_.size(); ++k)
            deposit_record(params_.receiver, records_[k], rays_->weight[k], h.cells);
        return h;
    }

    // Surface cells whose triangles change when `o` is committed.
    Patch affected_cells(const HeightOverlay& o) const {
        const Patch& np = o.normal_patch;
        return Patch{np.i0 - 1, np.j0 - 1, np.i1, np.j1}.clipped(surface_->nx() - 1, surface_->ny() - 1);
    }

    // Fewest rays worth handing to another thread (a few microseconds of tracing; a worker
    // that yields between runs answers within about one). 256 before the caller stopped
    // sleeping in its wait: 128 makes 201² / 100² moves (~270 rays) 1.46x faster on two
    // threads and changes nothing measurable at 101² (git show 1827177:benchmarks/results/speed12/min_rays_per_thread.txt).
    static constexpr std::size_t min_rays_per_thread = 128;

    // Retraces the rays `o` can affect against the surface with `o` applied, without
    // changing anything. Thread-safe for distinct `change` objects.
    // With a pool of several threads, a move with many rays is retraced by all of them,
    // each a contiguous run of its rays (change.part(0), part(1), ...): taken in order,
    // the parts are the serial change bit for bit, and their histogram changes are added
    // into the change's (exact integer sums). The pool must not be running a task of its
    // own already (no nesting).
    void evaluate(const HeightOverlay& o, TraceChange& change, TaskPool* pool = nullptr) const {
        const OverlayView view = overlay_view(*surface_, o);
#if !defined(__CUDACC__)
        if (packet::use_packets(params_)) {
            // Each thread retraces the rays it selected right away (one parallel section
            // a move instead of two), into its own part; commit() stores each part with
            // the thread that made it, so the rays, records and cells are never copied
            // into one list (that copy was 4 % of the caller's time with two threads).
            const hf_detail::Grid grid = hf_detail::grid_of(view);
            select_rays(o, change, pool, [&](TracePart& out) {
                out.records.resize(out.rays.size());
                out.cell_begin.resize(out.rays.size() + 1);
                retrace_packets_range(view, grid, out.rays.data(), out.rays.size(), out.records.data(),
                                      out.cell_begin.data(), out);
                out.cell_begin.back() = std::int32_t(out.cells.size());
            });
            return;
        }
#endif
        evaluate_with(o, change, [&](std::int32_t id, CellCollector& visit) {
            return trace_heightfield_ray(view, params_, rays_->origin[std::size_t(id)],
                                         rays_->direction[std::size_t(id)], visit);
        });
    }

    // Same, with a caller-supplied retrace (used by tracers that must see the move in
    // their own acceleration structure first, like Embree).
    template <class Retrace>
    void evaluate_with(const HeightOverlay& o, TraceChange& change, Retrace&& retrace) const {
        if (select_rays(o, change)) retrace_into(change, retrace);
    }

    // The rays evaluate() retraces for `o`, in its order, into change.rays (one part), and
    // nothing else; false when `o` changes nothing. A window of moves evaluated together
    // (trace/window.hpp) starts from the same selection.
    bool select_move_rays(const HeightOverlay& o, TraceChange& change) const { return select_rays(o, change); }

    // Retraces every ray against the surface with `o` applied: the reference's full
    // evaluation, with the same result as evaluate() (for comparisons and benchmarks).
    void evaluate_all(const HeightOverlay& o, TraceChange& change, TaskPool* pool = nullptr) const {
        change.reset(rays_->size(), std::int64_t(params_.receiver.width) * params_.receiver.height);
        change.rays.resize(std::size_t(rays_->size()));
        for (std::size_t k = 0; k < change.rays.size(); ++k) change.rays[k] = std::int32_t(k);
        const OverlayView view = overlay_view(*surface_, o);
#if !defined(__CUDACC__)
        if (packet::use_packets(params_)) {
            retrace_packets_into(view, change, pool);
            return;
        }
#endif
        retrace_into(change, [&](std::int32_t id, CellCollector& visit) {
            return trace_heightfield_ray(view, params_, rays_->origin[std::size_t(id)],
                                         rays_->direction[std::size_t(id)], visit);
        });
    }

    // Makes an evaluated change part of the state (the caller commits the heights).
    //
    // Each part's records are stored, and the cells of its rays that cross the same cells
    // as before (most of them), each in the ray's own slot; then the rays whose cells
    // changed are moved in the shared per-cell lists, in order. With a pool, a change
    // evaluated in parts has its parts stored by the pool's threads: a part's records and
    // cells sit in the cache of the thread that traced them, and the caller storing them
    // one by one waited on the other core's cache for each (perf: a fifth of the caller's
    // time with two threads). The state is the same either way, lists included.
    void commit(const TraceChange& change, TaskPool* pool = nullptr) {
        ++version_;
        const auto cells_of = [](const TracePart& part, std::size_t k) {
            return std::span(part.cells.data() + part.cell_begin[k],
                             std::size_t(part.cell_begin[k + 1] - part.cell_begin[k]));
        };
        if (int(relisted_.size()) < change.split) relisted_.resize(std::size_t(change.split));
        const auto store_part = [&](int p) {
            const TracePart& part = change.part(p);
            auto& later = relisted_[std::size_t(p)];
            later.clear();
            for (std::size_t k = 0; k < part.rays.size(); ++k) {
                records_[std::size_t(part.rays[k])] = part.records[k];
                if (!index_.update_ranges(part.rays[k], cells_of(part, k))) later.push_back(k);
            }
        };
        if (pool != nullptr && change.split > 1)
            run_parts(*pool, change.split, store_part);
        else
            for (int p = 0; p < change.split; ++p) store_part(p);
        for (int p = 0; p < change.split; ++p)
            for (std::size_t k : relisted_[std::size_t(p)])
                index_.relist(change.part(p).rays[k], cells_of(change.part(p), k));
        for (std::size_t s = 0; s < status_weight_.size(); ++s) status_weight_[s] += change.status_delta[s];
    }

private:
    // Starts `change` for the move `o` and lists the rays it must retrace; false (and an
    // empty change) when the move changes nothing. `per_part(part)` runs on each part of
    // the selection (the thread that selected it) once its rays are listed.
    template <class PerPart>
    bool select_rays(const HeightOverlay& o, TraceChange& change, TaskPool* pool, PerPart&& per_part) const {
        change.reset(rays_->size(), std::int64_t(params_.receiver.width) * params_.receiver.height);
        if (o.empty()) {
            change.cell_begin.push_back(0);
            return false;
        }
        collect_rays(o, affected_cells(o), change, pool, per_part);
        return true;
    }
    bool select_rays(const HeightOverlay& o, TraceChange& change) const {
        return select_rays(o, change, nullptr, [](TracePart&) {});
    }

    // Adds part `other`'s histogram change, weights per status and counts to `into`
    // (emptying other's histogram).
    static void add_totals(TracePart& into, TracePart& other) {
        other.histogram.drain([&](std::int32_t c, Fixed v) { into.histogram.add(c, v); });
        for (std::size_t st = 0; st < into.status_delta.size(); ++st) into.status_delta[st] += other.status_delta[st];
        into.rays_moved += other.rays_moved;
        into.rays_culled += other.rays_culled;
    }

    // Makes parts 1 .. parts - 1 of a split ready (part 0: the change itself).
    void start_parts(TraceChange& change, int parts) const {
        while (change.parts.size() < std::size_t(parts - 1)) change.parts.push_back(std::make_unique<TracePart>());
        for (int p = 1; p < parts; ++p)
            change.parts[std::size_t(p - 1)]->reset_part(rays_->size(), std::int64_t(change.histogram.value.size()));
    }

    // Runs task(p) for p in [0, parts) on the pool; the first exception (in part order) is
    // rethrown after all have ended.
    template <class Task>
    static void run_parts(TaskPool& pool, int parts, Task&& task) {
        std::vector<std::exception_ptr> errors(static_cast<std::size_t>(parts));
        pool.run(parts, [&](int p) {
            try {
                task(p);
            } catch (...) {
                errors[std::size_t(p)] = std::current_exception();
            }
        });
        for (const auto& e : errors)
            if (e) std::rethrow_exception(e);
    }

    // Retraces change.rays and records what changed.
    template <class Retrace>
    void retrace_into(TraceChange& change, Retrace&& retrace) const {
        const int cells_per_row = surface_->nx() - 1;
        change.records.resize(change.rays.size());
        change.cell_begin.resize(change.rays.size() + 1);
        for (std::size_t k = 0; k < change.rays.size(); ++k) {
            change.cell_begin[k] = std::int32_t(change.cells.size());
            CellCollector visit{&change.cells, change.cells.size(), cells_per_row, reach_.view()};
            const RayRecord now = retrace(change.rays[k], visit);
            visit.finish();
            change.records[k] = now;
            account(change.rays[k], now, change);
        }
        change.cell_begin[change.rays.size()] = std::int32_t(change.cells.size());
    }

#if !defined(__CUDACC__)
    // Traces up to packet::width rays in one packet: records into rec[0..n), the cells
    // each crosses into `lanes`.
    template <class View>
    void trace_packet(const View& view, const hf_detail::Grid& grid, const Vec3* o, const Vec3* d, int n,
                      RayRecord* rec, LaneCellBuffer& lanes) const {
        lanes.cells_per_row = surface_->nx() - 1;
        lanes.reach = reach_.view();
        lanes.clear();
        packet::trace_rays(view, grid, params_, o, d, n, rec, lanes);
    }

    // Appends lane l's cells (sorted and merged, as CellCollector::finish leaves them) to
    // `out`; a lane that overflowed its buffer is retraced by the scalar kernel.
    template <class View>
    void append_lane_cells(const View& view, LaneCellBuffer& lanes, int l, Vec3 o, Vec3 d, RayRecord& rec,
                           std::vector<CellCrossing>& out) const {
        if (lanes.overflow >> l & 1u) {
            CellCollector visit{&out, out.size(), surface_->nx() - 1, reach_.view()};
            rec = trace_heightfield_ray(view, params_, o, d, visit);
            visit.finish();
            return;
        }
        const std::size_t n = sort_merge_cells(lanes.cell[l], std::size_t(lanes.count[l]));
        // One to a few cells: push_back's inlined path (vector::insert's general one cost
        // more than the copy, about 85 instructions a ray under callgrind).
        for (std::size_t k = 0; k < n; ++k) out.push_back(lanes.cell[l][k]);
    }

    // retrace_into with the packet tracer, eight rays at a time, split over the pool's
    // threads when the move has rays enough.
    template <class View>
    void retrace_packets_into(const View& view, TraceChange& change, TaskPool* pool = nullptr) const {
        const std::size_t n = change.rays.size();
        change.records.resize(n);
        change.cell_begin.resize(n + 1);
        const hf_detail::Grid grid = hf_detail::grid_of(view);
        const int threads = pool != nullptr ? pool->threads() : 1;
        const int parts = int(std::min<std::size_t>(std::size_t(threads), n / min_rays_per_thread));
        if (parts <= 1) {
            retrace_packets_range(view, grid, change.rays.data(), n, change.records.data(), change.cell_begin.data(),
                                  change);
            change.cell_begin[n] = std::int32_t(change.cells.size());
            return;
        }
        // Contiguous ranges, whole packets each, so that every ray is traced in the same
        // packet as without the split (a lane's result does not depend on its packet
        // anyway, tests/test_packet.cpp).
        std::vector<std::size_t> bound(std::size_t(parts) + 1);
        for (int p = 0; p <= parts; ++p)
            bound[std::size_t(p)] = std::min(n, (n * std::size_t(p) / std::size_t(parts) + packet::width - 1) /
                                                    packet::width * packet::width);
        start_parts(change, parts);
        run_parts(*pool, parts, [&](int p) {
            const std::size_t b = bound[std::size_t(p)];
            retrace_packets_range(view, grid, change.rays.data() + b, bound[std::size_t(p) + 1] - b,
                                  change.records.data() + b, change.cell_begin.data() + b, change.part(p));
        });
        for (int p = 1; p < parts; ++p) {
            TracePart& other = *change.parts[std::size_t(p - 1)];
            const auto offset = std::int32_t(change.cells.size());
            for (std::size_t k = bound[std::size_t(p)]; k < bound[std::size_t(p) + 1]; ++k) change.cell_begin[k] += offset;
            change.cells.insert(change.cells.end(), other.cells.begin(), other.cells.end());
            add_totals(change, other);
        }
        change.cell_begin[n] = std::int32_t(change.cells.size());
    }

    // Retraces the n rays ids[0..n): their records into records[0..n), where each one's
    // cells start in out.cells into cell_begin[0..n), the cells and the rest into `out`.
    template <class View>
    void retrace_packets_range(const View& view, const hf_detail::Grid& grid, const std::int32_t* ids, std::size_t n,
                               RayRecord* records, std::int32_t* cell_begin, TracePart& out) const {
        Vec3 o[packet::width], d[packet::width];
        RayRecord rec[packet::width];
        for (std::size_t k0 = 0; k0 < n; k0 += packet::width) {
            const int count = int(std::min<std::size_t>(packet::width, n - k0));
            // The rays of a move are scattered over the ray arrays: ask for the next
            // packet's data now, so that it arrives while this packet is traced.
            for (std::size_t k = k0 + packet::width; k < std::min(n, k0 + 2 * packet::width); ++k) {
                const auto id = std::size_t(ids[k]);
                prefetch(rays_->origin.data() + id);
                prefetch(rays_->direction.data() + id);
                prefetch(rays_->weight.data() + id);
                prefetch(records_.data() + id);
            }
            for (int l = 0; l < count; ++l) {
                const auto id = std::size_t(ids[k0 + std::size_t(l)]);
                o[l] = rays_->origin[id], d[l] = rays_->direction[id];
            }
            trace_packet(view, grid, o, d, count, rec, out.lane_cells);
            for (int l = 0; l < count; ++l) {
                const std::size_t k = k0 + std::size_t(l);
                cell_begin[k] = std::int32_t(out.cells.size());
                append_lane_cells(view, out.lane_cells, l, o[l], d[l], rec[l], out.cells);
                records[k] = rec[l];
                account(ids[k], rec[l], out);
            }
        }
    }
#endif

    // If ray `id`'s new record differs from the maintained one, moves its weight (in `out`).
    void account(std::int32_t id, const RayRecord& now, TracePart& out) const {
        const RayRecord& before = records_[std::size_t(id)];
        if (now == before) return;
        ++out.rays_moved;
        const Fixed w = rays_->weight[std::size_t(id)];
        const Fixed w_before = delivered_weight(before, w), w_now = delivered_weight(now, w);
        account_weight(out.status_delta, before.status, w, w_before, -1);
        account_weight(out.status_delta, now.status, w, w_now);
        move_deposit(before, now, w_before, w_now, out.histogram);
    }

    // The weight per slot of the maintained records, from scratch.
    void recount_status_weights() {
        status_weight_.fill(0);
        for (std::size_t k = 0; k < records_.size(); ++k) account_weight(status_weight_, records_[k], rays_->weight[k]);
    }

    std::int64_t cell_count() const { return std::int64_t(surface_->nx() - 1) * (surface_->ny() - 1); }

    // The rays listed on the move's cells that can meet one of them, before or after the
    // move. A ray is left out when, on every one of those cells it crosses, its path lies
    // wholly above or below the cell's corner heights (widened by the walk's rounding
    // allowance) both before and after the move: the walk's culling test then skips the
    // cell either way, so the ray's path, record and cells are what they were. This is the
    // walk's own test on the same floats, so leaving the ray out is exact.
    //
    // With a pool, the move's rows of cells are shared out between its threads. Rows are
    // scanned in order and a ray is taken at its first sighting, so a thread skips the rays
    // that also cross a cell of an earlier thread's rows (that thread has them): the rays
    // of thread 0, then of thread 1, ... are exactly the serial selection, in its order.
    template <class PerPart>
    void collect_rays(const HeightOverlay& o, const Patch& cells, TraceChange& change, TaskPool* pool,
                      PerPart& per_part) const {
        const int row = surface_->nx() - 1;
        change.reach.resize(std::size_t(cells.count()));
        {
            const HeightfieldView before = surface_->view();
            const OverlayView after = overlay_view(*surface_, o);
            const float pad = hf_detail::grid_of(before).z_pad;
            std::size_t k = 0;
            for (int cj = cells.j0; cj <= cells.j1; ++cj)
                for (int ci = cells.i0; ci <= cells.i1; ++ci, ++k) {
                    CellReach& r = change.reach[k];
                    cell_height_range(before, ci, cj, pad, r.lo_before, r.hi_before);
                    cell_height_range(after, ci, cj, pad, r.lo_after, r.hi_after);
                }
        }
        // Slot of each move cell in change.reach, looked up by cell id (no divisions).
        auto& slot = change.cell_slot;
        if (std::int64_t(slot.size()) != cell_count()) slot.assign(std::size_t(cell_count()), -1);
        std::size_t listed = 0;
        for (int cj = cells.j0, k = 0; cj <= cells.j1; ++cj)
            for (int ci = cells.i0; ci <= cells.i1; ++ci) {
                slot[std::size_t(cj * row + ci)] = k++;
                listed += index_.rays_of(cj * row + ci).size();
            }
        const int threads = pool != nullptr ? pool->threads() : 1;
        const int parts = int(std::min<std::size_t>({std::size_t(threads), std::size_t(cells.height()),
                                                     listed / min_rays_per_thread}));
        if (parts <= 1) {
            scan_rows(cells, cells.j0, cells.j1 + 1, change, change);
            per_part(change);
        } else {
            start_parts(change, parts);
            const auto first_row = [&](int p) { return cells.j0 + cells.height() * p / parts; };
            run_parts(*pool, parts, [&](int p) {
                TracePart& out = change.part(p);
                scan_rows(cells, first_row(p), first_row(p + 1), change, out);
                per_part(out);
            });
            for (int p = 1; p < parts; ++p) add_totals(change, change.part(p));
            change.split = parts;
        }
        for (int cj = cells.j0; cj <= cells.j1; ++cj)
            for (int ci = cells.i0; ci <= cells.i1; ++ci) slot[std::size_t(cj * row + ci)] = -1;
    }

    // The ray selection over the move's rows [j_begin, j_end) (collect_rays): rays that
    // also cross a move cell of an earlier row are left to the thread that has that row.
    // Selected rays go to out.rays, deduplicated with out's marks.
    void scan_rows(const Patch& cells, int j_begin, int j_end, const TraceChange& change, TracePart& out) const {
        auto& ray_mark = out.ray_mark;
        const std::uint32_t generation = out.generation;
        const int row = surface_->nx() - 1;
        const std::int32_t first_slot = (j_begin - cells.j0) * cells.width();
        const auto& slot = change.cell_slot;
        enum class Verdict { earlier, reach, out_of_reach };
        // A ray's cells are sorted by id, and the move's slots follow cell ids (both row
        // major), so the first of its cells in the move has its smallest slot: that one
        // alone says whether an earlier part has the ray, and the first cell in reach
        // settles the rest.
        const auto judge = [&](std::int32_t id) {
            bool first = true;
            for (const CellCrossing& c : index_.cells_of(id)) {
                const std::int32_t k = slot[std::size_t(c.cell)];
                if (k < 0) continue;
                if (first && k < first_slot) return Verdict::earlier;
                first = false;
                if (within_reach(c, change.reach[std::size_t(k)])) return Verdict::reach;
            }
            return Verdict::out_of_reach;
        };
        for (int cj = j_begin; cj < j_end; ++cj)
            for (int ci = cells.i0; ci <= cells.i1; ++ci) {
                // The listed rays' marks and cells are scattered: prefetch ahead.
                const auto& listed = index_.rays_of(cj * row + ci);
                constexpr std::size_t ahead = 8;
                for (std::size_t k = 0; k < listed.size() && k < ahead; ++k) index_.prefetch_slot(listed[k]);
                for (std::size_t k = 0; k < listed.size(); ++k) {
                    if (k + ahead < listed.size()) {
                        index_.prefetch_slot(listed[k + ahead]);
                        prefetch(ray_mark.data() + listed[k + ahead]);
                    }
                    if (k + ahead / 2 < listed.size()) index_.prefetch_cells(listed[k + ahead / 2]);
                    const std::int32_t id = listed[k];
                    auto& mark = ray_mark[std::size_t(id)];
                    if (mark == generation) continue;
                    mark = generation;
                    switch (judge(id)) {
                        case Verdict::reach: out.rays.push_back(id); break;
                        case Verdict::out_of_reach: ++out.rays_culled; break;
                        case Verdict::earlier: break;
                    }
                }
            }
    }

    // Removes a ray's old deposit (w_before, the weight it delivered) and adds its new one
    // (w_now). A ray that moves a little keeps its four bilinear cells: their differences
    // are added once instead of eight times.
    void move_deposit(const RayRecord& before, const RayRecord& now, Fixed w_before, Fixed w_now,
                      SparseDelta& d) const {
        const bool was = before.status == RayStatus::receiver, is = now.status == RayStatus::receiver;
        const Splat a = was ? splat(params_.receiver, before.px, before.py, w_before) : Splat{};
        const Splat b = is ? splat(params_.receiver, now.px, now.py, w_now) : Splat{};
        if (was && is && a.cell[0] == b.cell[0] && a.cell[3] == b.cell[3]) {  // the same four cells
#pragma GCC unroll 4
            for (int k = 0; k < 4; ++k)
                if (b.amount[k] != a.amount[k]) d.add(a.cell[k], b.amount[k] - a.amount[k]);
            return;
        }
        if (was)
#pragma GCC unroll 4
            for (int k = 0; k < 4; ++k)
                if (a.amount[k] != 0) d.add(a.cell[k], -a.amount[k]);
        if (is)
#pragma GCC unroll 4
            for (int k = 0; k < 4; ++k)
                if (b.amount[k] != 0) d.add(b.cell[k], b.amount[k]);
    }

    // The envelope of the present heights, kept when a sample of every 64th ray says it
    // leaves out at least half of the crossings (set_reach_margin).
    void centre_reach() {
        if (!std::isfinite(reach_.margin)) {
            reach_.clear();
            return;
        }
        reach_.centre_on(*surface_);
        if (!sample_rebuild(*surface_, *rays_, params_, 64, reach_.view()).envelope_pays()) reach_.clear();
    }

    const Heightmap* surface_;
    const RaySet* rays_;
    PathParams params_;
    ReachEnvelope reach_;
    std::vector<RayRecord> records_;
    RayCellIndex index_;
    std::array<Fixed, weight_slots> status_weight_{};
    std::vector<std::vector<std::size_t>> relisted_;  // commit(): per part, the rays whose cells changed
    std::uint64_t version_ = 0;
};

}  // namespace freeform
