// The Embree tracer against the exact height-field tracer: same surfaces, same rays,
// same physics, so the irradiance must agree (up to which of two triangles sharing an
// edge a ray is said to hit). Then what only Embree does: refit, extra meshes, meshes in
// place of the height field.
#include <doctest/doctest.h>

#if defined(FREEFORM_WITH_EMBREE)

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#include <freeform/core/rng.hpp>
#include <freeform/embree.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

Traced embree_trace(const EmbreeTracer& tracer, const Scene& s, exec::omp_t policy = exec::omp) {
    Traced t{Histogram(s.receiver.width, s.receiver.height), {}};
    tracer.trace_all(policy, t.histogram, t.totals);
    return t;
}

// Heightfield and Embree tracers on the same surface and rays must agree: L1 of the
// histograms within 0.5 % of N, energy within 0.1 %.
void check_agreement(const Scene& s, const Heightmap& hm, std::uint64_t seed = 1) {
    const RaySet rays = generate_rays(s.light, hm, s.receiver, seed);
    const Traced ref = trace_scene(s, hm, rays, exec::omp);
    const EmbreeTracer tracer(hm, rays, make_path_params(s));
    const Traced got = embree_trace(tracer, s);
    const double n = double(rays.total);
    REQUIRE(ref.totals.emitted == got.totals.emitted);
    CHECK(got.totals.rays == ref.totals.rays);
    CHECK(ref.totals.energy() > 0.2);  // the scene must put light on the receiver to test anything
    INFO("L1 / N = ", l1_distance(ref.histogram, got.histogram) / n, ", energy ", ref.totals.energy(), " vs ",
         got.totals.energy());
    CHECK(l1_distance(ref.histogram, got.histogram) <= 0.005 * n);
    CHECK(std::abs(got.totals.energy() - ref.totals.energy()) <= 0.001 * ref.totals.energy());
    CHECK(got.histogram.total() == got.totals.on_receiver());
}

// A smooth random surface: Gaussian bumps of either sign, kept inside the bounds.
void bumpy(Heightmap& hm, std::uint64_t seed, int bumps = 12, double amplitude = 0.0015, double sigma = 0.012) {
    CounterRng rng(seed);
    std::vector<std::array<double, 4>> b;
    for (int k = 0; k < bumps; ++k) {
        const double u = rng.uniform(-0.05, 0.05), v = rng.uniform(-0.05, 0.05);
        const double a = rng.uniform(-amplitude, amplitude), sg = sigma * rng.uniform(0.7, 1.3);
        b.push_back({u, v, a, sg});
    }
    shape(hm, [&](double u, double v) {
        double h = 0;
        for (const auto& g : b) h += g[2] * std::exp(-((u - g[0]) * (u - g[0]) + (v - g[1]) * (v - g[1])) / (2 * g[3] * g[3]));
        return h;
    });
}

// A quad (two triangles) with corners c ± a ± b.
TriangleMesh quad(Vec3d c, Vec3d a, Vec3d b) {
    TriangleMesh m;
    m.vertices = {c - a - b, c + a - b, c + a + b, c - a + b};
    m.triangles = {{0, 1, 2}, {0, 2, 3}};
    m.compute_normals();
    return m;
}

// The height field's own triangulation as a mesh, with the Heightmap's normals.
TriangleMesh mesh_of(const Heightmap& hm, bool reverse_winding = false) {
    const HeightfieldView hf = hm.view();
    TriangleMesh m;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) {
            m.vertices.push_back(Vec3d(hf.vertex(i, j)));
            m.normals.push_back(Vec3d(hf.normal(i, j)));
        }
    const std::int32_t tris = 2 * (hm.nx() - 1) * (hm.ny() - 1);
    for (std::int32_t t = 0; t < tris; ++t) {
        int vi[3], vj[3];
        triangle_vertices(hm.nx(), t, vi, vj);
        std::array<std::int32_t, 3> tri{};
        for (int k = 0; k < 3; ++k) tri[std::size_t(k)] = vj[k] * hm.nx() + vi[k];
        if (reverse_winding) std::swap(tri[1], tri[2]);
        m.triangles.push_back(tri);
    }
    return m;
}

