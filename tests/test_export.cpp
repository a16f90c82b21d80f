// Fabrication export: the Phong-tessellated sheet, the lens solid, the mesh checker and
// the smoothing filter.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <functional>
#include <random>
#include <string>
#include <vector>

#include <freeform/core/rng.hpp>
#include <freeform/io/mesh.hpp>
#include <freeform/surface/export.hpp>
#include <freeform/surface/smooth.hpp>
#include <freeform/trace/heightfield_kernel.hpp>

#include "support.hpp"

using namespace freeform;
using freeform::testing::surface_hit_at;

namespace {

Heightmap make_surface(int nx, int ny, Vec2d size, double h_lo, double h_hi,
                       const std::function<double(double, double)>& h, Frame frame = {},
                       Aperture aperture = Aperture::rect) {
    Heightmap hm(nx, ny, size, h_lo, h_hi, frame, aperture);
    std::vector<float> v(std::size_t(nx) * ny);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) v[std::size_t(j) * nx + i] = float(h(hm.u_of(i), hm.v_of(j)));
    hm.set_heights(v);
    return hm;
}

// A spherical dome of radius R (apex at w = 0): strongly curved at the scale of a cell.
double dome(double u, double v, double R = 0.1) { return std::sqrt(R * R - u * u - v * v) - R; }

Heightmap cap_9x9() {
    return make_surface(9, 9, {0.1, 0.1}, -0.05, 0.05, [](double u, double v) { return dome(u, v); });
}

Heightmap wavy(int nx, int ny, Frame frame = {}, Aperture aperture = Aperture::rect) {
    return make_surface(
        nx, ny, {0.08, 0.05}, -0.004, 0.004,
        [](double u, double v) { return 0.002 * std::sin(90 * u) * std::cos(70 * v) + 0.01 * u * v; }, frame, aperture);
}

// Heights of a mesh under the vertical line through (x, y), by brute force over its
// triangles (the mesh is a height field over the surface plane). False when the line
// misses the mesh.
bool mesh_height_at(const TriangleMesh& m, double x, double y, double& w) {
    for (const auto& t : m.triangles) {
        const Vec3d a = m.vertices[std::size_t(t[0])], b = m.vertices[std::size_t(t[1])],
                    c = m.vertices[std::size_t(t[2])];
        const double det = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        if (!(det > 0)) continue;
        const double l1 = ((x - a.x) * (c.y - a.y) - (c.x - a.x) * (y - a.y)) / det;
        const double l2 = ((b.x - a.x) * (y - a.y) - (x - a.x) * (b.y - a.y)) / det;
        const double l0 = 1 - l1 - l2;
        constexpr double eps = -1e-12;
        if (l0 >= eps && l1 >= eps && l2 >= eps) {
            w = l0 * a.z + l1 * b.z + l2 * c.z;
            return true;
        }
    }
    return false;
}

// ∫(w + t) dA under the front triangles of a mesh, by prisms: projected area times the
// mean height of the corners (exact for a planar top). Only triangles facing +w count.
double prism_volume(const TriangleMesh& front, double t) {
    double v = 0;
    for (const auto& tri : front.triangles) {
        const Vec3d a = front.vertices[std::size_t(tri[0])], b = front.vertices[std::size_t(tri[1])],
                    c = front.vertices[std::size_t(tri[2])];
        const double area2 = (b.x - a.x) * (c.y - a.y) - (c.x - a.x) * (b.y - a.y);
        v += 0.5 * area2 * ((a.z + b.z + c.z) / 3.0 + t);
    }
    return v;
}

double laplacian_energy(const Heightmap& hm) {
    double e = 0;
    for (int j = 1; j + 1 < hm.ny(); ++j)
        for (int i = 1; i + 1 < hm.nx(); ++i) {
            const double l = double(hm(i - 1, j)) + hm(i + 1, j) + hm(i, j - 1) + hm(i, j + 1) - 4.0 * hm(i, j);
            e += l * l;
        }
    return e;
}

Frame tilted_frame() { return make_frame({0.3, -0.2, 1.0}, {1, 1, 2}, {0, 0, 1}, "surface"); }

