// Forward-model physics of the height-field tracer, checked against analytic optics.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

TEST_CASE("flat mirror under collimated light: uniform footprint, all energy on the receiver") {
    Scene s = basic_scene(100, 16);
    const Heightmap hm = surface_for(s, 51);
    const Traced t = trace_scene(s, hm);
    CHECK(t.totals.on_receiver() == t.totals.emitted);  // exactly: fixed-point sums
    CHECK(t.histogram.total() == t.totals.emitted);
    CHECK(t.totals.rays_hit_receiver == t.totals.rays);
    // The 0.1 m mirror reflects straight back: a 0.1 m square, i.e. the central 50 x 50
    // cells of the 0.2 m, 100 px receiver. Inside it every cell gets N / 2500.
    const double per_cell = from_fixed(t.totals.emitted) / 2500.0;
    int lit = 0;
    double worst = 0;
    for (int y = 0; y < 100; ++y)
        for (int x = 0; x < 100; ++x) {
            const double v = from_fixed(t.histogram.cells[std::size_t(y) * 100 + x]);
            const bool inside = x >= 25 && x < 75 && y >= 25 && y < 75;
            if (v > 0) ++lit;
            if (inside) worst = std::max(worst, std::abs(v - per_cell) / per_cell);
            if (!inside) CHECK(v == 0.0);
        }
    CHECK(lit == 2500);
    // Jittered strata straddle cell borders, so a cell holds its share +- one ray.
    CHECK(worst <= 1.0 / 16.0 + 1e-9);
}

TEST_CASE("tilted collimated light shifts the footprint by the analytic amount") {
    for (double deg : {5.0, 12.0, 20.0}) {
        Scene s = basic_scene(200, 16);
        s.receiver.size = {0.6, 0.6};
        const double a = degrees_to_radians(deg);
        s.light.shape = CollimatedLight{{std::sin(a), 0, -std::cos(a)}};
        const Heightmap hm = surface_for(s, 31);
        const Traced t = trace_scene(s, hm);
        CHECK(t.totals.energy() == doctest::Approx(1.0));
        // The reflected ray travels (sin a, 0, cos a); over 0.5 m it moves 0.5 tan(a) in +x,
        // which is -u on this receiver (u = up x normal = -x). 200 px over 0.6 m.
        const double expected_px = 100.0 - 0.5 * std::tan(a) / (0.6 / 200);
        const Vec2d c = centroid(t.histogram);
        CHECK(c.x == doctest::Approx(expected_px).epsilon(0.002));
        CHECK(c.y == doctest::Approx(100.0).epsilon(0.002));
    }
}

TEST_CASE("a paraboloid mirror focuses collimated light") {
    Scene s = basic_scene(200, 16);
    Heightmap hm = surface_for(s, 101);
    const double f = 0.5;  // focus on the receiver plane
    shape(hm, [&](double u, double v) { return (u * u + v * v) / (4 * f); });
    const Traced t = trace_scene(s, hm);
    CHECK(t.totals.energy() == doctest::Approx(1.0));
    double best = 0;
    for (int y = 1; y < 199; ++y)
        for (int x = 1; x < 199; ++x) {
            double sum = 0;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) sum += double(t.histogram.cells[std::size_t(y + dy) * 200 + x + dx]);
            best = std::max(best, sum);
        }
    CHECK(best / double(t.totals.emitted) >= 0.95);
}

