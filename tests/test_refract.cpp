// Refractive meshes (issue 10): a closed, outward-oriented mesh of index n refracts by
// Snell's law at every crossing and follows total internal reflection. Each case checks
// the physics against a closed form or against the height-field lens model.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include <freeform/design/cell_means.hpp>
#include <freeform/objective/target.hpp>
#include <freeform/surface/export.hpp>
#include <freeform/surface/triangle_mesh.hpp>

#include "start_support.hpp"
#include "support.hpp"

#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/design/fabrication.hpp>
#include <freeform/design/start.hpp>
#include <freeform/trace/embree.hpp>
#endif

using namespace freeform;
using namespace freeform::testing;

namespace {

// An axis-aligned box, triangles counter-clockwise seen from outside.
TriangleMesh box(Vec3d lo, Vec3d hi) {
    TriangleMesh m;
    for (int k = 0; k < 8; ++k)
        m.vertices.push_back({(k & 1) ? hi.x : lo.x, (k & 2) ? hi.y : lo.y, (k & 4) ? hi.z : lo.z});
    // Each face as a quad a-b-c-d, counter-clockwise seen from outside.
    const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4}, {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
    for (const auto& q : quads) {
        m.triangles.push_back({q[0], q[1], q[2]});
        m.triangles.push_back({q[0], q[2], q[3]});
    }
    return m;
}

TriangleMesh inside_out(TriangleMesh m) {
    for (auto& t : m.triangles) std::swap(t[1], t[2]);
    return m;
}

// A right-angle prism along y: the hypotenuse face on top (w = top, |x| <= half), the
// right-angle edge below it at w = top - half. Light coming down through the top meets
// the two 45° faces from inside.
TriangleMesh right_angle_prism(double half, double top, double y_half) {
    TriangleMesh m;
    const double xs[3] = {-half, half, 0}, zs[3] = {top, top, top - half};
    for (double y : {-y_half, y_half})
        for (int k = 0; k < 3; ++k) m.vertices.push_back({xs[k], y, zs[k]});
    // End caps (0 1 2 at -y, 3 4 5 at +y), then the three rectangular sides.
    m.triangles = {{0, 2, 1}, {3, 4, 5}, {0, 4, 3}, {0, 1, 4}, {1, 5, 4}, {1, 2, 5}, {2, 3, 5}, {2, 0, 3}};
    return m;
}

// A plano-convex lens about the w axis: a spherical cap of radius R (vertex at w = top)
// over a disk of radius a, a cylindrical side, a flat back at w = top - thickness.
// `rings` × `segments` facets on the cap.
TriangleMesh plano_convex(double R, double a, double top, double thickness, int rings, int segments) {
    TriangleMesh m;
    const auto cap = [&](double r) { return top - (R - std::sqrt(R * R - r * r)); };
    m.vertices.push_back({0, 0, top});  // 0: the vertex of the cap
    const auto ring_vertex = [&](int ring, int s) { return std::int32_t(1 + (ring - 1) * segments + (s % segments)); };
    for (int ring = 1; ring <= rings; ++ring) {
        const double r = a * ring / rings;
        for (int s = 0; s < segments; ++s) {
            const double phi = 2 * pi * s / segments;
            m.vertices.push_back({r * std::cos(phi), r * std::sin(phi), cap(r)});
        }
    }
    const double back = top - thickness;
    const auto bottom0 = std::int32_t(m.vertices.size());
    for (int s = 0; s < segments; ++s) {
        const double phi = 2 * pi * s / segments;
        m.vertices.push_back({a * std::cos(phi), a * std::sin(phi), back});
    }
    const auto bottom_centre = std::int32_t(m.vertices.size());
    m.vertices.push_back({0, 0, back});
    const auto bottom = [&](int s) { return std::int32_t(bottom0 + (s % segments)); };
    for (int s = 0; s < segments; ++s) {
        m.triangles.push_back({0, ring_vertex(1, s), ring_vertex(1, s + 1)});
        for (int ring = 1; ring < rings; ++ring) {
            m.triangles.push_back({ring_vertex(ring, s), ring_vertex(ring + 1, s), ring_vertex(ring + 1, s + 1)});
            m.triangles.push_back({ring_vertex(ring, s), ring_vertex(ring + 1, s + 1), ring_vertex(ring, s + 1)});
        }
        m.triangles.push_back({ring_vertex(rings, s), bottom(s), bottom(s + 1)});
        m.triangles.push_back({ring_vertex(rings, s), bottom(s + 1), ring_vertex(rings, s + 1)});
        m.triangles.push_back({bottom_centre, bottom(s + 1), bottom(s)});
    }
    return m;
}

}  // namespace