struct TempDir {
    std::filesystem::path path;
    TempDir() {
        std::random_device entropy;
        const auto stamp = std::chrono::steady_clock::now().time_since_epoch().count();
        path = std::filesystem::temp_directory_path() /
               ("freeform_test_export_" + std::to_string(stamp) + "_" + std::to_string(entropy()));
        std::filesystem::create_directories(path);
    }
    ~TempDir() {
        std::error_code ec;
        std::filesystem::remove_all(path, ec);
    }
};

}  // namespace

TEST_CASE("k = 1, alpha = 0 reproduces the grid and the tracer's triangles") {
    const Heightmap hm = wavy(7, 5);
    const TriangleMesh m = tessellate_surface(hm, 0.0f, 1, false);
    REQUIRE(m.vertices.size() == 7u * 5u);
    REQUIRE(m.normals.size() == m.vertices.size());
    REQUIRE(m.triangles.size() == 2u * 6u * 4u);
    for (int j = 0; j < 5; ++j)
        for (int i = 0; i < 7; ++i) {
            const Vec3d p = m.vertices[std::size_t(j) * 7 + i];
            CHECK(p.x == hm.u_of(i));
            CHECK(p.y == hm.v_of(j));
            CHECK(p.z == double(hm(i, j)));
            // alpha = 0: the stored normal is the facet normal of the triangle the vertex
            // is taken from: in the cell to its upper right (the last one at the far
            // borders), triangle 0 (v00, v10, v11) unless the vertex is that cell's v01.
            const int ci = std::min(i, 5), cj = std::min(j, 3);
            const bool upper = j > cj && i == ci;
            const Vec3d a{hm.u_of(ci), hm.v_of(cj), double(hm(ci, cj))},
                b{hm.u_of(ci + 1), hm.v_of(upper ? cj + 1 : cj), double(hm(ci + 1, upper ? cj + 1 : cj))},
                c{hm.u_of(upper ? ci : ci + 1), hm.v_of(cj + 1), double(hm(upper ? ci : ci + 1, cj + 1))};
            const Vec3d n = m.normals[std::size_t(j) * 7 + i];
            CHECK(length(n - normalize(cross(b - a, c - a))) < 1e-12);
        }
    // Triangle t of the mesh is triangle t of the tracer (same vertices, same order).
    for (std::int32_t t = 0; t < std::int32_t(m.triangles.size()); ++t) {
        int i[3], j[3];
        triangle_vertices(7, t, i, j);
        for (int k = 0; k < 3; ++k) CHECK(m.triangles[std::size_t(t)][std::size_t(k)] == j[k] * 7 + i[k]);
    }
    // Phong leaves the grid vertices where they are.
    const TriangleMesh mp = tessellate_surface(hm, 0.75f, 1, false);
    for (std::size_t v = 0; v < m.vertices.size(); ++v) CHECK(mp.vertices[v] == m.vertices[v]);
}

TEST_CASE("k = 4: shared-vertex grid, no duplicates, an oriented open sheet") {
    const int nx = 7, ny = 5, k = 4;
    const Heightmap hm = wavy(nx, ny);
    const TriangleMesh m = tessellate_surface(hm, 0.75f, k, false);
    const std::size_t fx = (nx - 1) * k + 1, fy = (ny - 1) * k + 1;
    CHECK(m.vertices.size() == fx * fy);
    CHECK(m.triangles.size() == 2u * (fx - 1) * (fy - 1));
    std::vector<std::array<double, 3>> sorted;
    for (const Vec3d& p : m.vertices) sorted.push_back({p.x, p.y, p.z});
    std::sort(sorted.begin(), sorted.end());
    CHECK(std::adjacent_find(sorted.begin(), sorted.end()) == sorted.end());
    for (const Vec3d& n : m.normals) CHECK(std::abs(length(n) - 1.0) < 1e-12);

    const MeshCheck c = check_mesh(m);
    CHECK(c.manifold);
    CHECK(c.oriented);
    CHECK_FALSE(c.closed);
    CHECK(c.degenerate_triangles == 0);
    CHECK(c.boundary_edges == int(2 * ((nx - 1) * k + (ny - 1) * k)));
    CHECK(c.area > 0.08 * 0.05);  // a wavy sheet is larger than its footprint
    // Every triangle faces the light side (+w).
    for (const auto& t : m.triangles) {
        const Vec3d n = cross(m.vertices[std::size_t(t[1])] - m.vertices[std::size_t(t[0])],
                              m.vertices[std::size_t(t[2])] - m.vertices[std::size_t(t[0])]);
        CHECK(n.z > 0);
    }
    // The square the brief asks for: ((n-1)·4 + 1)² vertices.
    const Heightmap sq = make_surface(9, 9, {0.1, 0.1}, -0.05, 0.05, [](double u, double v) { return dome(u, v); });
    CHECK(tessellate_surface(sq, 0.75f, 4).vertices.size() == std::size_t(33 * 33));
}