TEST_CASE("point light over a flat mirror matches the mirrored virtual source") {
    Scene s = basic_scene(100, 64);
    const double hz = 0.3, rz = 0.5, side = 0.4;
    s.light.shape = PointLight{{0, 0, hz}, {}, {}};
    s.receiver.size = {side, side};
    const Heightmap hm = surface_for(s, 21);
    const Traced t = trace_scene(s, hm);
    CHECK(t.totals.energy() == doctest::Approx(1.0));

    // Solid angle of the aperture seen from the source, by fine midpoint integration.
    double omega_ap = 0;
    const int m = 800;
    const double da = 0.1 / m;
    for (int j = 0; j < m; ++j)
        for (int i = 0; i < m; ++i) {
            const double u = -0.05 + (i + 0.5) * da, v = -0.05 + (j + 0.5) * da;
            const double r2 = u * u + v * v + hz * hz;
            omega_ap += hz / std::sqrt(r2) * da * da / r2;
        }
    // A receiver cell at (x, y, rz) sees the virtual source at (0, 0, -hz): irradiance
    // cos(theta) / r^2, so the cell's share of N is (cell solid angle) / omega_ap.
    const double cell = side / 100, N = from_fixed(t.totals.emitted);
    double err = 0;
    int lit = 0;
    const double edge = 0.05 * (rz + hz) / hz;  // footprint half-width on the receiver
    for (int y = 0; y < 100; ++y)
        for (int x = 0; x < 100; ++x) {
            const double px = -(-0.5 * side + (x + 0.5) * cell);  // u = -x
            const double py = 0.5 * side - (y + 0.5) * cell;
            if (std::abs(px) > edge - 1.5 * cell || std::abs(py) > edge - 1.5 * cell) continue;  // interior only
            const double dz = rz + hz, r2 = px * px + py * py + dz * dz;
            const double expected = N * (dz / std::sqrt(r2)) * cell * cell / r2 / omega_ap;
            const double got = from_fixed(t.histogram.cells[std::size_t(y) * 100 + x]);
            err += std::abs(got - expected) / expected;
            ++lit;
        }
    REQUIRE(lit > 1000);
    CHECK(err / lit < 0.02);
}

TEST_CASE("light beside a tilted mirror: the rays cover the tilted face, which shows the mirrored virtual source") {
    // A flat mirror tilted 1 in 4 about the u axis (25 mm of sag over 0.1 m), a point light
    // 10 cm off to its low side and 8 cm up. Rays aimed at the plane w = 0 (as until
    // 2026-12-07) pass beside its lowered edge and never sample the light its raised edge
    // catches beyond the aperture: here 6 % of them missed, and the receiver got 83 % of
    // the power per cell the tilted face really sends. Aimed at the face (surface_aim),
    // every ray meets it, and each receiver cell gets its share of the virtual source
    // mirrored in the face's plane, worked out here from the geometry alone.
    Scene s = basic_scene(100, 256);
    // The footprint spans y -0.05 .. 0.43 and x ±0.29 on the receiver.
    const double t = 0.25, rz = 0.5, side = 0.64, yc = 0.19;
    const Vec3d light{0, -0.1, 0.08};
    s.receiver.frame = make_frame({0, yc, rz}, {0, 0, -1}, {0, 1, 0}, "receiver");
    s.light.shape = PointLight{light, {}, {}};
    s.surface.h_min = -0.013, s.surface.h_max = 0.013;
    s.receiver.size = {side, side};
    Heightmap hm = surface_for(s, 41);
    shape(hm, [&](double, double v) { return t * v; });
    const Traced traced = trace_scene(s, hm);
    CHECK(traced.totals.energy() == doctest::Approx(1.0));

    // The face's plane z = t y, its unit normal n; the virtual source is the light
    // mirrored in it. The power the face catches is I times its solid angle seen from the
    // light, integrated over the face (midpoints of its plane projection, area element
    // (−d)·(−∂h/∂u, −∂h/∂v, 1) dA / r²).
    const Vec3d n = normalize(Vec3d{0, -t, 1});
    const Vec3d image = light - 2 * dot(light, n) * n;
    double omega = 0;
    const int m = 800;
    const double da = 0.1 / m;
    for (int j = 0; j < m; ++j)
        for (int i = 0; i < m; ++i) {
            const Vec3d p{-0.05 + (i + 0.5) * da, -0.05 + (j + 0.5) * da, t * (-0.05 + (j + 0.5) * da)};
            const Vec3d to = light - p;
            const double r2 = dot(to, to);
            omega += dot(to, Vec3d{0, -t, 1}) / std::sqrt(r2) * da * da / r2;
        }
    // A receiver cell whose line to the virtual source crosses the face's plane well inside
    // the face gets (its solid angle seen from the virtual source) / omega of N.
    const double cell = side / 100, N = from_fixed(traced.totals.emitted);
    double err = 0;
    int lit = 0;
    for (int y = 0; y < 100; ++y)
        for (int x = 0; x < 100; ++x) {
            const Vec3d q{-(-0.5 * side + (x + 0.5) * cell), yc + 0.5 * side - (y + 0.5) * cell, rz};  // u = -x
            const Vec3d d = q - image;
            const double a = -dot(image, n) / dot(d, n);  // where the line meets the plane
            const Vec3d on = image + a * d;
            if (std::abs(on.x) > 0.047 || std::abs(on.y) > 0.047) continue;  // interior only
            const double r2 = dot(d, d);
            const double expected = N * (d.z / std::sqrt(r2)) * cell * cell / r2 / omega;
            const double got = from_fixed(traced.histogram.cells[std::size_t(y) * 100 + x]);
            err += std::abs(got - expected) / expected;
            ++lit;
        }
    MESSAGE("cells compared " << lit << ", mean relative error " << err / std::max(lit, 1));
    REQUIRE(lit > 500);
    CHECK(err / lit < 0.02);

    // Collimated light 30° off the normal, towards the face's lowered edge: every ray meets
    // the face (aimed at the plane, 14 % passed beside that edge).
    s.light.shape = CollimatedLight{{0, -std::sin(pi / 6), -std::cos(pi / 6)}};
    const TraceTotals sun = trace_scene(s, hm).totals;
    CHECK(sun.weight_by_status[std::size_t(RayStatus::missed_surface)] == 0);
    CHECK(sun.emitted > 0);
}

