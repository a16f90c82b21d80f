// The smooth exported forms: the B-spline fitted to the designed surface for the STEP
// part (surface/bspline.hpp), and the grid sag table (io/sag.hpp), which carries the
// height map's own vertices and vertex-normal slopes. The table is checked with a bicubic
// evaluator written here from the format's definition (16 conditions per cell solved for
// the 16 coefficients of a bicubic polynomial), not with the reader's Hermite formula.
#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <algorithm>
#include <array>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include <freeform/io/sag.hpp>
#include <freeform/surface/bspline.hpp>
#include <freeform/surface/export.hpp>

#include "files.hpp"
#include "support.hpp"

using namespace freeform;

namespace {

// A smooth surface with curvature in both directions and a twist, about 0.3 mm of sag
// over a 40 × 30 mm rectangle.
double smooth_shape(double u, double v) {
    return 0.08 * u * u - 0.05 * v * v + 0.3 * u * v + 2e-4 * std::sin(90 * u) * std::cos(70 * v);
}

Heightmap smooth_surface(int nx, int ny) {
    Heightmap hm(nx, ny, {0.04, 0.03}, -0.01, 0.01);
    testing::shape(hm, smooth_shape);
    return hm;
}

// The file's numbers, parsed here without the library's reader.
struct RawSag {
    int nx = 0, ny = 0, unit = -1;
    double dx = 0, dy = 0, xdec = 0, ydec = 0;
    std::vector<std::array<double, 5>> rows;  // in file order
};

RawSag parse_raw(const std::filesystem::path& f) {
    std::ifstream in(f);
    RawSag r;
    in >> r.nx >> r.ny >> r.dx >> r.dy >> r.unit >> r.xdec >> r.ydec;
    std::array<double, 5> row{};
    while (in >> row[0] >> row[1] >> row[2] >> row[3] >> row[4]) r.rows.push_back(row);
    return r;
}

// The bicubic polynomial sum a_pq s^p t^q on one cell (s, t ∈ [0, 1], s along x) from the
// four corners' z, z_s, z_t, z_st, solved as a 16 × 16 linear system.
Eigen::Matrix<double, 16, 1> cell_coefficients(const double (&c)[4][4]) {
    // c[corner][0..3] = z, z_s, z_t, z_st at corners (0,0), (1,0), (0,1), (1,1).
    Eigen::Matrix<double, 16, 16> A = Eigen::Matrix<double, 16, 16>::Zero();
    Eigen::Matrix<double, 16, 1> b;
    const double corner[4][2] = {{0, 0}, {1, 0}, {0, 1}, {1, 1}};
    int row = 0;
    for (int k = 0; k < 4; ++k)
        for (int what = 0; what < 4; ++what, ++row) {
            const double s = corner[k][0], t = corner[k][1];
            for (int p = 0; p < 4; ++p)
                for (int q = 0; q < 4; ++q) {
                    const bool ds = what == 1 || what == 3, dt = what == 2 || what == 3;
                    if ((ds && p == 0) || (dt && q == 0)) continue;
                    const double fs = ds ? p * std::pow(s, p - 1) : std::pow(s, p);
                    const double ft = dt ? q * std::pow(t, q - 1) : std::pow(t, q);
                    A(row, 4 * p + q) = fs * ft;
                }
            b(row) = c[k][what];
        }
    return A.fullPivLu().solve(b);
}

// Evaluates the table at (x, y) (millimetres, the file's units) from its raw numbers.
std::array<double, 3> raw_eval(const RawSag& r, double x, double y) {
    const double x0 = r.xdec - 0.5 * (r.nx - 1) * r.dx, ytop = r.ydec + 0.5 * (r.ny - 1) * r.dy;
    const double fx = (x - x0) / r.dx, fy = (ytop - y) / r.dy;  // rows run from the top down
    const int i = std::min(int(fx), r.nx - 2), row = std::min(int(fy), r.ny - 2);
    const double s = fx - i, down = fy - row;
    // Cell corners with t running along +y: the lower row of the cell is file row row+1.
    const auto at = [&](int rr, int ii) { return r.rows[std::size_t(rr) * std::size_t(r.nx) + std::size_t(ii)]; };
    double c[4][4];
    const int rows_of[4] = {row + 1, row + 1, row, row}, cols_of[4] = {i, i + 1, i, i + 1};
    for (int k = 0; k < 4; ++k) {
        const auto v = at(rows_of[k], cols_of[k]);
        c[k][0] = v[0], c[k][1] = v[1] * r.dx, c[k][2] = v[2] * r.dy, c[k][3] = v[3] * r.dx * r.dy;
    }
    const auto a = cell_coefficients(c);
    const double t = 1 - down;
    double z = 0, zs = 0, zt = 0;
    for (int p = 0; p < 4; ++p)
        for (int q = 0; q < 4; ++q) {
            z += a(4 * p + q) * std::pow(s, p) * std::pow(t, q);
            if (p > 0) zs += a(4 * p + q) * p * std::pow(s, p - 1) * std::pow(t, q);
            if (q > 0) zt += a(4 * p + q) * q * std::pow(s, p) * std::pow(t, q - 1);
        }
    return {z, zs / r.dx, zt / r.dy};
}


// How far the table's bicubic surface (raw_eval) lies from the designed Phong patches
// between the vertices: at 3 × 3 points inside every cell (the cells of the outermost
// ring, whose border vertices carry one-sided normals, or all the others), heights
// compared at the patch point's own (x, y) and slopes against the patch's own normal.
struct Departure {
    double max_dz = 0, p90_dz = 0, max_slope = 0, p90_slope = 0;  // metres, radians
};

Departure departure_from_patches(const RawSag& r, const Heightmap& hm, double alpha, bool border_ring) {
    std::vector<double> dz, ds;
    for (int cj = 0; cj + 1 < hm.ny(); ++cj)
        for (int ci = 0; ci + 1 < hm.nx(); ++ci) {
            const bool ring = ci == 0 || cj == 0 || ci + 2 == hm.nx() || cj + 2 == hm.ny();
            if (ring != border_ring) continue;
            for (int m = 1; m <= 3; ++m)
                for (int n = 1; n <= 3; ++n) {
                    // Off the diagonal too: a = b lies on the edge between the two patches.
                    const double a = 0.25 * n + 0.05, b = 0.25 * m - 0.03;
                    const PhongVertex p = phong_vertex_in_cell(hm, ci, cj, a, b, alpha);
                    const auto t = raw_eval(r, p.position.x * 1e3, p.position.y * 1e3);
                    dz.push_back(std::abs(t[0] * 1e-3 - p.position.z));
                    const double sx = -p.normal.x / p.normal.z, sy = -p.normal.y / p.normal.z;
                    ds.push_back(std::max(std::abs(t[1] - sx), std::abs(t[2] - sy)));
                }
        }
    const auto p90 = [](std::vector<double> v) {
        const auto k = std::ptrdiff_t(0.9 * double(v.size() - 1));
        std::nth_element(v.begin(), v.begin() + k, v.end());
        return v[std::size_t(k)];
    };
    return {*std::max_element(dz.begin(), dz.end()), p90(dz), *std::max_element(ds.begin(), ds.end()), p90(ds)};
}

}  // namespace