TEST_CASE("points on shared edges get the same position from either side, bit for bit") {
    // The patches meet without cracks; their normals meet with a small kink (Phong
    // patches are continuous, not smooth, across edges), which the tracers simulate.
    const Heightmap hm = wavy(6, 5);
    const double alpha = SurfaceSpec{}.phong_alpha;  // the default, 1/2
    double kink = 0;
    const auto angle = [](Vec3d a, Vec3d b) { return std::atan2(length(cross(a, b)), dot(a, b)); };
    for (int cj = 0; cj + 1 < hm.ny(); ++cj)
        for (int ci = 0; ci + 1 < hm.nx(); ++ci) {
            const std::int32_t base = 2 * (cj * (hm.nx() - 1) + ci);
            for (int s = 0; s <= 13; ++s) {
                const double t = s / 13.0;
                // The diagonal from triangle 0 (v00, v10, v11) and from triangle 1 (v00, v11, v01).
                const PhongVertex d0 = phong_vertex(hm, base, 1 - t, 0, t, alpha);
                const PhongVertex d1 = phong_vertex(hm, base + 1, 1 - t, t, 0, alpha);
                CHECK(d0.position == d1.position);
                kink = std::max(kink, angle(d0.normal, d1.normal));
                if (ci + 2 < hm.nx()) {  // the side shared with the cell to the right
                    const PhongVertex a = phong_vertex_in_cell(hm, ci, cj, 1.0, t, alpha);
                    const PhongVertex b = phong_vertex_in_cell(hm, ci + 1, cj, 0.0, t, alpha);
                    CHECK(a.position == b.position);
                    kink = std::max(kink, angle(a.normal, b.normal));
                }
                if (cj + 2 < hm.ny()) {  // the side shared with the cell above
                    const PhongVertex a = phong_vertex_in_cell(hm, ci, cj, t, 1.0, alpha);
                    const PhongVertex b = phong_vertex_in_cell(hm, ci, cj + 1, t, 0.0, alpha);
                    CHECK(a.position == b.position);
                    kink = std::max(kink, angle(a.normal, b.normal));
                }
            }
        }
    MESSAGE("largest normal kink across an edge: ", kink, " rad");
    // Smaller than the turn of the vertex normals from one vertex to the next.
    double turn = 0;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i + 1 < hm.nx(); ++i)
            turn = std::max(turn, angle(Vec3d(hm.normals()[std::size_t(j) * hm.nx() + i]),
                                        Vec3d(hm.normals()[std::size_t(j) * hm.nx() + i + 1])));
    MESSAGE("largest turn of the vertex normals between neighbours: ", turn, " rad");
    CHECK(kink > 0);
    CHECK(kink < turn);
}

TEST_CASE("phong_vertex is phong_point up to float rounding") {
    const Heightmap hm = cap_9x9();
    const HeightfieldView view = hm.view();
    CounterRng rng(7);
    double worst_p = 0, worst_n = 0;
    for (int s = 0; s < 2000; ++s) {
        const auto tri = std::int32_t(rng.below(2u * 8u * 8u));
        double b1 = rng.uniform(), b2 = rng.uniform();
        if (b1 + b2 > 1) b1 = 1 - b1, b2 = 1 - b2;
        const double b0 = 1 - b1 - b2;
        const auto [hit, flat] = surface_hit_at(view, tri, b0, b1, b2);
        const Vec3d pf = Vec3d(phong_point(hit, flat, 0.75f));
        const Vec3d nf = Vec3d(normalize(patch_normal(hit, flat, 0.75f)));
        const PhongVertex pd = phong_vertex(hm, tri, double(hit.b0), double(hit.b1), double(hit.b2), 0.75);
        worst_p = std::max(worst_p, length(pd.position - pf));
        worst_n = std::max(worst_n, length(pd.normal - nf));
    }
    MESSAGE("phong_vertex vs phong_point: position ", worst_p, " m, normal ", worst_n);
    CHECK(worst_p < 2e-8);  // a few float ulps of 0.05 m coordinates
    CHECK(worst_n < 1e-5);  // the normal's formula has more float rounding than the position
}

