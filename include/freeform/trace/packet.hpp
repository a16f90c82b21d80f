#pragma once
// Packet tracing of one height field: eight rays side by side in SIMD lanes (host only).
//
// The scalar kernel (heightfield_kernel.hpp, path.hpp) is the definition; a packet runs
// exactly its operations, in the same order, in every lane, so a lane's record is bit
// for bit the scalar record of its ray (tests/test_packet.cpp). What differs between the
// lanes of a packet (which cell a walk is in, which triangle of a cell it tests, whether
// it has ended) is a mask, not a branch: a lane that is done simply stops changing.
//
// SIMD comes from std::experimental::simd (the Parallelism TS v2, in libstdc++ since
// GCC 11 and usable from clang): no dependency beyond the standard library. A packet is
// the build's own eight-lane type where it has one (one AVX register with -mavx2: each
// selection one blend) and fixed_size<8> elsewhere (two SSE registers in a baseline
// x86-64 build). The lane count is eight either way, so results never depend on the
// instruction set.
//
// The packet covers the common path of a mirror: walks seen from the front, Phong
// patches shaded with their true normal, the receiver. Rare cases within a packet are
// handed to the scalar kernel lane by lane (a segment that enters the slab beside the
// grid, or runs parallel to it); whole packets go to the scalar kernel for lenses and
// for interpolated normals (`packet::supports`).
#if !defined(__CUDACC__)
#include <experimental/simd>

#include <cstdint>
#include <type_traits>

#include "heightfield_kernel.hpp"

