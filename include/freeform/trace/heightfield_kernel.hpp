#pragma once
// Exact ray / triangulated-height-field intersection without a BVH.
//
// A segment is clipped to the slab h_min <= w <= h_max and to the grid rectangle, then
// walked cell by cell along its projection (a 2-D DDA). The two triangles of a cell lie
// over that cell only, so the first cell (in walking order) holding a hit holds the
// nearest hit. A cell whose four heights lie entirely above or below the segment's
// height range over the cell is skipped after four loads.
#include <cmath>
#include <cstdint>
#include <type_traits>

#include "../core/hd.hpp"
#include "../surface/heightmap.hpp"
#include "../surface/overlay.hpp"
#include "path.hpp"


namespace freeform {

// Branch-free min/max and floor that compile to single instructions on every target
// (fminf/floorf are library calls on baseline x86-64 and handle NaN, which we never feed).
FREEFORM_HD constexpr float min_f(float a, float b) { return a < b ? a : b; }
FREEFORM_HD constexpr float max_f(float a, float b) { return a > b ? a : b; }
FREEFORM_HD constexpr int floor_i(float x) {
    const int i = int(x);
    return x < float(i) ? i - 1 : i;
}

// Visits nothing: used when no bookkeeping of crossed cells is needed.
struct NoCellVisitor {
    FREEFORM_HD void operator()(int, int) const {}
};

// Tells a visitor of crossed cells that the walk tests cell (ci, cj) over the segment's
// height range z0..z1 (the ends of the walk over that cell, in the surface frame). A
// visitor that takes (ci, cj, zlo, zhi) learns the range, which is what the cell's
// culling test compares with its heights (the incremental evaluation uses it to skip rays
// that pass a move's cells too high or too low to meet them, trace/incremental.hpp);
// a visitor that takes (ci, cj) only learns the cell.
template <class Visitor>
FREEFORM_HD FREEFORM_FORCE_INLINE void visit_cell(Visitor& visit, int ci, int cj, float z0, float z1) {
    if constexpr (requires { visit(ci, cj, z0, z1); })
        visit(ci, cj, z0 < z1 ? z0 : z1, z0 > z1 ? z0 : z1);
    else
        visit(ci, cj);
}

// Triangle ids: cell (ci, cj) holds triangles 2c and 2c+1 with c = cj*(nx-1) + ci;
// triangle 0 is (v00, v10, v11), triangle 1 is (v00, v11, v01).
FREEFORM_HD inline void triangle_vertices(int nx, std::int32_t tri, int (&i)[3], int (&j)[3]) {
    const std::int32_t c = tri >> 1;
    const int ci = int(c % (nx - 1)), cj = int(c / (nx - 1));
    if ((tri & 1) == 0) {
        i[0] = ci, j[0] = cj, i[1] = ci + 1, j[1] = cj, i[2] = ci + 1, j[2] = cj + 1;
    } else {
        i[0] = ci, j[0] = cj, i[1] = ci + 1, j[1] = cj + 1, i[2] = ci, j[2] = cj + 1;
    }
}

namespace hf_detail {

// What the walk needs of a view that does not change along a ray's path: computed once
// per ray, not once per segment.
struct Grid {
    float x_max = 0, y_max = 0;    // the grid rectangle in grid units: [0, x_max] x [0, y_max]
    float inv_du = 1, inv_dv = 1;  // grid units per metre
    int last_ci = 0, last_cj = 0;  // index of the last cell along u and v
    int row = 0;                   // cells per row
    float z_pad = 0;               // the cell culling's allowance for rounding (metres)
};

template <class View>
FREEFORM_HD inline Grid grid_of(const View& hf) {
    Grid g;
    g.x_max = float(hf.nx - 1);
    g.y_max = float(hf.ny - 1);
    g.inv_du = 1.0f / hf.du;
    g.inv_dv = 1.0f / hf.dv;
    g.last_ci = hf.nx - 2;
    g.last_cj = hf.ny - 2;
    g.row = hf.nx - 1;
    // A few float roundings of the heights themselves, and a little of the slab.
    g.z_pad = 1e-5f * (hf.h_max - hf.h_min) + 1e-6f * max_f(fabsf(hf.h_min), fabsf(hf.h_max));
    return g;
}

// The four corner heights of a cell.
struct Corners {
    float h00, h10, h01, h11;
};

template <class View>
FREEFORM_HD FREEFORM_FORCE_INLINE Corners corners(const View& hf, int ci, int cj) {
    return {hf.height(ci, cj), hf.height(ci + 1, cj), hf.height(ci, cj + 1), hf.height(ci + 1, cj + 1)};
}
FREEFORM_HD FREEFORM_FORCE_INLINE Corners corners(const HeightfieldView& hf, int ci, int cj) {
    const float* p = hf.h + (cj * hf.nx + ci);
    return {p[0], p[1], p[hf.nx], p[hf.nx + 1]};
}
// One range test for the cell's 2 x 2 vertices instead of one per vertex. The rays an
// evaluation retraces are those crossing the move, so cells wholly inside the overlay
// are as common as cells wholly outside it.
FREEFORM_HD FREEFORM_FORCE_INLINE Corners corners(const OverlayView& hf, int ci, int cj) {
    // Cell (ci, cj) spans vertices a..a+1 and b..b+1 of the overlay (unsigned: below it wraps).
    const unsigned a = unsigned(ci - hf.pi0), b = unsigned(cj - hf.pj0);
    if (a + 1u <= unsigned(hf.pw) && b + 1u <= unsigned(hf.ph)) {  // touches the overlay
        if (a < unsigned(hf.pw - 1) && b < unsigned(hf.ph - 1)) {  // and lies inside it
            const float* p = hf.oh + (b * unsigned(hf.pw) + a);
            return {p[0], p[1], p[hf.pw], p[hf.pw + 1]};
        }
        return {hf.height(ci, cj), hf.height(ci + 1, cj), hf.height(ci, cj + 1), hf.height(ci + 1, cj + 1)};
    }
    return corners(static_cast<const HeightfieldView&>(hf), ci, cj);
}

// The normals of triangle k of cell (ci, cj): vertices (ci, cj), (ci + 1, cj + k) and
// (ci + 1 - k, cj + 1).
template <class View>
FREEFORM_HD FREEFORM_FORCE_INLINE void triangle_normals(const View& hf, int ci, int cj, int k, Vec3 (&n)[3]) {
    n[0] = hf.normal(ci, cj);
    n[1] = hf.normal(ci + 1, cj + k);
    n[2] = hf.normal(ci + 1 - k, cj + 1);
}
FREEFORM_HD FREEFORM_FORCE_INLINE void triangle_normals(const OverlayView& hf, int ci, int cj, int k, Vec3 (&n)[3]) {
    const unsigned a = unsigned(ci - hf.ni0), b = unsigned(cj - hf.nj0);  // below: wraps
    const unsigned aw = unsigned(hf.nw > 0 ? hf.nw - 1 : 0), bh = unsigned(hf.nh > 0 ? hf.nh - 1 : 0);
    if (a < aw && b < bh) {  // the cell's four vertices all lie in the overlay
        const Vec3* p = hf.on + (b * unsigned(hf.nw) + a);
        n[0] = p[0];
        n[1] = p[1 + k * hf.nw];
        n[2] = p[1 - k + hf.nw];
    } else {
        n[0] = hf.normal(ci, cj);
        n[1] = hf.normal(ci + 1, cj + k);
        n[2] = hf.normal(ci + 1 - k, cj + 1);
    }
}

// Writes the hit on triangle k of cell (ci, cj) at cell-local (a, b) into `hit`.
// Triangle 0 is (v00, v10, v11) with weights (1-a, a-b, b), triangle 1 is
// (v00, v11, v01) with weights (1-b, a, b-a); written as selects on k, not branches
// (which triangle is hit is a coin toss to the branch predictor).
template <class View>
FREEFORM_HD FREEFORM_FORCE_INLINE void set_hit(const View& hf, const Grid& g, const Corners& c, int ci, int cj, int k,
                                            float t, float a, float b, SurfaceHit& hit) {
    hit.kind = HitKind::surface;
    hit.t = t;
    hit.tri = 2 * (cj * g.row + ci) + k;
    a = min_f(max_f(a, 0.0f), 1.0f), b = min_f(max_f(b, 0.0f), 1.0f);
    const float hi = k == 0 ? a : b, lo = min_f(k == 0 ? b : a, hi);
    hit.b0 = 1.0f - hi;
    hit.b1 = k == 0 ? hi - lo : lo;
    hit.b2 = k == 0 ? lo : hi - lo;
    // Vertex positions exactly as View::vertex computes them.
    const float x0 = hf.u0 + float(ci) * hf.du, x1 = hf.u0 + float(ci + 1) * hf.du;
    const float y0 = hf.v0 + float(cj) * hf.dv, y1 = hf.v0 + float(cj + 1) * hf.dv;
    hit.p[0] = Vec3{x0, y0, c.h00};
    hit.p[1] = Vec3{x1, k == 0 ? y0 : y1, k == 0 ? c.h10 : c.h11};
    hit.p[2] = Vec3{k == 0 ? x1 : x0, y1, k == 0 ? c.h11 : c.h01};
    triangle_normals(hf, ci, cj, k, hit.n);
}

// Triangle k of a cell with corner heights c against the cell-local ray
// (ao + ad t, bo + bd t, ez + dz t): the t of an admissible hit (t >= t_min, inside the
// triangle up to eps, seen from the wanted side), or infinity. (a, b) receives the
// cell-local hit point.
template <bool Front>
FREEFORM_HD FREEFORM_FORCE_INLINE float triangle_t(int k, const Corners& c, float ao, float bo, float ez, float ad,
                                                float bd, float dz, float t_min, float& a, float& b) {
    // Plane z = h00 + A a + B b; denom = d · (-A/du, -B/dv, 1) is negative when the ray
    // meets the front.
    const float A = k == 0 ? c.h10 - c.h00 : c.h11 - c.h01;
    const float B = k == 0 ? c.h11 - c.h10 : c.h01 - c.h00;
    const float den = dz - A * ad - B * bd;
    if (!(Front ? den < 0.0f : den > 0.0f)) return INFINITY;
    const float t = (c.h00 + A * ao + B * bo - ez) / den;
    a = ao + ad * t, b = bo + bd * t;
    constexpr float eps = 1e-5f;  // tolerance in cell units: no cracks between cells
    // Triangle 0 is b <= a, triangle 1 is a <= b; swapping (a, b) maps one onto the other.
    const float lo = k == 0 ? b : a, hi = k == 0 ? a : b;
    const bool inside = (lo >= -eps) & (hi <= 1.0f + eps) & (lo <= hi + eps) & (t >= t_min);
    return inside ? t : INFINITY;
}

// Distance (in cell units) from the diagonal within which a walk may meet either
// triangle of a cell. Far above the rounding of the walk (about 1e-5 cells after
// hundreds of cells), far below a cell.
inline constexpr float diagonal_margin = 1e-3f;

// Clips a ray that enters the slab outside the grid rectangle to the rectangle:
// narrows [t0, t1] and moves (gx, gy) to the entry. Rays from the side of the grid and
// rays that miss it take this path; everything else starts inside.
FREEFORM_HD inline bool clip_to_grid(const Grid& g, float gox, float goy, float ad, float bd, float& t0, float& t1,
                                     float& gx, float& gy) {
    if (fabsf(ad) > 1e-30f) {  // the walk's threshold for an axis that moves
        const float r = 1.0f / ad;
        const float ta = -gox * r, tb = (g.x_max - gox) * r;
        t0 = max_f(t0, min_f(ta, tb));
        t1 = min_f(t1, max_f(ta, tb));
    } else if (!(gox >= 0.0f && gox <= g.x_max)) {
        return false;
    }
    if (fabsf(bd) > 1e-30f) {
        const float r = 1.0f / bd;
        const float ta = -goy * r, tb = (g.y_max - goy) * r;
        t0 = max_f(t0, min_f(ta, tb));
        t1 = min_f(t1, max_f(ta, tb));
    } else if (!(goy >= 0.0f && goy <= g.y_max)) {
        return false;
    }
    if (!(t0 <= t1)) return false;
    gx = gox + ad * t0, gy = goy + bd * t0;
    return true;
}

// The segment's walk over one cell: tests the cell's triangles for the nearest admissible
// hit. The segment is the cell-local ray (ao + ad t, bo + bd t, ez + dz t) for t from tc
// to tc_end; t0 is where the segment starts on the ray.
template <bool Front, class View>
FREEFORM_HD FREEFORM_FORCE_INLINE bool cell_hit(const View& hf, const Grid& g, int ci, int cj, float gx, float gy,
                                             float ez, float ad, float bd, float dz, float tc, float tc_end, float t0,
                                             std::int32_t exclude, SurfaceHit& hit) {
    if (!hf.cell_active(ci, cj)) return false;
    const Corners c = corners(hf, ci, cj);
    const float z0 = ez + tc * dz, z1 = ez + tc_end * dz;
    const float hlo = min_f(min_f(c.h00, c.h10), min_f(c.h01, c.h11));
    const float hhi = max_f(max_f(c.h00, c.h10), max_f(c.h01, c.h11));
    if (!(min_f(z0, z1) <= hhi + g.z_pad && max_f(z0, z1) >= hlo - g.z_pad)) return false;
    const float ao = gx - float(ci), bo = gy - float(cj);  // cell-local start
    const std::int32_t base = 2 * (cj * g.row + ci);
    // Hits a rounding error before the segment start still count when they lie in front
    // of the origin (the ray cannot meet the surface outside the slab).
    const float t_min = -t0;
    // Side of the diagonal (a - b) where the walk enters and leaves the cell: the
    // triangle under the middle of the walk is tested first, the other one only when the
    // walk comes near the diagonal.
    const float sa = ao - bo, sd = ad - bd;
    const float s0 = sa + sd * tc, s1 = sa + sd * tc_end;
    int k = s0 + s1 < 0.0f ? 1 : 0;
    float a = 0, b = 0;
    float t = base + k != exclude ? triangle_t<Front>(k, c, ao, bo, ez, ad, bd, dz, t_min, a, b) : INFINITY;
    if (min_f(s0, s1) < diagonal_margin && max_f(s0, s1) > -diagonal_margin) {
        const int k2 = 1 - k;
        float a2 = 0, b2 = 0;
        const float t2 =
            base + k2 != exclude ? triangle_t<Front>(k2, c, ao, bo, ez, ad, bd, dz, t_min, a2, b2) : INFINITY;
        if (t2 < t || (t2 == t && k2 == 0)) t = t2, a = a2, b = b2, k = k2;
    }
    if (t == INFINITY) return false;
    set_hit(hf, g, c, ci, cj, k, t0 + t, a, b, hit);
    return true;
}

// The part of a ray over the grid, inside the slab, in grid units (x = (u - u0)/du,
// y = (v - v0)/dv; the grid is [0, nx-1] x [0, ny-1]). The ray is re-based at the
// segment's start so that cell-local arithmetic stays small.
struct GridSegment {
    float gx = 0, gy = 0;  // start, grid units
    float ez = 0;          // height at the start
    float ad = 0, bd = 0;  // grid units per unit t
    float t0 = 0;          // where the segment starts on the ray
    float t_len = 0;       // its length in t
};

// Clips the ray (o, d), t in [0, t_limit], to the slab and the grid rectangle; the
// segment's length is extended by `t_slack` past its end (a walk that must reach the
// cell of a hit found by another tracer, a rounding error beyond it). False when the
// ray misses.
template <class View>
FREEFORM_HD FREEFORM_FORCE_INLINE bool grid_segment(const View& hf, const Grid& g, Vec3 o, Vec3 d, float t_limit,
                                                    float t_slack, GridSegment& s) {
    // Slab interval.
    float t0 = 0.0f, t1 = INFINITY;
    if (d.z != 0.0f) {
        const float r = 1.0f / d.z;
        const float ta = (hf.h_min - o.z) * r, tb = (hf.h_max - o.z) * r;
        t0 = max_f(0.0f, min_f(ta, tb));
        t1 = max_f(ta, tb);
        if (!(t0 <= t1)) return false;
    } else if (!(o.z >= hf.h_min && o.z <= hf.h_max)) {
        return false;
    }
    if (t_limit < t1) t1 = t_limit;
    if (!(t0 <= t1)) return false;
    s.ad = d.x * g.inv_du, s.bd = d.y * g.inv_dv;
    const float gox = (o.x - hf.u0) * g.inv_du, goy = (o.y - hf.v0) * g.inv_dv;
    s.gx = gox + s.ad * t0, s.gy = goy + s.bd * t0;
    if (!(s.gx >= 0.0f && s.gx <= g.x_max && s.gy >= 0.0f && s.gy <= g.y_max) &&
        !clip_to_grid(g, gox, goy, s.ad, s.bd, t0, t1, s.gx, s.gy))
        return false;
    s.ez = o.z + d.z * t0;
    s.t0 = t0;
    s.t_len = (t1 - t0) + t_slack;
    return true;
}

// The walk's block skip: over a tile of cells (TileView) whose heights all lie above or
// below the segment's height range across the tile, cell_hit would reject every cell for
// its height range, so the walk jumps to where it leaves the tile instead of testing them.
// A ray that slants through a deep slab (a point light beside its mirror: some 240 cells
// of a 60 mm slab) meets only the few cells near its hit; the rest are skipped in eights.
// The jump lands in the cell, with the crossing times, that the cell-by-cell walk would
// reach: every crossing time is computed from its grid line as that walk does, and the
// lines of the other axis crossed on the way are stepped over one by one, by the walk's
// own comparison. So a walk with tiles finds the same hit, bit for bit
// (tests/test_packet.cpp), and only plain traces use it: a visitor of crossed cells (the
// incremental evaluation's index) must see every cell. A tile is tested once, when the
// walk enters it: testing it again for a later cell could only skip what the first test
// kept, with the same hit either way.
inline constexpr int tile_shift = 3;  // tiles of 8 x 8 cells

struct NoSkip {
    static constexpr bool enabled = false;
};
struct TileSkip {
    static constexpr bool enabled = true;
    TileView tiles;
    float ez = 0, dz = 0;  // the segment's height at its start, and per unit t
    float z_pad = 0;       // cell_hit's allowance, taken twice: the tile's test never rejects what a cell's keeps
};

// The DDA's state between cells: the cell, where the walk entered it, and the next grid
// line on each axis with the t of crossing it.
struct DdaState {
    int ci, cj;
    float tc, line_i, line_j, tn_i, tn_j;
};

// Tests the tile of st's cell against the segment across it; where the segment passes
// above or below all of it, moves st to the first cell past the tile and returns 1, or
// returns 2 when the segment ends or leaves the grid inside the tile; 0: the tile's cells
// must be tested.
FREEFORM_HD FREEFORM_FORCE_INLINE int skip_tile(const Grid& g, const GridSegment& s, const TileSkip& skip, float ra,
                                                float rb, int step_i, int step_j, DdaState& st) {
    const int ti = st.ci >> tile_shift, tj = st.cj >> tile_shift;
    const int k = tj * skip.tiles.tiles_x + ti;
    const float inf = INFINITY;
    // The tile's last grid line in the walking direction on each axis, clipped to the grid.
    const int bi = s.ad > 0.0f ? (((ti + 1) << tile_shift) < g.last_ci + 1 ? (ti + 1) << tile_shift : g.last_ci + 1)
                               : ti << tile_shift;
    const int bj = s.bd > 0.0f ? (((tj + 1) << tile_shift) < g.last_cj + 1 ? (tj + 1) << tile_shift : g.last_cj + 1)
                               : tj << tile_shift;
    const float te_i = ra != 0.0f ? (float(bi) - s.gx) * ra : inf;
    const float te_j = rb != 0.0f ? (float(bj) - s.gy) * rb : inf;
    const float te = min_f(te_i, te_j);
    const float z0 = skip.ez + st.tc * skip.dz, z1 = skip.ez + min_f(te, s.t_len) * skip.dz;
    if (min_f(z0, z1) <= skip.tiles.hi[k] + skip.z_pad && max_f(z0, z1) >= skip.tiles.lo[k] - skip.z_pad) return 0;
    if (te >= s.t_len) return 2;
    if (te_i < te_j) {  // leaves across the i line (the walk's rule: i first only when strictly earlier)
        st.ci = s.ad > 0.0f ? bi : bi - 1;
        if (st.ci < 0 || st.ci > g.last_ci) return 2;
        st.tc = te_i;
        while (st.tn_j <= te_i) st.line_j += float(step_j), st.tn_j = (st.line_j - s.gy) * rb, st.cj += step_j;
        st.line_i = float(st.ci + (s.ad > 0.0f ? 1 : 0));
        st.tn_i = (st.line_i - s.gx) * ra;
    } else {
        st.cj = s.bd > 0.0f ? bj : bj - 1;
        if (st.cj < 0 || st.cj > g.last_cj) return 2;
        st.tc = te_j;
        while (st.tn_i < te_j) st.line_i += float(step_i), st.tn_i = (st.line_i - s.gx) * ra, st.ci += step_i;
        st.line_j = float(st.cj + (s.bd > 0.0f ? 1 : 0));
        st.tn_j = (st.line_j - s.gy) * rb;
    }
    return 1;
}

// The one grid traversal (the SIMD packet walk of trace/packet.hpp is its tested twin):
// calls on_cell(ci, cj, tc, tc_end) for every cell the segment crosses, in walking order,
// with [tc, tc_end] the part over the cell (t from the segment's start), until on_cell
// returns true (then returns true) or the segment leaves the grid or ends. A segment
// that stays over one cell (light arriving steeply, light leaving a mirror steeply) is
// handed over without setting up the walk. Cell crossings are multiplications by the
// reciprocal direction, recomputed from the grid line rather than accumulated, so that
// long walks do not drift. With a TileSkip, tiles the segment passes above or below are
// not handed over (skip_tile).
template <class Skip, class OnCell>
FREEFORM_HD FREEFORM_FORCE_INLINE bool walk_cells(const Grid& g, const GridSegment& s, const Skip& skip,
                                                  OnCell&& on_cell) {
    const float inf = INFINITY;
    const float gx = s.gx, gy = s.gy, ad = s.ad, bd = s.bd, t_len = s.t_len;
    // gx, gy >= 0 here: truncation is floor.
    DdaState st{};
    st.ci = int(gx), st.cj = int(gy);
    st.ci = st.ci > g.last_ci ? g.last_ci : st.ci;
    st.cj = st.cj > g.last_cj ? g.last_cj : st.cj;
    {
        const float fi = float(st.ci), fj = float(st.cj);
        const float ex = gx + ad * t_len, ey = gy + bd * t_len;  // end of the segment
        if (ex >= fi && ex <= fi + 1.0f && ey >= fj && ey <= fj + 1.0f) return on_cell(st.ci, st.cj, 0.0f, t_len);
    }
    // Next grid line on each axis and the t (from the segment start) of crossing it; an
    // axis that does not move (1e-30: no 0 * inf below) never crosses one.
    const int step_i = ad > 0.0f ? 1 : -1, step_j = bd > 0.0f ? 1 : -1;
    const float ra = fabsf(ad) > 1e-30f ? 1.0f / ad : 0.0f, rb = fabsf(bd) > 1e-30f ? 1.0f / bd : 0.0f;
    st.line_i = float(st.ci + (ad > 0.0f ? 1 : 0)), st.line_j = float(st.cj + (bd > 0.0f ? 1 : 0));
    st.tn_i = ra != 0.0f ? (st.line_i - gx) * ra : inf;
    st.tn_j = rb != 0.0f ? (st.line_j - gy) * rb : inf;
    st.tc = 0.0f;
    [[maybe_unused]] int tested = -1;  // the tile last tested, (tj << 16) | ti
    while (true) {
        if constexpr (Skip::enabled) {
            const int tile = ((st.cj >> tile_shift) << 16) | (st.ci >> tile_shift);
            if (tile != tested) {
                tested = tile;
                const int jumped = skip_tile(g, s, skip, ra, rb, step_i, step_j, st);
                if (jumped == 2) return false;
                if (jumped == 1) continue;
            }
        }
        const float tn = min_f(st.tn_i, st.tn_j);
        if (on_cell(st.ci, st.cj, st.tc, min_f(tn, t_len))) return true;
        if (tn >= t_len) return false;
        if (st.tn_i < st.tn_j) {
            st.ci += step_i;
            if (st.ci < 0 || st.ci > g.last_ci) return false;
            st.tc = st.tn_i;
            st.line_i += float(step_i);
            st.tn_i = (st.line_i - gx) * ra;
        } else {
            st.cj += step_j;
            if (st.cj < 0 || st.cj > g.last_cj) return false;
            st.tc = st.tn_j;
            st.line_j += float(step_j);
            st.tn_j = (st.line_j - gy) * rb;
        }
    }
}
template <class OnCell>
FREEFORM_HD FREEFORM_FORCE_INLINE bool walk_cells(const Grid& g, const GridSegment& s, OnCell&& on_cell) {
    return walk_cells(g, s, NoSkip{}, on_cell);
}

// The nearest admissible hit of the segment (o, d) on the front (Front) or back side:
// sets `hit` (kind surface) and returns true, or returns false and leaves `hit` alone.
// Each cell walked over is tested by cell_hit and reported to `visit` with the height
// range of the walk over it.
template <bool Front, class View, class Visitor>
FREEFORM_HD inline bool walk(const View& hf, const Grid& g, Vec3 o, Vec3 d, std::int32_t exclude, Visitor& visit,
                             SurfaceHit& hit) {
    GridSegment s;
    if (!grid_segment(hf, g, o, d, INFINITY, 0.0f, s)) return false;
    const auto on_cell = [&](int ci, int cj, float tc, float tc_end) {
        visit_cell(visit, ci, cj, s.ez + tc * d.z, s.ez + tc_end * d.z);
        return cell_hit<Front>(hf, g, ci, cj, s.gx, s.gy, s.ez, s.ad, s.bd, d.z, tc, tc_end, s.t0, exclude, hit);
    };
    if constexpr (std::is_same_v<View, HeightfieldView> && std::is_same_v<std::remove_cvref_t<Visitor>, NoCellVisitor>)
        if (hf.tiles.lo != nullptr) return walk_cells(g, s, TileSkip{hf.tiles, s.ez, d.z, 2.0f * g.z_pad}, on_cell);
    return walk_cells(g, s, on_cell);
}

template <class View, class Visitor>
FREEFORM_HD inline bool nearest_hit(const View& hf, const Grid& g, Vec3 o, Vec3 d, std::int32_t exclude, bool front,
                                    Visitor& visit, SurfaceHit& hit) {
    return front ? walk<true>(hf, g, o, d, exclude, visit, hit) : walk<false>(hf, g, o, d, exclude, visit, hit);
}

}  // namespace hf_detail

// Fills the vertex positions and normals of triangle hit.tri (a tracer that found the
// triangle by other means, like Embree, calls this), exactly as the walk does.
template <class View>
FREEFORM_HD inline void fill_hit_vertices(const View& hf, SurfaceHit& hit) {
    const std::int32_t c = hit.tri >> 1;
    const int ci = int(c % (hf.nx - 1)), cj = int(c / (hf.nx - 1)), k = int(hit.tri & 1);
    const float x0 = hf.u0 + float(ci) * hf.du, x1 = hf.u0 + float(ci + 1) * hf.du;
    const float y0 = hf.v0 + float(cj) * hf.dv, y1 = hf.v0 + float(cj + 1) * hf.dv;
    const hf_detail::Corners h = hf_detail::corners(hf, ci, cj);
    hit.p[0] = Vec3{x0, y0, h.h00};
    hit.p[1] = Vec3{x1, k == 0 ? y0 : y1, k == 0 ? h.h10 : h.h11};
    hit.p[2] = Vec3{k == 0 ? x1 : x0, y1, k == 0 ? h.h11 : h.h01};
    hf_detail::triangle_normals(hf, ci, cj, k, hit.n);
}

// Finds the nearest hit of the ray (o, d) with the height field, ignoring triangle
// `exclude` and triangles seen from the wrong side (front: from +w). `visit(ci, cj)` is
// called for every cell the segment crosses inside the slab, up to and including the
// cell of the hit. `View` is HeightfieldView or OverlayView (surface/overlay.hpp).
template <class View, class Visitor>
FREEFORM_HD inline SurfaceHit find_heightfield_hit(const View& hf, Vec3 o, Vec3 d, std::int32_t exclude, bool front,
                                                   Visitor&& visit) {
    SurfaceHit hit;
    const hf_detail::Grid g = hf_detail::grid_of(hf);
    hf_detail::nearest_hit(hf, g, o, d, exclude, front, visit, hit);
    return hit;
}

// Traces one ray through the height field to its end.
template <class View, class Visitor>
FREEFORM_HD inline RayRecord trace_heightfield_ray(const View& hf, const PathParams& pp, Vec3 o, Vec3 d,
                                                   Visitor&& visit) {
    const hf_detail::Grid g = hf_detail::grid_of(hf);
    PathState s;
    s.o = o;
    s.d = d;
    RayRecord rec;
    SurfaceHit hit;
    while (true) {
        hit.kind = HitKind::none;
        hf_detail::nearest_hit(hf, g, s.o, s.d, s.exclude, wants_front(s), visit, hit);
        if (!advance(pp, s, hit, rec)) return rec;
    }
}

}  // namespace freeform

