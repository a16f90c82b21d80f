// The machinist's report (design/machining.hpp) against surfaces with known answers: a
// spherical bowl (every principal curvature 1/R), a paraboloid (radius of curvature 2f at
// its apex), a saddle and a dome (nothing concave), and on a design's start surface
// against an independent computation (Eigen's eigenvalues of the shape operator).
#include <doctest/doctest.h>

#include <cmath>
#include <functional>

#include <Eigen/Dense>

#include <freeform/design/fabrication.hpp>
#include <freeform/design/machining.hpp>
#include <freeform/design/designer.hpp>
#include <freeform/objective/penalty.hpp>
#include <freeform/io/scene_json.hpp>
#include <freeform/surface/tool.hpp>
#include <freeform/design/start.hpp>
#include <freeform/surface/export.hpp>

#include "start_support.hpp"
#include "support.hpp"

using namespace freeform;

namespace {

Heightmap shaped(int n, const std::function<double(double, double)>& h, double size = 0.1) {
    Scene s = testing::basic_scene();
    s.surface.size = {size, size};
    s.surface.h_min = -1;
    s.surface.h_max = 1;
    Heightmap hm = testing::surface_for(s, n);
    testing::shape(hm, h);
    return hm;
}

// Largest positive eigenvalue of I⁻¹ II (Eigen's eigen-solver, not the report's closed
// form) for the derivatives hu, hv, huu, huv, hvv.
double kappa_max(double hu, double hv, double huu, double huv, double hvv) {
    Eigen::Matrix2d I, II;
    I << 1 + hu * hu, hu * hv, hu * hv, 1 + hv * hv;
    II << huu, huv, huv, hvv;
    II /= std::sqrt(1 + hu * hu + hv * hv);
    const Eigen::Vector2cd k = (I.inverse() * II).eigenvalues();
    return std::max({0.0, k(0).real(), k(1).real()});
}

// Smallest concave radius with the derivatives from least-squares quadratic fits over
// each vertex's (2w + 1)² neighbourhood; w = 0 takes central differences instead.
double independent_min_concave_radius(const Heightmap& h, int w) {
    const double du = h.size().x / (h.nx() - 1), dv = h.size().y / (h.ny() - 1);
    const int span = std::max(w, 1), n = (2 * span + 1) * (2 * span + 1);
    Eigen::MatrixXd A(n, 6);
    for (int b = -span, row = 0; b <= span; ++b)
        for (int a = -span; a <= span; ++a, ++row) {
            const double x = a * du, y = b * dv;
            A.row(row) << 1, x, y, x * x, x * y, y * y;
        }
    const auto solver = A.colPivHouseholderQr();
    double kappa = 0;
    for (int j = span; j < h.ny() - span; ++j)
        for (int i = span; i < h.nx() - span; ++i) {
            if (w == 0) {
                const auto at = [&](int a, int b) { return double(h(i + a, j + b)); };
                kappa = std::max(kappa, kappa_max((at(1, 0) - at(-1, 0)) / (2 * du), (at(0, 1) - at(0, -1)) / (2 * dv),
                                                  (at(1, 0) - 2 * at(0, 0) + at(-1, 0)) / (du * du),
                                                  (at(1, 1) - at(1, -1) - at(-1, 1) + at(-1, -1)) / (4 * du * dv),
                                                  (at(0, 1) - 2 * at(0, 0) + at(0, -1)) / (dv * dv)));
                continue;
            }
            Eigen::VectorXd z(n);
            for (int b = -span, row = 0; b <= span; ++b)
                for (int a = -span; a <= span; ++a, ++row) z(row) = h(i + a, j + b);
            const Eigen::VectorXd c = solver.solve(z);
            kappa = std::max(kappa, kappa_max(c(1), c(2), 2 * c(3), c(4), 2 * c(5)));
        }
    return 1.0 / kappa;
}

}  // namespace

