#pragma once
// The part that gets milled: the exported mesh of a design (an open sheet for a mirror,
// a closed solid for a lens), its subdivision level chosen from a tolerance, and, with
// Embree, the irradiance of that mesh traced as the flat triangles it is.
//
// The tracers simulate Phong patches with their true normals (trace/path.hpp,
// patch_normal); an exported mesh replaces each patch by k × k pairs of flat facets. A
// facet whose normal is off by an angle δ sends its light about gδD off course (D: the
// distance to the receiver; g = 2 for a mirror, g = n − 1 for a lens face of index n,
// both at small angles). The
// "auto" level is the smallest k whose facets stay within δ_max = tol · cell / (gD) of
// the patch normals for 90 % of the facets (tessellation_normal_error), with tol the
// scene's optimise.export_tolerance in receiver cells (0.05 by default) and cell the
// receiver's smaller cell size, and within the triangle budget below. Not 100 %: a
// designed surface's curvature has a long tail (the letter E's transport start: 90th
// percentile 0.85 mrad at k = 1, maximum 20 mrad), and the worst facets set no level.
// The check that matters is the traced one: design/exported.hpp gives the cell-mean
// error a user's milled part will have (error_physical in metrics.json).
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include "../scene/scene.hpp"
#include "../surface/export.hpp"
#include "../surface/heightmap.hpp"
#include "options.hpp"

namespace freeform {

// The top of what is exported: the face itself, or for a lens with a rim (lens_rim) the
// face and, beyond its edges, the rim's top, rounded up to whole cells of the face's mesh.
// Light falls on the face only and rays inside the glass only go down, so nothing traced
// meets the rim's top. Its first vertex beyond an edge continues the parabola through the
// face's last three, so that the top's central-difference normal at the face's edge is
// the face's own second-order one-sided one (Heightmap::vertex_normal) and the face's
// border cells keep their Phong patches; from there the rim goes on straight (its slope
// beyond the first vertex constant: no growing curvature, and the spline fitted over the
// whole top stays smooth across the edge). The exported solid's walls and back face then
// stand where the tracer's do (make_material_view).
//
// export_rim_cells: how many whole cells the rim adds beyond each edge (u: at each end
// along u, v: along v; 0 without a rim), the border the exported mesh keeps at one facet
// pair a cell (CoarseBorder, surface/export.hpp).
inline CoarseBorder export_rim_cells(const Scene& scene, const Heightmap& face) {
    const double rim = lens_rim(scene);
    if (!(rim > 0)) return {};
    return {int(std::ceil(rim / face.du() - 1e-9)), int(std::ceil(rim / face.dv() - 1e-9))};
}

inline Heightmap export_blank(const Scene& scene, const Heightmap& face) {
    const CoarseBorder border = export_rim_cells(scene, face);
    if (border.u == 0 && border.v == 0) return face;
    const int pu = border.u, pv = border.v;
    const int nx = face.nx() + 2 * pu, ny = face.ny() + 2 * pv;
    std::vector<double> h(std::size_t(nx) * std::size_t(ny));
    const auto at = [&](int i, int j) -> double& { return h[std::size_t(j) * std::size_t(nx) + std::size_t(i)]; };
    for (int j = 0; j < face.ny(); ++j)
        for (int i = 0; i < face.nx(); ++i) at(i + pu, j + pv) = face(i, j);
    // A line of the top, x(k) its k-th point: n on the face, continued p beyond each end
    // (edge e, inner neighbours e + d and e + 2d, outwards -d).
    const auto extend = [](auto&& x, int n, int p) {
        const auto side = [&](int e, int d) {
            const double second = n >= 3 ? x(e) - 2 * x(e + d) + x(e + 2 * d) : 0.0;
            const double first = x(e) + (x(e) - x(e + d)) + second;  // the parabola, one step out
            for (int k = 1; k <= p; ++k) x(e - k * d) = first + (k - 1) * (first - x(e));
        };
        if (p > 0) side(p, 1), side(p + n - 1, -1);
    };
    // Along u on the face's rows, then along v on every column (the corners continue both).
    for (int j = pv; j < pv + face.ny(); ++j) extend([&](int i) -> double& { return at(i, j); }, face.nx(), pu);
    for (int i = 0; i < nx; ++i) extend([&](int j) -> double& { return at(i, j); }, face.ny(), pv);
    const auto [lo, hi] = std::minmax_element(h.begin(), h.end());
    Heightmap blank(nx, ny, {face.du() * (nx - 1), face.dv() * (ny - 1)}, std::min(double(face.h_min()), *lo),
                    std::max(double(face.h_max()), *hi), face.frame(), Aperture::rect);
    blank.set_heights(std::vector<float>(h.begin(), h.end()));
    return blank;
}

// δ_max of the header (radians) for a scene, with tol = `tolerance_cells`
// (ExportOptions::tolerance).
inline double facet_normal_tolerance(const Scene& scene, double tolerance_cells) {
    const Receiver& r = scene.receiver;
    const double cell = std::min(r.size.x / r.width, r.size.y / r.height);
    const double distance = std::max(length(r.frame.origin - scene.surface.frame.origin), 1e-9);
    const auto* lens = std::get_if<Lens>(&scene.surface.material);
    const double gain = lens ? std::max(lens->ior - 1.0, 0.05) : 2.0;
    return tolerance_cells * cell / (gain * distance);
}

struct Fabrication {
    TriangleMesh mesh;          // world frame: the sheet (mirror) or the solid (lens)
    double subdivisions = 1;    // k: about k² facet pairs per grid cell (fractional: fills the budget)
    bool automatic = true;      // k chosen from the tolerance (export_subdivisions "auto")
    double normal_error = 0;    // tessellation_normal_error at k (90 % of facets), radians
    double normal_tolerance = 0;  // δ_max, radians
    // normal_error <= normal_tolerance. False when the triangle budget (or the cap of 16)
    // stopped k short: the summary and metrics.json say so (docs/export.md).
    bool tolerance_met = false;
    // The tolerance was missed at the cap of max_auto_subdivisions, with triangles to spare:
    // the cap, not optimise.export_max_triangles, stopped k (export_subdivisions sets more).
    bool capped = false;
    std::int64_t max_triangles = 0;  // the budget it was chosen within (optimise.export_max_triangles)