TEST_CASE("Phong-corrected tracer hits lie on the fine tessellated mesh") {
    // What we simulate is what gets machined: a vertical ray traced by the kernel and
    // moved by phong_point lands on the exported mesh, while the flat hit does not. The
    // remaining gap is the chord error of the sub-triangles on the curved Phong patch, so
    // it falls as 1/k².
    const Heightmap hm = cap_9x9();
    const HeightfieldView view = hm.view();
    struct Sample {
        Vec3d corrected, flat;
    };
    std::vector<Sample> samples;
    CounterRng rng(3);
    for (int s = 0; s < 150; ++s) {
        const Vec3 o{float(rng.uniform(-0.045, 0.045)), float(rng.uniform(-0.045, 0.045)), 0.1f};
        const SurfaceHit hit = find_heightfield_hit(view, o, Vec3{0, 0, -1}, -1, true, NoCellVisitor{});
        REQUIRE(hit.kind == HitKind::surface);
        const Vec3 flat = o + hit.t * Vec3{0, 0, -1};
        samples.push_back({Vec3d(phong_point(hit, flat, 0.75f)), Vec3d(flat)});
    }
    double previous = INFINITY;
    for (int k : {8, 16, 32}) {
        const TriangleMesh fine = tessellate_surface(hm, 0.75f, k, false);
        double max_corrected = 0, max_flat = 0, sum_corrected = 0, sum_flat = 0;
        for (const Sample& s : samples) {
            double w_p = 0, w_f = 0;
            REQUIRE(mesh_height_at(fine, s.corrected.x, s.corrected.y, w_p));
            REQUIRE(mesh_height_at(fine, s.flat.x, s.flat.y, w_f));
            const double dc = std::abs(s.corrected.z - w_p), df = std::abs(s.flat.z - w_f);
            max_corrected = std::max(max_corrected, dc), max_flat = std::max(max_flat, df);
            sum_corrected += dc, sum_flat += df;
        }
        MESSAGE("k = ", k, ": corrected hit to mesh max ", max_corrected, " m, mean ", sum_corrected / samples.size(),
                "; flat hit max ", max_flat, " m, mean ", sum_flat / samples.size());
        CHECK(max_flat > 1e-4);  // the flat triangles are far from the fabricated surface
        CHECK(max_corrected < 0.02 * max_flat);
        CHECK(sum_corrected < 0.02 * sum_flat);
        CHECK(max_corrected < 0.35 * previous);  // second-order convergence onto the patch
        previous = max_corrected;
        if (k == 32) CHECK(max_corrected < 1e-6);
    }
}

TEST_CASE("elliptical aperture: only active cells, only their vertices") {
    const int nx = 11, ny = 9, k = 3;
    const Heightmap hm = wavy(nx, ny, {}, Aperture::ellipse);
    int active = 0;
    for (int cj = 0; cj + 1 < ny; ++cj)
        for (int ci = 0; ci + 1 < nx; ++ci) active += hm.cell_active(ci, cj) ? 1 : 0;
    REQUIRE(active < (nx - 1) * (ny - 1));
    const TriangleMesh m = tessellate_surface(hm, 0.75f, k, false);
    CHECK(m.triangles.size() == std::size_t(2 * k * k * active));
    std::vector<int> used(m.vertices.size(), 0);
    for (const auto& t : m.triangles)
        for (std::int32_t v : t) used[std::size_t(v)] = 1;
    CHECK(std::count(used.begin(), used.end(), 0) == 0);
    const MeshCheck c = check_mesh(m);
    CHECK(c.manifold);
    CHECK(c.oriented);
    CHECK(c.boundary_edges > 0);
    // Every kept triangle lies over an active cell.
    for (const auto& t : m.triangles) {
        Vec3d centre{0, 0, 0};
        for (std::int32_t v : t) centre = centre + m.vertices[std::size_t(v)];
        centre = centre / 3.0;
        const int ci = std::clamp(int((centre.x + 0.04) / hm.du()), 0, nx - 2);
        const int cj = std::clamp(int((centre.y + 0.025) / hm.dv()), 0, ny - 2);
        CHECK(hm.cell_active(ci, cj));
    }
}