TEST_CASE("machining report: a spherical bowl's concave radius, slope and sag") {
    const double R = 0.2;
    const Heightmap bowl = shaped(101, [&](double u, double v) { return R - std::sqrt(R * R - u * u - v * v); });
    const TriangleMesh mesh = tessellate_surface(bowl, 0.0f, 1);
    Scene scene = testing::basic_scene();
    const MachiningReport r = machining_report(scene, bowl, mesh);
    REQUIRE(r.min_concave_radius.has_value());
    CHECK(*r.min_concave_radius == doctest::Approx(R).epsilon(0.02));
    // Steepest at the corners (r = 0.05 √2): asin(r / R); the report's slopes come from the
    // vertices one step inside the edge.
    const double corner = 0.05 * std::sqrt(2.0), inner = (0.05 - 0.001) * std::sqrt(2.0);
    CHECK(r.max_slope_degrees <= std::asin(corner / R) * 180 / pi + 0.05);
    CHECK(r.max_slope_degrees >= std::asin(inner / R) * 180 / pi - 0.05);
    CHECK(r.sag_min == doctest::Approx(0).epsilon(1e-6));
    CHECK(r.sag_max == doctest::Approx(R - std::sqrt(R * R - corner * corner)).epsilon(1e-5));
    // The sheet's box: the surface's size in x and y, its sag in z (frame at the origin).
    CHECK(r.box_min.x == doctest::Approx(-0.05));
    CHECK(r.box_max.y == doctest::Approx(0.05));
    CHECK(r.box_max.z - r.box_min.z == doctest::Approx(r.sag_range()).epsilon(1e-6));
    CHECK(!r.min_glass_thickness.has_value());
}

TEST_CASE("machining report: paraboloid apex radius 2f; saddle 1/R; a dome has nothing concave") {
    const double f = 0.25;
    const MachiningReport p =
        machining_report(testing::basic_scene(), shaped(101, [&](double u, double v) { return (u * u + v * v) / (4 * f); }), {});
    REQUIRE(p.min_concave_radius.has_value());
    CHECK(*p.min_concave_radius == doctest::Approx(2 * f).epsilon(0.02));
    CHECK(std::abs(p.min_concave_u) < 1e-9);
    CHECK(std::abs(p.min_concave_v) < 1e-9);
    const double corner = 0.049 * std::sqrt(2.0);
    CHECK(p.max_slope_degrees == doctest::Approx(std::atan(corner / (2 * f)) * 180 / pi).epsilon(0.01));

    const double R = 0.3;
    const MachiningReport s =
        machining_report(testing::basic_scene(), shaped(101, [&](double u, double v) { return (u * u - v * v) / (2 * R); }), {});
    REQUIRE(s.min_concave_radius.has_value());
    CHECK(*s.min_concave_radius == doctest::Approx(R).epsilon(0.02));

    const MachiningReport d = machining_report(
        testing::basic_scene(), shaped(101, [](double u, double v) { return -(u * u + v * v) / 0.5; }), {});
    CHECK(!d.min_concave_radius.has_value());
}

TEST_CASE("machining report: a lens's thinnest glass is its thickness plus its lowest height") {
    Scene scene = testing::basic_scene();
    scene.surface.material = Lens{1.49, 0.008};
    const Heightmap h = shaped(41, [](double u, double v) { return -0.002 + 10 * (u * u + v * v); });
    const MachiningReport r = machining_report(scene, h, {});
    REQUIRE(r.min_glass_thickness.has_value());
    CHECK(*r.min_glass_thickness == doctest::Approx(0.008 - 0.002).epsilon(1e-5));
}

TEST_CASE("machining report on a design's start surface agrees with quadratic fits within 10 %") {
    Scene scene = testing::basic_scene(100, 16);
    scene.target = TargetSpec{};
    const ImageD target = testing::two_blocks(100, 100);
    // Any transport surface serves here: the first solve's (testing::first_solve_start).
    DesignStart start = testing::first_solve_start(scene, testing::surface_for(scene, 101), target, 1, 2);
    const MachiningReport r = machining_report(scene, start.surface, {});
    REQUIRE(start.report.used == StartKind::transport);
    REQUIRE(r.min_concave_radius.has_value());
    const double independent = independent_min_concave_radius(start.surface, 0);
    // The cutter meets the surface at its finest scale: quadratic fits over 3 x 3 and 5 x 5
    // vertices smooth away the cell-scale ripple of a design and read 2.6 and 4.5 times
    // larger radii here (see machining.hpp).
    MESSAGE("start surface: min concave radius " << *r.min_concave_radius * 1e3 << " mm (report), "
                                                 << independent * 1e3 << " mm (central differences, Eigen), "
                                                 << independent_min_concave_radius(start.surface, 1) * 1e3
                                                 << " mm (3 x 3 fits), "
                                                 << independent_min_concave_radius(start.surface, 2) * 1e3
                                                 << " mm (5 x 5 fits)");
    CHECK(*r.min_concave_radius == doctest::Approx(independent).epsilon(1e-6));
    CHECK(independent_min_concave_radius(start.surface, 1) > *r.min_concave_radius);
}

