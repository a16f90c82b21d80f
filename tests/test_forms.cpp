// The smooth exported forms do what the designed surface does (docs/export.md): the
// fitted B-spline (the surface of surface.step), tessellated and traced
// with its own normals interpolated, throws the light of the simulated Phong surface, far
// closer than flat facets of the same grid do.
#include <doctest/doctest.h>

#include <filesystem>
#include <optional>

#include <freeform/design/fabrication.hpp>
#include <freeform/design/pipeline.hpp>
#include <freeform/design/start.hpp>
#include <freeform/io/forms.hpp>
#include <freeform/surface/bspline.hpp>
#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/design/exported.hpp>
#endif

#include "files.hpp"
#include "start_support.hpp"
#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

#if defined(FREEFORM_WITH_EMBREE)
namespace {

// A transport start for `s` on a coarse 51² grid (curved at the scale of cells: the
// patches' kinks, which the spline smooths, are large), and the L1 distance (a share of the light, 0..1) between
// its own irradiance and that of (a) its spline tessellated with k = 2 and traced
// smooth, (b) its flat facets with k = 1.
struct FormDistances {
    double smooth = 0, facets = 0, energy_change = 0;
};

FormDistances distances(Scene s, int n) {
    s.target = TargetSpec{};
    s.receiver.deposit = Deposit::bilinear;
    const ImageD target = ring_and_bar(s.receiver.width, s.receiver.height);
    // Any transport surface serves here: the first solve's (testing::first_solve_start).
    const DesignStart st = first_solve_start(s, surface_for(s, n), target, 3, 1);
    REQUIRE(st.report.used == StartKind::transport);
    const Heightmap& hm = st.surface;
    const TraceSetup setup = make_trace_setup(s, hm, nullptr, 1);
    const RaySet& rays = setup.rays;
    const Traced design = trace_scene(s, hm, rays, exec::omp);
    const BSplineSurface spline = fit_bspline(hm, s.surface.phong_alpha, spline_samples_per_cell);
    const ExportedGeometry g = smooth_geometry(s, hm, 2, [&](int ci, int cj, double a, double b) {
        return spline_vertex(spline, hm, ci, cj, a, b);
    });
    const ExportedTrace smooth = trace_exported(exec::omp, s, g, setup);
    const ExportedTrace facets = trace_exported(exec::omp, s, hm, 1, setup);
    FormDistances d;
    d.smooth = l1_distance(design.histogram, smooth.histogram) / (2.0 * double(rays.total));
    d.facets = l1_distance(design.histogram, facets.histogram) / (2.0 * double(rays.total));
    d.energy_change = std::abs(smooth.totals.energy() - design.totals.energy());
    MESSAGE("L1 to the design: spline traced smooth ", d.smooth, ", flat facets k = 1 ", d.facets);
    return d;
}

}  // namespace

TEST_CASE("the spline form throws the designed surface's light") {
    Scene s = basic_scene(100);
    SUBCASE("collimated mirror") {
        const FormDistances d = distances(s, 51);
        CHECK(d.smooth < 0.025);
        CHECK(d.smooth < 0.4 * d.facets);
        CHECK(d.energy_change < 0.005);
    }
    SUBCASE("point light, elliptical aperture") {
        s.light.shape = PointLight{{0, 0, 0.3}, {}, {}};
        s.surface.aperture = Aperture::ellipse;
        s.receiver.size = {0.3, 0.3};
        const FormDistances d = distances(s, 51);
        CHECK(d.smooth < 0.025);
        CHECK(d.smooth < 0.4 * d.facets);
    }
    SUBCASE("lens: a smooth front on a flat-walled solid") {
        s.surface.material = Lens{1.49, 0.01};
        s.surface.h_min = -0.008, s.surface.h_max = 0.008;
        s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
        s.receiver.size = {0.15, 0.15};
        const FormDistances d = distances(s, 51);
        CHECK(d.smooth < 0.025);
        CHECK(d.smooth < 0.4 * d.facets);
        CHECK(d.energy_change < 0.005);
    }
}