TEST_CASE("world frame output maps surface points with to_world") {
    const Frame f = tilted_frame();
    const Heightmap hm = wavy(6, 5, f);
    const TriangleMesh local = tessellate_surface(hm, 0.75f, 3, false);
    const TriangleMesh world = tessellate_surface(hm, 0.75f, 3);
    REQUIRE(local.vertices.size() == world.vertices.size());
    REQUIRE(local.triangles == world.triangles);
    // One vertex by hand: grid vertex (0, 0) at (u_of(0), v_of(0), h(0, 0)).
    const Vec3d by_hand = f.origin + hm.u_of(0) * f.u + hm.v_of(0) * f.v + double(hm(0, 0)) * f.w;
    CHECK(length(world.vertices[0] - by_hand) < 1e-15);
    for (std::size_t v = 0; v < world.vertices.size(); ++v) {
        CHECK(world.vertices[v] == f.to_world(local.vertices[v]));
        CHECK(world.normals[v] == f.dir_to_world(local.normals[v]));
    }
    // Still counter-clockwise seen from the surface normal's side.
    for (const auto& t : world.triangles) {
        const Vec3d n = cross(world.vertices[std::size_t(t[1])] - world.vertices[std::size_t(t[0])],
                              world.vertices[std::size_t(t[2])] - world.vertices[std::size_t(t[0])]);
        CHECK(dot(n, f.w) > 0);
    }
}

TEST_CASE("check_mesh on small meshes") {
    TriangleMesh tet;
    tet.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    tet.triangles = {{0, 2, 1}, {0, 1, 3}, {1, 2, 3}, {0, 3, 2}};
    MeshCheck c = check_mesh(tet);
    CHECK(c.closed);
    CHECK(c.manifold);
    CHECK(c.oriented);
    CHECK(c.watertight());
    CHECK(c.volume == doctest::Approx(1.0 / 6.0).epsilon(1e-14));
    CHECK(c.area == doctest::Approx(1.5 + std::sqrt(3.0) / 2).epsilon(1e-14));

    TriangleMesh flipped = tet;
    std::swap(flipped.triangles[2][0], flipped.triangles[2][1]);
    c = check_mesh(flipped);
    CHECK(c.closed);
    CHECK_FALSE(c.oriented);

    TriangleMesh fin = tet;  // a third triangle on edge 0-1
    fin.vertices.push_back({0.5, -1, 0.5});
    fin.triangles.push_back({1, 0, 4});
    c = check_mesh(fin);
    CHECK(c.non_manifold_edges == 1);
    CHECK_FALSE(c.manifold);
    CHECK_FALSE(c.closed);

    TriangleMesh open = tet;
    open.triangles.pop_back();
    c = check_mesh(open);
    CHECK(c.boundary_edges == 3);
    CHECK(c.manifold);
    CHECK(c.oriented);
    CHECK_FALSE(c.closed);

    TriangleMesh bad = tet;
    bad.triangles.push_back({0, 1, 9});
    CHECK_THROWS_AS(check_mesh(bad), InputError);
}

TEST_CASE("lens solid of a flat surface is the slab") {
    const Heightmap hm(9, 6, {0.1, 0.06}, -0.005, 0.005);
    const Lens lens{1.49, 0.01};
    for (int k : {1, 3}) {
        const TriangleMesh s = lens_solid(hm, lens, 0.75f, k, false);
        const MeshCheck c = check_mesh(s);
        CHECK(c.watertight());
        CHECK(c.boundary_edges == 0);
        CHECK(c.non_manifold_edges == 0);
        CHECK(std::abs(c.volume - 0.1 * 0.06 * 0.01) < 1e-9 * 0.1 * 0.06 * 0.01);
        CHECK(std::abs(c.area - (2 * 0.1 * 0.06 + 2 * 0.01 * (0.1 + 0.06))) < 1e-12);
    }
}