std::vector<std::int32_t> all_ids(const RaySet& rays) {
    std::vector<std::int32_t> ids(std::size_t(rays.size()));
    for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = std::int32_t(k);
    return ids;
}

}  // namespace

TEST_CASE("EmbreeTracer satisfies the Tracer concept") {
    static_assert(Tracer<EmbreeTracer>);
    CHECK(EmbreeTracer::name() == "embree");
}

TEST_CASE("flat mirror under collimated light: Embree matches the height-field tracer") {
    Scene s = basic_scene(64, 16);
    const Heightmap hm = surface_for(s, 51);
    check_agreement(s, hm);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const EmbreeTracer tracer(hm, rays, make_path_params(s));
    const Traced t = embree_trace(tracer, s);
    CHECK(t.totals.on_receiver() == t.totals.emitted);
}

TEST_CASE("paraboloid mirror: Embree focuses like the height-field tracer") {
    // An odd resolution puts the focus in the middle of a cell, not on a corner shared by
    // four cells where rounding alone would decide which of them gets each ray.
    Scene s = basic_scene(101, 8);
    Heightmap hm = surface_for(s, 101);
    shape(hm, [](double u, double v) { return (u * u + v * v) / (4 * 0.5); });
    check_agreement(s, hm);
}

TEST_CASE("tilted light on a bumpy surface, Phong alpha 0.75 and 0") {
    for (double alpha : {0.75, 0.0}) {
        CAPTURE(alpha);
        Scene s = basic_scene(64, 16);
        s.surface.phong_alpha = alpha;
        s.receiver.size = {0.4, 0.4};
        const double a = degrees_to_radians(15.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.3 * std::sin(a), -std::cos(a)}};
        Heightmap hm = surface_for(s, 65);
        bumpy(hm, 7);
        check_agreement(s, hm);
    }
}

TEST_CASE("point light over a bumpy mirror") {
    Scene s = basic_scene(64, 16);
    s.light.shape = PointLight{{0.01, -0.02, 0.3}, {}, {}};
    s.receiver.size = {0.5, 0.5};
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 11);
    check_agreement(s, hm);
}

TEST_CASE("lens: refraction through the height field and the flat back face") {
    Scene s = basic_scene(64, 16);
    s.surface.material = Lens{1.49, 0.01};
    s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.3, 0.3};
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 3, 12, 0.003, 0.01);
    check_agreement(s, hm);
}

TEST_CASE("grazing light (80 degrees) on a bumpy mirror: shadowing and interreflections") {
    Scene s = basic_scene(64, 16);
    const double a = degrees_to_radians(80.0);
    s.light.shape = CollimatedLight{{std::sin(a), 0, -std::cos(a)}};
    const Vec3d out{std::sin(a), 0, std::cos(a)};
    s.receiver.frame = make_frame(0.3 * out, -1.0 * out, {0, 1, 0}, "receiver");
    s.receiver.size = {0.3, 0.3};
    s.trace.max_depth = 8;
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 5, 16, 0.002, 0.008);
    // Interreflections must actually happen for this test to mean something.
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const HeightfieldTracer ref(hm, rays, make_path_params(s));
    std::vector<RayRecord> rec(std::size_t(rays.size()));
    const auto ids = all_ids(rays);
    ref.trace(exec::omp, ids, rec);
    const auto multi = std::count_if(rec.begin(), rec.end(), [](const RayRecord& r) { return r.depth >= 2; });
    CHECK(multi > rays.size() / 200);
    check_agreement(s, hm);
}

TEST_CASE("elliptical aperture: inactive cells are not traced") {
    Scene s = basic_scene(64, 16);
    s.surface.aperture = Aperture::ellipse;
    s.light.shape = PointLight{{0, 0, 0.3}, {}, {}};
    s.receiver.size = {0.5, 0.5};
    Heightmap hm = surface_for(s, 41);
    bumpy(hm, 9);
    check_agreement(s, hm);
}