namespace {
Scene lens_scene(double receiver_z) {
    Scene s = basic_scene(100, 16);
    s.surface.material = Lens{1.49, 0.01};
    s.receiver.frame = make_frame({0, 0, receiver_z}, {0, 0, 1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.4, 0.4};
    return s;
}
}  // namespace

TEST_CASE("a refractive slab leaves normal-incidence light undeviated") {
    Scene s = lens_scene(-0.5);
    s.receiver.size = {0.2, 0.2};
    const Heightmap hm = surface_for(s, 21);
    const Traced t = trace_scene(s, hm);
    CHECK(t.totals.energy() == doctest::Approx(1.0));
    CHECK(t.totals.lost_tir() == 0);
    // The 0.1 m slab casts exactly the central 50 x 50 cells (2 mm) of the receiver.
    const Vec2d c = centroid(t.histogram);
    CHECK(c.x == doctest::Approx(50.0).epsilon(1e-3));
    CHECK(c.y == doctest::Approx(50.0).epsilon(1e-3));
    int lit = 0;
    for (Fixed v : t.histogram.cells) lit += v > 0;
    CHECK(lit == 2500);
}

TEST_CASE("a refractive wedge deflects light by Snell's law") {
    const double n = 1.49;
    for (double beta_deg : {3.0, 8.0}) {
        const double beta = degrees_to_radians(beta_deg);
        // Centroid on two receiver planes: the slope gives the exit angle independently of
        // where the rays leave the back face.
        double cx[2];
        const double zs[2] = {-0.3, -0.6};
        for (int k = 0; k < 2; ++k) {
            Scene s = lens_scene(zs[k]);
            s.surface.h_min = -0.008;
            s.surface.h_max = 0.008;
            s.surface.material = Lens{n, 0.02};
            Heightmap hm = surface_for(s, 11);
            shape(hm, [&](double u, double) { return std::tan(beta) * u; });
            const Traced t = trace_scene(s, hm);
            // A few rays near the rising edge drift sideways out of the body's side wall.
            CHECK(t.totals.energy() > 0.98);
            cx[k] = centroid(t.histogram).x * (0.4 / 100);
        }
        // Independent scalar Snell: entry at the tilted face, exit at the flat back face.
        const double inside = beta - std::asin(std::sin(beta) / n);  // angle from -w inside
        const double out = std::asin(n * std::sin(inside));
        const double slope = std::abs(cx[1] - cx[0]) / 0.3;
        CHECK(slope == doctest::Approx(std::tan(out)).epsilon(0.01));
    }
}

TEST_CASE("total internal reflection at the back face is counted as lost") {
    // Light grazing at 80 degrees from the normal, travelling +u, enters a face tilted 30
    // degrees towards -u. Inside, it runs at more than the critical angle (42.2 degrees
    // for n = 1.49) to the flat back face, so every ray reaching the back face is lost to
    // TIR; rays that reach the side wall first refract out through it (at 29 degrees from
    // the wall's normal, below the critical angle) and miss the receiver. A scalar 2-D
    // calculation predicts which rays do which.
    const double n = 1.49, beta = degrees_to_radians(30.0), phi = degrees_to_radians(80.0), thick = 0.03;
    Scene s = lens_scene(-0.5);
    s.surface.h_min = -0.029;
    s.surface.h_max = 0.029;
    s.surface.phong_alpha = 0;
    s.surface.material = Lens{n, thick, 0.0};  // rim 0: the side walls at the face's edges
    s.light.shape = CollimatedLight{{std::sin(phi), 0, -std::cos(phi)}};
    Heightmap hm = surface_for(s, 11);
    shape(hm, [&](double u, double) { return std::tan(beta) * u; });
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 5);
    const Traced t = trace_scene(s, hm, rays);