TEST_CASE("refractive solids are checked: closed, oriented, outward") {
    const TriangleMesh b = box({0, 0, 0}, {1, 2, 3});
    CHECK(check_refractive_solid(b, "box").volume == doctest::Approx(6.0));
    CHECK(check_refractive_solid(right_angle_prism(1, 0, 1), "prism").volume == doctest::Approx(2.0));
    const double R = 0.1, a = 0.01;
    CHECK(check_refractive_solid(plano_convex(R, a, 0, 0.004, 8, 32), "lens").volume > 0);
    CHECK_THROWS_WITH_AS(check_refractive_solid(inside_out(b), "b.obj"), doctest::Contains("b.obj"), InputError);
    CHECK_THROWS_WITH_AS(check_refractive_solid(inside_out(b), "b.obj"), doctest::Contains("inside out"), InputError);
    TriangleMesh open = b;
    open.triangles.pop_back();
    CHECK_THROWS_WITH_AS(check_refractive_solid(open, "open.obj"), doctest::Contains("not closed"), InputError);
    TriangleMesh mixed = b;
    std::swap(mixed.triangles[0][1], mixed.triangles[0][2]);
    CHECK_THROWS_WITH_AS(check_refractive_solid(mixed, "mixed.obj"), doctest::Contains("consistently oriented"),
                         InputError);
}

namespace {

// Unpolarised Fresnel transmittance from the angles (Fresnel's sine and tangent laws),
// written apart from the tracer's cosine form.
double fresnel_by_angles(double theta_i, double n1, double n2) {
    if (theta_i == 0) return 1 - std::pow((n1 - n2) / (n1 + n2), 2);
    const double theta_t = std::asin(n1 / n2 * std::sin(theta_i));
    const double rs = std::pow(std::sin(theta_i - theta_t) / std::sin(theta_i + theta_t), 2);
    const double rp = std::pow(std::tan(theta_i - theta_t) / std::tan(theta_i + theta_t), 2);
    return 1 - 0.5 * (rs + rp);
}

// A lens of index n under light straight down, the receiver 0.5 m below facing up.
Scene fresnel_lens(double n, double thickness, bool fresnel) {
    Scene s = basic_scene(50, 16);
    s.surface.material = Lens{n, thickness};
    s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.2, 0.2};
    s.trace.fresnel = fresnel;
    return s;
}

Fixed slot_sum(const TraceTotals& t) {
    Fixed sum = 0;
    for (const Fixed w : t.weight_by_status) sum += w;
    return sum;
}

}  // namespace