TEST_CASE("the fitted spline follows the designed surface, closer as the grid is refined") {
    const Heightmap hm = smooth_surface(41, 31);
    const BSplineSurface s = fit_bspline(hm, 1.0, 4);
    CHECK(s.nu == 43);
    CHECK(s.nv == 33);
    const SplineFitReport r = check_spline_fit(s, hm, 1.0, 4);
    // The Phong patches have kinks of their normal across cell edges that a C² spline
    // smooths over: heights within a fraction of a micrometre, normals within a milliradian.
    CHECK(r.max_height_error < 1e-6);
    CHECK(r.p90_normal_error < 1e-3);
    // Refined 2× the kinks shrink, and so does the spline's distance to the patches.
    const Heightmap fine = smooth_surface(81, 61);
    const SplineFitReport rf = check_spline_fit(fit_bspline(fine, 1.0, 4), fine, 1.0, 4);
    CHECK(rf.max_height_error < 0.5 * r.max_height_error);
    CHECK(rf.p90_normal_error < 0.6 * r.p90_normal_error);  // first order in the cell size
    // The poles' (u, v) make the spline a graph over its rectangle: its corners are the grid's.
    CHECK(s.u_min() == doctest::Approx(hm.u_of(0)).epsilon(1e-15));
    CHECK(s.v_max() == doctest::Approx(hm.v_of(hm.ny() - 1)).epsilon(1e-15));
    // Derivatives agree with finite differences of the spline itself.
    const double u = 0.0031, v = -0.0047, e = 1e-6;
    const SplineSample q = s.eval(u, v);
    CHECK(q.z_u == doctest::Approx((s.eval(u + e, v).z - s.eval(u - e, v).z) / (2 * e)).epsilon(1e-6));
    CHECK(q.z_v == doctest::Approx((s.eval(u, v + e).z - s.eval(u, v - e).z) / (2 * e)).epsilon(1e-6));
    CHECK(q.z_uv == doctest::Approx((s.eval(u + e, v).z_v - s.eval(u - e, v).z_v) / (2 * e)).epsilon(1e-5));
    CHECK_THROWS_AS(fit_bspline(hm, 1.0, 1), InputError);
}

