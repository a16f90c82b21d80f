// The smooth exported form: the B-spline fitted to the designed surface
// (surface/bspline.hpp) and the grid sag table written from it (io/sag.hpp). The table is
// checked with a bicubic evaluator written here from the format's definition (16
// conditions per cell solved for the 16 coefficients of a bicubic polynomial), not with
// the reader's Hermite formula.
#include <doctest/doctest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Dense>

#include <freeform/io/sag.hpp>
#include <freeform/surface/bspline.hpp>

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

TEST_CASE("the grid sag table is the spline: an independent bicubic evaluator reproduces it") {
    const Heightmap hm = smooth_surface(41, 31);
    const BSplineSurface s = fit_bspline(hm, 1.0, 4);
    const std::filesystem::path f = "sag_test.dat";
    io::write_grid_sag(f, s);
    const RawSag raw = parse_raw(f);
    REQUIRE(raw.nx == 41);
    REQUIRE(raw.ny == 31);
    CHECK(raw.unit == 0);  // millimetres
    CHECK(raw.dx == doctest::Approx(1.0));  // 40 mm over 40 cells
    CHECK(raw.dy == doctest::Approx(1.0));
    REQUIRE(raw.rows.size() == std::size_t(41 * 31));
    // First point: the upper left corner (x = -20 mm, y = +15 mm).
    CHECK(raw.rows[0][0] == doctest::Approx(s.eval(-0.02, 0.015).z * 1e3).epsilon(1e-12));
    CHECK(raw.rows[1][0] == doctest::Approx(s.eval(-0.019, 0.015).z * 1e3).epsilon(1e-12));
    CHECK(raw.rows[41][0] == doctest::Approx(s.eval(-0.02, 0.014).z * 1e3).epsilon(1e-12));
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> ux(-0.02, 0.02), vy(-0.015, 0.015);
    double dz = 0, dslope = 0;
    for (int n = 0; n < 300; ++n) {
        const double u = ux(rng), v = vy(rng);
        const auto t = raw_eval(raw, u * 1e3, v * 1e3);
        const SplineSample q = s.eval(u, v);
        dz = std::max(dz, std::abs(t[0] * 1e-3 - q.z));
        dslope = std::max({dslope, std::abs(t[1] - q.z_u), std::abs(t[2] - q.z_v)});
    }
    CHECK(dz < 1e-10);       // 0.1 nm: the table is the spline, to the digits written
    CHECK(dslope < 1e-8);    // 0.01 µrad
    // The library's reader and evaluator agree with it.
    const io::GridSag g = io::read_grid_sag(f);
    for (int n = 0; n < 100; ++n) {
        const double u = ux(rng), v = vy(rng);
        const SplineSample a = g.eval(u, v), b = s.eval(u, v);
        CHECK(std::abs(a.z - b.z) < 1e-10);
        CHECK(std::abs(a.z_u - b.z_u) < 1e-8);
        CHECK(std::abs(a.z_v - b.z_v) < 1e-8);
    }
    // Against the designed surface's own vertices (heights, and the vertex normals the
    // Phong patches are built from), away from the rim where one-sided differences make
    // the normals: within half a micrometre and a milliradian (the fit's smoothing of the
    // patches' kinks, see above).
    double vz = 0, vslope = 0;
    for (int j = 1; j + 1 < hm.ny(); ++j)
        for (int i = 1; i + 1 < hm.nx(); ++i) {
            const SplineSample q = g.eval(hm.u_of(i), hm.v_of(j));
            vz = std::max(vz, std::abs(q.z - double(hm(i, j))));
            const Vec3d n = normalize(Vec3d(hm.normals()[std::size_t(j) * hm.nx() + i]));
            vslope = std::max(vslope, std::acos(std::min(1.0, dot(q.normal(), n))));
        }
    MESSAGE("grid sag at the vertices: heights within " << vz * 1e6 << " um, normals within " << vslope * 1e3
                                                          << " mrad");
    CHECK(vz < 5e-7);
    CHECK(vslope < 1e-3);
}

TEST_CASE("grid sag reader: bad files are refused with the line") {
    const std::filesystem::path f = "bad.dat";
    const auto write = [&](const std::string& text) { std::ofstream(f) << text; };
    write("3 3 1 1 0 0 0\n0 0 0 0 0\n");
    CHECK_THROWS_AS(io::read_grid_sag(f), InputError);  // too few points
    write("3 3 1 1 7 0 0\n");
    CHECK_THROWS_WITH_AS(io::read_grid_sag(f), doctest::Contains("unit flag"), InputError);
    write("2 2 1 1 0 0 0\n0 0 0 0 0\n0 0 0 0 0\nx 0 0 0 0\n0 0 0 0 0\n");
    CHECK_THROWS_WITH_AS(io::read_grid_sag(f), doctest::Contains("line 4"), InputError);
    CHECK_THROWS_AS(io::read_grid_sag("no-such-file.dat"), IoError);
}