TEST_CASE("the ball-end mill: a bowl it fits is left alone; a V-groove is filled with the ball's round") {
    Scene scene = testing::basic_scene();
    {
        // A spherical bowl of radius 4 r over the whole part: the ball reaches everywhere.
        const double r = 0.02, R = 4 * r;
        Heightmap bowl = shaped(101, [&](double u, double v) { return R - std::sqrt(R * R - u * u - v * v); });
        const Heightmap before = bowl;
        CHECK(cut_with_ball(bowl, r) == 0.0);
        double moved = 0;
        for (int j = 0; j < 101; ++j)
            for (int i = 0; i < 101; ++i) moved = std::max(moved, std::abs(double(bowl(i, j)) - double(before(i, j))));
        CHECK(moved == 0.0);
        CHECK(ToolRadiusTerm{r}.cost(HeightsView(bowl), 50, 50) == 0.0);
        // A tool of radius 4 R meets a curvature four times what it can cut: shortfall 3.
        CHECK(ToolRadiusTerm{4 * R}.cost(HeightsView(bowl), 50, 50) == doctest::Approx(9.0).epsilon(0.02));
    }
    const double r = 0.005;

    // A V-groove along v with flanks of slope s: the ball touches both flanks at
    // |u| = r s / sqrt(1 + s^2), and its bottom sits r (sqrt(1 + s^2) - 1) above the groove.
    const double s = 0.5;
    Heightmap groove = shaped(201, [&](double u, double) { return s * std::abs(u); });
    const Heightmap sharp = groove;
    const double added = cut_with_ball(groove, r);
    const double du = 0.1 / 200, touch = r * s / std::sqrt(1 + s * s);
    CHECK(added == doctest::Approx(r * (std::sqrt(1 + s * s) - 1)).epsilon(0.01));
    for (int i = 0; i < 201; ++i) {
        const double u = groove.u_of(i), g = groove(i, 100), h = sharp(i, 100);
        CHECK(g >= h);
        if (std::abs(u) > r + du) CHECK(g == h);  // out of the ball's reach of the groove: untouched
        // Between the contact points and r, balls centred on vertices leave scallops.
        if (std::abs(u) > touch + du) CHECK(g - h < 1e-5);
        // Inside, the ball's own round: a circle of radius r about its centre.
        if (std::abs(u) < touch - du)
            CHECK(g == doctest::Approx(r * std::sqrt(1 + s * s) - std::sqrt(r * r - u * u)).epsilon(1e-3));
    }
    // The machinist's report now finds no radius under the tool's (central differences).
    const MachiningReport rep = machining_report(scene, groove, tessellate_surface(groove, 0.0f, 1));
    REQUIRE(rep.min_concave_radius.has_value());
    CHECK(*rep.min_concave_radius >= 0.95 * r);
    // A second cut changes nothing.
    CHECK(cut_with_ball(groove, r) < 1e-7);
}

TEST_CASE("scene file: surface.tool_radius") {
    const auto parse = [](const std::string& surface) {
        return scene_from_json(nlohmann::json::parse(R"({"light": {"type": "collimated"}, "surface": )" + surface +
                                                     R"(, "receiver": {}})"));
    };
    const Scene s = parse(R"({"tool_radius": 0.005})");
    CHECK(s.surface.tool_radius == 0.005);
    CHECK(scene_to_json(s)["surface"]["tool_radius"] == 0.005);
    CHECK(!scene_to_json(parse("{}"))["surface"].contains("tool_radius"));  // 0: no key, as before
    CHECK_THROWS_WITH_AS(parse(R"({"tool_radius": -0.001})"), doctest::Contains("surface.tool_radius"), InputError);
    // The designer's default terms include the tool's exactly when there is one.
    const PenaltyWeights o;
    CHECK(default_penalties(o, 0.005).names().back() == "tool_radius");
    CHECK(default_penalties(o).names().size() + 1 == default_penalties(o, 0.005).names().size());
}