TEST_CASE("a cubic is fitted exactly: the spline space holds it") {
    Heightmap hm(21, 17, {0.02, 0.016}, -0.01, 0.01);
    const auto cubic = [](double u, double v) { return 2.0 * u * u * u - 3.0 * u * v * v + 0.1 * u - 0.2 * v; };
    testing::shape(hm, cubic);
    // The fit samples the Phong patches, which only approach the cubic; on a 1 mm grid
    // with slopes of 0.2 they stay within a micrometre of it, and so must the spline.
    const BSplineSurface s = fit_bspline(hm, 1.0, 4);
    double worst = 0;
    for (int n = 0; n <= 50; ++n)
        for (int m = 0; m <= 50; ++m) {
            const double u = -0.01 + 0.02 * n / 50, v = -0.008 + 0.016 * m / 50;
            worst = std::max(worst, std::abs(s.eval(u, v).z - cubic(u, v)));
        }
    CHECK(worst < 1e-6);
}

TEST_CASE("the grid sag table carries the designed vertices and their normals") {
    const Heightmap hm = smooth_surface(41, 31);
    const testing::TempDir dir;
    const std::filesystem::path f = dir / "sag_test.dat";
    io::write_grid_sag(f, hm);
    const RawSag raw = parse_raw(f);
    REQUIRE(raw.nx == 41);
    REQUIRE(raw.ny == 31);
    CHECK(raw.unit == 0);  // millimetres
    CHECK(raw.dx == doctest::Approx(1.0));  // 40 mm over 40 cells
    CHECK(raw.dy == doctest::Approx(1.0));
    CHECK(raw.xdec == 0);
    CHECK(raw.ydec == 0);
    REQUIRE(raw.rows.size() == std::size_t(41 * 31));
    // Every vertex, the file's rows from the top (+y, j = ny − 1) down: the height map's
    // height (float, written in 13 digits) and the slopes of its vertex normal.
    double vz = 0, vslope = 0, twist = 0;
    int nodata = 0;
    for (int row = 0; row < raw.ny; ++row)
        for (int i = 0; i < raw.nx; ++i) {
            const int j = raw.ny - 1 - row;
            const auto& v = raw.rows[std::size_t(row) * std::size_t(raw.nx) + std::size_t(i)];
            nodata += v[4] != 0;
            const Vec3d n = Vec3d(hm.normals()[std::size_t(j) * std::size_t(hm.nx()) + std::size_t(i)]);
            vz = std::max(vz, std::abs(v[0] * 1e-3 - double(hm(i, j))));
            vslope = std::max({vslope, std::abs(v[1] + n.x / n.z), std::abs(v[2] + n.y / n.z)});
            if (i == 0 || j == 0 || i + 1 == hm.nx() || j + 1 == hm.ny()) continue;
            // Inside, the twist is the four-point cross difference of the heights (1/mm).
            const double cross = (double(hm(i + 1, j + 1)) - hm(i - 1, j + 1) - hm(i + 1, j - 1) + hm(i - 1, j - 1)) /
                                 (4 * hm.du() * hm.dv());
            twist = std::max(twist, std::abs(v[3] * 1e3 - cross));
        }
    MESSAGE("grid sag at the vertices: heights within " << vz * 1e6 << " um, slopes within " << vslope * 1e3
                                                          << " mrad of the height map's");
    CHECK(nodata == 0);
    CHECK(vz < 1e-7);       // goal: 0.1 um (it is the float heights' rounding)
    CHECK(vslope < 1e-5);   // goal: 0.01 mrad
    CHECK(twist < 1e-3);    // 1/m: the heights' float rounding over 4 du dv = 4 mm²
    // The library's reader gives them back at the vertices' (u, v), rows in the right order.
    const io::GridSag g = io::read_grid_sag(f);
    double rz = 0, rn = 0;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) {
            const SplineSample q = g.eval(hm.u_of(i), hm.v_of(j));
            rz = std::max(rz, std::abs(q.z - double(hm(i, j))));
            const Vec3d n = normalize(Vec3d(hm.normals()[std::size_t(j) * std::size_t(hm.nx()) + std::size_t(i)]));
            rn = std::max(rn, std::acos(std::min(1.0, dot(q.normal(), n))));
        }
    CHECK(rz < 1e-7);
    CHECK(rn < 1e-5);
    // The reader's Hermite formula and the independent evaluator agree between vertices.
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> ux(-0.02, 0.02), vy(-0.015, 0.015);
    for (int n = 0; n < 200; ++n) {
        const double u = ux(rng), v = vy(rng);
        const auto t = raw_eval(raw, u * 1e3, v * 1e3);
        const SplineSample q = g.eval(u, v);
        CHECK(std::abs(t[0] * 1e-3 - q.z) < 1e-12);
        CHECK(std::abs(t[1] - q.z_u) < 1e-9);
        CHECK(std::abs(t[2] - q.z_v) < 1e-9);
    }
}

