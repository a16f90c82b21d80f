#pragma once
// The kernels of a window of moves evaluated together (trace/window.hpp): the selection
// of each proposal's rays from a flat ray/cell index, the retrace of one ray of one
// proposal through that proposal's overlay, and each ray's change summed into its
// proposal's. In their own header, which the CUDA tracer (cuda/trace_cuda.cuh) includes
// as well, so that the device runs this very code.
#include <algorithm>
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "../core/atomic.hpp"
#include "../core/hd.hpp"
#include "../surface/overlay.hpp"
#include "crossing.hpp"
#include "heightfield_kernel.hpp"
#include "path.hpp"

namespace freeform {

// One proposal's change in a window: what IncrementalTrace::evaluate's TraceChange holds
// but for the records and cells, compactly (the cells it changes, not a receiver-sized
// array: a window holds many).
struct WindowChange {
    std::vector<std::int32_t> cells;                 // histogram cells whose value changes, in the order first touched
    std::vector<Fixed> values;                       // their changes
    std::array<Fixed, weight_slots> status_delta{};  // change of weight per slot (RayStatus, Fresnel)
    std::int64_t rays_moved = 0;                     // rays whose record changed
};

// The kernels' views of a window's moves over `base` (host memory), one per move.
inline void overlay_views(const Heightmap& base, std::span<const HeightOverlay> moves, std::vector<OverlayView>& out) {
    out.resize(moves.size());
    for (std::size_t p = 0; p < moves.size(); ++p) out[p] = overlay_view(base, moves[p]);
}

// The ray/cell index as the selection kernel reads it: both directions of RayCellIndex
// (trace/incremental.hpp) as compressed rows, a form a device can hold (the host's index
// is a vector of vectors, updated in place). Each cell's rays are in the host list's
// order, so the kernel selects the rays in evaluate()'s order.
struct RayCellIndexView {
    const std::int64_t* cell_begin = nullptr;  // per surface cell and one past: its rays in cell_rays
    const std::int32_t* cell_rays = nullptr;
    const std::int64_t* ray_begin = nullptr;  // per ray and one past: its crossings
    const CellCrossing* crossings = nullptr;  // each ray's sorted by cell
    int row = 0;                              // surface cells per row
    // A slotted index (trace/index_kernel.hpp) has room after each list: these give the
    // lists' lengths (from cell_begin[c] and ray_begin[r]); null for compressed rows.
    const std::int32_t* cell_count = nullptr;
    const std::int32_t* ray_count = nullptr;

    FREEFORM_HD std::int64_t cell_end(std::int32_t c) const {
        return cell_count != nullptr ? cell_begin[c] + cell_count[c] : cell_begin[c + 1];
    }
    FREEFORM_HD std::int64_t ray_end(std::int32_t r) const {
        return ray_count != nullptr ? ray_begin[r] + ray_count[r] : ray_begin[r + 1];
    }
};

// The arrays behind a RayCellIndexView, on the host (flatten() in trace/window.hpp fills
// them from an incremental trace; cuda::DeviceWindowEvaluation copies them up).
struct FlatRayCellIndex {
    std::vector<std::int64_t> cell_begin, ray_begin;
    std::vector<std::int32_t> cell_rays;
    std::vector<CellCrossing> crossings;
    int row = 0;

    std::int64_t cells() const { return std::int64_t(cell_begin.size()) - 1; }
    std::int64_t rays() const { return std::int64_t(ray_begin.size()) - 1; }
    RayCellIndexView view() const {
        return {cell_begin.data(), cell_rays.data(), ray_begin.data(), crossings.data(), row};
    }
};

// One proposal's move as the selection sees it: the surface cells whose triangles it
// changes (IncrementalTrace::affected_cells, bounds inclusive; none when i1 < i0), and
// where its cells start among the window's slots (a slot per cell, row major).
struct WindowPatch {
    int i0 = 0, j0 = 0, i1 = -1, j1 = -1;
    std::int64_t slot = 0;