    // Inside direction from Snell's law in vector form, written out in 2-D (x, z).
    const double nx = -std::sin(beta), nz = std::cos(beta);  // face normal, outward
    const double dx = std::sin(phi), dz = -std::cos(phi);
    const double ci = -(dx * nx + dz * nz), eta = 1 / n;
    const double ct = std::sqrt(1 - eta * eta * (1 - ci * ci));
    const double ix = eta * dx + (eta * ci - ct) * nx, iz = eta * dz + (eta * ci - ct) * nz;
    REQUIRE(n * std::abs(ix) > 1.0);  // beyond the critical angle at the back face
    double predicted = 0;
    for (std::int64_t k = 0; k < rays.size(); ++k) {
        const double ox = rays.origin[std::size_t(k)].x, oz = rays.origin[std::size_t(k)].z;
        const double te = (std::tan(beta) * ox - oz) / (dz - std::tan(beta) * dx);  // entry
        const double ex = ox + te * dx, ez = oz + te * dz;
        if (std::abs(ex) > 0.05) continue;
        const double xb = ex + (-thick - ez) / iz * ix;  // where it meets the back plane
        if (std::abs(xb) <= 0.05) predicted += double(rays.weight[std::size_t(k)]);
    }
    REQUIRE(predicted > 0.2 * double(rays.total));
    CHECK(double(t.totals.lost_tir()) == doctest::Approx(predicted).epsilon(0.01));
    CHECK(t.totals.energy() < 0.01);
}

TEST_CASE("Phong correction: corrected hits lie closer to a sphere than flat hits") {
    // Convex spherical cap of radius R sampled on a coarse 9 x 9 grid.
    const double R = 0.2;
    Scene s = basic_scene();
    s.surface.h_min = -0.02;
    s.surface.h_max = 0.02;
    Heightmap hm = surface_for(s, 9);
    shape(hm, [&](double u, double v) { return std::sqrt(R * R - u * u - v * v) - R; });
    // Exact sphere normals at the vertices (the central differences are only close).
    const HeightfieldView hf = hm.view();
    double flat_err = 0, phong_err = 0;
    int hits = 0;
    CounterRng rng(7, 0);
    for (int k = 0; k < 2000; ++k) {
        const Vec3 o{float(rng.uniform(-0.045, 0.045)), float(rng.uniform(-0.045, 0.045)), 0.05f};
        const Vec3 d{0, 0, -1};
        const SurfaceHit h = find_heightfield_hit(hf, o, d, -1, true, NoCellVisitor{});
        REQUIRE(h.kind == HitKind::surface);
        const Vec3 flat = o + h.t * d;
        const Vec3 phong = phong_point(h, flat, 0.75f);
        const Vec3d c{0, 0, -R};
        flat_err += std::abs(length(Vec3d(flat) - c) - R);
        phong_err += std::abs(length(Vec3d(phong) - c) - R);
        ++hits;
    }
    MESSAGE("mean distance to sphere: flat ", flat_err / hits, " m, Phong ", phong_err / hits, " m");
    CHECK(phong_err < 0.5 * flat_err);
}