TEST_CASE("1 and 2 threads give identical histograms") {
    Scene s = basic_scene(64, 16);
    s.receiver.deposit = Deposit::bilinear;
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 21);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const EmbreeTracer tracer(hm, rays, make_path_params(s));
    const Traced one = embree_trace(tracer, s, exec::omp_t{1});
    const Traced two = embree_trace(tracer, s, exec::omp_t{2});
    Traced serial{Histogram(64, 64), {}};
    tracer.trace_all(exec::seq, serial.histogram, serial.totals);
    CHECK(one.histogram == two.histogram);
    CHECK(one.histogram == serial.histogram);
    CHECK(one.totals.weight_by_status == two.totals.weight_by_status);
    CHECK(one.totals.rays_hit_receiver == two.totals.rays_hit_receiver);
}

TEST_CASE("retracing a subset gives each ray the record it has in a full trace") {
    // Incremental evaluation relies on this: a ray's record must not depend on which
    // other rays share its packet.
    Scene s = basic_scene(64, 16);
    s.surface.material = Lens{1.49, 0.01};
    s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 13, 12, 0.003, 0.01);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const EmbreeTracer tracer(hm, rays, make_path_params(s));
    const auto ids = all_ids(rays);
    std::vector<RayRecord> full(ids.size());
    tracer.trace(exec::omp, ids, full);

    // The records of the full trace rebuild trace_all's histogram.
    Histogram from_records(64, 64);
    for (std::size_t k = 0; k < ids.size(); ++k) deposit_record(tracer.params().receiver, full[k], rays.weight[k], from_records.cells);
    CHECK(from_records == embree_trace(tracer, s).histogram);

    // Every 7th ray, in a scrambled order, and ray by ray.
    std::vector<std::int32_t> subset;
    for (std::int32_t k = 0; k < std::int32_t(ids.size()); k += 7) subset.push_back(k);
    std::vector<std::int32_t> scrambled = subset;
    for (std::size_t k = 0; k < scrambled.size(); ++k)
        std::swap(scrambled[k], scrambled[std::size_t(mix64(k) % scrambled.size())]);
    std::vector<RayRecord> part(scrambled.size());
    tracer.trace(exec::omp, scrambled, part);
    int mismatches = 0;
    for (std::size_t k = 0; k < scrambled.size(); ++k)
        if (!(part[k] == full[std::size_t(scrambled[k])])) ++mismatches;
    CHECK(mismatches == 0);
    mismatches = 0;
    for (std::size_t k = 0; k < subset.size(); k += 5)
        if (!(tracer.trace_one(subset[k], [](int, int) {}) == full[std::size_t(subset[k])])) ++mismatches;
    CHECK(mismatches == 0);
}

TEST_CASE("refit after a height change equals a fresh build, and touches only the patch's tiles") {
  for (EmbreeTileLayout layout : {EmbreeTileLayout::instanced, EmbreeTileLayout::flat}) {
    CAPTURE(int(layout));
    Scene s = basic_scene(64, 16);
    s.receiver.size = {0.4, 0.4};
    s.light.shape = PointLight{{0.01, 0.0, 0.3}, {}, {}};
    Heightmap hm = surface_for(s, 65);
    bumpy(hm, 17);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    EmbreeTracer tracer(hm, rays, pp, {}, 8, layout);
    CHECK(tracer.tile_count() == 64);
    const Traced before = embree_trace(tracer, s);

    // Vertices 14..18 x 20..24 straddle the tile borders at 16 and 24: with 8-cell tiles
    // they belong to tiles (1..2) x (2..3).
    const Patch changed{14, 20, 18, 24};
    for (int j = changed.j0; j <= changed.j1; ++j)
        for (int i = changed.i0; i <= changed.i1; ++i) hm.set(i, j, hm(i, j) + 0.002f);
    hm.update_normals(hm.normal_support(changed));
    tracer.surface_changed(changed);
    CHECK(tracer.tiles_touched_last_update() == 4);

    const Traced after = embree_trace(tracer, s);
    const EmbreeTracer fresh(hm, rays, pp, {}, 8, layout);
    const Traced rebuilt = embree_trace(fresh, s);
    CHECK(!(after.histogram == before.histogram));  // the change is visible
    CHECK(after.histogram == rebuilt.histogram);
    CHECK(after.totals.weight_by_status == rebuilt.totals.weight_by_status);

    // A second change, undone: back to the first result bit for bit.
    const HeightSnapshot saved = hm.snapshot(Patch{42, 42, 43, 43});
    hm.set(42, 42, hm.h_max());
    hm.set(43, 43, hm.h_min());
    hm.update_normals(hm.normal_support(saved.patch));
    tracer.surface_changed(saved.patch);
    CHECK(tracer.tiles_touched_last_update() == 1);
    hm.restore(saved);
    tracer.surface_changed(saved.patch);
    CHECK(embree_trace(tracer, s).histogram == after.histogram);

    // Patches outside the grid are clipped; an empty one touches nothing.
    tracer.surface_changed(Patch{-10, -10, 0, 0});
    CHECK(tracer.tiles_touched_last_update() == 1);
    tracer.surface_changed(Patch{});
    CHECK(tracer.tiles_touched_last_update() == 0);
    CHECK(embree_trace(tracer, s).histogram == after.histogram);
  }
}

