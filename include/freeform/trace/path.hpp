#pragma once
// The per-ray physics shared by every tracer: hits on Phong patches, reflection and
// refraction, the lens back face, the receiver and the deposit. A tracer only has to
// find the nearest surface hit of a segment; `advance` does the rest. All functions are
// FREEFORM_HD and work in the surface frame (surface plane w = 0, normal +w).
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "../core/deposit.hpp"
#include "../core/fixed_point.hpp"
#include "../core/hd.hpp"
#include "../core/math.hpp"
#include "../core/view.hpp"
#include "../surface/phong.hpp"

namespace freeform {

// What finally happened to a ray.
enum class RayStatus : std::uint8_t {
    receiver = 0,         // landed on the receiver (deposited)
    missed_receiver = 1,  // left the surface but does not reach the receiver's front
    missed_surface = 2,   // never interacted with the surface
    lost_tir = 3,         // total internal reflection inside a lens
    lost_depth = 4,       // more surface interactions than max_depth
    absorbed = 5,         // blocked by an absorbing mesh, or lost in a leaking solid
    active = 255,         // still being traced
};

// Slots of the weight a trace accounts for: one per RayStatus (0..5), and the part of
// the rays' weight reflected away at refractive faces (Fresnel, PathParams::fresnel).
inline constexpr std::size_t weight_slots = 7;
inline constexpr std::size_t fresnel_reflected_slot = 6;

// The outcome of tracing one ray: where it lands on the receiver, in continuous pixel
// coordinates (px along columns, py along rows from the top), its status, and the
// fraction of its weight its faces let through (1 unless Fresnel losses are modelled).
struct RayRecord {
    float px = 0, py = 0;
    RayStatus status = RayStatus::missed_surface;
    std::uint8_t depth = 0;  // surface interactions
    float transmit = 1;      // product of the Fresnel transmittances met on the way

    friend FREEFORM_HD bool operator==(const RayRecord& a, const RayRecord& b) {
        return a.px == b.px && a.py == b.py && a.status == b.status && a.depth == b.depth &&
               a.transmit == b.transmit;
    }
};

// The weight a ray of weight w delivers where it ends (its status's slot); the rest,
// w - delivered_weight, was reflected away at refractive faces.
FREEFORM_HD inline Fixed delivered_weight(const RayRecord& r, Fixed w) { return fixed_part(w, r.transmit); }

// Adds a ray of weight w that ended with `status` and delivered `delivered` of it to
// per-slot weights (sign -1 takes it away).
template <class Slots>
inline void account_weight(Slots& slots, RayStatus status, Fixed w, Fixed delivered, int sign = 1) {
    slots[std::size_t(status)] += sign * delivered;
    if (delivered != w) slots[fresnel_reflected_slot] += sign * (w - delivered);
}
template <class Slots>
inline void account_weight(Slots& slots, const RayRecord& r, Fixed w) {
    account_weight(slots, r.status, w, delivered_weight(r, w));
}

// The receiver plane in the surface frame.
struct ReceiverView {
    Vec3 center{}, u{}, v{}, n{};  // n: front normal (facing the arriving light)
    float inv_cell_u = 1, inv_cell_v = 1;
    int width = 1, height = 1;
    Deposit deposit = Deposit::fine_bilinear;
    float fine_factor = float(fine_deposit_factor);  // fine_bilinear's k (trace/setup.hpp)

