#pragma once
// What the incremental evaluation keeps of a ray's path over one surface cell, and the
// test that says whether a move can change that path (trace/incremental.hpp), as plain
// data and FREEFORM_HD functions: the host's selection and the window's selection kernel
// (trace/window_kernel.hpp) make the same decision with the same code.
#include <cmath>
#include <cstdint>

#include "../core/hd.hpp"
#include "heightfield_kernel.hpp"

namespace freeform {

// One cell a ray's path crosses inside the slab, with the height range of the path over
// it (the range the walk's culling test compares with the cell's corner heights).
// Visitors that know no range (Embree's) record the whole line: never culled.
struct CellCrossing {
    std::int32_t cell = 0;
    float zlo = -INFINITY, zhi = INFINITY;
};

// The height ranges of one surface cell's corners before and after a move, widened by
// the walk's rounding allowance.
struct CellReach {
    float lo_before, hi_before, lo_after, hi_after;
};

// The corner height range of cell (ci, cj) of `view`, widened by `pad`.
template <class View>
FREEFORM_HD FREEFORM_FORCE_INLINE void cell_height_range(const View& view, int ci, int cj, float pad, float& lo,
                                                         float& hi) {
    const hf_detail::Corners c = hf_detail::corners(view, ci, cj);
    lo = min_f(min_f(c.h00, c.h10), min_f(c.h01, c.h11)) - pad;
    hi = max_f(max_f(c.h00, c.h10), max_f(c.h01, c.h11)) + pad;
}

// Whether a path crossing a cell over heights [c.zlo, c.zhi] can meet the cell's
// triangles before or after the move: if not, the move cannot change the path there.
FREEFORM_HD FREEFORM_FORCE_INLINE bool within_reach(const CellCrossing& c, const CellReach& r) {
    return (c.zlo <= r.hi_before && c.zhi >= r.lo_before) || (c.zlo <= r.hi_after && c.zhi >= r.lo_after);
}

}  // namespace freeform