TEST_CASE("instanced and flat tile layouts, any tile size and any build thread count find the same hits") {
    Scene s = basic_scene(64, 16);
    s.receiver.deposit = Deposit::bilinear;  // sensitive to the last bit of every landing point
    const double a = degrees_to_radians(70.0);
    s.light.shape = CollimatedLight{{std::sin(a), 0, -std::cos(a)}};
    const Vec3d out{std::sin(a), 0, std::cos(a)};
    s.receiver.frame = make_frame(0.3 * out, -1.0 * out, {0, 1, 0}, "receiver");
    s.receiver.size = {0.3, 0.3};
    Heightmap hm = surface_for(s, 50);  // 49 cells: the last tiles are partial
    bumpy(hm, 41, 16, 0.002, 0.008);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    const Traced ref = embree_trace(EmbreeTracer(hm, rays, pp, {}, 32, EmbreeTileLayout::instanced), s);
    CHECK(ref.totals.energy() > 0.5);
    CHECK(embree_trace(EmbreeTracer(hm, rays, pp, {}, 32, EmbreeTileLayout::flat), s).histogram == ref.histogram);
    CHECK(embree_trace(EmbreeTracer(hm, rays, pp, {}, 5), s).histogram == ref.histogram);
    CHECK(embree_trace(EmbreeTracer(hm, rays, pp, {}, 100), s).histogram == ref.histogram);
    // BVHs built by one thread (a design's own thread count, Embree's "threads=1"): the same.
    CHECK(embree_trace(EmbreeTracer(hm, rays, pp, {}, 32, EmbreeTileLayout::instanced, 1), s).histogram ==
          ref.histogram);
    // And the exact height-field walk, with bilinear deposits, is close.
    const Traced hf = trace_scene(s, hm, rays, exec::omp);
    CHECK(l1_distance(hf.histogram, ref.histogram) <= 0.005 * double(rays.total));
}

