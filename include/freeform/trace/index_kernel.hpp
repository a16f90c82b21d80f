#pragma once
// The ray/cell index as a device keeps it from window to window (docs/cuda.md, "Towards
// designs on the GPU"): the flat form of trace/window_kernel.hpp with room to grow, each
// cell's list and each ray's crossings in a slot of fixed capacity, updated in place by
// the commit kernels below when a move is accepted instead of being copied up whole.
//
// The lists are kept sorted by ray id, so that they do not depend on the order in which
// threads append to them. The host's lists (RayCellIndex) are in the order of its
// commits, so a window selected from this index lists each move's rays in another order
// than the host's: the same rays and, the sums being of integers, the same changes.
//
// A list or a ray's crossings that outgrow their slot move to a new one, twice the size,
// taken from the spare room at the end of their pool (a bump allocator: which slot goes
// where depends on the threads, what the lists hold does not). Only when a pool's spare
// room runs out is the commit reported as failed; the caller then assigns the index again
// from the host's, with room to spare.
#include <algorithm>
#include <cstdint>
#include <vector>

#include "../core/atomic.hpp"
#include "../core/exec.hpp"
#include "../core/hd.hpp"
#include "crossing.hpp"
#include "path.hpp"
#include "window_kernel.hpp"

namespace freeform {

// The index's arrays (host or device memory).
struct SlottedIndexView {
    std::int64_t* cell_begin = nullptr;  // per surface cell: where its slot starts in cell_rays
    std::int32_t* cell_count = nullptr;  // its rays now
    std::int32_t* cell_room = nullptr;   // its slot's capacity
    std::int32_t* cell_rays = nullptr;
    std::int64_t* ray_begin = nullptr;  // per ray: where its slot starts in crossings
    std::int32_t* ray_count = nullptr;
    std::int32_t* ray_room = nullptr;
    CellCrossing* crossings = nullptr;
    int row = 0;
    unsigned long long* cell_rays_used = nullptr;  // the pools' used length (their slots end there)
    unsigned long long* crossings_used = nullptr;
    std::int64_t cell_rays_size = 0, crossings_size = 0;  // the pools' lengths

    // The selection kernel's view of it.
    RayCellIndexView selection() const {
        return {cell_begin, cell_rays, ray_begin, crossings, row, cell_count, ray_count};
    }
};

// An accepted move's change as the commit kernels read it: its rays, each one's new
// record and new crossings (crossing_begin: per ray and one past, as TracePart keeps them).
struct IndexChangeView {
    const std::int32_t* rays = nullptr;
    const RayRecord* records = nullptr;
    const std::int32_t* crossing_begin = nullptr;
    const CellCrossing* crossings = nullptr;
};

// The commit's scratch (per surface cell: zero between commits; the kernels leave it so).
struct IndexCommitScratch {
    unsigned int* dirty_mark = nullptr;  // per cell: listed in `dirty`
    unsigned int* added = nullptr;       // per cell: rays to append (step 1), then appended (step 3)
    std::int32_t* dirty = nullptr;       // the cells whose list changes (room for every cell)
    unsigned long long* dirty_count = nullptr;
    unsigned int* overflow = nullptr;  // set when a pool runs out of room
};

namespace index_detail {
// Whether `cell` is among crossings [begin, end).
FREEFORM_HD inline bool has_cell(const CellCrossing* c, std::int64_t begin, std::int64_t end, std::int32_t cell) {
    for (std::int64_t k = begin; k < end; ++k)
        if (c[k].cell == cell) return true;
    return false;
}
}  // namespace index_detail

// Commit, step 1 (a thread per changed ray): the ray's entry marked (-1) in the list of
// each cell it no longer crosses, and counted in `added` of each cell it newly crosses;
// both cells marked dirty. Reads the ray's old crossings (step 4 replaces them).
struct IndexUnlistKernel {
    SlottedIndexView index;
    IndexChangeView change;
    IndexCommitScratch scratch;

    FREEFORM_HD void dirty(std::int32_t cell) const {
        if (atomic_claim(scratch.dirty_mark + cell)) scratch.dirty[atomic_fetch_add(scratch.dirty_count, 1ull)] = cell;
    }

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t r = change.rays[k];
        const std::int64_t ob = index.ray_begin[r], oe = ob + index.ray_count[r];
        const std::int64_t nb = change.crossing_begin[k], ne = change.crossing_begin[k + 1];
        for (std::int64_t j = ob; j < oe; ++j) {
            const std::int32_t cell = index.crossings[j].cell;
            if (index_detail::has_cell(change.crossings, nb, ne, cell)) continue;
            std::int32_t* list = index.cell_rays + index.cell_begin[cell];
            // Other threads mark their own rays' entries in the same list meanwhile.
            for (std::int32_t e = 0; e < index.cell_count[cell]; ++e)
                if (atomic_load(list + e) == r) atomic_store(list + e, -1);
            dirty(cell);
        }
        for (std::int64_t j = nb; j < ne; ++j) {
            const std::int32_t cell = change.crossings[j].cell;
            if (index_detail::has_cell(index.crossings, ob, oe, cell)) continue;
            atomic_fetch_add(scratch.added + cell, 1u);
            dirty(cell);
        }
    }
};