TEST_CASE("lens solid of a curved surface: watertight, volume = integral of (h + t)") {
    const Lens lens{1.49, 0.04};
    const Heightmap cap = cap_9x9();
    const double du = cap.du(), dv = cap.dv();
    // alpha = 0: the flat triangles, whatever k; ∫(h + t) dA straight from the grid (each
    // triangle: du·dv/2 times the mean of its corner heights).
    double grid_volume = 0;
    for (int cj = 0; cj + 1 < cap.ny(); ++cj)
        for (int ci = 0; ci + 1 < cap.nx(); ++ci) {
            const double h00 = cap(ci, cj), h10 = cap(ci + 1, cj), h11 = cap(ci + 1, cj + 1), h01 = cap(ci, cj + 1);
            grid_volume += 0.5 * du * dv * ((h00 + h10 + h11) / 3 + lens.thickness);
            grid_volume += 0.5 * du * dv * ((h00 + h11 + h01) / 3 + lens.thickness);
        }
    for (int k : {1, 4}) {
        const MeshCheck c = check_mesh(lens_solid(cap, lens, 0.0f, k, false));
        CHECK(c.watertight());
        CHECK(std::abs(c.volume - grid_volume) < 1e-9 * grid_volume);
    }
    // alpha = 3/4: integrate the tessellated heights by prisms, independently of the
    // divergence-theorem sum over the closed solid.
    const int k = 8;
    const TriangleMesh front = tessellate_surface(cap, 0.75f, k, false);
    const double prisms = prism_volume(front, lens.thickness);
    const TriangleMesh solid = lens_solid(cap, lens, 0.75f, k, false);
    const MeshCheck c = check_mesh(solid);
    CHECK(c.watertight());
    CHECK(std::abs(c.volume - prisms) < 1e-6 * prisms);
    // The dome's Phong patches bulge outward past the flat triangles, towards the sphere.
    double sphere_volume = 0;  // midpoint rule on the analytic dome
    const int q = 1200;
    for (int j = 0; j < q; ++j)
        for (int i = 0; i < q; ++i)
            sphere_volume += dome(-0.05 + (i + 0.5) * 0.1 / q, -0.05 + (j + 0.5) * 0.1 / q) + lens.thickness;
    sphere_volume *= (0.1 / q) * (0.1 / q);
    MESSAGE("volumes: flat ", grid_volume, ", Phong ", c.volume, ", sphere ", sphere_volume);
    CHECK(c.volume > grid_volume);
    CHECK(std::abs(c.volume - sphere_volume) < std::abs(grid_volume - sphere_volume));
    // The front of the solid is the tessellated sheet, vertex for vertex.
    for (std::size_t v = 0; v < front.vertices.size(); ++v) CHECK(solid.vertices[v] == front.vertices[v]);
}

TEST_CASE("lens solid: elliptical aperture, tilted frame, STL round trip") {
    const Lens lens{1.49, 0.01};
    const Frame f = tilted_frame();
    for (int n : {2, 3, 4, 7, 12}) {
        const Heightmap hm = wavy(n + 2, n, f, Aperture::ellipse);
        const TriangleMesh local = lens_solid(hm, lens, 0.75f, 3, false);
        const MeshCheck c = check_mesh(local);
        CHECK(c.watertight());
        const double prisms = prism_volume(tessellate_surface(hm, 0.75f, 3, false), lens.thickness);
        CHECK(std::abs(c.volume - prisms) < 1e-9 * prisms);
        // The world placement moves the solid rigidly.
        const MeshCheck cw = check_mesh(lens_solid(hm, lens, 0.75f, 3));
        CHECK(cw.watertight());
        CHECK(std::abs(cw.volume - c.volume) < 1e-9 * c.volume);
        CHECK(std::abs(cw.area - c.area) < 1e-9 * c.area);
    }
    // Written as STL (float32 corners, welded back on reading) it is still a valid solid.
    const Heightmap hm = wavy(13, 9, f);
    const TriangleMesh solid = lens_solid(hm, lens, 0.75f, 4);
    const MeshCheck c = check_mesh(solid);
    REQUIRE(c.watertight());
    TempDir dir;
    io::write_stl(dir.path / "lens.stl", solid);
    const TriangleMesh back = io::read_stl(dir.path / "lens.stl");
    CHECK(back.vertices.size() == solid.vertices.size());
    CHECK(back.triangles.size() == solid.triangles.size());
    const MeshCheck cb = check_mesh(back);
    CHECK(cb.watertight());
    CHECK(std::abs(cb.volume - c.volume) < 1e-5 * c.volume);
    // The sheet as OBJ comes back exactly, normals included.
    const TriangleMesh sheet = tessellate_surface(hm, 0.75f, 2);
    io::write_obj(dir.path / "sheet.obj", sheet);
    const TriangleMesh sheet_back = io::read_obj(dir.path / "sheet.obj");
    CHECK(sheet_back.vertices == sheet.vertices);
    CHECK(sheet_back.triangles == sheet.triangles);
    REQUIRE(sheet_back.normals.size() == sheet.normals.size());
    for (std::size_t v = 0; v < sheet.normals.size(); ++v)
        CHECK(length(sheet_back.normals[v] - sheet.normals[v]) < 1e-15);
}