    FREEFORM_HD int width() const { return i1 - i0 + 1; }
    FREEFORM_HD bool holds(int ci, int cj) const { return ci >= i0 && ci <= i1 && cj >= j0 && cj <= j1; }
    // The cell of slot s (one of this patch's).
    FREEFORM_HD void cell_of(std::int64_t s, int& ci, int& cj) const {
        const auto k = int(s - slot);
        cj = j0 + k / width();
        ci = i0 + k - (cj - j0) * width();
    }
    FREEFORM_HD std::int64_t slot_of(int ci, int cj) const { return slot + std::int64_t(cj - j0) * width() + ci - i0; }
};

// Slot s's cell's corner height ranges before and after its proposal's move: reach[s]
// (as IncrementalTrace's selection works them out for one move).
template <class View>
struct WindowReachKernel {
    HeightfieldView base;               // the surface before the moves
    const View* views;                  // per proposal: the surface after its move
    const WindowPatch* patches;         // per proposal
    const std::int32_t* slot_proposal;  // per slot
    float pad;                          // the walk's rounding allowance (hf_detail::Grid::z_pad)
    CellReach* reach;                   // per slot

    FREEFORM_HD void operator()(std::int64_t s) const {
        const std::int32_t p = slot_proposal[s];
        int ci = 0, cj = 0;
        patches[p].cell_of(s, ci, cj);
        CellReach& r = reach[s];
        cell_height_range(base, ci, cj, pad, r.lo_before, r.hi_before);
        cell_height_range(views[p], ci, cj, pad, r.lo_after, r.hi_after);
    }
};

// The rays slot s selects: those listed on its cell whose first cell in the proposal's
// patch is this one (so that a ray crossing several of them is taken once, where the
// host's scan meets it first) and that pass some cell of the patch within reach. Run
// twice: with `offset` null it counts them into count[s]; then, with each slot's place
// (the counts' exclusive scan), it writes them as (proposal, ray) pairs.
struct WindowSelectKernel {
    RayCellIndexView index;
    const WindowPatch* patches;            // per proposal
    const std::int32_t* slot_proposal;     // per slot
    const CellReach* reach;                // per slot
    std::int64_t* count = nullptr;         // counting: per slot
    const std::int64_t* offset = nullptr;  // writing: per slot, its first pair
    std::int32_t* proposal = nullptr;      // writing: per pair
    std::int32_t* ray = nullptr;

    FREEFORM_HD bool selects(const WindowPatch& w, std::int32_t cell, std::int32_t id) const {
        bool first = true;
        for (std::int64_t k = index.ray_begin[id], end = index.ray_end(id); k < end; ++k) {
            const CellCrossing& c = index.crossings[k];
            const int cj = c.cell / index.row, ci = c.cell - cj * index.row;
            if (!w.holds(ci, cj)) continue;
            if (first && c.cell != cell) return false;  // another slot of the patch takes it
            first = false;
            if (within_reach(c, reach[w.slot_of(ci, cj)])) return true;
        }
        return false;
    }

    FREEFORM_HD void operator()(std::int64_t s) const {
        const std::int32_t p = slot_proposal[s];
        const WindowPatch& w = patches[p];
        int ci = 0, cj = 0;
        w.cell_of(s, ci, cj);
        const std::int32_t cell = cj * index.row + ci;
        std::int64_t n = 0;
        for (std::int64_t k = index.cell_begin[cell], end = index.cell_end(cell); k < end; ++k) {
            const std::int32_t id = index.cell_rays[k];
            if (!selects(w, cell, id)) continue;
            if (offset != nullptr) proposal[offset[s] + n] = p, ray[offset[s] + n] = id;
            ++n;
        }
        if (offset == nullptr) count[s] = n;
    }
};

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

// Pair k's change added into its proposal's totals with atomics, so that a whole window's
// pairs are summed in one kernel call: the cell amounts into the proposal's dense
// histogram change (proposals x cells, fixed point as unsigned), the first touch of each
// cell claimed and listed in the proposal's list of touched cells, the weights per status
// and the count of rays moved. The sums are of integers, so neither the order the pairs
// arrive in nor the thread count changes them; only the lists' order does (the caller
// sorts each).
struct WindowDepositKernel {
    const std::int32_t* proposal;    // per pair
    const PairChange* changes;       // per pair, after WindowAccountKernel
    std::int64_t cells;              // receiver cells
    unsigned long long* sums;        // proposals x cells, zero before
    unsigned int* claimed;           // proposals x cells, zero before
    const std::int64_t* list_begin;  // per proposal: where its touched cells go (room for 8 per pair)
    unsigned long long* listed;      // per proposal: cells listed so far, zero before
    std::int32_t* touched;           // the lists
    unsigned long long* status;      // proposals x weight_slots, zero before
    unsigned long long* moved;       // per proposal, zero before