// Takes `n` entries from the end of a pool of `size` (its used length `used`); -1 when
// the pool has no room left (the commit then fails).
FREEFORM_HD inline std::int64_t take_room(unsigned long long* used, std::int64_t size, std::int64_t n,
                                          unsigned int* overflow) {
    const auto at = std::int64_t(atomic_fetch_add(used, static_cast<unsigned long long>(n)));
    if (at + n <= size) return at;
    atomic_claim(overflow);
    return -1;
}

// Commit, step 2 (a thread per dirty cell): a list that its additions would overflow
// moves to a slot twice the size; the cell's count of additions restarts (step 3 counts
// its appends with it).
struct IndexGrowKernel {
    SlottedIndexView index;
    IndexCommitScratch scratch;

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t cell = scratch.dirty[k];
        const std::int64_t need = std::int64_t(index.cell_count[cell]) + scratch.added[cell];
        scratch.added[cell] = 0;
        if (need <= index.cell_room[cell]) return;
        const std::int64_t at = take_room(index.cell_rays_used, index.cell_rays_size, 2 * need, scratch.overflow);
        if (at < 0) return;
        const std::int32_t* old = index.cell_rays + index.cell_begin[cell];
        for (std::int32_t e = 0; e < index.cell_count[cell]; ++e) index.cell_rays[at + e] = old[e];
        index.cell_begin[cell] = at;
        index.cell_room[cell] = std::int32_t(2 * need);
    }
};

// Commit, step 3 (a thread per changed ray): the ray appended to the list of each cell it
// newly crosses (after the list's entries, in the order threads arrive: step 4 sorts).
struct IndexAppendKernel {
    SlottedIndexView index;
    IndexChangeView change;
    IndexCommitScratch scratch;

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t r = change.rays[k];
        const std::int64_t ob = index.ray_begin[r], oe = ob + index.ray_count[r];
        for (std::int64_t j = change.crossing_begin[k]; j < change.crossing_begin[k + 1]; ++j) {
            const std::int32_t cell = change.crossings[j].cell;
            if (index_detail::has_cell(index.crossings, ob, oe, cell)) continue;
            const auto at = std::int64_t(index.cell_count[cell]) + atomic_fetch_add(scratch.added + cell, 1u);
            if (at < index.cell_room[cell]) index.cell_rays[index.cell_begin[cell] + at] = r;  // else: no room left
        }
    }
};

// Commit, step 4 (a thread per dirty cell): the list's marked entries removed and its
// appended rays sorted in, in ray order; the cell's scratch cleared.
struct IndexSettleKernel {
    SlottedIndexView index;
    IndexCommitScratch scratch;

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t cell = scratch.dirty[k];
        std::int32_t* list = index.cell_rays + index.cell_begin[cell];
        std::int32_t end = index.cell_count[cell] + std::int32_t(scratch.added[cell]);
        if (end > index.cell_room[cell]) end = index.cell_room[cell];  // no room was left: the commit fails
        std::int32_t n = 0;
        for (std::int32_t e = 0; e < end; ++e) {  // kept entries, each sorted in (the old ones are in order)
            const std::int32_t r = list[e];
            if (r < 0) continue;
            std::int32_t j = n++;
            for (; j > 0 && list[j - 1] > r; --j) list[j] = list[j - 1];
            list[j] = r;
        }
        index.cell_count[cell] = n;
        scratch.added[cell] = 0;
        scratch.dirty_mark[cell] = 0;
    }
};

// Commit, step 5 (a thread per changed ray): its new crossings into its slot (a new one,
// twice the size, if they outgrow it), its new record into the maintained records.
struct IndexStoreKernel {
    SlottedIndexView index;
    IndexChangeView change;
    RayRecord* records;  // per ray: the maintained records
    unsigned int* overflow;

    FREEFORM_HD void operator()(std::int64_t k) const {
        const std::int32_t r = change.rays[k];
        records[r] = change.records[k];
        const std::int64_t nb = change.crossing_begin[k], ne = change.crossing_begin[k + 1];
        if (ne - nb > index.ray_room[r]) {
            const std::int64_t at = take_room(index.crossings_used, index.crossings_size, 2 * (ne - nb), overflow);
            if (at < 0) return;
            index.ray_begin[r] = at;
            index.ray_room[r] = std::int32_t(2 * (ne - nb));
        }
        for (std::int64_t j = nb; j < ne; ++j) index.crossings[index.ray_begin[r] + (j - nb)] = change.crossings[j];
        index.ray_count[r] = std::int32_t(ne - nb);
    }
};