namespace freeform {

namespace packet {

namespace stdx = std::experimental;
inline constexpr int width = 8;
// The build's own eight-lane type where it has one (one AVX register: every operation
// inlines to a single instruction), else fixed_size<8>; the lanes are the same either way.
using F = stdx::simd<float, stdx::simd_abi::deduce_t<float, width>>;
using I = stdx::simd<std::int32_t, stdx::simd_abi::deduce_t<std::int32_t, width>>;
using FM = F::mask_type;
using IM = I::mask_type;

}  // namespace packet

// Lane-wise selections, with the scalar kernel's comparisons (a < b ? a : b keeps b when a
// is NaN, as the scalar helpers do). In namespace freeform so that the generic
// phong_point / patch_normal of path.hpp find them.
FREEFORM_FORCE_INLINE packet::F pick(packet::FM c, packet::F a, packet::F b) {
    where(c, b) = a;
    return b;
}
FREEFORM_FORCE_INLINE packet::I pick(packet::IM c, packet::I a, packet::I b) {
    where(c, b) = a;
    return b;
}
FREEFORM_FORCE_INLINE Vec3T<packet::F> pick(packet::FM c, Vec3T<packet::F> a, Vec3T<packet::F> b) {
    return {pick(c, a.x, b.x), pick(c, a.y, b.y), pick(c, a.z, b.z)};
}
FREEFORM_FORCE_INLINE packet::F min_f(packet::F a, packet::F b) { return pick(a < b, a, b); }
FREEFORM_FORCE_INLINE packet::F max_f(packet::F a, packet::F b) { return pick(a > b, a, b); }

namespace packet {

using V = Vec3T<F>;

// Whether the packet path applies to a scene (else every ray takes the scalar kernel).
inline bool supports(const PathParams& pp) { return !pp.material.lens && !pp.interpolated_normals; }

// Whether the tracers use packets in this build. Eight lanes pay off with AVX2 (about
// 2.4 times the scalar kernel on the benchmarks, docs/performance.md); in a baseline
// x86-64 build (two SSE registers a packet) and with AVX-512 (where GCC's fixed-size
// packets go through mask registers) the packet loop measured slower than the scalar
// kernel, so those builds keep the scalar kernel. Define FREEFORM_PACKET_TRACING to 0 or
// 1 to decide yourself; results are the same bit for bit either way.
#if defined(FREEFORM_PACKET_TRACING)
inline constexpr bool enabled = FREEFORM_PACKET_TRACING != 0;
#elif defined(__AVX2__) && !defined(__AVX512F__)
inline constexpr bool enabled = true;
#else
inline constexpr bool enabled = false;
#endif

inline bool use_packets(const PathParams& pp) { return enabled && supports(pp); }

// Visits nothing: trace_all needs no record of crossed cells.
struct NoLaneVisitor {
    static constexpr bool active = false;
    void operator()(int, int, int, float, float) const {}
};

namespace detail {

FREEFORM_FORCE_INLINE F to_f(I v) { return stdx::static_simd_cast<F>(v); }
FREEFORM_FORCE_INLINE I to_i(F v) { return stdx::static_simd_cast<I>(v); }
// Masks of floats and of ints: the TS converts only fixed_size masks implicitly;
// libstdc++'s static_simd_cast extension converts native ones.
template <class To, class M>
FREEFORM_FORCE_INLINE To mask_cast(M m) {
    if constexpr (std::is_same_v<typename M::abi_type, stdx::simd_abi::fixed_size<width>>)
        return To(m);
    else
        return stdx::__proposed::static_simd_cast<To>(m);
}
FREEFORM_FORCE_INLINE FM fm(IM m) { return mask_cast<FM>(m); }
FREEFORM_FORCE_INLINE IM im(FM m) { return mask_cast<IM>(m); }
// Bit l set where lane l of m is set.
FREEFORM_FORCE_INLINE unsigned lane_bits(FM m) {
    unsigned b = 0;
    for (int l = 0; l < width; ++l) b |= m[l] ? 1u << l : 0u;
    return b;
}

// One lane's values, written by scalar code and read as a packet.
struct alignas(32) Lanes {
    float v[width];
    F load() const { return F(v, stdx::vector_aligned); }
};
struct alignas(32) IntLanes {
    std::int32_t v[width];
    I load() const { return I(v, stdx::vector_aligned); }
};

// What a segment's walk found, per lane (the packet form of SurfaceHit for a height field).
struct Hits {
    FM found{false};
    F t{0}, b0{0}, b1{0}, b2{0};
    I tri{-1};
    V p[3], n[3];
};

// The walk's state of a lane that is not done.
struct Walk {
    F gx, gy, ez, ad, bd, dz, t0, t_len;
    F tc, tn_i, tn_j, line_i, line_j, ra, rb;
    I ci, cj, step_i, step_j;
    I tested;   // the tile last tested by skip_tiles, (tj << 16) | ti
    FM single;  // the segment stays over one cell: tested once, over its whole length
};

// Corner heights of each lane's cell (scalar loads: the overlay view decides per vertex).
template <class View>
FREEFORM_FORCE_INLINE void load_corners(const View& hf, FM m, I ci, I cj, F& h00, F& h10, F& h01, F& h11) {
    Lanes a, b, c, d;
    for (int l = 0; l < width; ++l) {
        if (!m[l]) {
            a.v[l] = b.v[l] = c.v[l] = d.v[l] = 0.0f;
            continue;
        }
        const hf_detail::Corners k = hf_detail::corners(hf, ci[l], cj[l]);
        a.v[l] = k.h00, b.v[l] = k.h10, c.v[l] = k.h01, d.v[l] = k.h11;
    }
    h00 = a.load(), h10 = b.load(), h01 = c.load(), h11 = d.load();
}

// triangle_t<true> of heightfield_kernel.hpp in every lane; k1 holds where the lane tests
// triangle 1.
FREEFORM_FORCE_INLINE F triangle_t(FM k1, F h00, F h10, F h01, F h11, F ao, F bo, F ez, F ad, F bd, F dz, F t_min,
                                   F& a, F& b) {
    const F A = pick(k1, h11 - h01, h10 - h00);
    const F B = pick(k1, h01 - h00, h11 - h10);
    const F den = dz - A * ad - B * bd;
    const F t = (h00 + A * ao + B * bo - ez) / den;
    a = ao + ad * t, b = bo + bd * t;
    constexpr float eps = 1e-5f;
    const F lo = pick(k1, a, b), hi = pick(k1, b, a);
    const FM ok = (den < 0.0f) && (lo >= -eps) && (hi <= 1.0f + eps) && (lo <= hi + eps) && (t >= t_min);
    return pick(ok, t, F(INFINITY));
}

// cell_hit<true> of heightfield_kernel.hpp for the lanes in m; returns the lanes that hit
// and fills their entries of `hits` (set_hit).
template <class View>
FREEFORM_FORCE_INLINE FM cell_hit(const View& hf, const hf_detail::Grid& g, FM m, const Walk& w, F tc_end, F z0, F z1,
                                  I exclude, Hits& hits) {
    if (hf.cell_on != nullptr)
        for (int l = 0; l < width; ++l)
            if (m[l] && !hf.cell_active(w.ci[l], w.cj[l])) m[l] = false;
    F h00, h10, h01, h11;
    load_corners(hf, m, w.ci, w.cj, h00, h10, h01, h11);
    const F hlo = min_f(min_f(h00, h10), min_f(h01, h11));
    const F hhi = max_f(max_f(h00, h10), max_f(h01, h11));
    m = m && (min_f(z0, z1) <= hhi + g.z_pad) && (max_f(z0, z1) >= hlo - g.z_pad);
    if (stdx::none_of(m)) return m;
    const F fci = to_f(w.ci), fcj = to_f(w.cj);
    const F ao = w.gx - fci, bo = w.gy - fcj;
    const I base = 2 * (w.cj * g.row + w.ci);
    const F t_min = -w.t0;
    const F sa = ao - bo, sd = w.ad - w.bd;
    const F s0 = sa + sd * w.tc, s1 = sa + sd * tc_end;
    const FM k1 = s0 + s1 < 0.0f;  // the triangle under the middle of the walk
    const I k = pick(im(k1), I(1), I(0));
    F a, b, a2, b2;
    F t = triangle_t(k1, h00, h10, h01, h11, ao, bo, w.ez, w.ad, w.bd, w.dz, t_min, a, b);
    t = pick(fm(base + k == exclude), F(INFINITY), t);
    const FM near = (min_f(s0, s1) < hf_detail::diagonal_margin) && (max_f(s0, s1) > -hf_detail::diagonal_margin);
    const I k2 = 1 - k;
    F t2 = triangle_t(!k1, h00, h10, h01, h11, ao, bo, w.ez, w.ad, w.bd, w.dz, t_min, a2, b2);
    t2 = pick(fm(base + k2 == exclude), F(INFINITY), t2);
    const FM take2 = near && ((t2 < t) || ((t2 == t) && k1));  // k1: the other triangle is triangle 0
    t = pick(take2, t2, t), a = pick(take2, a2, a), b = pick(take2, b2, b);
    const FM tri1 = k1 != take2;  // which triangle the lane ends on
    const FM hit = m && (t != F(INFINITY));
    if (stdx::none_of(hit)) return hit;
    // set_hit
    const I tri = base + pick(im(tri1), I(1), I(0));
    a = min_f(max_f(a, F(0.0f)), F(1.0f)), b = min_f(max_f(b, F(0.0f)), F(1.0f));
    const F hi = pick(tri1, b, a), lo = min_f(pick(tri1, a, b), hi);
    const F x0 = hf.u0 + fci * hf.du, x1 = hf.u0 + to_f(w.ci + 1) * hf.du;
    const F y0 = hf.v0 + fcj * hf.dv, y1 = hf.v0 + to_f(w.cj + 1) * hf.dv;
    where(hit, hits.t) = w.t0 + t;
    where(im(hit), hits.tri) = tri;
    where(hit, hits.b0) = 1.0f - hi;
    where(hit, hits.b1) = pick(tri1, lo, hi - lo);
    where(hit, hits.b2) = pick(tri1, hi - lo, lo);
    const V p0{x0, y0, h00};
    const V p1{x1, pick(tri1, y1, y0), pick(tri1, h11, h10)};
    const V p2{pick(tri1, x0, x1), y1, pick(tri1, h01, h11)};
    hits.p[0] = pick(hit, p0, hits.p[0]);
    hits.p[1] = pick(hit, p1, hits.p[1]);
    hits.p[2] = pick(hit, p2, hits.p[2]);
    Lanes n[9];
    for (int q = 0; q < 9; ++q) hits.n[q / 3][q % 3].copy_to(n[q].v, stdx::vector_aligned);
    for (int l = 0; l < width; ++l) {
        if (!hit[l]) continue;
        Vec3 nl[3];
        hf_detail::triangle_normals(hf, w.ci[l], w.cj[l], tri1[l] ? 1 : 0, nl);
        for (int q = 0; q < 3; ++q) n[3 * q].v[l] = nl[q].x, n[3 * q + 1].v[l] = nl[q].y, n[3 * q + 2].v[l] = nl[q].z;
    }
    for (int q = 0; q < 3; ++q) hits.n[q] = V{n[3 * q].load(), n[3 * q + 1].load(), n[3 * q + 2].load()};
    hits.found = hits.found || hit;
    return hit;
}

// skip_tile of heightfield_kernel.hpp in every lane of `walking` that has entered a tile
// it has not tested (a segment over one cell excepted: it is tested once): moves the lanes whose segment passes above or below their
// cell's tile to the first cell past it, drops from `walking` those that end or leave
// the grid inside it, and returns the lanes that skipped (their new cell is tested on
// the next round).
FREEFORM_FORCE_INLINE FM skip_tiles(const HeightfieldView& hf, const hf_detail::Grid& g, Walk& w, FM& walking) {
    constexpr int shift = hf_detail::tile_shift;
    const I ti = w.ci >> shift, tj = w.cj >> shift;
    const I tile = (tj << 16) | ti;
    const FM lanes = walking && !w.single && fm(tile != w.tested);
    w.tested = pick(im(lanes), tile, w.tested);
    Lanes lo, hi;
    {
        IntLanes k;
        (tj * hf.tiles.tiles_x + ti).copy_to(k.v, stdx::vector_aligned);
        for (int l = 0; l < width; ++l) {
            lo.v[l] = lanes[l] ? hf.tiles.lo[k.v[l]] : -INFINITY;
            hi.v[l] = lanes[l] ? hf.tiles.hi[k.v[l]] : INFINITY;
        }
    }
    const FM ad_pos = w.ad > 0.0f, bd_pos = w.bd > 0.0f;
    const I up_i = (ti + 1) << shift, up_j = (tj + 1) << shift;
    const I end_i(g.last_ci + 1), end_j(g.last_cj + 1);
    const I bi = pick(im(ad_pos), pick(up_i < end_i, up_i, end_i), ti << shift);
    const I bj = pick(im(bd_pos), pick(up_j < end_j, up_j, end_j), tj << shift);
    const F te_i = pick(w.ra != 0.0f, (to_f(bi) - w.gx) * w.ra, F(INFINITY));
    const F te_j = pick(w.rb != 0.0f, (to_f(bj) - w.gy) * w.rb, F(INFINITY));
    const F te = min_f(te_i, te_j);
    const F z0 = w.ez + w.tc * w.dz, z1 = w.ez + min_f(te, w.t_len) * w.dz;
    const F pad = 2.0f * g.z_pad;
    const FM skip = lanes && !((min_f(z0, z1) <= hi.load() + pad) && (max_f(z0, z1) >= lo.load() - pad));
    if (stdx::none_of(skip)) return skip;
    const FM ends = skip && (te >= w.t_len);
    const FM via_i = skip && !ends && (te_i < te_j), via_j = skip && !ends && !(te_i < te_j);
    w.ci = pick(im(via_i), pick(im(ad_pos), bi, bi - 1), w.ci);
    w.cj = pick(im(via_j), pick(im(bd_pos), bj, bj - 1), w.cj);
    const FM out = fm((w.ci < 0) || (w.ci > I(g.last_ci)) || (w.cj < 0) || (w.cj > I(g.last_cj)));
    w.tc = pick(via_i, te_i, pick(via_j, te_j, w.tc));
    // The other axis's lines crossed on the way, one by one, by the walk's comparison.
    for (FM m = via_i && !out && (w.tn_j <= te_i); stdx::any_of(m); m = m && (w.tn_j <= te_i)) {
        w.line_j = pick(m, w.line_j + to_f(w.step_j), w.line_j);
        w.tn_j = pick(m, (w.line_j - w.gy) * w.rb, w.tn_j);
        w.cj = pick(im(m), w.cj + w.step_j, w.cj);
    }
    for (FM m = via_j && !out && (w.tn_i < te_j); stdx::any_of(m); m = m && (w.tn_i < te_j)) {
        w.line_i = pick(m, w.line_i + to_f(w.step_i), w.line_i);
        w.tn_i = pick(m, (w.line_i - w.gx) * w.ra, w.tn_i);
        w.ci = pick(im(m), w.ci + w.step_i, w.ci);
    }
    w.line_i = pick(via_i, to_f(w.ci + pick(im(ad_pos), I(1), I(0))), w.line_i);
    w.tn_i = pick(via_i, (w.line_i - w.gx) * w.ra, w.tn_i);
    w.line_j = pick(via_j, to_f(w.cj + pick(im(bd_pos), I(1), I(0))), w.line_j);
    w.tn_j = pick(via_j, (w.line_j - w.gy) * w.rb, w.tn_j);
    walking = walking && !ends && !(skip && out);
    return skip;
}

// Writes one lane's scalar hit into the packet's hits.
inline void store_lane(Hits& hits, int l, const SurfaceHit& h) {
    if (h.kind == HitKind::none) return;
    hits.found[l] = true;
    hits.t[l] = h.t, hits.tri[l] = h.tri, hits.b0[l] = h.b0, hits.b1[l] = h.b1, hits.b2[l] = h.b2;
    for (int q = 0; q < 3; ++q) {
        hits.p[q].x[l] = h.p[q].x, hits.p[q].y[l] = h.p[q].y, hits.p[q].z[l] = h.p[q].z;
        hits.n[q].x[l] = h.n[q].x, hits.n[q].y[l] = h.n[q].y, hits.n[q].z[l] = h.n[q].z;
    }
}

// The lanes of `lanes` walked by the scalar kernel (rare: kept out of line, so that the
// packet walk below can be inlined whole).
template <class View, class Visitor>
[[gnu::noinline]] void scalar_lanes(const View& hf, const hf_detail::Grid& g, FM lanes, const V& o, const V& d,
                                    I exclude, Visitor& visit, Hits& hits) {
    for (int l = 0; l < width; ++l) {
        if (!lanes[l]) continue;
        SurfaceHit h;
        const Vec3 ol{o.x[l], o.y[l], o.z[l]}, dl{d.x[l], d.y[l], d.z[l]};
        if constexpr (Visitor::active) {
            auto lane_visit = [&](int ci, int cj, float zlo, float zhi) { visit(l, ci, cj, zlo, zhi); };
            hf_detail::walk<true>(hf, g, ol, dl, exclude[l], lane_visit, h);
        } else {
            NoCellVisitor none;  // a plain walk: it may skip tiles
            hf_detail::walk<true>(hf, g, ol, dl, exclude[l], none, h);
        }
        store_lane(hits, l, h);
    }
}

// The DDA's start for the lanes of `go` (gx, gy, ad, bd already set): the segment's
// length and height, the first cell, whether the segment stays over it, and the next grid
// line on each axis with the t of crossing it (walk_cells of heightfield_kernel.hpp).
FREEFORM_FORCE_INLINE void begin_dda(const hf_detail::Grid& g, FM go, F t0, F t1, F oz, F dz, Walk& w) {
    w.t0 = t0;
    w.dz = dz;
    w.ez = oz + dz * t0;
    w.t_len = t1 - t0;
    const I last_ci(g.last_ci), last_cj(g.last_cj);
    w.ci = pick(im(go), to_i(w.gx), I(0)), w.cj = pick(im(go), to_i(w.gy), I(0));
    w.ci = pick(w.ci > last_ci, last_ci, w.ci);
    w.cj = pick(w.cj > last_cj, last_cj, w.cj);
    {
        const F fi = to_f(w.ci), fj = to_f(w.cj);
        const F ex = w.gx + w.ad * w.t_len, ey = w.gy + w.bd * w.t_len;
        w.single = (ex >= fi) && (ex <= fi + 1.0f) && (ey >= fj) && (ey <= fj + 1.0f);
    }
    const FM ad_pos = w.ad > 0.0f, bd_pos = w.bd > 0.0f;
    w.step_i = pick(im(ad_pos), I(1), I(-1)), w.step_j = pick(im(bd_pos), I(1), I(-1));
    const FM a_moves = stdx::abs(w.ad) > 1e-30f, b_moves = stdx::abs(w.bd) > 1e-30f;
    w.ra = pick(a_moves, 1.0f / w.ad, F(0.0f)), w.rb = pick(b_moves, 1.0f / w.bd, F(0.0f));
    w.line_i = to_f(w.ci + pick(im(ad_pos), I(1), I(0))), w.line_j = to_f(w.cj + pick(im(bd_pos), I(1), I(0)));
    w.tn_i = pick(w.ra != 0.0f, (w.line_i - w.gx) * w.ra, F(INFINITY));
    w.tn_j = pick(w.rb != 0.0f, (w.line_j - w.gy) * w.rb, F(INFINITY));
    w.tc = F(0.0f);
    w.tested = I(-1);
}

// The nearest front-side hit of every lane's segment (o, d) in m: walk<true> of
// heightfield_kernel.hpp. Lanes whose segment needs the walk's rare set-up (entry beside
// the grid, a direction parallel to the surface plane) are walked by the scalar kernel.
template <class View, class Visitor>
inline void nearest_hits(const View& hf, const hf_detail::Grid& g, FM m, const V& o, const V& d, I exclude,
                         Visitor& visit, Hits& hits) {
    hits.found = FM(false);
    // Slab interval.
    const FM flat_dir = d.z == 0.0f;
    const F r = 1.0f / d.z;
    const F ta = (hf.h_min - o.z) * r, tb = (hf.h_max - o.z) * r;
    F t0 = max_f(F(0.0f), min_f(ta, tb));
    const F t1 = max_f(ta, tb);
    FM go = m && !flat_dir && (t0 <= t1);
    Walk w;
    w.ad = d.x * g.inv_du, w.bd = d.y * g.inv_dv;
    const F gox = (o.x - hf.u0) * g.inv_du, goy = (o.y - hf.v0) * g.inv_dv;
    w.gx = gox + w.ad * t0, w.gy = goy + w.bd * t0;
    const FM on_grid = (w.gx >= 0.0f) && (w.gx <= g.x_max) && (w.gy >= 0.0f) && (w.gy <= g.y_max);
    // The scalar kernel takes the lanes that start beside the grid or move parallel to it.
    const FM scalar = m && (flat_dir || ((t0 <= t1) && !on_grid));
    go = go && on_grid;
    if (stdx::any_of(scalar)) scalar_lanes(hf, g, scalar, o, d, exclude, visit, hits);
    if (stdx::none_of(go)) return;
    begin_dda(g, go, t0, t1, o.z, d.z, w);
    const I last_ci(g.last_ci), last_cj(g.last_cj);
    FM walking = go;
    // Plain traces skip the tiles a segment passes above or below (skip_tiles).
    constexpr bool can_skip = std::is_same_v<View, HeightfieldView> && !Visitor::active;
    bool tiled = false;
    if constexpr (can_skip) tiled = hf.tiles.lo != nullptr;
    while (stdx::any_of(walking)) {
        if constexpr (can_skip) {
            if (tiled && stdx::any_of(skip_tiles(hf, g, w, walking))) continue;
        }
        const F tn = min_f(w.tn_i, w.tn_j);
        const F tc_end = pick(w.single, w.t_len, min_f(tn, w.t_len));
        const F z0 = w.ez + w.tc * w.dz, z1 = w.ez + tc_end * w.dz;
        if constexpr (Visitor::active) {
            Lanes zlo, zhi;
            IntLanes ci, cj;
            pick(z0 < z1, z0, z1).copy_to(zlo.v, stdx::vector_aligned);
            pick(z0 > z1, z0, z1).copy_to(zhi.v, stdx::vector_aligned);
            w.ci.copy_to(ci.v, stdx::vector_aligned);
            w.cj.copy_to(cj.v, stdx::vector_aligned);
            const unsigned bits = lane_bits(walking);
            for (int l = 0; l < width; ++l)
                if (bits >> l & 1u) visit(l, ci.v[l], cj.v[l], zlo.v[l], zhi.v[l]);
        }
        const FM hit = cell_hit(hf, g, walking, w, tc_end, z0, z1, exclude, hits);
        walking = walking && !hit && !w.single && !(tn >= w.t_len);
        if (stdx::none_of(walking)) break;
        const FM along_i = walking && (w.tn_i < w.tn_j), along_j = walking && !(w.tn_i < w.tn_j);
        w.ci = pick(im(along_i), w.ci + w.step_i, w.ci);
        w.cj = pick(im(along_j), w.cj + w.step_j, w.cj);
        walking = walking && fm((w.ci >= 0) && (w.ci <= last_ci) && (w.cj >= 0) && (w.cj <= last_cj));
        w.tc = pick(along_i, w.tn_i, pick(along_j, w.tn_j, w.tc));
        w.line_i = pick(along_i, w.line_i + to_f(w.step_i), w.line_i);
        w.line_j = pick(along_j, w.line_j + to_f(w.step_j), w.line_j);
        w.tn_i = pick(along_i, (w.line_i - w.gx) * w.ra, w.tn_i);
        w.tn_j = pick(along_j, (w.line_j - w.gy) * w.rb, w.tn_j);
    }
}

// ReceiverView::hit in every lane: `reaches` holds where the scalar version computes
// (px, py) (it writes them even when they fall outside the receiver), the result where it
// returns true.
FREEFORM_FORCE_INLINE FM receiver_hit(const ReceiverView& rv, const V& o, const V& d, F& px, F& py, FM& reaches) {
    const V n{F(rv.n.x), F(rv.n.y), F(rv.n.z)};
    const V c{F(rv.center.x), F(rv.center.y), F(rv.center.z)};
    const V u{F(rv.u.x), F(rv.u.y), F(rv.u.z)}, v{F(rv.v.x), F(rv.v.y), F(rv.v.z)};
    const F dn = dot(d, n);
    const F t = dot(c - o, n) / dn;
    const V q = o + t * d - c;
    px = dot(q, u) * rv.inv_cell_u + 0.5f * float(rv.width);
    py = 0.5f * float(rv.height) - dot(q, v) * rv.inv_cell_v;
    reaches = (dn < 0.0f) && (t > 0.0f);
    return reaches && (px >= 0.0f) && (py >= 0.0f) && (px < float(rv.width)) && (py < float(rv.height));
}

}  // namespace detail

// Traces up to `width` rays (o[l], d[l]) for l < n to their ends, as trace_heightfield_ray
// would, into out[0..n). visit(l, ci, cj, zlo, zhi) is called for every cell lane l's
// path crosses inside the slab, in the order the scalar walk visits them (a visitor with
// `static constexpr bool active = false` is never called). Needs supports(pp).
template <class View, class Visitor>
inline void trace_rays(const View& hf, const hf_detail::Grid& g, const PathParams& pp, const Vec3* o, const Vec3* d,
                       int n, RayRecord* out, Visitor& visit) {
    using namespace detail;
    const FM active_init = fm(I([](int l) { return l; }) < I(n));
    FM active = active_init;
    V po{F([&](int l) { return l < n ? o[l].x : 0.0f; }), F([&](int l) { return l < n ? o[l].y : 0.0f; }),
         F([&](int l) { return l < n ? o[l].z : 1.0f; })};
    V pd{F([&](int l) { return l < n ? d[l].x : 0.0f; }), F([&](int l) { return l < n ? d[l].y : 0.0f; }),
         F([&](int l) { return l < n ? d[l].z : -1.0f; })};
    I exclude(-1), depth(0);
    I status = I(std::int32_t(RayStatus::active));
    F px(0.0f), py(0.0f);
    const I max_depth(pp.max_depth);
    Hits hits;
    while (stdx::any_of(active)) {
        nearest_hits(hf, g, active, po, pd, exclude, visit, hits);
        // advance(): a hit on the height field (a mirror).
        const FM hit = active && hits.found;
        if (stdx::any_of(hit)) {
            depth = pick(im(hit), depth + 1, depth);
            const FM too_deep = hit && fm(depth > max_depth);
            status = pick(im(too_deep), I(int(RayStatus::lost_depth)), status);
            const FM go = hit && !too_deep;
            const V flat = po + hits.t * pd;
            const F b[3] = {hits.b0, hits.b1, hits.b2};
            const V m = patch_normal(hits.p, hits.n, b, flat, pp.phong_alpha);
            po = pick(go, phong_point(hits.p, hits.n, b, flat, pp.phong_alpha), po);
            exclude = pick(im(go), hits.tri, exclude);
            pd = pick(go, pd - ((2.0f * dot(pd, m)) / dot(m, m)) * m, pd);
        }
        // end_of_segment(): no surface ahead; the ray leaves for the receiver.
        const FM ends = active && !hits.found;
        if (stdx::any_of(ends)) {
            F qx, qy;
            FM reaches;
            const FM lands = receiver_hit(pp.receiver, po, pd, qx, qy, reaches);
            const FM never = ends && fm(depth == 0);
            I s = pick(im(lands), I(int(RayStatus::receiver)), I(int(RayStatus::missed_receiver)));
            s = pick(im(never), I(int(RayStatus::missed_surface)), s);
            status = pick(im(ends), s, status);
            const FM written = ends && !never && reaches;
            px = pick(written, qx, px), py = pick(written, qy, py);
        }
        active = active && fm(status == int(RayStatus::active));
    }
    for (int l = 0; l < n; ++l) {
        RayRecord& r = out[l];
        r.status = RayStatus(std::int32_t(status[l]));
        r.depth = std::uint8_t(depth[l]);
        r.px = px[l];
        r.py = py[l];
        r.transmit = 1.0f;  // mirrors only: no refractive face on the way
    }
}

}  // namespace packet

}  // namespace freeform
#endif
