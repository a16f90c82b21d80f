#pragma once
// The Phong patch over a triangle (docs/architecture.md §1): where a flat hit moves to on
// the curved patch its vertex normals define, and the patch's own normal there. The
// tracers shade with it (trace/path.hpp) and the exporter places its sub-vertices with it
// (surface/export.hpp), so what is simulated is what is milled.
#include "../core/hd.hpp"
#include "../core/math.hpp"

namespace freeform {

// Picks a when c holds, else b. The packet tracer (trace/packet.hpp) adds overloads for
// SIMD lanes, so the templates below serve one ray or a packet with the same operations.
template <class T>
FREEFORM_HD FREEFORM_FORCE_INLINE Vec3T<T> pick(bool c, Vec3T<T> a, Vec3T<T> b) {
    return c ? a : b;
}

// Phong tessellation (Boubekeur & Alexa 2008): moves a flat hit onto the curved patch
// defined by the vertex normals; alpha = 0 leaves it flat. Returns the corrected point.
// T is float, double (the exporter), or a packet of floats (one ray per lane); alpha is
// one number.
template <class T, class A>
FREEFORM_HD FREEFORM_FORCE_INLINE Vec3T<T> phong_point(const Vec3T<T> (&p)[3], const Vec3T<T> (&n)[3],
                                                     const T (&b)[3], Vec3T<T> flat, A alpha) {
    if (alpha == A(0)) return flat;
    Vec3T<T> offset{T(0), T(0), T(0)};
    for (int k = 0; k < 3; ++k) offset = offset + (b[k] * dot(flat - p[k], n[k])) * n[k];
    return flat - T(alpha) * offset;
}

// The true normal (not unit; facing the side cross(p1 - p0, p2 - p0) faces) of the
// Phong-tessellated patch at the flat hit `flat`: the cross product of the partial
// derivatives of phong_point along the two triangle edges from vertex 0. With
// b0 = 1 - b1 - b2, flat = p0 + b1 e1 + b2 e2 and s_k = (flat - p_k)·n_k,
//   P = flat - alpha Σ b_k s_k n_k,
//   ∂P/∂b1 = e1 - alpha [(b0 e1·n0 - s0) n0 + (b1 e1·n1 + s1) n1 + b2 (e1·n2) n2],
//   ∂P/∂b2 = e2 - alpha [(b0 e2·n0 - s0) n0 + b1 (e2·n1) n1 + (b2 e2·n2 + s2) n2].
// alpha = 0 gives the flat facet's normal. This is the normal of the surface that is
// exported and milled (surface/export.hpp); the patch is continuous across triangle
// edges, its normal in general is not.
template <class T, class A>
FREEFORM_HD FREEFORM_FORCE_INLINE Vec3T<T> patch_normal(const Vec3T<T> (&p)[3], const Vec3T<T> (&n)[3], const T (&b)[3],
                                         Vec3T<T> flat, A alpha_in) {
    const Vec3T<T> e1 = p[1] - p[0], e2 = p[2] - p[0];
    const Vec3T<T> facet = cross(e1, e2);
    if (alpha_in == A(0)) return facet;
    const T alpha = T(alpha_in);
    const T s0 = dot(flat - p[0], n[0]), s1 = dot(flat - p[1], n[1]), s2 = dot(flat - p[2], n[2]);
    const T a0 = dot(e1, n[0]), a1 = dot(e1, n[1]), a2 = dot(e1, n[2]);
    const T c0 = dot(e2, n[0]), c1 = dot(e2, n[1]), c2 = dot(e2, n[2]);
    const Vec3T<T> t1 = e1 - alpha * ((b[0] * a0 - s0) * n[0] + (b[1] * a1 + s1) * n[1] + (b[2] * a2) * n[2]);
    const Vec3T<T> t2 = e2 - alpha * ((b[0] * c0 - s0) * n[0] + (b[1] * c1) * n[1] + (b[2] * c2 + s2) * n[2]);
    const Vec3T<T> m = cross(t1, t2);
    // A patch folded over itself (vertex normals far from the facet's) has no normal
    // there; the facet's is the nearest meaningful one.
    return pick(dot(m, facet) > T(0), m, facet);
}

}  // namespace freeform