TEST_CASE("between the vertices the grid sag's bicubic surface follows the designed Phong patches") {
    const Heightmap hm = smooth_surface(41, 31);
    const double alpha = 0.5;  // the scenes' default phong_alpha
    const testing::TempDir dir;
    const std::filesystem::path f = dir / "sag_between.dat";
    io::write_grid_sag(f, hm);
    const RawSag raw = parse_raw(f);
    REQUIRE(raw.rows.size() == std::size_t(41 * 31));
    const Departure d = departure_from_patches(raw, hm, alpha, false);
    const Departure ring = departure_from_patches(raw, hm, alpha, true);
    MESSAGE("grid sag between the vertices vs the Phong patches (alpha 0.5, 1 mm cells): inside, heights max "
            << d.max_dz * 1e9 << " nm, p90 " << d.p90_dz * 1e9 << " nm; slopes max " << d.max_slope * 1e3
            << " mrad, p90 " << d.p90_slope * 1e3 << " mrad. Outermost ring of cells: heights max "
            << ring.max_dz * 1e9 << " nm, p90 " << ring.p90_dz * 1e9 << " nm; slopes max " << ring.max_slope * 1e3
            << " mrad, p90 " << ring.p90_slope * 1e3 << " mrad");
    // Inside, measured 5.0 nm / 0.020 mrad at most (3.3 nm / 0.015 mrad p90): a cubic and
    // the quadratic patches built from the same corner data, and the patches' kinks
    // across edges. The bounds are twice that, and tight enough to catch a wrong
    // derivative (below).
    const double bound_dz = 1e-8, bound_slope = 4e-5;  // 10 nm, 0.04 mrad
    CHECK(d.max_dz < bound_dz);
    CHECK(d.max_slope < bound_slope);
    // The outermost ring depends on the border normals' stencil: 3.4 nm / 0.014 mrad with
    // second-order one-sided slopes, 43 nm / 0.21 mrad with two-point ones (the slope half
    // a cell inwards, which a cubic and a Phong patch bend differently).
    CHECK(ring.max_dz < 1e-7);
    CHECK(ring.max_slope < 5e-4);
    // The same table with its slope columns swapped, dz/dy of the wrong sign, the twist's
    // sign flipped or the twist left out fails the inside bounds.
    const auto mutated = [&](auto&& change) {
        RawSag m = raw;
        for (auto& row : m.rows) change(row);
        const Departure e = departure_from_patches(m, hm, alpha, false);
        MESSAGE("  mutated: heights max " << e.max_dz * 1e9 << " nm, slopes max " << e.max_slope * 1e3 << " mrad");
        return e;
    };
    const Departure swapped = mutated([](std::array<double, 5>& r) { std::swap(r[1], r[2]); });
    CHECK((swapped.max_dz > bound_dz || swapped.max_slope > bound_slope));
    const Departure sign = mutated([](std::array<double, 5>& r) { r[2] = -r[2]; });
    CHECK((sign.max_dz > bound_dz || sign.max_slope > bound_slope));
    const Departure twist = mutated([](std::array<double, 5>& r) { r[3] = -r[3]; });
    CHECK((twist.max_dz > bound_dz || twist.max_slope > bound_slope));
    const Departure flat = mutated([](std::array<double, 5>& r) { r[3] = 0; });
    CHECK((flat.max_dz > bound_dz || flat.max_slope > bound_slope));
}