    FREEFORM_HD void add_weight(std::int32_t p, RayStatus st, Fixed w, Fixed delivered, int sign) const {
        unsigned long long* slots = status + std::int64_t(p) * weight_slots;
        atomic_add(slots + int(st), static_cast<unsigned long long>(sign * delivered));
        if (delivered != w)
            atomic_add(slots + fresnel_reflected_slot, static_cast<unsigned long long>(sign * (w - delivered)));
    }

    FREEFORM_HD void operator()(std::int64_t k) const {
        const PairChange& c = changes[k];
        if (!c.moved) return;
        const std::int32_t p = proposal[k];
        atomic_add(moved + p, 1ull);
        add_weight(p, c.status_before, c.weight, c.before, -1);
        add_weight(p, c.status_now, c.weight, c.now, 1);
        for (int j = 0; j < 8; ++j) {
            if (c.amount[j] == 0) continue;
            const std::int64_t at = std::int64_t(p) * cells + c.cell[j];
            atomic_add(sums + at, static_cast<unsigned long long>(c.amount[j]));
            if (atomic_claim(claimed + at))
                touched[list_begin[p] + std::int64_t(atomic_fetch_add(listed + p, 1ull))] = std::int32_t(c.cell[j]);
        }
    }
};

// Touched entry t (of proposal entry_proposal[t], cell touched[t]): its summed value
// taken out of the dense change into values[t], and the change's cell and claim cleared
// for the next window.
struct WindowGatherKernel {
    const std::int32_t* entry_proposal;  // per entry
    const std::int32_t* touched;         // per entry
    std::int64_t cells;
    unsigned long long* sums;
    unsigned int* claimed;
    Fixed* values;  // per entry

    FREEFORM_HD void operator()(std::int64_t t) const {
        const std::int64_t at = std::int64_t(entry_proposal[t]) * cells + touched[t];
        values[t] = static_cast<Fixed>(sums[at]);
        sums[at] = 0;
        claimed[at] = 0;
    }
};

// After WindowDepositKernel: each proposal's list of touched cells (listed[p] of them from
// touched[list_begin[p]]) sorted, so that the order threads claimed them in does not show,
// and packed one proposal after another as (proposal, cell) entries for WindowGatherKernel.
inline void pack_touched(std::vector<std::int32_t>& touched, std::span<const std::int64_t> list_begin,
                         std::span<const unsigned long long> listed, std::vector<std::int32_t>& entry_proposal,
                         std::vector<std::int32_t>& entry_cell) {
    entry_proposal.clear();
    entry_cell.clear();
    for (std::size_t p = 0; p < list_begin.size(); ++p) {
        const auto first = touched.begin() + list_begin[p];
        std::sort(first, first + std::int64_t(listed[p]));
        entry_cell.insert(entry_cell.end(), first, first + std::int64_t(listed[p]));
        entry_proposal.insert(entry_proposal.end(), std::size_t(listed[p]), std::int32_t(p));
    }
}

// Each proposal's WindowChange from the gathered entries (cells whose sum came to zero
// left out, as SparseDelta::drain leaves them) and its totals (proposals x weight_slots
// weights, rays moved).
inline void unpack_changes(std::span<const unsigned long long> listed, std::span<const std::int32_t> entry_cell,
                           std::span<const Fixed> entry_value, std::span<const unsigned long long> status,
                           std::span<const unsigned long long> moved, std::vector<WindowChange>& changes) {
    changes.resize(listed.size());
    for (std::size_t p = 0, t = 0; p < listed.size(); ++p) {
        WindowChange& c = changes[p];
        c.cells.clear();
        c.values.clear();
        for (const std::size_t end = t + std::size_t(listed[p]); t < end; ++t)
            if (entry_value[t] != 0) c.cells.push_back(entry_cell[t]), c.values.push_back(entry_value[t]);
        for (std::size_t st = 0; st < weight_slots; ++st)
            c.status_delta[st] = static_cast<Fixed>(status[p * weight_slots + st]);
        c.rays_moved = std::int64_t(moved[p]);
    }
}

}  // namespace freeform
