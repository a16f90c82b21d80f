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

#include "../core/hd.hpp"
#include "../surface/heightmap.hpp"
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

template <class View>
FREEFORM_HD inline void fill_hit_vertices(const View& hf, SurfaceHit& hit) {
    int i[3], j[3];
    triangle_vertices(hf.nx, hit.tri, i, j);
    for (int k = 0; k < 3; ++k) {
        hit.p[k] = hf.vertex(i[k], j[k]);
        hit.n[k] = hf.normal(i[k], j[k]);
    }
}

// Finds the nearest hit of the ray (o, d) with the height field, ignoring triangle
// `exclude` and triangles seen from the wrong side (front: from +w). `visit(ci, cj)` is
// called for every cell the segment crosses inside the slab, up to and including the
// cell of the hit. `View` is HeightfieldView or OverlayView (surface/overlay.hpp).
template <class View, class Visitor>
FREEFORM_HD inline SurfaceHit find_heightfield_hit(const View& hf, Vec3 o, Vec3 d, std::int32_t exclude,
                                                   bool front, Visitor&& visit) {
    SurfaceHit hit;
    const float inf = INFINITY;
    // Slab interval.
    float t0 = 0.0f, t1 = inf;
    if (d.z != 0.0f) {
        const float ta = (hf.h_min - o.z) / d.z, tb = (hf.h_max - o.z) / d.z;
        t0 = max_f(t0, min_f(ta, tb));
        t1 = min_f(t1, max_f(ta, tb));
    } else if (o.z < hf.h_min || o.z > hf.h_max) {
        return hit;
    }
    // Rectangle interval.
    const float u1 = hf.u0 + float(hf.nx - 1) * hf.du, v1 = hf.v0 + float(hf.ny - 1) * hf.dv;
    if (d.x != 0.0f) {
        const float ta = (hf.u0 - o.x) / d.x, tb = (u1 - o.x) / d.x;
        t0 = max_f(t0, min_f(ta, tb));
        t1 = min_f(t1, max_f(ta, tb));
    } else if (o.x < hf.u0 || o.x > u1) {
        return hit;
    }
    if (d.y != 0.0f) {
        const float ta = (hf.v0 - o.y) / d.y, tb = (v1 - o.y) / d.y;
        t0 = max_f(t0, min_f(ta, tb));
        t1 = min_f(t1, max_f(ta, tb));
    } else if (o.y < hf.v0 || o.y > v1) {
        return hit;
    }
    if (!(t0 <= t1)) return hit;

    // Re-base the ray at the slab entry so that cell-local arithmetic stays small.
    const Vec3 e = o + t0 * d;
    const float inv_du = 1.0f / hf.du, inv_dv = 1.0f / hf.dv;
    const float gx = (e.x - hf.u0) * inv_du, gy = (e.y - hf.v0) * inv_dv;  // grid coordinates
    int ci = floor_i(gx), cj = floor_i(gy);
    ci = ci < 0 ? 0 : (ci > hf.nx - 2 ? hf.nx - 2 : ci);
    cj = cj < 0 ? 0 : (cj > hf.ny - 2 ? hf.ny - 2 : cj);
    const float ad = d.x * inv_du, bd = d.y * inv_dv;  // grid units per unit t
    const int step_i = ad > 0.0f ? 1 : -1, step_j = bd > 0.0f ? 1 : -1;
    const float dt_i = ad != 0.0f ? fabsf(1.0f / ad) : inf;
    const float dt_j = bd != 0.0f ? fabsf(1.0f / bd) : inf;
    float tn_i = ad != 0.0f ? (float(ci + (ad > 0.0f ? 1 : 0)) - gx) / ad : inf;  // t (from e) to next column
    float tn_j = bd != 0.0f ? (float(cj + (bd > 0.0f ? 1 : 0)) - gy) / bd : inf;
    const float t_len = t1 - t0;
    float tc = 0.0f;
    constexpr float eps = 1e-5f;  // tolerance in cell units: no cracks between cells

    while (true) {
        const float tc_end = min_f(min_f(tn_i, tn_j), t_len);
        visit(ci, cj);
        if (hf.cell_active(ci, cj)) {
            const float h00 = hf.height(ci, cj), h10 = hf.height(ci + 1, cj);
            const float h01 = hf.height(ci, cj + 1), h11 = hf.height(ci + 1, cj + 1);
            const float z0 = e.z + tc * d.z, z1 = e.z + tc_end * d.z;
            const float zlo = min_f(z0, z1), zhi = max_f(z0, z1);
            const float hlo = min_f(min_f(h00, h10), min_f(h01, h11));
            const float hhi = max_f(max_f(h00, h10), max_f(h01, h11));
            if (zlo <= hhi && zhi >= hlo) {
                // Cell-local ray: a = (x - x_i)/du, b = (y - y_j)/dv, z.
                const float ao = gx - float(ci), bo = gy - float(cj);
                const std::int32_t base = 2 * (cj * (hf.nx - 1) + ci);
                float best_t = inf;
                int best_k = -1;
                float best_a = 0, best_b = 0;
                for (int k = 0; k < 2; ++k) {
                    if (base + k == exclude) continue;
                    // Plane z = h00 + A a + B b over the triangle.
                    const float A = k == 0 ? h10 - h00 : h11 - h01;
                    const float B = k == 0 ? h11 - h10 : h01 - h00;
                    // denom = d · (-A/du, -B/dv, 1): negative when the ray meets the front.
                    const float denom = d.z - A * ad - B * bd;
                    if (front ? !(denom < 0.0f) : !(denom > 0.0f)) continue;
                    const float t = (h00 + A * ao + B * bo - e.z) / denom;
                    if (!(t >= 0.0f)) continue;  // the (a, b) test below keeps it in this cell
                    const float a = ao + ad * t, b = bo + bd * t;
                    const bool inside = k == 0 ? (b >= -eps && a <= 1.0f + eps && b <= a + eps)
                                               : (a >= -eps && b <= 1.0f + eps && a <= b + eps);
                    if (inside && t < best_t) {
                        best_t = t, best_k = k, best_a = a, best_b = b;
                    }
                }
                if (best_k >= 0) {
                    hit.kind = HitKind::surface;
                    hit.t = t0 + best_t;
                    hit.tri = base + best_k;
                    const float a = min_f(max_f(best_a, 0.0f), 1.0f), b = min_f(max_f(best_b, 0.0f), 1.0f);
                    if (best_k == 0) {  // (v00, v10, v11): (1-a, a-b, b)
                        const float bb = min_f(b, a);
                        hit.b0 = 1.0f - a, hit.b1 = a - bb, hit.b2 = bb;
                    } else {  // (v00, v11, v01): (1-b, a, b-a)
                        const float aa = min_f(a, b);
                        hit.b0 = 1.0f - b, hit.b1 = aa, hit.b2 = b - aa;
                    }
                    fill_hit_vertices(hf, hit);
                    return hit;
                }
            }
        }
        if (tc_end >= t_len) return hit;
        if (tn_i < tn_j) {
            ci += step_i;
            if (ci < 0 || ci > hf.nx - 2) return hit;
            tc = tn_i;
            tn_i += dt_i;
        } else {
            cj += step_j;
            if (cj < 0 || cj > hf.ny - 2) return hit;
            tc = tn_j;
            tn_j += dt_j;
        }
    }
}

// Traces one ray through the height field to its end.
template <class View, class Visitor>
FREEFORM_HD inline RayRecord trace_heightfield_ray(const View& hf, const PathParams& pp, Vec3 o, Vec3 d,
                                                   Visitor&& visit) {
    PathState s;
    s.o = o;
    s.d = d;
    RayRecord rec;
    while (true) {
        const SurfaceHit hit = find_heightfield_hit(hf, s.o, s.d, s.exclude, wants_front(s), visit);
        if (!advance(pp, s, hit, rec)) return rec;
    }
}

}  // namespace freeform