    // Whether k is a whole number (every cell k × k) or a fraction that fills the budget.
    bool whole() const { return subdivisions == std::floor(subdivisions); }
};

// Upper bound of the "auto" level. The level is also held to the scene's
// optimise.export_max_triangles (2 million by default: a 100 MB binary STL), so the
// surface's own mesh decides how fine the facets can be: k² ≤ max / (2 · cells) for a
// mirror's sheet; a lens's solid counts its rim (one facet pair a cell), walls and back too.
//
// Why so fine: error_physical (cell means, docs/measures.md) sees every displacement of
// light across a cell edge, and facets displace it most where the surface is most
// curved, the tail that a quantile of the normal error hides. Measured on designs of the
// letter E (101², 20 s) and the camera photograph (401², 60 s), `design --start-only`
// with the design's heightmap as `initial` and a fixed export_subdivisions: the E's
// exported error_physical is 0.0445 at k = 3 (the former default tolerance of 0.25
// cells), 0.0343 at 8 and 0.0331 at 14 against 0.0322 for the simulated surface; the
// camera's 0.0399 at k = 2, 0.0334 at 4 against 0.0320 (docs/measures.md).
//
// The same k everywhere: levels chosen per cell from each cell's own normal error (more
// facets where the surface is most curved, crack-free stitching between levels) were
// tried and lost at the same budget, 0.0517 against 0.0415 on a photograph and 0.0231
// against 0.0216 on the letter E: error_physical follows the bulk of the facets, and the
// per-cell rule coarsens most cells (docs/export.md).
inline constexpr int max_auto_subdivisions = 16;

// The largest whole k (at least 1, at most max_k) whose mesh stays within `max_triangles`:
// the sheet of `top` (a mirror) or, with `solid`, the lens solid over it with `border`
// kept at one facet pair a cell (export_triangle_count, surface/export.hpp).
inline int subdivisions_for_triangles(const Heightmap& top, std::int64_t max_triangles, int max_k = 1 << 16,
                                      CoarseBorder border = {}, bool solid = false) {
    const std::int64_t cells = detail::cells_inside_border(top, border);
    if (cells == 0) return 1;
    // The first guess counts 2 k² for each cell inside the border: an upper bound, which
    // the border's cells, a solid's walls and its back face bring down.
    int k = std::clamp(int(std::floor(std::sqrt(double(max_triangles) / (2.0 * double(cells))))), 1, max_k);
    while (k > 1 && export_triangle_count(top, detail::fine_grid(top, k, border), solid) > max_triangles) --k;
    return k;
}

// The triangles of the sheet with s facet pairs a cell side (detail::fine_grid).
inline std::int64_t sheet_triangles(const Heightmap& surface, double s) {
    return export_triangle_count(surface, detail::fine_grid(surface, s), false);
}

// The largest fractional k (to a thousandth, at most max_k) whose mesh stays within
// `max_triangles` (as subdivisions_for_triangles), or 1 where even that does not.
//
// Why fractional: the budget rarely falls on a whole k. On the 401² mesh of a 200²
// receiver 2 million triangles allow k = 2.5 where the whole k = 2 uses 1.28 million,
// and on 513² (512²) they allow 1.95 where k = 1 uses a quarter of them. Flat facets
// lose about as 1/k² (docs/export.md, "The facets"), so the mixed k buys about what a
// whole k would: measured on the letter E's demo design (401²), k = 2 0.0185, k = 3 0.0163
// (2.9 million triangles), k = 2.5 within the budget; on the 512² photograph k = 1 0.115,
// k = 2 0.061 (2.1 million), k = 1.95 within it.
inline double fractional_subdivisions_for_triangles(const Heightmap& top, std::int64_t max_triangles, double max_k,
                                                    CoarseBorder border = {}, bool solid = false) {
    const std::int64_t cells = detail::cells_inside_border(top, border);
    if (cells == 0) return 1;
    // The first guess counts 2 s² for each cell inside the border; rounding the fine lines
    // can add a line per axis, and the border's cells, a solid's walls and its back face
    // add more: step down until the count fits.
    double s = std::min(max_k, std::floor(1000 * std::sqrt(double(max_triangles) / (2.0 * double(cells)))) / 1000);
    while (s > 1 && export_triangle_count(top, detail::fine_grid(top, s, border), solid) > max_triangles)
        s = std::max(1.0, s - 0.001);
    return std::max(1.0, s);
}

// What stopped k short of the tolerance, in words for the summary and metrics.json.
inline std::string what_stopped_k(const Fabrication& f) {
    if (!f.automatic) return "optimise.export_subdivisions";
    if (f.capped)
        return "the cap of " + std::to_string(max_auto_subdivisions) +
               " facet pairs a cell side for \"auto\"; optimise.export_subdivisions sets more";
    return "optimise.export_max_triangles = " + std::to_string(f.max_triangles) + " allows no more";
}

// The exported mesh of `surface` with s facet pairs a cell side, in the world frame or
// the surface frame: the sheet (a mirror) or the closed solid over the lens blank
// (export_blank), its rim kept at one facet pair a cell (export_rim_cells). The one
// place that decides the mesh, so that what is written (make_fabrication) and what is
// judged (design/exported.hpp) are the same triangles.
//
// exported_mesh_over takes the top already made: `surface` itself for a mirror, the lens
// blank with its rim `border` for a lens.
inline TriangleMesh exported_mesh_over(const Scene& scene, const Heightmap& top, CoarseBorder border, double s,
                                       bool world_frame) {
    const auto alpha = float(scene.surface.phong_alpha);
    if (const auto* lens = std::get_if<Lens>(&scene.surface.material))
        return lens_solid(top, *lens, alpha, s, world_frame, border);
    return tessellate_surface(top, alpha, s, world_frame);
}

inline TriangleMesh exported_mesh(const Scene& scene, const Heightmap& surface, double s, bool world_frame = true) {
    if (std::holds_alternative<Lens>(scene.surface.material))
        return exported_mesh_over(scene, export_blank(scene, surface), export_rim_cells(scene, surface), s,
                                  world_frame);
    return exported_mesh_over(scene, surface, {}, s, world_frame);
}

inline Fabrication make_fabrication(const Scene& scene, const ExportOptions& options, const Heightmap& surface) {
    Fabrication f;
    const double alpha = scene.surface.phong_alpha;
    f.normal_tolerance = facet_normal_tolerance(scene, options.tolerance);
    f.automatic = options.subdivisions <= 0;
    f.max_triangles = options.max_triangles;
    // What is exported: the surface (a mirror's sheet) or the solid over the lens blank.
    const bool solid = std::holds_alternative<Lens>(scene.surface.material);
    const std::optional<Heightmap> blank = solid ? std::optional<Heightmap>(export_blank(scene, surface)) : std::nullopt;
    const Heightmap& top = blank ? *blank : surface;
    const CoarseBorder border = export_rim_cells(scene, surface);
    if (f.automatic) {
        // The budget counts every triangle written: a lens's rim, walls and back face too.
        const int max_k =
            subdivisions_for_triangles(top, options.max_triangles, max_auto_subdivisions, border, solid);
        const SubdivisionChoice c = subdivisions_for_tolerance(surface, alpha, f.normal_tolerance, max_k);
        f.subdivisions = c.k;
        f.normal_error = c.normal_error;
        // The budget stopped k short of the tolerance: fill it with a fractional k.
        if (c.normal_error > f.normal_tolerance && c.k == max_k) {
            const double s = fractional_subdivisions_for_triangles(top, options.max_triangles,
                                                                    double(max_auto_subdivisions), border, solid);
            if (s > double(c.k)) {
                f.subdivisions = s;
                f.normal_error = tessellation_normal_error(surface, alpha, s, 0.9);
            }
        }
    } else {
        f.subdivisions = options.subdivisions;
        f.normal_error = tessellation_normal_error(surface, alpha, f.subdivisions, 0.9);
    }
    f.tolerance_met = f.normal_error <= f.normal_tolerance;
    f.capped = f.automatic && !f.tolerance_met && f.subdivisions >= double(max_auto_subdivisions);
    f.mesh = exported_mesh_over(scene, top, border, f.subdivisions, true);
    return f;
}

}  // namespace freeform