TEST_CASE("a fractional k: cells of ⌊k⌋ and ⌈k⌉ sub-cells a side, one sheet on the patches, a valid solid") {
    const int nx = 7, ny = 5;
    const double k = 2.5;
    const Heightmap hm = wavy(nx, ny);
    // 6 cells along u take round(c·2.5) = 0, 3, 5, 8, 10, 13, 15: 15 sub-cells; 4 along v take 10.
    const std::size_t fx = 16, fy = 11;
    const TriangleMesh m = tessellate_surface(hm, 0.75f, k, false);
    CHECK(m.vertices.size() == fx * fy);
    CHECK(m.triangles.size() == 2u * (fx - 1) * (fy - 1));
    const MeshCheck c = check_mesh(m);
    CHECK(c.manifold);
    CHECK(c.oriented);
    CHECK_FALSE(c.closed);
    CHECK(c.degenerate_triangles == 0);
    CHECK(c.boundary_edges == int(2 * ((fx - 1) + (fy - 1))));
    for (const auto& t : m.triangles) {
        const Vec3d n = cross(m.vertices[std::size_t(t[1])] - m.vertices[std::size_t(t[0])],
                              m.vertices[std::size_t(t[2])] - m.vertices[std::size_t(t[0])]);
        CHECK(n.z > 0);
    }
    // alpha = 0: the surface is the grid's flat triangles. Every vertex lies on them, and
    // each cell holds 2·kx·ky facets with kx, ky in {2, 3}, both of them somewhere.
    const TriangleMesh flat = tessellate_surface(hm, 0.0f, 1, false);
    const TriangleMesh fine = tessellate_surface(hm, 0.0f, k, false);
    for (const Vec3d& p : fine.vertices) {
        double w = 0;
        REQUIRE(mesh_height_at(flat, p.x, p.y, w));
        CHECK(std::abs(p.z - w) < 1e-12);
    }
    std::vector<int> per_cell(std::size_t(nx - 1) * (ny - 1), 0);
    for (const auto& t : fine.triangles) {
        Vec3d centre{0, 0, 0};
        for (std::int32_t v : t) centre = centre + fine.vertices[std::size_t(v)];
        centre = centre / 3.0;
        const int ci = std::clamp(int((centre.x + 0.04) / hm.du()), 0, nx - 2);
        const int cj = std::clamp(int((centre.y + 0.025) / hm.dv()), 0, ny - 2);
        ++per_cell[std::size_t(cj) * (nx - 1) + std::size_t(ci)];
    }
    for (int n : per_cell) CHECK((n == 8 || n == 12 || n == 18));
    CHECK(std::count(per_cell.begin(), per_cell.end(), 8) > 0);
    CHECK(std::count(per_cell.begin(), per_cell.end(), 18) > 0);
    // Lens solids over it, rectangular and elliptical: closed, their volume the prisms'.
    const Lens lens{1.49, 0.01};
    for (double kk : {1.5, 2.5, 3.25}) {
        const TriangleMesh solid = lens_solid(hm, lens, 0.75f, kk, false);
        const MeshCheck cs = check_mesh(solid);
        CHECK(cs.watertight());
        const double prisms = prism_volume(tessellate_surface(hm, 0.75f, kk, false), lens.thickness);
        CHECK(std::abs(cs.volume - prisms) < 1e-9 * prisms);
        const Heightmap oval = wavy(12, 9, tilted_frame(), Aperture::ellipse);
        CHECK(check_mesh(lens_solid(oval, lens, 0.75f, kk)).watertight());
    }
    // The facets' normal error at a fractional k lies between the whole levels around it.
    const double e2 = tessellation_normal_error(hm, 0.75, 2, 0.9), e25 = tessellation_normal_error(hm, 0.75, k, 0.9),
                 e3 = tessellation_normal_error(hm, 0.75, 3, 0.9);
    MESSAGE("90th percentile facet normal error: k = 2 ", e2, ", 2.5 ", e25, ", 3 ", e3, " rad");
    CHECK(e25 <= e2);
    CHECK(e25 >= e3);
    CHECK_THROWS_AS(tessellate_surface(hm, 0.75f, 0.9, false), InputError);
    CHECK_THROWS_AS(tessellate_surface(hm, 0.75f, NAN, false), InputError);
}

