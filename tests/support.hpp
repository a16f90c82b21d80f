#pragma once
// Small builders shared by the tests: scenes made in code, traced in one call.
#include <cmath>
#include <functional>

#include <freeform/scene/rays.hpp>
#include <freeform/scene/scene.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>

namespace freeform::testing {

// True in the AddressSanitizer and ThreadSanitizer builds (CMakePresets.json's sanitize
// and tsan presets), which run the tests about eight times slower. A case may leave out
// there the repetitions that measure only accuracy along code its other repetitions
// already run; the release run checks every one. GCC defines __SANITIZE_ADDRESS__,
// clang answers __has_feature.
#if defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define FREEFORM_TESTING_SANITIZED 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__) || defined(FREEFORM_TESTING_SANITIZED)
inline constexpr bool sanitized = true;
#else
inline constexpr bool sanitized = false;
#endif

// The reference scene of docs/architecture.md §2: a 0.1 m mirror at the origin facing +z, light
// straight down, a 0.2 m receiver at z = 0.5 facing the mirror.
inline Scene basic_scene(int receiver_px = 100, double rays_per_cell = 16) {
    Scene s;
    s.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    s.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    s.receiver.width = s.receiver.height = receiver_px;
    s.receiver.deposit = Deposit::nearest;
    s.light.rays_per_cell = rays_per_cell;
    return s;
}

// A bar across the upper part of a w x h receiver and a block lower left: mass
// off-centre, an empty gap, and sharp edges (a target for transport starts).
inline ImageD two_blocks(int w, int h) {
    ImageD t = ImageD::Zero(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const double u = (x + 0.5) / w, v = (y + 0.5) / h;
            if ((v > 0.15 && v < 0.35 && u > 0.1 && u < 0.9) || (v > 0.55 && v < 0.9 && u > 0.15 && u < 0.5)) t(y, x) = 1;
        }
    return t;
}

inline Heightmap surface_for(const Scene& s, int n) {
    return Heightmap(n, n, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame, s.surface.aperture);
}

// Sets h(u, v) at every vertex (clamped to the bounds) and recomputes normals.
inline void shape(Heightmap& hm, const std::function<double(double, double)>& h) {
    std::vector<float> v(std::size_t(hm.nx()) * hm.ny());
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) v[std::size_t(j) * hm.nx() + i] = float(h(hm.u_of(i), hm.v_of(j)));
    hm.set_heights(v);
}

struct Traced {
    Histogram histogram;
    TraceTotals totals;
};

template <class P = exec::seq_t>
inline Traced trace_scene(const Scene& s, const Heightmap& hm, const RaySet& rays, P policy = {}) {
    HeightfieldTracer tracer(hm, rays, make_path_params(s));
    Traced t{Histogram(s.receiver.width, s.receiver.height), {}};
    tracer.trace_all(policy, t.histogram, t.totals);
    return t;
}

inline Traced trace_scene(const Scene& s, const Heightmap& hm, std::uint64_t seed = 1) {
    const RaySet rays = generate_rays(s.light, hm, s.receiver, seed);
    return trace_scene(s, hm, rays);
}

// Weighted centroid of a histogram in pixel coordinates (x = column, y = row).
inline Vec2d centroid(const Histogram& h) {
    double sx = 0, sy = 0, sw = 0;
    for (int y = 0; y < h.height; ++y)
        for (int x = 0; x < h.width; ++x) {
            const double w = double(h.cells[std::size_t(y) * h.width + x]);
            sx += w * (x + 0.5), sy += w * (y + 0.5), sw += w;
        }
    return {sx / sw, sy / sw};
}

inline double l1_distance(const Histogram& a, const Histogram& b) {
    double s = 0;
    for (std::size_t k = 0; k < a.cells.size(); ++k) s += std::abs(double(a.cells[k]) - double(b.cells[k]));
    return s;
}

// A hit on surface triangle `tri` at barycentrics (b0, b1, b2), with its vertices filled
// in as the tracers do, and the point on the flat triangle (phong_point's argument).
struct HitAt {
    SurfaceHit hit;
    Vec3 flat;
};
inline HitAt surface_hit_at(const HeightfieldView& view, std::int32_t tri, double b0, double b1, double b2) {
    HitAt h;
    h.hit.tri = tri;
    h.hit.kind = HitKind::surface;
    h.hit.b0 = float(b0), h.hit.b1 = float(b1), h.hit.b2 = float(b2);
    fill_hit_vertices(view, h.hit);
    h.flat = h.hit.b0 * h.hit.p[0] + h.hit.b1 * h.hit.p[1] + h.hit.b2 * h.hit.p[2];
    return h;
}

// A target with empty regions, sharp edges and its mass off-centre: a ring and a bar.
inline ImageD ring_and_bar(int w, int h) {
    ImageD t = ImageD::Zero(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const double u = (x + 0.5) / w - 0.5, v = (y + 0.5) / h - 0.5;
            const double r = std::hypot(u + 0.1, v + 0.05);
            if ((r > 0.15 && r < 0.3) || (v > 0.32 && v < 0.42 && u > -0.3 && u < 0.35)) t(y, x) = 1;
        }
    return t;
}

}  // namespace freeform::testing