TEST_CASE("a smooth lens solid keeps its walls and back flat and stays a closed solid") {
    Scene s = basic_scene(50);
    s.surface.material = Lens{1.5, 0.01};
    Heightmap hm = surface_for(s, 21);
    shape(hm, [](double u, double v) { return 0.02 * u * u - 0.01 * v * v; });
    const BSplineSurface spline = fit_bspline(hm, 1.0, 4);
    const ExportedGeometry g = smooth_geometry(s, hm, 3, [&](int ci, int cj, double a, double b) {
        return spline_vertex(spline, hm, ci, cj, a, b);
    });
    REQUIRE(g.solid_ior);
    CHECK(g.smooth_triangles == 2 * 9 * 20 * 20);
    CHECK(check_refractive_solid(g.mesh, "smooth lens").volume > 0);
    REQUIRE(g.mesh.normals.size() == g.mesh.vertices.size());
    // The front's normals are the spline's: facing +w and equal to its graph normal.
    const SplineSample q = spline.eval(hm.u_of(7), hm.v_of(4));
    bool found = false;
    for (std::size_t k = 0; k < g.mesh.vertices.size(); ++k)
        if (std::abs(g.mesh.vertices[k].x - hm.u_of(7)) < 1e-12 && std::abs(g.mesh.vertices[k].y - hm.v_of(4)) < 1e-12 &&
            g.mesh.vertices[k].z > -0.005) {
            CHECK(length(g.mesh.normals[k] - q.normal()) < 1e-12);
            found = true;
        }
    CHECK(found);
}
#endif

TEST_CASE("export formats: auto is STEP and the mesh where STEP is built, else the mesh; a format the build lacks "
          "is refused") {
    ExportOptions s;  // "auto"
    const std::vector<ExportFormat> f = io::export_formats(s);
    REQUIRE(!f.empty());
    CHECK(f.back() == ExportFormat::mesh);
    CHECK((f.size() == 2) == io::format_available(ExportFormat::step));
    if (f.size() == 2) CHECK(f.front() == ExportFormat::step);
    s.formats = {ExportFormat::sag, ExportFormat::mesh};
    CHECK(io::export_formats(s) == s.formats);
    s.formats = {ExportFormat::step};
    if (!io::format_available(ExportFormat::step)) CHECK_THROWS_AS(io::export_formats(s), InputError);
}

TEST_CASE("the STEP part's spline: Hermite while it fits about 50 MB, else least squares; the key overrides") {
    const Heightmap small(201, 201, {0.1, 0.1}, -0.01, 0.01), big(400, 400, {0.1, 0.1}, -0.01, 0.01);
    REQUIRE(4LL * 201 * 201 <= hermite_max_poles);
    REQUIRE(4LL * 400 * 400 > hermite_max_poles);
    const BSplineSurface a = step_spline(small, 1.0, SplineForm::automatic);
    CHECK(a.hermite);
    CHECK(a.nu == 402);
    const BSplineSurface b = step_spline(big, 1.0, SplineForm::automatic);
    CHECK_FALSE(b.hermite);
    CHECK(b.nu == 402);  // one knot per grid line: 400 + 2 poles
    CHECK_FALSE(step_spline(small, 1.0, SplineForm::least_squares).hermite);
    CHECK(step_spline(big, 1.0, SplineForm::hermite).hermite);
}

TEST_CASE("a grid sag written and read back is judged from the file") {
    Scene s = basic_scene(40);
    Heightmap hm = surface_for(s, 21);
    shape(hm, [](double u, double v) { return 0.05 * u * u + 0.02 * u * v; });
    const BSplineSurface spline = fit_bspline(hm, 1.0, 4);
    const ImageD target = ImageD::Constant(40, 40, 1.0);
    const testing::TempDir dir;
    const io::FormCheck fc = io::write_and_check_form(ExportFormat::sag, dir / "form.dat", s, hm, spline, &target, 1, 1);
    CHECK(fc.bytes == std::filesystem::file_size(dir / "form.dat"));
    CHECK(fc.valid == "yes");
#if defined(FREEFORM_WITH_EMBREE)
    REQUIRE(fc.cells);
    CHECK(fc.tessellation == 4);
    CHECK(fc.cells->error >= 0);
    CHECK(fc.cells->totals.energy() > 0.5);
#endif
    CHECK_THROWS_AS(io::write_and_check_form(ExportFormat::mesh, "x", s, hm, spline, &target, 1, 1), InputError);
}