TEST_CASE("Fresnel: a flat lens at normal incidence passes (1 - R)^2; the rest is counted as reflected") {
    const double n = 1.5, r = std::pow((n - 1) / (n + 1), 2);  // 0.04 per face
    Scene s = fresnel_lens(n, 0.01, false);
    const Heightmap flat = surface_for(s, 21);
    const Traced off = trace_scene(s, flat);
    CHECK(off.totals.energy() == 1.0);  // off: today's model, nothing lost
    CHECK(off.totals.fresnel_reflected() == 0);

    s.trace.fresnel = true;
    const Traced on = trace_scene(s, flat);
    const double single_pass = (1 - r) * (1 - r);         // 0.9216
    const double all_reflections = single_pass / (1 - r * r);  // 0.92308: internal reflections followed
    MESSAGE("slab, Fresnel: energy ", on.totals.energy(), " (closed forms ", single_pass, ", ", all_reflections, ")");
    CHECK(on.totals.energy() == doctest::Approx(single_pass).epsilon(1e-6));
    CHECK(std::abs(on.totals.energy() - all_reflections) < 0.002);  // the goal
    // Every unit of weight is accounted for: delivered, or reflected away.
    CHECK(slot_sum(on.totals) == on.totals.emitted);
    CHECK(double(on.totals.fresnel_reflected()) / double(on.totals.emitted) == doctest::Approx(1 - single_pass).epsilon(1e-5));
    // The same footprint, each cell scaled by the transmittance.
    for (std::size_t k = 0; k < on.histogram.cells.size(); ++k)
        CHECK(double(on.histogram.cells[k]) == doctest::Approx(single_pass * double(off.histogram.cells[k])).epsilon(1e-6));

    // A target is scaled to what a flat lens passes: the flat lens meets its own footprint
    // exactly, instead of being blamed for the 7.8 % its faces must reflect.
    const RaySet rays = generate_rays(s.light, flat, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    CHECK(double(target_total(rays, pp)) == doctest::Approx(single_pass * double(rays.total)).epsilon(1e-6));
    ImageD footprint(50, 50);
    for (int y = 0; y < 50; ++y)
        for (int x = 0; x < 50; ++x) footprint(y, x) = double(off.histogram.cells[std::size_t(y) * 50 + x]);
    const double fair = l1_error(on.histogram, make_target(footprint, 50, 50, target_total(rays, pp)));
    const double blamed = l1_error(on.histogram, make_target(footprint, 50, 50, rays.total));
    MESSAGE("flat Fresnel lens against its own footprint: error ", fair, " (", blamed, " against the unreduced total)");
    CHECK(fair < 1e-6);
    CHECK(blamed == doctest::Approx((1 - single_pass) / 2).epsilon(1e-4));

    // The cell means (error_physical) judge the same way and report the share delivered,
    // not the share of what a flat lens passes.
    CellMeanOptions o;
    o.rays_per_cell = 16;
    const auto trace = [&](const Scene& sc, const TraceSetup& batch, Histogram& h, TraceTotals& t) {
        const Traced tr = trace_scene(sc, flat, batch.rays);
        h = tr.histogram;
        t = tr.totals;
    };
    const CellMeans cells = converged_cell_means(s, flat, &footprint, o, trace);
    CHECK(cells.totals.energy() == doctest::Approx(single_pass).epsilon(1e-6));
    CHECK(cells.error < 0.01);  // the flat lens's own footprint, up to the nearest deposit's edges

    s.trace.fresnel = false;
    CHECK(target_total(rays, make_path_params(s)) == rays.total);
}

TEST_CASE("Fresnel: a tilted lens face passes T(front) T(back), the two found from the angles") {
    for (const double degrees : {10.0, 30.0, 45.0}) {
        CAPTURE(degrees);
        const double n = 1.5, alpha = degrees * pi / 180;
        Scene s = fresnel_lens(n, 0.08, true);
        s.surface.h_min = -0.06, s.surface.h_max = 0.06;
        s.receiver.size = {1.2, 1.2};  // the wedge bends the beam up to 0.25 m aside
        Heightmap wedge = surface_for(s, 21);
        shape(wedge, [&](double u, double) { return u * std::tan(alpha); });
        const RaySet rays = generate_rays(s.light, wedge, s.receiver, 1);
        // Light straight down meets the face at alpha, runs alpha - beta from the vertical
        // inside, and leaves through the flat back face at that angle.
        const double beta = std::asin(std::sin(alpha) / n);
        const double expected = fresnel_by_angles(alpha, 1.0, n) * fresnel_by_angles(alpha - beta, n, 1.0);
        std::vector<std::int32_t> ids;
        for (std::int64_t k = 0; k < rays.size(); ++k)
            if (std::abs(rays.origin[std::size_t(k)].x) < 0.02) ids.push_back(std::int32_t(k));  // far from the side walls
        std::vector<RayRecord> rec(ids.size());
        HeightfieldTracer(wedge, rays, make_path_params(s)).trace(exec::seq, ids, rec);
        double worst = 0;
        int received = 0;
        for (const RayRecord& x : rec) {
            if (x.status != RayStatus::receiver) continue;
            ++received;
            worst = std::max(worst, std::abs(double(x.transmit) - expected));
        }
        MESSAGE(degrees, " degrees: T = ", expected, ", worst record off by ", worst);
        CHECK(received == int(ids.size()));
        CHECK(worst < 2e-6);
    }
}

#if defined(FREEFORM_WITH_EMBREE)

namespace {

// Light straight down (or tilted in x), the receiver `depth` below the surface plane
// facing up; the meshes alone are traced (no designed surface).
Scene lens_bench(double depth, double receiver_size, int px) {
    Scene s = basic_scene(px);
    s.receiver.frame = make_frame({0, 0, -depth}, {0, 0, 1}, {0, 1, 0}, "receiver");
    s.receiver.size = {receiver_size, receiver_size};
    return s;
}

std::vector<RayRecord> trace_records(const Scene& s, const RaySet& rays, std::vector<ExtraMesh> meshes) {
    PathParams pp = make_path_params(s);
    pp.material = MaterialView{};
    pp.phong_alpha = 0.0f;
    EmbreeTracer tracer(rays, pp, std::move(meshes));
    std::vector<std::int32_t> ids(std::size_t(rays.size()));
    for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = std::int32_t(k);
    std::vector<RayRecord> records(ids.size());
    tracer.trace(exec::seq, ids, records);
    return records;
}

Traced trace_meshes(const Scene& s, const RaySet& rays, std::vector<ExtraMesh> meshes, int threads = 2) {
    PathParams pp = make_path_params(s);
    pp.material = MaterialView{};
    pp.phong_alpha = 0.0f;
    EmbreeTracer tracer(rays, pp, std::move(meshes));
    Traced t{Histogram(s.receiver.width, s.receiver.height), {}};
    tracer.trace_all(exec::omp_t{threads}, t.histogram, t.totals);
    return t;
}

// Where a record landed, in metres along the receiver's u and v from its centre (w = 0).
Vec3d landing(const Scene& s, const RayRecord& r) {
    const double cu = s.receiver.size.x / s.receiver.width, cv = s.receiver.size.y / s.receiver.height;
    return {(r.px - 0.5 * s.receiver.width) * cu, (0.5 * s.receiver.height - r.py) * cv, 0};
}

}  // namespace

TEST_CASE("a flat glass slab leaves a collimated footprint unchanged, shifted by the closed-form amount") {
    const double n = 1.5, t = 0.01;
    const ExtraMesh slab{box({-0.2, -0.2, -0.001 - t}, {0.2, 0.2, -0.001}), MeshMaterial::refractive(n)};

    SUBCASE("normal incidence: every ray lands under its entry point, irradiance uniform") {
        Scene s = lens_bench(0.5, 0.2, 100);  // 2 mm cells: the 0.1 m aperture covers 50 x 50
        const RaySet rays = generate_rays(s.light, surface_for(s, 21), s.receiver, 1);
        const std::vector<RayRecord> rec = trace_records(s, rays, {slab});
        double worst = 0;
        int other = 0;
        for (std::size_t k = 0; k < rec.size(); ++k) {
            if (rec[k].status != RayStatus::receiver || rec[k].depth != 2) ++other;
            worst = std::max(worst, length(landing(s, rec[k]) - Vec3d{rays.origin[k].x, rays.origin[k].y, 0}));
        }
        CHECK(other == 0);
        CHECK(worst < 1e-7);
        const Traced tr = trace_meshes(s, rays, {slab});
        CHECK(tr.totals.energy() == 1.0);  // no Fresnel loss, nothing lost
        // 16 rays per receiver cell on average over 100 x 100 cells = 64 per footprint cell,
        // one per stratum of the aperture. A ray whose stratum touches a cell border may
        // round into the neighbour: a few cells get 63 or 65.
        const Fixed one = rays.weight[0];
        Fixed lo = std::numeric_limits<Fixed>::max(), hi = 0, outside = 0;
        int off = 0;
        for (int y = 0; y < 100; ++y)
            for (int x = 0; x < 100; ++x) {
                const Fixed c = tr.histogram.cells[std::size_t(y) * 100 + x];
                if (x >= 25 && x < 75 && y >= 25 && y < 75) {
                    lo = std::min(lo, c), hi = std::max(hi, c);
                    off += c != 64 * one ? 1 : 0;
                } else {
                    outside += c;
                }
            }
        MESSAGE("slab, normal incidence: footprint cells from ", double(lo) / double(one), " to ",
                double(hi) / double(one), " rays (64 expected), ", off, " of 2500 not 64");
        CHECK(lo >= 63 * one);
        CHECK(hi <= 65 * one);
        CHECK(off <= 10);
        CHECK(outside == 0);
    }

    SUBCASE("30 degrees: the beam leaves parallel, displaced by t (tan θ - tan θt)") {
        Scene s = lens_bench(0.5, 0.4, 200);
        const double theta = 30 * pi / 180, theta_t = std::asin(std::sin(theta) / n);
        s.light.shape = CollimatedLight{{std::sin(theta), 0, -std::cos(theta)}};
        s.receiver.frame = make_frame({0.5 * std::tan(theta), 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
        const RaySet rays = generate_rays(s.light, surface_for(s, 21), s.receiver, 1);
        const std::vector<RayRecord> rec = trace_records(s, rays, {slab});
        const double shift = -t * (std::tan(theta) - std::tan(theta_t));
        double worst = 0;
        int other = 0;
        for (std::size_t k = 0; k < rec.size(); ++k) {
            if (rec[k].status != RayStatus::receiver || rec[k].depth != 2) ++other;  // in and out
            // Straight from the ray's origin to the receiver plane, then the slab's shift.
            const Vec3d o(rays.origin[k]), d(rays.direction[k]);
            const double tr = (-0.5 - o.z) / d.z;
            const Vec3d want{o.x + tr * d.x + shift - 0.5 * std::tan(theta), o.y + tr * d.y, 0};
            const Vec3d got = landing(s, rec[k]);
            worst = std::max(worst, length(got - want));
        }
        MESSAGE("slab at 30°: shift ", shift * 1e3, " mm, worst landing error ", worst * 1e6, " µm");
        CHECK(other == 0);
        CHECK(worst < 2e-6);
        const Traced tr = trace_meshes(s, rays, {slab});
        CHECK(tr.totals.energy() == 1.0);
    }
}

TEST_CASE("a plano-convex lens mesh focuses at the lensmaker's focal length") {
    // R = 0.1 m, n = 1.5: f = R / (n - 1) = 0.2 m. The back focal distance from the flat
    // face is f - d / n for a centre thickness d (the rear principal plane lies d/n inside).
    const double n = 1.5, R = 0.1, a = 0.006, d = 0.004, top = -0.001;
    const double f = R / (n - 1), bfd = f - d / n, back = top - d;
    const ExtraMesh lens{plano_convex(R, a, top, d, 60, 240), MeshMaterial::refractive(n)};
    Scene s = lens_bench(0.2, 0.02, 100);
    s.surface.size = {0.008, 0.008};  // a beam 8 mm across, inside the 12 mm lens
    s.surface.aperture = Aperture::ellipse;
    s.light.rays = 20000;
    const RaySet rays = generate_rays(s.light, surface_for(s, 21), s.receiver, 1);

    // Mean square radius of the spot on a receiver plane at w = z (every ray must land).
    int lost = 0;
    const auto spot = [&](double z) {
        s.receiver.frame = make_frame({0, 0, z}, {0, 0, 1}, {0, 1, 0}, "receiver");
        const std::vector<RayRecord> rec = trace_records(s, rays, {lens});
        double sum = 0;
        for (const RayRecord& r : rec) {
            if (r.status != RayStatus::receiver || r.depth != 2) ++lost;
            sum += dot(landing(s, r), landing(s, r));
        }
        return sum / double(rec.size());
    };
    std::vector<double> zs, rms2;
    for (int step = -12; step <= 12; ++step) {
        zs.push_back(back - bfd * (1 + 0.01 * step));
        rms2.push_back(spot(zs.back()));
    }
    // rms² = A (z - z0)² + B: the blur of the facets adds in quadrature to the cone's
    // linear convergence. Least squares in (z², z, 1), then the vertex.
    double S[3][4] = {};
    for (std::size_t k = 0; k < zs.size(); ++k) {
        const double x = zs[k] - back, row[3] = {x * x, x, 1};
        for (int i = 0; i < 3; ++i) {
            for (int j = 0; j < 3; ++j) S[i][j] += row[i] * row[j];
            S[i][3] += row[i] * rms2[k];
        }
    }
    for (int i = 0; i < 3; ++i)
        for (int r = i + 1; r < 3; ++r) {
            const double q = S[r][i] / S[i][i];
            for (int j = i; j < 4; ++j) S[r][j] -= q * S[i][j];
        }
    double c[3];
    for (int i = 2; i >= 0; --i) {
        double v = S[i][3];
        for (int j = i + 1; j < 3; ++j) v -= S[i][j] * c[j];
        c[i] = v / S[i][i];
    }
    const double focus = -c[1] / (2 * c[0]);  // below the back face, so negative
    const std::size_t best = std::size_t(std::min_element(rms2.begin(), rms2.end()) - rms2.begin());
    const double f_measured = -focus + d / n;
    MESSAGE("plano-convex R = ", R, ", n = ", n, ": f expected ", f, " m, measured ", f_measured, " m (error ",
            (f_measured - f) / f * 100, " %); smallest sampled spot ", std::sqrt(rms2[best]) * 1e6,
            " µm RMS at ", (back - zs[best]) / bfd, " BFD");
    CHECK(std::abs(f_measured - f) / f < 0.005);
    CHECK(std::abs((back - zs[best]) / bfd - 1) <= 0.011);
    // A cone: halfway to the focus the footprint is half as wide as the beam that entered,
    // and as wide again as far past the focus.
    double entry = 0;
    for (const Vec3 o : rays.origin) entry += double(o.x) * o.x + double(o.y) * o.y;
    entry = std::sqrt(entry / double(rays.size()));
    const double before = std::sqrt(spot(back - 0.5 * bfd)), after = std::sqrt(spot(back - 1.5 * bfd));
    MESSAGE("RMS radius: entering ", entry * 1e3, " mm, at BFD/2 ", before * 1e3, " mm, at 3 BFD/2 ", after * 1e3,
            " mm");
    CHECK(before / entry == doctest::Approx(0.5).epsilon(0.03));
    CHECK(after / before == doctest::Approx(1.0).epsilon(0.02));
    CHECK(lost == 0);
}

TEST_CASE("total internal reflection is followed: a right-angle prism turns a beam back") {
    // Light straight down enters the hypotenuse face, meets the two 45° faces from inside
    // (sin 45° · 1.5 > 1: totally reflected both times) and leaves upwards, mirrored in x,
    // towards the receiver above the prism.
    Scene s = basic_scene(100);
    const RaySet rays = generate_rays(s.light, surface_for(s, 21), s.receiver, 1);
    const TriangleMesh prism = right_angle_prism(0.06, -0.001, 0.06);

    const std::vector<RayRecord> rec = trace_records(s, rays, {ExtraMesh{prism, MeshMaterial::refractive(1.5)}});
    double worst = 0;
    int near_apex = 0, other = 0;
    for (std::size_t k = 0; k < rec.size(); ++k) {
        const Vec3d o(rays.origin[k]);
        if (std::abs(o.x) < 1e-4) {  // splits at the apex edge
            ++near_apex;
            continue;
        }
        if (rec[k].status != RayStatus::receiver || rec[k].depth != 4) ++other;  // in, reflected twice, out
        // The receiver's u axis is -x (it faces down): mirrored in x lands at +x in u.
        const Vec3d got = landing(s, rec[k]);
        worst = std::max(worst, length(got - Vec3d{o.x, o.y, 0}));
    }
    MESSAGE("prism: worst distance from the mirrored entry point ", worst * 1e6, " µm (", near_apex,
            " rays at the apex skipped)");
    CHECK(other == 0);
    CHECK(worst < 2e-6);
    const Traced glass = trace_meshes(s, rays, {ExtraMesh{prism, MeshMaterial::refractive(1.5)}});
    CHECK(glass.totals.energy() > 0.995);
    CHECK(glass.totals.lost_tir() == 0);
    // Below the critical index (sin 45° · 1.3 < 1) the light refracts out of the 45° faces,
    // downwards, and never reaches the receiver.
    const Traced weak = trace_meshes(s, rays, {ExtraMesh{prism, MeshMaterial::refractive(1.3)}});
    CHECK(weak.totals.energy() < 0.005);
    // Every crossing and every reflection counts towards trace.max_depth: with 3 the
    // light is lost inside the glass before its way out.
    s.trace.max_depth = 3;
    const Traced shallow = trace_meshes(s, rays, {ExtraMesh{prism, MeshMaterial::refractive(1.5)}});
    const double lost_depth =
        double(shallow.totals.weight_by_status[std::size_t(RayStatus::lost_depth)]) / double(rays.total);
    CHECK(shallow.totals.energy() < 0.005);
    CHECK(lost_depth > 0.995);
}

TEST_CASE("the exported lens solid, traced as a refractive mesh, gives the design's irradiance") {
    // As in test_fabrication: the transport start of a lens towards a ring and a bar.
    Scene s = basic_scene(100);
    s.surface.material = Lens{1.49, 0.01};
    s.surface.h_min = -0.008, s.surface.h_max = 0.008;
    s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.15, 0.15};
    s.receiver.deposit = Deposit::bilinear;
    s.target = TargetSpec{};
    const ImageD target = ring_and_bar(s.receiver.width, s.receiver.height);
    // Any transport surface serves here: the first solve's (testing::first_solve_start).
    const DesignStart st = first_solve_start(s, surface_for(s, 51), target, 3, 1);
    REQUIRE(st.report.used == StartKind::transport);
    const RaySet rays = generate_rays(s.light, st.surface, s.receiver, 1);
    const Traced design = trace_scene(s, st.surface, rays, exec::omp);

    const Fabrication fab = make_fabrication(s, ExportOptions{}, st.surface);  // the watertight lens solid
    REQUIRE(check_mesh(fab.mesh).watertight());
    const ExtraMesh solid = to_surface_frame(fab.mesh, s.surface.frame, MeshMaterial::refractive(1.49));
    RaySet lifted = rays;
    start_above(s.light, s.surface.size, solid.mesh, lifted);
    const Traced traced = trace_meshes(s, lifted, {solid});
    const double l1 = l1_distance(design.histogram, traced.histogram) / (2.0 * double(rays.total));
    MESSAGE("lens solid (k = ", fab.subdivisions, ", ", fab.mesh.triangles.size(), " triangles): L1 to the design ",
            l1, ", energy ", traced.totals.energy(), " vs ", design.totals.energy());
    CHECK(l1 <= 0.02);
    CHECK(std::abs(traced.totals.energy() - design.totals.energy()) < 0.01);
    // The thread count changes nothing: packets are fixed, sums are integers.
    const Traced one = trace_meshes(s, lifted, {solid}, 1);
    CHECK(one.histogram == traced.histogram);
}

TEST_CASE("light that meets the lens model's side wall is reflected inside, as in the solid it models") {
    // A flat lens lit at 0.3 rad: inside, rays run 11.4 degrees from the normal, so those
    // entering within 2 mm of the +u edge meet the side wall first, at 78.6 degrees from
    // its normal (beyond the critical angle), and leave through the back face after one
    // reflection. The height-field lens model must do what its solid, a glass box, does.
    // With a rim (surface.material.rim) the walls stand that far beyond the face: the glass
    // box is wider by it, the light still falls on the face only, and the rays drifting
    // past the face's edge leave through the back face without meeting a wall.
    const double n = 1.49, t = 0.01;
    for (const double rim : {0.0, 0.003}) {
        CAPTURE(rim);
        Scene s = lens_bench(0.3, 0.4, 100);
        s.surface.material = Lens{n, t, rim};
        s.surface.h_min = -0.002, s.surface.h_max = 0.002;
        s.light.shape = CollimatedLight{{std::sin(0.3), 0, -std::cos(0.3)}};
        const Heightmap flat = surface_for(s, 11);
        const RaySet rays = generate_rays(s.light, flat, s.receiver, 1);
        const Traced model = trace_scene(s, flat, rays);
        const double hu = 0.5 * s.surface.size.x + rim, hv = 0.5 * s.surface.size.y + rim;
        const Traced solid =
            trace_meshes(s, rays, {ExtraMesh{box({-hu, -hv, -t}, {hu, hv, 0}), MeshMaterial::refractive(n)}});
        const double l1 = l1_distance(model.histogram, solid.histogram) / (2.0 * double(rays.total));
        MESSAGE("energy: lens model ", model.totals.energy(), ", glass box ", solid.totals.energy(), "; L1 ", l1);
        CHECK(model.totals.energy() > 0.999);  // absorbing walls would lose about 2 %
        CHECK(solid.totals.energy() > 0.999);
        CHECK(l1 < 0.002);
        if (rim > 0) {
            // And the rim matters here: the face-sized box mirrors the edge light elsewhere.
            const Traced flush = trace_meshes(s, rays, {ExtraMesh{box({-hu + rim, -hv + rim, -t}, {hu - rim, hv - rim, 0}),
                                                                  MeshMaterial::refractive(n)}});
            CHECK(l1_distance(model.histogram, flush.histogram) / (2.0 * double(rays.total)) > 0.01);
        }
    }
}

TEST_CASE("Fresnel on refractive meshes: a glass box at normal and at 30 degrees' incidence") {
    const double n = 1.5;
    const ExtraMesh slab{box({-0.2, -0.2, -0.011}, {0.2, 0.2, -0.001}), MeshMaterial::refractive(n)};
    for (const double degrees : {0.0, 30.0}) {
        CAPTURE(degrees);
        const double theta = degrees * pi / 180;
        Scene s = lens_bench(0.5, 0.6, 60);
        s.light.shape = CollimatedLight{{std::sin(theta), 0, -std::cos(theta)}};
        s.receiver.frame = make_frame({0.5 * std::tan(theta), 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
        s.trace.fresnel = true;
        const RaySet rays = generate_rays(s.light, surface_for(s, 21), s.receiver, 1);
        const Traced t = trace_meshes(s, rays, {slab});
        // In at theta, out at the refracted angle: the same transmittance twice.
        const double face = fresnel_by_angles(theta, 1.0, n);
        CHECK(t.totals.energy() == doctest::Approx(face * face).epsilon(1e-6));
        CHECK(slot_sum(t.totals) == t.totals.emitted);
        s.trace.fresnel = false;
        CHECK(trace_meshes(s, rays, {slab}).totals.energy() == 1.0);
    }
}

TEST_CASE("the tracer refuses refractive meshes that do not bound a solid") {
    Scene s = lens_bench(0.5, 0.2, 20);
    const RaySet rays = generate_rays(s.light, surface_for(s, 5), s.receiver, 1);
    const TriangleMesh b = box({-0.1, -0.1, -0.02}, {0.1, 0.1, -0.01});
    PathParams pp = make_path_params(s);
    CHECK_THROWS_WITH_AS(EmbreeTracer(rays, pp, {ExtraMesh{inside_out(b), MeshMaterial::refractive(1.5)}}),
                         doctest::Contains("mesh 0: a refractive mesh must be a closed solid"), InputError);
    CHECK_THROWS_WITH_AS(EmbreeTracer(rays, pp, {ExtraMesh{b, MeshMaterial::refractive(0.9)}}),
                         doctest::Contains("must be > 1"), InputError);
    CHECK_NOTHROW(EmbreeTracer(rays, pp, {ExtraMesh{inside_out(b), MeshMaterial::absorber()}}));
}

#endif