TEST_CASE("trace_one reports every cell whose change can alter the ray") {
    Scene s = basic_scene(64, 16);
    const double a = degrees_to_radians(60.0);
    s.light.shape = CollimatedLight{{std::sin(a), 0, -std::cos(a)}};
    const Vec3d out{std::sin(a), 0, std::cos(a)};
    s.receiver.frame = make_frame(0.4 * out, -1.0 * out, {0, 1, 0}, "receiver");
    s.receiver.size = {0.3, 0.3};
    Heightmap hm = surface_for(s, 49);
    bumpy(hm, 29, 12, 0.002, 0.008);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    EmbreeTracer tracer(hm, rays, make_path_params(s), {}, 16);
    const auto ids = all_ids(rays);
    std::vector<RayRecord> old_rec(ids.size());
    tracer.trace(exec::seq, ids, old_rec);

    // Raise heights in a patch; its cells, and the cells of the vertices whose normals
    // change, are what a ray must have crossed to be affected.
    const Patch changed{20, 22, 24, 25};
    const Patch normals = hm.normal_support(changed);
    const int ci0 = normals.i0 - 1, ci1 = normals.i1, cj0 = normals.j0 - 1, cj1 = normals.j1;
    std::vector<char> crosses(ids.size(), 0);
    for (std::size_t k = 0; k < ids.size(); ++k) {
        const RayRecord r = tracer.trace_one(ids[k], [&](int ci, int cj) {
            if (ci >= ci0 && ci <= ci1 && cj >= cj0 && cj <= cj1) crosses[k] = 1;
        });
        CHECK(r == old_rec[k]);
    }
    for (int j = changed.j0; j <= changed.j1; ++j)
        for (int i = changed.i0; i <= changed.i1; ++i) hm.set(i, j, hm(i, j) + 0.003f);
    hm.update_normals(normals);
    tracer.surface_changed(changed);
    std::vector<RayRecord> new_rec(ids.size());
    tracer.trace(exec::seq, ids, new_rec);
    int changed_rays = 0, unexplained = 0;
    for (std::size_t k = 0; k < ids.size(); ++k) {
        if (new_rec[k] == old_rec[k]) continue;
        ++changed_rays;
        if (!crosses[k]) ++unexplained;
    }
    CHECK(changed_rays > 50);
    CHECK(unexplained == 0);
}

TEST_CASE("an absorbing quad over half of the mirror removes half of the light") {
    Scene s = basic_scene(64, 16);
    s.light.shape = PointLight{{0, 0, 0.3}, {}, {}};
    s.receiver.size = {0.6, 0.6};
    const Heightmap hm = surface_for(s, 33);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    const EmbreeTracer open(hm, rays, pp);
    const Traced free_path = embree_trace(open, s);
    CHECK(free_path.totals.energy() == doctest::Approx(1.0));

    // World frame = surface frame here; the quad covers u < 0 half way up to the light.
    const TriangleMesh blocker = quad({-0.1, 0, 0.15}, {0.1, 0, 0}, {0, 0.2, 0});
    std::vector<ExtraMesh> meshes{to_surface_frame(blocker, hm.frame(), false)};
    const EmbreeTracer blocked(hm, rays, pp, meshes);
    const Traced half = embree_trace(blocked, s);
    CHECK(half.totals.energy() == doctest::Approx(0.5).epsilon(0.02));
    const double absorbed = from_fixed(half.totals.weight_by_status[std::size_t(RayStatus::absorbed)]);
    CHECK(absorbed / from_fixed(half.totals.emitted) == doctest::Approx(0.5).epsilon(0.02));
}

TEST_CASE("a 45 degree fold mirror sends the reflected beam sideways onto a receiver") {
    Scene s = basic_scene(64, 16);
    const double a = degrees_to_radians(30.0);
    s.light.shape = CollimatedLight{{0, -std::sin(a), -std::cos(a)}};
    // The surface reflects the beam up along r_in; the fold mirror at 0.3 m along it turns
    // it to +x (normal along r_out - r_in), towards a receiver 0.3 m further.
    const Vec3d r_in{0, -std::sin(a), std::cos(a)}, r_out{1, 0, 0};
    const Vec3d fold = 0.3 * r_in;
    const Vec3d n = normalize(r_out - r_in);
    const Vec3d e1 = normalize(cross(n, Vec3d{0, 0, 1})), e2 = cross(n, e1);
    s.receiver.frame = make_frame(fold + 0.3 * r_out, -1.0 * r_out, {0, 0, 1}, "receiver");
    s.receiver.size = {0.3, 0.3};
    const Heightmap hm = surface_for(s, 33);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);

    const EmbreeTracer without(hm, rays, pp);
    CHECK(embree_trace(without, s).totals.energy() == 0.0);

    std::vector<ExtraMesh> meshes{to_surface_frame(quad(fold, 0.15 * e1, 0.15 * e2), hm.frame(), true)};
    const EmbreeTracer with(hm, rays, pp, std::move(meshes));
    const Traced t = embree_trace(with, s);
    CHECK(t.totals.energy() == doctest::Approx(1.0));
    std::vector<RayRecord> rec(std::size_t(rays.size()));
    with.trace(exec::seq, all_ids(rays), rec);
    CHECK(std::all_of(rec.begin(), rec.end(), [](const RayRecord& r) { return r.depth == 2; }));
    // The beam keeps its 0.1 m x 0.1 cos(30) m cross-section: about 21 x 19 of 64 x 64 px.
    const auto lit = std::count_if(t.histogram.cells.begin(), t.histogram.cells.end(), [](Fixed c) { return c > 0; });
    CHECK(lit > 300);
    CHECK(lit < 500);
}

