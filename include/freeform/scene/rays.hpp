#pragma once
// Turning a light into rays. Rays are expressed in the surface frame (the tracing frame
// of every tracer): the surface plane is w = 0 and its normal is +w. Every ray is aimed
// at one stratum of the aperture, at the point of the surface above it (docs/
// architecture.md §1, "Where the rays are aimed"); its weight is the power that stratum
// of the surface receives, normalised so the mean weight is one, and stored in fixed
// point (core/fixed_point.hpp).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/fixed_point.hpp"
#include "../core/rng.hpp"
#include "../surface/heightmap.hpp"
#include "light.hpp"
#include "receiver.hpp"

namespace freeform {

struct RaySet {
    std::vector<Vec3> origin;     // surface frame
    std::vector<Vec3> direction;  // unit, surface frame
    std::vector<Fixed> weight;
    Fixed total = 0;  // N of the error formula: the weight reaching the surface

    std::int64_t size() const { return std::int64_t(origin.size()); }
};

// Number of rays a light asks for in a scene with this receiver.
inline std::int64_t ray_budget(const Light& light, const Receiver& receiver) {
    if (light.rays > 0) return light.rays;
    return std::max<std::int64_t>(1, std::llround(light.rays_per_cell * double(receiver.cells())));
}

namespace detail {

// A jittered grid of about `count` points over the aperture: (u, v, dA).
struct AperturePoint {
    double u, v;
};

inline std::vector<AperturePoint> stratify_aperture(const Heightmap& s, std::int64_t count, std::uint64_t seed,
                                                    double& cell_area) {
    const Vec2d size = s.size();
    // An elliptical aperture covers pi/4 of its bounding box: scale the grid so that
    // about `count` strata fall inside.
    const double fill = s.aperture() == Aperture::ellipse ? pi / 4.0 : 1.0;
    const double strata = double(count) / fill;
    int gx = std::max(1, int(std::lround(std::sqrt(strata * size.x / size.y))));
    int gy = std::max(1, int(std::lround(strata / gx)));
    cell_area = size.x * size.y / (double(gx) * gy);
    std::vector<AperturePoint> pts;
    pts.reserve(std::size_t(gx) * gy);
    const double cu = size.x / (s.nx() - 1), cv = size.y / (s.ny() - 1);
    for (int y = 0; y < gy; ++y) {
        for (int x = 0; x < gx; ++x) {
            CounterRng rng(seed, std::uint64_t(y) * std::uint64_t(gx) + std::uint64_t(x));
            const double u = ((x + rng.uniform()) / gx - 0.5) * size.x;
            const double v = ((y + rng.uniform()) / gy - 0.5) * size.y;
            // Keep the sample only where the aperture mask has a surface cell.
            const int ci = std::clamp(int((u + 0.5 * size.x) / cu), 0, s.nx() - 2);
            const int cj = std::clamp(int((v + 0.5 * size.y) / cv), 0, s.ny() - 2);
            if (s.cell_active(ci, cj)) pts.push_back({u, v});
        }
    }
    return pts;
}

// The point of `s`'s surface above the plane point (u, v), on the triangle the tracers
// meet there (trace/heightfield_kernel.hpp: cell (ci, cj) is split along its diagonal,
// triangle 0 where b <= a), and that triangle's normal scaled to unit w: (−∂h/∂u, −∂h/∂v,
// 1). Light arriving along d delivers (−d)·n of its irradiance per unit plane area there.
//
// Rays are aimed at these points rather than at the plane w = 0 because a surface with
// sag meets the line to a plane point elsewhere: under oblique or diverging light its
// lowered edges let the rays aimed inside the aperture pass beside it, and its raised or
// lowered edges catch light that no ray aimed at the plane samples. A mirror 9 cm beside
// and 6 cm above a point light, tilted 51 mm towards it, caught 46 % more light than the
// plane's rays carried, and 7.6 % of those missed it (docs/performance.md, "Where the
// rays are aimed"). Aimed at the surface, every stratum is lit by the ray aimed at it, as
// long as the surface traced is the one aimed at; a design's levels aim at the surface
// they start from, and its judgements at the surface they judge. Flat at w = 0, the
// point is (u, v, 0) and n is (0, 0, 1) exactly, and the rays are the plane's.
struct SurfaceAim {
    Vec3d point, normal;
};

inline SurfaceAim surface_aim(const Heightmap& s, double u, double v) {
    const double du = s.du(), dv = s.dv();
    const double fx = std::clamp((u - s.u_of(0)) / du, 0.0, double(s.nx() - 1));
    const double fy = std::clamp((v - s.v_of(0)) / dv, 0.0, double(s.ny() - 1));
    const int i = std::min(int(fx), s.nx() - 2), j = std::min(int(fy), s.ny() - 2);
    const double a = fx - i, b = fy - j;
    const double h00 = s(i, j), h10 = s(i + 1, j), h01 = s(i, j + 1), h11 = s(i + 1, j + 1);
    // Triangle 0 (v00, v10, v11) where b <= a, triangle 1 (v00, v11, v01) otherwise.
    const double gu = b <= a ? h10 - h00 : h11 - h01, gv = b <= a ? h11 - h10 : h01 - h00;
    return {{u, v, h00 + a * gu + b * gv}, {-gu / du, -gv / dv, 1.0}};
}

// A point of the unit square for the k-th aperture stratum: one of side x side strata,
// chosen by a fixed scramble of k, jittered inside it. An extended source pairs its own
// strata with the aperture's this way.
inline std::pair<double, double> scrambled_stratum(std::size_t k, int side, std::uint64_t scramble_seed,
                                                   std::uint64_t jitter_seed) {
    const std::uint64_t g = std::uint64_t(side);
    const std::uint64_t s = mix64(std::uint64_t(k) ^ mix64(scramble_seed)) % (g * g);
    CounterRng rng(jitter_seed, std::uint64_t(k));
    const double a = (double(s % g) + rng.uniform()) / double(g);
    return {a, (double(s / g) + rng.uniform()) / double(g)};
}

// Directions of a distant source of angular radius `degrees` around the unit vector
// `centre` (surface frame), uniform over the cone's solid angle. Each aperture point
// sends `per_point` rays (directions_per_point), one into each of as many equal parts
// of the disc (two rings of equal solid angle, each cut into per_point / 2 sectors),
// the pattern turned and jittered from point to point. Every point of the surface thus
// throws its light over the whole disc, as the sun does: an optimiser cannot steer one
// ray per point into the cells that one random direction happens to favour (with one
// direction per point, designs fitted that noise: held-out 0.072 against fitted 0.050
// on the sunlit lens). With a radius of 0 every direction is `centre`, exactly.
class ConeSampler {
public:
    static constexpr int directions_per_point = 8;
    // Rays per aperture point for a source of this angular radius.
    static int rays_per_point(double degrees) { return degrees == 0 ? 1 : directions_per_point; }