TEST_CASE("Phong correction brings a coarse paraboloid's irradiance closer to a fine reference") {
    // A strongly curved mirror (f = 5 cm) on a 5 x 5 grid and a receiver 2 cm away: here
    // the hit position matters, not only the interpolated normal.
    Scene s = basic_scene(100, 32);
    s.surface.h_min = -0.05;
    s.surface.h_max = 0.05;
    s.receiver.frame = make_frame({0, 0, 0.02}, {0, 0, -1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.3, 0.3};
    const double f = 0.05;
    auto parab = [&](double u, double v) { return (u * u + v * v) / (4 * f); };
    Heightmap fine = surface_for(s, 401);
    shape(fine, parab);
    const Traced ref = trace_scene(s, fine, generate_rays(s.light, fine, s.receiver, 3));
    Heightmap coarse = surface_for(s, 5);
    shape(coarse, parab);
    const RaySet rays = generate_rays(s.light, coarse, s.receiver, 3);
    s.surface.phong_alpha = 0.0;
    const Traced flat = trace_scene(s, coarse, rays);
    s.surface.phong_alpha = SurfaceSpec{}.phong_alpha;  // the default, 1/2
    const Traced phong = trace_scene(s, coarse, rays);
    const double e_flat = l1_distance(flat.histogram, ref.histogram) / double(ref.totals.emitted);
    const double e_phong = l1_distance(phong.histogram, ref.histogram) / double(ref.totals.emitted);
    MESSAGE("L1 to the fine reference / N: flat ", e_flat, ", Phong ", e_phong);
    CHECK(e_phong < 0.95 * e_flat);
}

TEST_CASE("same seed gives the same histogram; thread count does not change it") {
    Scene s = basic_scene(100, 16);
    s.light.shape = CollimatedLight{{0.2, -0.1, -1}};
    Heightmap hm = surface_for(s, 41);
    shape(hm, [](double u, double v) { return 0.003 * std::sin(60 * u) * std::cos(45 * v); });
    const RaySet a = generate_rays(s.light, hm, s.receiver, 11);
    const RaySet b = generate_rays(s.light, hm, s.receiver, 11);
    const RaySet c = generate_rays(s.light, hm, s.receiver, 12);
    const Traced t1 = trace_scene(s, hm, a, exec::seq);
    const Traced t2 = trace_scene(s, hm, b, exec::omp_t{2});
    const Traced t3 = trace_scene(s, hm, a, exec::omp_t{1});
    const Traced t4 = trace_scene(s, hm, c, exec::seq);
    CHECK(t1.histogram == t2.histogram);
    CHECK(t1.histogram == t3.histogram);
    CHECK_FALSE(t1.histogram == t4.histogram);  // another seed jitters the strata differently
}

TEST_CASE("interreflection: a 90-degree V-groove retro-reflects after two bounces") {
    // Two 45-degree facets meeting along v: a ray straight down hits one facet, crosses to
    // the other and leaves straight up on the far side of the crease (x -> -x).
    Scene s = basic_scene(100, 8);
    s.surface.h_min = -0.06;
    s.surface.h_max = 0.06;
    s.surface.phong_alpha = 0;
    s.receiver.size = {0.4, 0.4};
    Heightmap hm = surface_for(s, 201);
    shape(hm, [](double u, double) { return std::abs(u); });
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    HeightfieldTracer tracer(hm, rays, make_path_params(s));
    std::vector<std::int32_t> ids(std::size_t(rays.size()));
    for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = std::int32_t(k);
    std::vector<RayRecord> rec(ids.size());
    tracer.trace(exec::seq, ids, rec);
    int checked = 0, two_bounces = 0, mirrored = 0;
    for (std::size_t k = 0; k < ids.size(); ++k) {
        const double x0 = rays.origin[k].x;
        if (std::abs(x0) < 0.004) continue;  // next to the crease normals are averaged
        ++checked;
        two_bounces += rec[k].depth == 2 && rec[k].status == RayStatus::receiver;
        // Receiver u = -x: a flat mirror would land at px < 50 for x0 > 0; the groove
        // sends the ray across the crease, so it lands on the same side as x0.
        mirrored += (rec[k].px - 50.0) * x0 > 0;
    }
    CHECK(two_bounces > 0.99 * checked);
    CHECK(mirrored > 0.99 * checked);
}
