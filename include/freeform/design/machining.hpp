#pragma once
// The figures a machinist needs before milling a design (metrics.json "fabrication"):
// which ball-end cutter fits, how steep and how deep the surface is, how large the part
// is and, for a lens, how thin its glass gets.
//
// The cutter comes from the side of the freeform face that is not material: the light's
// side of a mirror (+normal of the surface frame) and the air side of a lens's front face
// (also +normal: the glass lies between the surface and its flat back face at
// -thickness). A ball of radius r reaches the bottom of a concave region only where the
// surface's largest principal curvature, seen from that side, is at most 1/r; so
// min_concave_radius = 1 / max κ₁ over the surface (κ₁ > 0 for a bowl seen from +normal).
//
// Curvatures are those of the height field z = h(u, v) at the grid vertices, from
// central differences of the heights (the exported facets follow the same heights), by
// the first and second fundamental forms of a graph:
//   E = 1 + h_u², F = h_u h_v, G = 1 + h_v², W = √(1 + h_u² + h_v²),
//   L = h_uu / W, M = h_uv / W, N = h_vv / W,
//   H = (E N − 2 F M + G L) / (2 (E G − F²)), K = (L N − M²) / (E G − F²),
//   κ₁ = H + √(H² − K).
// Central differences see the surface at its finest scale, the grid's, which is where a
// cutter meets it: a design's cell-scale ripple is milled too. (On a transport start of
// a 101² mesh, quadratic fits over 3 × 3 and 5 × 5 vertices, which smooth that ripple,
// read 2.6 and 4.5 times the radius; tests/test_machining.cpp prints all three.)
// Only vertices whose four surrounding cells are inside the aperture count. Slopes are
// the angle between the surface normal (−h_u, −h_v, 1) and the frame normal, at the same
// vertices; heights are the grid's (the facets' corners).
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <variant>

#include "../core/math.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"
#include "../surface/tool.hpp"
#include "../surface/triangle_mesh.hpp"

namespace freeform {

struct MachiningReport {
    std::optional<double> min_concave_radius;  // metres; none when no region is concave from the cutter's side
    double min_concave_u = 0, min_concave_v = 0;  // where (surface frame, metres)
    double max_slope_degrees = 0;
    double sag_min = 0, sag_max = 0;            // heights along the surface normal, metres
    Vec3d box_min{0, 0, 0}, box_max{0, 0, 0};   // the exported part's bounding box (world, metres)
    std::optional<double> min_glass_thickness;  // lenses: from the freeform face to the back face, metres

    double sag_range() const { return sag_max - sag_min; }
};


// The report for a design's surface and the part exported from it (fabrication.hpp).
inline MachiningReport machining_report(const Scene& scene, const Heightmap& surface, const TriangleMesh& exported) {
    MachiningReport r;
    double kappa = 0;
    r.sag_min = std::numeric_limits<double>::infinity();
    r.sag_max = -r.sag_min;
    for (int j = 0; j < surface.ny(); ++j)
        for (int i = 0; i < surface.nx(); ++i) {
            // A vertex is on the part when one of its cells is.
            bool on_part = false;
            for (int cj = std::max(j - 1, 0); cj <= std::min(j, surface.ny() - 2); ++cj)
                for (int ci = std::max(i - 1, 0); ci <= std::min(i, surface.nx() - 2); ++ci)
                    on_part = on_part || surface.cell_active(ci, cj);
            if (!on_part) continue;
            r.sag_min = std::min(r.sag_min, double(surface(i, j)));
            r.sag_max = std::max(r.sag_max, double(surface(i, j)));
            if (i == 0 || j == 0 || i == surface.nx() - 1 || j == surface.ny() - 1) continue;
            if (!(surface.cell_active(i - 1, j - 1) && surface.cell_active(i, j - 1) &&
                  surface.cell_active(i - 1, j) && surface.cell_active(i, j)))
                continue;
            const VertexCurvature s = vertex_curvature(surface, i, j, surface.size().x / (surface.nx() - 1),
                                                       surface.size().y / (surface.ny() - 1));
            r.max_slope_degrees = std::max(r.max_slope_degrees, s.slope * 180.0 / pi);
            if (s.kappa_max > kappa) {
                kappa = s.kappa_max;
                r.min_concave_u = surface.u_of(i);
                r.min_concave_v = surface.v_of(j);
            }
        }
    if (kappa > 0) r.min_concave_radius = 1.0 / kappa;
    if (!(r.sag_min <= r.sag_max)) r.sag_min = r.sag_max = 0;
    if (!exported.vertices.empty()) {
        r.box_min = r.box_max = exported.vertices.front();
        for (const Vec3d& p : exported.vertices) {
            r.box_min = {std::min(r.box_min.x, p.x), std::min(r.box_min.y, p.y), std::min(r.box_min.z, p.z)};
            r.box_max = {std::max(r.box_max.x, p.x), std::max(r.box_max.y, p.y), std::max(r.box_max.z, p.z)};
        }
    }
    if (const auto* lens = std::get_if<Lens>(&scene.surface.material)) r.min_glass_thickness = lens->thickness + r.sag_min;
    return r;
}

}  // namespace freeform