    ConeSampler(Vec3d centre, double degrees, std::uint64_t seed)
        : centre_(centre), cos_max_(std::cos(degrees * pi / 180.0)), seed_(seed ^ 0x2545f4914f6cdd1dULL),
          parallel_(degrees == 0) {
        // An orthonormal pair across the central direction.
        const Vec3d helper = std::abs(centre.z) < 0.9 ? Vec3d{0, 0, 1} : Vec3d{1, 0, 0};
        e1_ = normalize(cross(helper, centre));
        e2_ = cross(centre, e1_);
    }
    bool parallel() const { return parallel_; }
    int per_point() const { return parallel_ ? 1 : directions_per_point; }
    // Direction m (< per_point()) of aperture point q.
    Vec3d direction(std::size_t q, int m) const {
        if (parallel_) return centre_;
        constexpr int sectors = directions_per_point / 2;
        CounterRng turn(seed_, std::uint64_t(q));
        const double offset = turn.uniform();
        CounterRng jitter(seed_ ^ 0x9e3779b97f4a7c15ULL, std::uint64_t(q) * directions_per_point + std::uint64_t(m));
        const double a = (double(m % 2) + jitter.uniform()) / 2.0;
        double b = (double(m / 2) + jitter.uniform()) / sectors + offset;
        b -= std::floor(b);
        // Uniform in solid angle over the cap: cos(angle) uniform in [cos_max, 1].
        const double cos_a = 1.0 - a * (1.0 - cos_max_), sin_a = std::sqrt(std::max(0.0, 1.0 - cos_a * cos_a));
        const double phi = 2 * pi * b;
        return normalize(cos_a * centre_ + (sin_a * std::cos(phi)) * e1_ + (sin_a * std::sin(phi)) * e2_);
    }

private:
    Vec3d centre_, e1_{}, e2_{};
    double cos_max_;
    std::uint64_t seed_;
    bool parallel_;
};

inline void finish(RaySet& rays, const std::vector<double>& w) {
    double sum = 0;
    for (double x : w) sum += x;
    if (!(sum > 0)) throw InputError("light: no ray reaches the surface aperture (check light position and direction)");
    const double scale = double(w.size()) / sum;
    rays.weight.resize(w.size());
    rays.total = 0;
    for (std::size_t k = 0; k < w.size(); ++k) {
        rays.weight[k] = to_fixed(w[k] * scale);
        rays.total += rays.weight[k];
    }
}

// Rays of a collimated light c (at the points of `s` above `pts`, from the plane w = top),
// their weights appended to w.
inline void collimated_rays(const CollimatedLight& c, const Heightmap& s, const std::vector<AperturePoint>& pts,
                            double top, std::uint64_t seed, RaySet& rays, std::vector<double>& w,
                            std::vector<Vec2d>* aims) {
    const Frame& f = s.frame();
    const double dl = length(c.direction);
    if (!(dl > 0) || !std::isfinite(dl)) throw InputError("light.direction must be a finite non-zero vector");
    const Vec3d d = f.dir_to_local(c.direction / dl);
    if (!(d.z < -1e-9))
        throw InputError("light.direction must point towards the surface's front (against surface.normal)");
    const ConeSampler cone(d, c.angular_radius, seed);
    for (std::size_t q = 0; q < pts.size(); ++q) {
        const SurfaceAim at = surface_aim(s, pts[q].u, pts[q].v);
        for (int m = 0; m < cone.per_point(); ++m) {
            const Vec3d dk = cone.direction(q, m);
            if (!(dk.z < -1e-9)) continue;  // a wide source's edge grazing or behind the aperture plane
            // Power onto the surface per unit plane area, relative to the central
            // direction's onto the plane (exactly 1 for light along the normal, or for
            // parallel light onto a flat surface); none where the surface faces away.
            const double weight = -dot(dk, at.normal) / -d.z;
            if (!(weight > 0)) continue;
            const double t = (top - at.point.z) / -dk.z;  // from the plane w = top down to the surface
            const Vec3d o{at.point.x - t * dk.x, at.point.y - t * dk.y, top};
            rays.origin.push_back(static_cast<Vec3>(o));
            rays.direction.push_back(static_cast<Vec3>(dk));
            w.push_back(weight);
            if (aims) aims->push_back({pts[q].u, pts[q].v});
        }
    }
}

// Rays of a point light pl to the points of `s` above `pts` (each standing for a plane
// area dA).
inline void point_light_rays(const PointLight& pl, const Heightmap& s, const std::vector<AperturePoint>& pts,
                             double top, double dA, RaySet& rays, std::vector<double>& w, std::vector<Vec2d>* aims) {
    const Frame& f = s.frame();
    const Vec3d pos = f.to_local(pl.position);
    if (!(pos.z > top)) throw InputError("light.position must lie in front of the surface, above its height bounds");
    Vec3d axis = length(pl.axis) > 0 ? f.dir_to_local(normalize(pl.axis)) : normalize(Vec3d{0, 0, 0} - pos);
    for (const auto& p : pts) {
        const SurfaceAim at = surface_aim(s, p.u, p.v);
        const Vec3d to = at.point - pos;
        const double r2 = dot(to, to);
        const Vec3d d = to / std::sqrt(r2);
        const double deg = std::acos(std::clamp(dot(d, axis), -1.0, 1.0)) * 180.0 / pi;
        // Intensity times the solid angle of the surface over dA (none where it faces away).
        const double weight = profile_intensity(pl.profile, deg) * -dot(d, at.normal) * dA / r2;
        if (!(weight > 0)) continue;
        rays.origin.push_back(static_cast<Vec3>(pos));
        rays.direction.push_back(static_cast<Vec3>(d));
        w.push_back(weight);
        if (aims) aims->push_back({p.u, p.v});
    }
}

// Rays of a disk light, one from a point of the disk to the point of `s` above each
// aperture point.
inline void disk_light_rays(const DiskLight& disk, const Heightmap& s, const std::vector<AperturePoint>& pts,
                            double top, double dA, std::uint64_t seed, RaySet& rays, std::vector<double>& w,
                            std::vector<Vec2d>* aims) {
    const Frame& f = s.frame();
    const Vec3d c = f.to_local(disk.center);
    const Frame df =
        make_frame(disk.center, disk.normal, std::abs(disk.normal.z) < 0.9 ? Vec3d{0, 0, 1} : Vec3d{0, 1, 0}, "light");
    const Vec3d du = f.dir_to_local(df.u), dv = f.dir_to_local(df.v), dn = f.dir_to_local(df.w);
    if (!(c.z > top)) throw InputError("light.center must lie in front of the surface, above its height bounds");
    const double disk_area = pi * disk.radius * disk.radius;
    // Stratify the disk too, pairing disk strata with aperture strata by a fixed
    // scramble so that every aperture stratum sees a different part of the source.
    const std::int64_t n = std::int64_t(pts.size());
    const int g = std::max(1, int(std::lround(std::sqrt(double(n)))));
    for (std::int64_t k = 0; k < n; ++k) {
        const auto& p = pts[std::size_t(k)];
        const auto [a, b] = scrambled_stratum(std::size_t(k), g, seed, seed ^ 0x5bd1e995ULL);
        // Concentric-free polar mapping is enough here: uniform in area.
        const double r = disk.radius * std::sqrt(a), phi = 2 * pi * b;
        const Vec3d o = c + (r * std::cos(phi)) * du + (r * std::sin(phi)) * dv;
        const SurfaceAim at = surface_aim(s, p.u, p.v);
        const Vec3d to = at.point - o;
        const double r2 = dot(to, to);
        const Vec3d d = to / std::sqrt(r2);
        const double cos_src = dot(d, dn);
        const double weight = std::max(0.0, cos_src) * -dot(d, at.normal) * dA * disk_area / r2;
        if (!(weight > 0)) continue;
        rays.origin.push_back(static_cast<Vec3>(o));
        rays.direction.push_back(static_cast<Vec3>(d));
        w.push_back(weight);
        if (aims) aims->push_back({p.u, p.v});
    }
}

}  // namespace detail

// Generates the rays of `light` aimed at `surface` over its aperture (surface_aim),
// deterministic for `seed`. `aims`, when given, receives the plane point (u, v) each ray
// is aimed above.
inline RaySet generate_rays(const Light& light, const Heightmap& surface, const Receiver& receiver,
                            std::uint64_t seed, std::vector<Vec2d>* aims = nullptr) {
    const std::int64_t count = ray_budget(light, receiver);
    double dA = 0;
    // A source of finite angular size sends several rays from each aperture point.
    const auto* collimated = std::get_if<CollimatedLight>(&light.shape);
    const int per_point = collimated ? detail::ConeSampler::rays_per_point(collimated->angular_radius) : 1;
    const auto pts = detail::stratify_aperture(surface, std::max<std::int64_t>(1, count / per_point), seed, dA);
    RaySet rays;
    if (aims) aims->clear();
    rays.origin.reserve(pts.size());
    rays.direction.reserve(pts.size());
    std::vector<double> w;
    w.reserve(pts.size());
    // Rays start just above the slab so that the whole path through it is traced.
    const double top = double(surface.h_max()) + 1e-6 * std::max(surface.size().x, surface.size().y);

    if (collimated)
        detail::collimated_rays(*collimated, surface, pts, top, seed, rays, w, aims);
    else if (const auto* pl = std::get_if<PointLight>(&light.shape))
        detail::point_light_rays(*pl, surface, pts, top, dA, rays, w, aims);
    else
        detail::disk_light_rays(std::get<DiskLight>(light.shape), surface, pts, top, dA, seed, rays, w, aims);
    detail::finish(rays, w);
    return rays;
}

// Moves the origins of a collimated light's rays back along their direction to the
// plane w = w_top (surface frame) where they start below it. Rays start just above the
// surface's height bounds; geometry that rises higher (an imported solid) needs them to
// start above it. The light is the same light: it comes from infinitely far away.
// Point and disk lights start at their source, which no solid may hide.
inline void start_collimated_above(const Light& light, double w_top, RaySet& rays) {
    if (!std::holds_alternative<CollimatedLight>(light.shape)) return;
    for (std::size_t k = 0; k < rays.origin.size(); ++k) {
        const Vec3 o = rays.origin[k], d = rays.direction[k];
        if (!(double(o.z) < w_top) || !(d.z < 0.0f)) continue;
        const double t = (w_top - double(o.z)) / double(d.z);  // negative: back towards the light
        rays.origin[k] = Vec3{float(double(o.x) + t * double(d.x)), float(double(o.y) + t * double(d.y)), float(w_top)};
    }
}

}  // namespace freeform