TEST_CASE("a mesh of the height field's triangulation traces like the height field") {
    Scene s = basic_scene(64, 16);
    s.receiver.size = {0.4, 0.4};
    s.light.shape = PointLight{{0.01, 0.0, 0.3}, {}, {}};
    Heightmap hm = surface_for(s, 49);
    bumpy(hm, 31);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    const Traced ref = trace_scene(s, hm, rays, exec::omp);
    const double n = double(rays.total);
    for (bool reverse : {false, true}) {
        CAPTURE(reverse);  // the front side follows the vertex normals, not the winding
        const EmbreeTracer tracer(mesh_of(hm, reverse), rays, pp);
        const Traced got = embree_trace(tracer, s);
        CHECK(l1_distance(ref.histogram, got.histogram) <= 0.005 * n);
        CHECK(std::abs(got.totals.energy() - ref.totals.energy()) <= 0.001 * ref.totals.energy());
    }
    // As a lens front face too.
    s.surface.material = Lens{1.49, 0.01};
    s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
    const PathParams lens = make_path_params(s);
    const Traced lens_ref = trace_scene(s, hm, rays, exec::omp);
    const EmbreeTracer tracer(mesh_of(hm), rays, lens);
    const Traced got = embree_trace(tracer, s);
    CHECK(lens_ref.totals.energy() > 0.5);
    CHECK(l1_distance(lens_ref.histogram, got.histogram) <= 0.005 * n);
    // surface_changed has nothing to refit.
    EmbreeTracer movable = EmbreeTracer(mesh_of(hm), rays, lens);
    movable.surface_changed(hm.full_patch());
    CHECK(movable.tiles_touched_last_update() == 0);
    CHECK(embree_trace(movable, s).histogram == got.histogram);
}

TEST_CASE("bad input and Embree errors become exceptions") {
    Scene s = basic_scene(16, 4);
    const Heightmap hm = surface_for(s, 9);
    const RaySet rays = generate_rays(s.light, hm, s.receiver, 1);
    const PathParams pp = make_path_params(s);
    CHECK_THROWS_AS(EmbreeTracer(hm, rays, pp, {}, 0), InputError);
    TriangleMesh broken = quad({0, 0, 0.1}, {0.01, 0, 0}, {0, 0.01, 0});
    broken.triangles.push_back({0, 1, 7});
    CHECK_THROWS_WITH_AS(EmbreeTracer(hm, rays, pp, {ExtraMesh{broken, MeshMaterial::mirror()}}),
                         doctest::Contains("mesh 0 triangle 2 uses vertex 7"), InputError);
    CHECK_THROWS_AS(EmbreeTracer(TriangleMesh{}, rays, pp), InputError);

    // Embree reports errors through the device callback; check() rethrows them.
    const EmbreeDevice device;
    CHECK_NOTHROW(device.check("nothing"));
    RTCGeometry g = rtcNewGeometry(device.get(), RTCGeometryType(12345));
    CHECK(g == nullptr);
    CHECK_THROWS_WITH_AS(device.check("rtcNewGeometry"), doctest::Contains("Embree error in rtcNewGeometry"),
                         std::runtime_error);
    CHECK_NOTHROW(device.check("cleared after being reported"));
}

#else

// Without Embree 3 nothing here is built: the one case left is reported as skipped
// (doctest's skip decorator), not as a pass.
TEST_CASE("EmbreeTracer is not built (no Embree 3)" * doctest::skip()) {
    FAIL("freeform::embree unavailable: this case is skipped, never run");
}

#endif