TEST_CASE("the STEP part's Hermite spline is the grid sag table's surface") {
    // A design-like height map: curved, twisted and rippled at the cell scale.
    Heightmap hm(41, 31, {0.04, 0.03}, -0.01, 0.01);
    testing::shape(hm, [](double u, double v) { return smooth_shape(u, v) + 3e-6 * std::sin(2500 * u + 1800 * v); });
    const BSplineSurface s = hermite_bspline(hm);
    CHECK(s.hermite);
    CHECK(s.nu == 82);
    CHECK(s.nv == 62);
    // At the vertices: the height map's heights and vertex normals.
    double vz = 0, vn = 0;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) {
            const SplineSample q = s.eval(hm.u_of(i), hm.v_of(j));
            vz = std::max(vz, std::abs(q.z - double(hm(i, j))));
            const Vec3d n = normalize(Vec3d(hm.normals()[std::size_t(j) * std::size_t(hm.nx()) + std::size_t(i)]));
            vn = std::max(vn, std::acos(std::min(1.0, dot(q.normal(), n))));
        }
    CHECK(vz < 1e-15);
    CHECK(vn < 1e-6);  // the normals are floats
    // Everywhere: the table's bicubic surface by this file's own evaluator (16 × 16 solve
    // per cell), against the spline's Cox–de Boor evaluation.
    const testing::TempDir dir;
    const std::filesystem::path f = dir / "sag_hermite.dat";
    io::write_grid_sag(f, hm);
    const RawSag raw = parse_raw(f);
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> ux(-0.02, 0.02), vy(-0.015, 0.015);
    double dz = 0, ds = 0;
    for (int n = 0; n < 400; ++n) {
        const double u = ux(rng), v = vy(rng);
        const auto t = raw_eval(raw, u * 1e3, v * 1e3);
        const SplineSample q = s.eval(u, v);
        dz = std::max(dz, std::abs(t[0] * 1e-3 - q.z));
        ds = std::max({ds, std::abs(t[1] - q.z_u), std::abs(t[2] - q.z_v)});
    }
    MESSAGE("Hermite spline against the sag table's bicubic surface: heights within " << dz << " m, slopes within "
                                                                                     << ds);
    CHECK(dz < 1e-12);  // the table's 13 digits
    CHECK(ds < 1e-9);
}

TEST_CASE("grid sag reader: bad files are refused with the line") {
    const testing::TempDir dir;
    const std::filesystem::path f = dir / "bad.dat";
    const auto write = [&](const std::string& text) { std::ofstream(f) << text; };
    write("3 3 1 1 0 0 0\n0 0 0 0 0\n");
    CHECK_THROWS_AS(io::read_grid_sag(f), InputError);  // too few points
    write("3 3 1 1 7 0 0\n");
    CHECK_THROWS_WITH_AS(io::read_grid_sag(f), doctest::Contains("unit flag"), InputError);
    write("2 2 1 1 0 0 0\n0 0 0 0 0\n0 0 0 0 0\nx 0 0 0 0\n0 0 0 0 0\n");
    CHECK_THROWS_WITH_AS(io::read_grid_sag(f), doctest::Contains("line 4"), InputError);
    CHECK_THROWS_AS(io::read_grid_sag("no-such-file.dat"), IoError);
}