// The slotted index on the host: what a device holds, for the kernels under exec::seq and
// exec::omp (tests/test_incremental.cpp), and the layout a device copy is made from.
struct SlottedRayCellIndex {
    std::vector<std::int64_t> cell_begin, ray_begin;
    std::vector<std::int32_t> cell_count, cell_room, cell_rays, ray_count, ray_room;
    std::vector<CellCrossing> crossings;
    std::vector<unsigned long long> used;  // the pools' used lengths: cell_rays, crossings
    int row = 0;
    // Commit scratch.
    std::vector<unsigned int> dirty_mark, added, overflow;
    std::vector<std::int32_t> dirty;
    std::vector<unsigned long long> dirty_count;

    // Room in a slot of `n` entries: a quarter more and a few; and a pool's spare room at
    // its end for the slots that outgrow theirs (half its length again).
    static std::int32_t room(std::int64_t n, int few) { return std::int32_t(n + n / 4 + few); }
    static std::size_t spare(std::size_t n) { return n / 2 + 1024; }

    // The index of `flat` with room to grow, each cell's rays sorted.
    void assign(const FlatRayCellIndex& flat) {
        row = flat.row;
        lay_out(flat.cell_begin, flat.cell_rays, 8, std::int32_t(-1), cell_begin, cell_count, cell_room, cell_rays);
        for (std::size_t c = 0; c < cell_begin.size(); ++c)
            std::sort(cell_rays.begin() + cell_begin[c], cell_rays.begin() + cell_begin[c] + cell_count[c]);
        lay_out(flat.ray_begin, flat.crossings, 4, CellCrossing{-1}, ray_begin, ray_count, ray_room, crossings);
        const std::size_t cells = cell_begin.size();
        used = {cell_rays.size(), crossings.size()};
        cell_rays.resize(cell_rays.size() + spare(cell_rays.size()), -1);
        crossings.resize(crossings.size() + spare(crossings.size()), CellCrossing{-1});
        dirty_mark.assign(cells, 0), added.assign(cells, 0);
        dirty.resize(std::max<std::size_t>(cells, 1));
        dirty_count.assign(1, 0), overflow.assign(1, 0);
    }

    // Compressed rows (`in`, row k at [in_begin[k], in_begin[k + 1])) laid out in slots
    // with room, the room filled with `fill`.
    template <class T>
    static void lay_out(const std::vector<std::int64_t>& in_begin, const std::vector<T>& in, int few, T fill,
                        std::vector<std::int64_t>& begin, std::vector<std::int32_t>& count,
                        std::vector<std::int32_t>& capacity, std::vector<T>& out) {
        const std::size_t rows = in_begin.size() - 1;
        begin.resize(rows), count.resize(rows), capacity.resize(rows);
        out.clear();
        for (std::size_t k = 0; k < rows; ++k) {
            const std::int64_t b = in_begin[k], e = in_begin[k + 1];
            begin[k] = std::int64_t(out.size());
            count[k] = std::int32_t(e - b);
            capacity[k] = room(e - b, few);
            out.insert(out.end(), in.begin() + b, in.begin() + e);
            out.resize(out.size() + std::size_t(capacity[k] - (e - b)), fill);
        }
    }

    SlottedIndexView view() {
        return {cell_begin.data(),
                cell_count.data(),
                cell_room.data(),
                cell_rays.data(),
                ray_begin.data(),
                ray_count.data(),
                ray_room.data(),
                crossings.data(),
                row,
                used.data(),
                used.data() + 1,
                std::int64_t(cell_rays.size()),
                std::int64_t(crossings.size())};
    }

    // Commits the change of `n` rays (`change`), their records into `records`, with the
    // commit kernels under `policy`. False when a pool ran out of room: then the index is
    // not usable and must be assigned again.
    template <HostPolicy P>
    bool commit(P policy, IndexChangeView change, std::int64_t n, RayRecord* records) {
        const SlottedIndexView v = view();
        const IndexCommitScratch s{dirty_mark.data(), added.data(), dirty.data(), dirty_count.data(), overflow.data()};
        dirty_count[0] = 0;
        for_each(policy, n, IndexUnlistKernel{v, change, s});
        const auto dirty_cells = std::int64_t(dirty_count[0]);
        for_each(policy, dirty_cells, IndexGrowKernel{v, s});
        for_each(policy, n, IndexAppendKernel{v, change, s});
        for_each(policy, dirty_cells, IndexSettleKernel{v, s});
        for_each(policy, n, IndexStoreKernel{v, change, records, s.overflow});
        return overflow[0] == 0;
    }
};

}  // namespace freeform