TEST_CASE("export arguments are checked") {
    const Heightmap hm = wavy(5, 4);
    CHECK_THROWS_AS(tessellate_surface(hm, 0.75f, 0), InputError);
    CHECK_THROWS_AS(tessellate_surface(hm, NAN, 2), InputError);
    CHECK_THROWS_AS(lens_solid(hm, Lens{1.49, 0.0}, 0.75f, 2), InputError);
    CHECK_THROWS_AS(lens_solid(hm, Lens{1.49, -1.0}, 0.75f, 2), InputError);
    // The back face must clear the front: the wavy surface dips to about -2.4 mm.
    CHECK_THROWS_AS(lens_solid(hm, Lens{1.49, 0.001}, 0.75f, 2), InputError);
    CHECK_NOTHROW(lens_solid(hm, Lens{1.49, 0.005}, 0.75f, 2));
}

TEST_CASE("smoothing lowers the Laplacian energy and keeps heights in bounds") {
    Heightmap hm(33, 25, {0.1, 0.08}, -0.001, 0.001);
    CounterRng rng(11);
    std::vector<float> noisy(hm.heights().size());
    for (float& h : noisy) h = float(rng.uniform(-0.0015, 0.0015));  // some clamp at the bounds
    hm.set_heights(noisy);
    const double e0 = laplacian_energy(hm);

    Heightmap half = hm;
    smooth_heights(half, 1, 0.5);
    Heightmap full = hm;
    smooth_heights(full, 1);
    Heightmap many = hm;
    smooth_heights(many, 5);
    const double e_half = laplacian_energy(half), e_full = laplacian_energy(full), e_many = laplacian_energy(many);
    MESSAGE("Laplacian energy: noisy ", e0, ", 1 pass at 0.5 ", e_half, ", 1 pass ", e_full, ", 5 passes ", e_many);
    CHECK(e_half < 0.5 * e0);
    CHECK(e_full < e_half);
    CHECK(e_many < 0.05 * e_full);
    for (const Heightmap* s : {&half, &full, &many})
        for (float h : s->heights()) {
            CHECK(h >= hm.h_min());
            CHECK(h <= hm.h_max());
        }
    // Normals are recomputed from the new heights.
    Heightmap fresh = many;
    fresh.set_heights(many.heights());
    CHECK(fresh.normals() == many.normals());
    CHECK_FALSE(many.normals() == hm.normals());

    // strength 0 and zero iterations change nothing.
    Heightmap same = hm;
    smooth_heights(same, 3, 0.0);
    CHECK(same.heights() == hm.heights());
    smooth_heights(same, 0);
    CHECK(same.heights() == hm.heights());
    CHECK_THROWS_AS(smooth_heights(same, -1), InputError);
    CHECK_THROWS_AS(smooth_heights(same, 1, 1.5), InputError);
    CHECK_THROWS_AS(smooth_heights(same, 1, NAN), InputError);
}

TEST_CASE("smoothing keeps a plane a plane") {
    const auto plane = [](double u, double v) { return 0.01 * u - 0.02 * v + 1e-4; };
    Heightmap hm = make_surface(17, 13, {0.1, 0.08}, -0.01, 0.01, plane);
    const Heightmap before = hm;
    smooth_heights(hm, 10);
    double worst = 0;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) worst = std::max(worst, std::abs(double(hm(i, j)) - double(before(i, j))));
    MESSAGE("plane after 10 passes: largest change ", worst, " m");
    CHECK(worst < 1e-9);  // a few float ulps of millimetre heights
    for (std::size_t v = 0; v < hm.normals().size(); ++v)
        CHECK(length(Vec3d(hm.normals()[v]) - Vec3d(before.normals()[v])) < 1e-6);
}