    // Continuous pixel coordinates where the ray (o, d) meets the receiver's front.
    FREEFORM_HD bool hit(Vec3 o, Vec3 d, float& px, float& py) const {
        const float dn = dot(d, n);
        if (!(dn < 0.0f)) return false;
        const float t = dot(center - o, n) / dn;
        if (!(t > 0.0f)) return false;
        const Vec3 q = o + t * d - center;
        px = dot(q, u) * inv_cell_u + 0.5f * float(width);
        py = 0.5f * float(height) - dot(q, v) * inv_cell_v;
        return px >= 0.0f && py >= 0.0f && px < float(width) && py < float(height);
    }
};

// A ray's weight split over receiver cells: the four cells around it (which repeat at the
// receiver's edges), or one cell with the whole weight and three empty shares. The
// amounts always sum to exactly the weight, so energy is conserved to the last bit.
struct Splat {
    std::int64_t cell[4];
    Fixed amount[4];
};

FREEFORM_HD inline Splat splat(const ReceiverView& rv, float px, float py, Fixed w) {
    Splat s;
    if (rv.deposit == Deposit::nearest) {
        int x = int(px), y = int(py);
        x = x < rv.width ? x : rv.width - 1;
        y = y < rv.height ? y : rv.height - 1;
        const std::int64_t c = std::int64_t(y) * rv.width + x;
        s.cell[0] = s.cell[1] = s.cell[2] = s.cell[3] = c;
        s.amount[0] = w;
        s.amount[1] = s.amount[2] = s.amount[3] = 0;
        return s;
    }
    const float sx = px - 0.5f, sy = py - 0.5f;  // >= -0.5: floor by truncation and one compare
    int x0 = int(sx), y0 = int(sy);
    x0 -= sx < float(x0) ? 1 : 0;
    y0 -= sy < float(y0) ? 1 : 0;
    double fx = double(sx - float(x0)), fy = double(sy - float(y0));
    if (rv.deposit == Deposit::fine_bilinear) {
        // Bilinear between the centres of a grid k times finer, summed into cells: the
        // share of the next cell is 0 up to half a fine cell before the cells' common
        // edge, 1/2 on it, 1 half a fine cell past it (core/deposit.hpp).
        const double k = double(rv.fine_factor);
        fx = k * (fx - 0.5) + 0.5;
        fy = k * (fy - 0.5) + 0.5;
        fx = fx < 0.0 ? 0.0 : fx > 1.0 ? 1.0 : fx;
        fy = fy < 0.0 ? 0.0 : fy > 1.0 ? 1.0 : fy;
    }
    int x1 = x0 + 1, y1 = y0 + 1;
    x0 = x0 < 0 ? 0 : x0;
    y0 = y0 < 0 ? 0 : y0;
    x1 = x1 >= rv.width ? rv.width - 1 : x1;
    y1 = y1 >= rv.height ? rv.height - 1 : y1;
    const double wd = double(w);
    const Fixed w11 = Fixed(wd * fx * fy);
    const Fixed w10 = Fixed(wd * fx * (1.0 - fy));
    const Fixed w01 = Fixed(wd * (1.0 - fx) * fy);
    s.amount[0] = w - w11 - w10 - w01;
    s.amount[1] = w10;
    s.amount[2] = w01;
    s.amount[3] = w11;
    s.cell[0] = std::int64_t(y0) * rv.width + x0;
    s.cell[1] = std::int64_t(y0) * rv.width + x1;
    s.cell[2] = std::int64_t(y1) * rv.width + x0;
    s.cell[3] = std::int64_t(y1) * rv.width + x1;
    return s;
}

// Splits a ray's weight over receiver cells: calls add(cell_index, amount) for each
// share of splat() (the first only for nearest deposits: the others are empty).
template <class Add>
FREEFORM_HD inline void deposit(const ReceiverView& rv, float px, float py, Fixed w, Add&& add) {
    const Splat s = splat(rv, px, py, w);
    for (int k = 0, n = rv.deposit == Deposit::nearest ? 1 : 4; k < n; ++k) add(s.cell[k], s.amount[k]);
}

// The nearest hit of a segment on a triangle of the surface (or of an extra mesh).
// refractive_mesh: a facet of a closed, outward-oriented solid (core/material.hpp,
// MeshMaterial); the hit carries the solid's index.
enum class HitKind : std::uint8_t { none, surface, mirror_mesh, absorber, refractive_mesh };

struct SurfaceHit {
    float t = 0;
    std::int32_t tri = -1;  // triangle id within its geometry (excluded on the next segment)
    HitKind kind = HitKind::none;
    float b0 = 0, b1 = 0, b2 = 0;  // barycentric weights of the three vertices
    float ior = 1;                 // refractive_mesh: the index of the solid
    Vec3 p[3];                     // vertex positions (valid when kind != none)
    Vec3 n[3];                     // unit vertex normals (valid when kind != none)
};

FREEFORM_HD inline Vec3 phong_point(const SurfaceHit& h, Vec3 flat, float alpha) {
    const float b[3] = {h.b0, h.b1, h.b2};
    return phong_point<float>(h.p, h.n, b, flat, alpha);
}

// The interpolated vertex normal (unit). Not the normal of any surface: a mill follows
// positions, and the surface whose positions phong_point gives has the normal of
// patch_normal below. Kept for shading meshes "with their stored normals" on request.
FREEFORM_HD inline Vec3 shading_normal(const SurfaceHit& h) {
    return normalize(h.b0 * h.n[0] + h.b1 * h.n[1] + h.b2 * h.n[2]);
}

FREEFORM_HD inline Vec3 patch_normal(const SurfaceHit& h, Vec3 flat, float alpha) {
    const float b[3] = {h.b0, h.b1, h.b2};
    return patch_normal<float>(h.p, h.n, b, flat, alpha);
}

// Material parameters in kernel form.
struct MaterialView {
    bool lens = false;
    float ior = 1.5f;
    float back_w = 0;              // lens back face plane (w = -thickness)
    float half_u = 0, half_v = 0;  // lens body half extents (side walls)
};

// The state of a ray between segments.
struct PathState {
    Vec3 o{}, d{};
    std::int32_t exclude = -1;  // triangle the current segment starts on
    bool inside = false;        // inside the lens body
    float medium = 1;           // index of the refractive mesh solid the ray is in; 1: in air
    float transmit = 1;         // product of the Fresnel transmittances so far
    std::uint8_t depth = 0;
    RayStatus status = RayStatus::active;
};

// Which side of the surface a segment may hit: a mirror and the outside of a lens are
// hit from the front (+w side); the inside of a lens from the back.
FREEFORM_HD inline bool wants_front(const PathState& s) { return !s.inside; }

struct PathParams {
    MaterialView material;
    ReceiverView receiver;
    float phong_alpha = 0.5f;  // shape of the height field's patches (0: flat triangles; Surface's default)
    int max_depth = 8;
    // false (the physical model): a hit is shaded with the normal of the surface it lies
    // on, patch_normal of the height field's Phong patch, the facet normal of a mesh
    // triangle (meshes are their geometry). true: the interpolated vertex normals of
    // Phong shading, with mirror meshes Phong-corrected too; no milled surface has these
    // normals (kept to compare with tools that shade this way).
    bool interpolated_normals = false;
    // Fresnel losses at refractive faces (the lens's front, back and side faces, and
    // refractive meshes): each crossing keeps the unpolarised transmittance of the light
    // that passes; the reflected part is dropped (docs/scene.md says why). false: every
    // crossing lets all the light through.
    bool fresnel = false;
};

namespace path_detail {

inline constexpr float no_exit = 3.0e38f;  // "never", as a distance

// A refractive crossing of direction d at unit normal n from index `from` into `to`:
// keeps the Fresnel transmittance when the scene models it.
FREEFORM_HD inline void transmit_through(const PathParams& pp, PathState& s, Vec3 d, Vec3 n, float from, float to) {
    if (pp.fresnel) s.transmit *= fresnel_transmittance(dot(d, n) / std::sqrt(dot(d, d)), from, to);
}

// Ends a ray's path with status `status`.
FREEFORM_HD inline void finish(PathState& s, RayRecord& rec, RayStatus status) {
    s.status = rec.status = status;
    rec.depth = s.depth;
    rec.transmit = s.transmit;
}

// Distance along one axis from o to the wall at -half or +half that direction d moves
// towards (no_exit when it moves along neither).
FREEFORM_HD inline float distance_to_wall(float o, float d, float half) {
    return d > 0.0f ? (half - o) / d : d < 0.0f ? (-half - o) / d : no_exit;
}

// The segment met no surface: inside a lens body it leaves through the back face or a
// side wall; otherwise the ray has left the surface and ends on the receiver (or misses
// it).
FREEFORM_HD inline bool end_of_segment(const PathParams& pp, PathState& s, RayRecord& rec) {
    if (s.medium > 1.0f) {
        // Inside a refractive solid and no facet ahead: the mesh leaks (a crack, or a
        // facet missed through rounding at an edge). The light is lost, not let out.
        s.status = RayStatus::absorbed;
    } else if (s.inside) {
        // No front facet ahead: the ray leaves the lens body through its flat back face
        // or a side wall (the vertical planes |u| = half_u, |v| = half_v, glass like the
        // rest of a milled solid). Steep rays meet a wall beyond the critical angle and
        // are reflected back inside (each reflection counts towards max_depth); the others
        // refract out and go on to the receiver. Total internal reflection at the back face
        // is counted as lost.
        const MaterialView& m = pp.material;
        for (;;) {
            const float t_back = s.d.z < 0.0f ? (m.back_w - s.o.z) / s.d.z : no_exit;
            const float t_u = distance_to_wall(s.o.x, s.d.x, m.half_u);
            const float t_v = distance_to_wall(s.o.y, s.d.y, m.half_v);
            const float t = std::fmin(t_back, std::fmin(t_u, t_v));
            if (!(t < no_exit)) {  // at rest or going straight up: no face ahead (rounding)
                s.status = RayStatus::absorbed;
                break;
            }
            const bool back = t_back == t;
            const Vec3 n = back          ? Vec3{0, 0, -1}
                           : t_u <= t_v ? Vec3{s.d.x > 0.0f ? 1.0f : -1.0f, 0, 0}
                                        : Vec3{0, s.d.y > 0.0f ? 1.0f : -1.0f, 0};
            s.o = s.o + std::fmax(t, 0.0f) * s.d;
            Vec3 out;
            if (refract(s.d, n, m.ior, 1.0f, out)) {
                transmit_through(pp, s, s.d, n, m.ior, 1.0f);
                s.d = normalize(out);
                s.inside = false;
                s.exclude = -1;
                s.status = RayStatus::active;
                return true;  // one more segment: it may still meet nothing but the receiver
            }
            if (back) {
                s.status = RayStatus::lost_tir;
                break;
            }
            if (++s.depth > pp.max_depth) {
                s.status = RayStatus::lost_depth;
                break;
            }
            s.d = reflect(s.d, n);
        }
    } else if (s.depth == 0) {
        s.status = RayStatus::missed_surface;
    } else if (pp.receiver.hit(s.o, s.d, rec.px, rec.py)) {
        s.status = RayStatus::receiver;
    } else {
        s.status = RayStatus::missed_receiver;
    }
    finish(s, rec, s.status);
    return false;
}

// A crossing of a refractive mesh's facet at s.o, with m the (not unit) normal to shade
// with. The facet's winding says which side is outside: the ray enters when it travels
// against the facet normal. Solids sit in air (they do not nest), so leaving goes back
// to index 1. Total internal reflection is followed: the ray stays inside, reflected.
FREEFORM_HD inline void refractive_crossing(const PathParams& pp, PathState& s, const SurfaceHit& hit, Vec3 m) {
    const Vec3 facet = cross(hit.p[1] - hit.p[0], hit.p[2] - hit.p[0]);
    const bool entering = dot(s.d, facet) < 0.0f;
    const float from = entering ? s.medium : hit.ior;
    const float to = entering ? hit.ior : 1.0f;
    const Vec3 ns = m * (1.0f / std::sqrt(dot(m, m)));
    Vec3 out;
    if (refract(s.d, ns, from, to, out)) {
        transmit_through(pp, s, s.d, ns, from, to);
        s.d = normalize(out);
        s.medium = to;
    } else {
        s.d = reflect(s.d, ns);
    }
}

}  // namespace path_detail

// Given the nearest hit of the current segment (kind none when there is none), moves the
// ray to its next segment or finishes it. Returns true while the ray is still active.
//
// Directions leaving a mirror are unit only up to rounding (see the reflection below):
// every intersection a segment takes part in is invariant under scaling its direction,
// and the refraction formula is off by no more than that rounding.
FREEFORM_HD inline bool advance(const PathParams& pp, PathState& s, const SurfaceHit& hit, RayRecord& rec) {
    if (hit.kind == HitKind::none) return path_detail::end_of_segment(pp, s, rec);
    if (hit.kind == HitKind::absorber) {
        path_detail::finish(s, rec, RayStatus::absorbed);
        return false;
    }
    if (++s.depth > pp.max_depth) {
        path_detail::finish(s, rec, RayStatus::lost_depth);
        return false;
    }
    const Vec3 flat = s.o + hit.t * s.d;
    // Extra meshes are flat triangles unless interpolated normals are asked for.
    const float alpha = hit.kind == HitKind::surface || pp.interpolated_normals ? pp.phong_alpha : 0.0f;
    // The normal before normalisation: a mirror needs only its direction.
    const Vec3 m = pp.interpolated_normals ? hit.b0 * hit.n[0] + hit.b1 * hit.n[1] + hit.b2 * hit.n[2]
                                           : patch_normal(hit, flat, alpha);
    s.o = phong_point(hit, flat, alpha);
    s.exclude = hit.tri;
    if (hit.kind == HitKind::refractive_mesh) {
        path_detail::refractive_crossing(pp, s, hit, m);
        return true;
    }
    if (hit.kind == HitKind::mirror_mesh || !pp.material.lens) {
        // d - 2 (d·n) n with n = m / |m|, written without the square root and the two
        // normalisations: |d| stays 1 up to rounding.
        s.d = s.d - (2.0f * dot(s.d, m) / dot(m, m)) * m;
        return true;
    }
    // Lens front face: into the material from outside, out of it from inside.
    const Vec3 ns = m * (1.0f / std::sqrt(dot(m, m)));
    Vec3 out;
    const float from = s.inside ? pp.material.ior : 1.0f;
    const float to = s.inside ? 1.0f : pp.material.ior;
    if (!refract(s.d, ns, from, to, out)) {
        path_detail::finish(s, rec, RayStatus::lost_tir);
        return false;
    }
    path_detail::transmit_through(pp, s, s.d, ns, from, to);
    s.d = normalize(out);
    s.inside = !s.inside;
    return true;
}

}  // namespace freeform
