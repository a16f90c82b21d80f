// STEP export through Open CASCADE (io/step.hpp): the part written from a fitted spline is
// read back by OCCT and judged on OCCT's geometry — valid, one closed solid, the volume
// under the spline, and the re-read top face's heights and normals against
// BSplineSurface::eval. Without freeform::step (no OCCT) the file has no test cases.
#include <doctest/doctest.h>

#if defined(FREEFORM_WITH_OCCT)

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <string>
#include <vector>

#include <freeform/io/step.hpp>
#include <freeform/surface/bspline.hpp>

#include "files.hpp"
#include "support.hpp"

using namespace freeform;

namespace {

struct TempDir : testing::TempDir {
    TempDir() : testing::TempDir("freeform_test_step_") {}
};

// A tilted paraboloid with a ripple: curved in both directions, no symmetry that could
// hide a swapped u/v or a mirrored axis.
double smooth_shape(double u, double v) {
    return 0.0004 + 0.05 * u - 0.02 * v + 2.0 * u * u + 1.2 * v * v + 0.0002 * std::sin(400 * u) * std::cos(300 * v);
}

// The least-squares spline (one knot per grid line) or the Hermite one (double knots).
BSplineSurface smooth_spline(int nx, int ny, Vec2d size, bool hermite = false) {
    Heightmap hm(nx, ny, size, -0.01, 0.01);
    freeform::testing::shape(hm, smooth_shape);
    return hermite ? hermite_bspline(hm) : fit_bspline(hm, 1.0, 4);
}

double lowest_pole(const BSplineSurface& s) { return *std::min_element(s.z.begin(), s.z.end()); }

// ∫∫ (z − back_w) du dv by 3-point Gauss–Legendre on every knot span of both directions:
// exact (to rounding) for the bicubic pieces, and independent of OCCT.
double volume_under(const BSplineSurface& s, double back_w) {
    const std::array<double, 3> x{-std::sqrt(0.6), 0.0, std::sqrt(0.6)}, w{5.0 / 9, 8.0 / 9, 5.0 / 9};
    double sum = 0;
    for (std::size_t a = 0; a + 1 < s.knots_u.size(); ++a) {
        const double u0 = s.knots_u[a], u1 = s.knots_u[a + 1];
        if (!(u1 > u0)) continue;
        for (std::size_t b = 0; b + 1 < s.knots_v.size(); ++b) {
            const double v0 = s.knots_v[b], v1 = s.knots_v[b + 1];
            if (!(v1 > v0)) continue;
            double cell = 0;
            for (int p = 0; p < 3; ++p)
                for (int q = 0; q < 3; ++q) {
                    const double u = 0.5 * (u0 + u1) + 0.5 * (u1 - u0) * x[std::size_t(p)];
                    const double v = 0.5 * (v0 + v1) + 0.5 * (v1 - v0) * x[std::size_t(q)];
                    cell += w[std::size_t(p)] * w[std::size_t(q)] * (s.eval(u, v).z - back_w);
                }
            sum += cell * 0.25 * (u1 - u0) * (v1 - v0);
        }
    }
    return sum;
}

std::string file_text(const std::filesystem::path& p) {
    std::ifstream in(p, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

double angle_between(Vec3d a, Vec3d b) { return std::atan2(length(cross(a, b)), dot(a, b)); }

}  // namespace

TEST_CASE("STEP part of a spline: one valid closed solid, its volume, and OCCT's top face equals the spline") {
    const Vec2d size{0.020, 0.015};
    BSplineSurface s;
    SUBCASE("the least-squares spline") { s = smooth_spline(41, 33, size); }
    SUBCASE("the Hermite spline: double knots, four times the poles") {
        s = smooth_spline(41, 33, size, true);
        CHECK(s.nu == 82);
        CHECK(s.nv == 66);
    }
    TempDir dir;
    const auto file = dir.path / "part.step";
    io::StepSolid solid;
    solid.back_w = lowest_pole(s) - 0.002;
    solid.name = "test part 'A'";
    io::write_step(file, s, solid);
    REQUIRE(std::filesystem::exists(file));

    // What the file says of itself: AP214, millimetres, our product name.
    const std::string text = file_text(file);
    CHECK(text.find("AUTOMOTIVE_DESIGN") != std::string::npos);
    CHECK(text.find("SI_UNIT(.MILLI.,.METRE.)") != std::string::npos);
    CHECK(text.find("PRODUCT('test part ''A''','test part ''A''',") != std::string::npos);  // quotes doubled
    CHECK(text.find("B_SPLINE_SURFACE_WITH_KNOTS") != std::string::npos);

    const io::StepPart part = io::read_step(file);
    CHECK(part.is_valid());
    CHECK(part.solid_count() == 1);
    CHECK(part.closed());

    const double expected = volume_under(s, solid.back_w);
    const double volume = part.volume_m3();
    MESSAGE("OCCT volume " << volume << " m^3, quadrature " << expected << " m^3, relative difference "
                           << (volume - expected) / expected);
    CHECK(volume > 0);
    CHECK(std::abs(volume - expected) <= 1e-6 * expected);

    // The re-read surface's parameter rectangle is the spline's, in mm.
    CHECK(part.s_min == doctest::Approx(s.u_min() * 1000).epsilon(1e-12));
    CHECK(part.s_max == doctest::Approx(s.u_max() * 1000).epsilon(1e-12));
    CHECK(part.t_min == doctest::Approx(s.v_min() * 1000).epsilon(1e-12));
    CHECK(part.t_max == doctest::Approx(s.v_max() * 1000).epsilon(1e-12));

    // Heights and normals at random points, the corners and edge midpoints.
    std::mt19937 rng(20240611);
    std::uniform_real_distribution<double> uu(s.u_min(), s.u_max()), vv(s.v_min(), s.v_max());
    std::vector<std::array<double, 2>> at;
    for (int k = 0; k < 200; ++k) at.push_back({uu(rng), vv(rng)});
    for (const double u : {s.u_min(), 0.0, s.u_max()})
        for (const double v : {s.v_min(), 0.0, s.v_max()}) at.push_back({u, v});
    double worst_dz = 0, worst_xy = 0, worst_angle = 0;
    for (const auto& [u, v] : at) {
        const SplineSample ref = s.eval(u, v);
        const Vec3d p = part.point_m(u, v);
        worst_dz = std::max(worst_dz, std::abs(p.z - ref.z));
        worst_xy = std::max({worst_xy, std::abs(p.x - u), std::abs(p.y - v)});
        const Vec3d n = part.normal(u, v);
        CHECK(std::abs(length(n) - 1) < 1e-12);
        CHECK(n.z > 0);
        worst_angle = std::max(worst_angle, angle_between(n, ref.normal()));
    }
    MESSAGE("re-read top face against BSplineSurface::eval: worst height " << worst_dz << " m, sideways "
                                                                         << worst_xy << " m, normal " << worst_angle << " rad");
    CHECK(worst_dz <= 1e-9);
    CHECK(worst_xy <= 1e-12);
    CHECK(worst_angle <= 1e-7);

    // Outside the rectangle the sampler clamps, as BSplineSurface::eval does.
    const Vec3d out = part.point_m(s.u_max() + 0.01, s.v_min() - 0.01);
    CHECK(std::abs(out.z - s.eval(s.u_max(), s.v_min()).z) <= 1e-9);
}

TEST_CASE("STEP export: an elliptical aperture's spline still gives the rectangular part") {
    Heightmap hm(21, 17, {0.02, 0.015}, -0.01, 0.01, Frame{}, Aperture::ellipse);
    freeform::testing::shape(hm, smooth_shape);
    const BSplineSurface s = fit_bspline(hm, 1.0, 4);
    TempDir dir;
    const auto file = dir.path / "ellipse.step";
    io::write_step(file, s, {lowest_pole(s) - 0.001});
    const io::StepPart part = io::read_step(file);
    CHECK(part.is_valid());
    CHECK(part.closed());
    const double expected = volume_under(s, lowest_pole(s) - 0.001);
    CHECK(std::abs(part.volume_m3() - expected) <= 1e-6 * expected);
    // A corner, outside the ellipse, is on the part.
    CHECK(std::abs(part.point_m(s.u_min(), s.v_max()).z - s.eval(s.u_min(), s.v_max()).z) <= 1e-9);
}

TEST_CASE("STEP export and import errors") {
    const BSplineSurface s = smooth_spline(9, 7, {0.01, 0.01});
    TempDir dir;
    SUBCASE("back face not below the surface") {
        const double lowest = lowest_pole(s);
        CHECK_THROWS_AS(io::write_step(dir.path / "a.step", s, {lowest}), InputError);
        CHECK_THROWS_AS(io::write_step(dir.path / "a.step", s, {lowest + 0.001}), InputError);
        CHECK_THROWS_AS(io::write_step(dir.path / "a.step", s, {std::nan("")}), InputError);
        try {
            io::write_step(dir.path / "a.step", s, {lowest + 0.001});
        } catch (const InputError& e) {
            CHECK(std::string(e.what()).find("back_w") != std::string::npos);
        }
        CHECK_FALSE(std::filesystem::exists(dir.path / "a.step"));
    }
    SUBCASE("malformed spline") {
        BSplineSurface bad = s;
        bad.z.pop_back();
        CHECK_THROWS_AS(io::write_step(dir.path / "b.step", bad, {-1.0}), InputError);
    }
    SUBCASE("unwritable place") {
        // Under a regular file, where no folder can be made.
        { std::ofstream(dir.path / "a-file") << "x"; }
        const auto file = dir.path / "a-file" / "c.step";
        try {
            io::write_step(file, s, {lowest_pole(s) - 0.001});
            FAIL("no exception");
        } catch (const IoError& e) {
            CHECK(std::string(e.what()).find(file.string()) != std::string::npos);
        }
    }
    SUBCASE("missing and unreadable files") {
        const auto missing = dir.path / "missing.step";
        CHECK_THROWS_AS((void)io::read_step(missing), IoError);
        try {
            (void)io::read_step(missing);
        } catch (const IoError& e) {
            CHECK(std::string(e.what()).find(missing.string()) != std::string::npos);
        }
        const auto junk = dir.path / "junk.step";
        std::ofstream(junk) << "this is not a STEP file\n";
        CHECK_THROWS_AS((void)io::read_step(junk), IoError);
        CHECK_THROWS_AS((void)io::read_step(dir.path), IoError);  // a folder
    }
}

TEST_CASE("STEP export of a 513 x 513 grid: size and time") {
    Heightmap hm(513, 513, {0.1, 0.1}, -0.05, 0.05);
    freeform::testing::shape(hm, [](double u, double v) { return smooth_shape(0.2 * u, 0.15 * v); });
    const BSplineSurface s = fit_bspline(hm, 1.0, 2);
    REQUIRE(s.nu == 515);
    TempDir dir;
    const auto file = dir.path / "large.step";
    const auto t0 = std::chrono::steady_clock::now();
    io::write_step(file, s, {lowest_pole(s) - 0.005});
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double megabytes = double(std::filesystem::file_size(file)) / 1e6;
    MESSAGE("513 x 513 grid (515 x 515 poles): write_step " << seconds << " s, " << megabytes << " MB");
    CHECK(megabytes < 50);
    // The time is reported, not asserted: speed is measured in benchmarks/, not tests.

    // Read back (a few seconds): still one closed solid with the spline's heights.
    const io::StepPart part = io::read_step(file);
    CHECK(part.solid_count() == 1);
    CHECK(part.closed());
    for (const auto& [u, v] : {std::array<double, 2>{-0.05, -0.05}, {0.0123, -0.0377}, {0.049, 0.031}})
        CHECK(std::abs(part.point_m(u, v).z - s.eval(u, v).z) <= 1e-9);
}

#endif  // FREEFORM_WITH_OCCT
