#pragma once
// The irradiance of a design's exported geometry (design/fabrication.hpp), traced with
// Embree as the flat triangles a mill produces: no Phong correction, no vertex normals.
// Needs freeform::embree.
//
// A mirror's sheet is traced in place of the height field. A lens is traced as its
// exported closed solid (lens_solid: front facets, flat back face, side walls), a
// refractive mesh with Snell at every crossing and total internal reflection followed:
// what a milled or printed lens does (the design's lens model follows the same walls,
// so the difference is the facets).
#include <optional>
#include <vector>

#include "../objective/trace_setup.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/export.hpp"
#include "../trace/embree.hpp"
#include "cell_means.hpp"
#include "fabrication.hpp"

namespace freeform {

struct ExportedTrace {
    Histogram histogram;
    TraceTotals totals;
};

// The exported part as Embree traces it: the mirror's sheet, or the lens's closed solid.
struct ExportedGeometry {
    TriangleMesh mesh;  // surface frame
    std::optional<double> solid_ior;  // a lens: the mesh is a refractive solid of this index
    // A smooth form (spline, STEP part): the mesh is a fine tessellation whose front is
    // traced with its vertex normals interpolated, the first `smooth_triangles` of a lens
    // solid (its walls and back stay flat). Facets of the milled mesh: false.
    bool smooth = false;
    std::int64_t smooth_triangles = -1;
};

inline ExportedGeometry exported_geometry(const Scene& scene, const Heightmap& surface, double subdivisions) {
    const Lens* lens = std::get_if<Lens>(&scene.surface.material);
    return {exported_mesh(scene, surface, subdivisions, false), lens ? std::optional<double>(lens->ior) : std::nullopt};
}

// A smooth form of the design (`point` as in detail::tessellate_local: a fitted spline,
// the re-read STEP part) tessellated with k × k facet pairs per cell over `grid`'s active
// cells (for a lens, `grid` is the exported top, export_blank), its vertex normals those
// of the form. Traced with interpolated normals, the
// facets only place the hits: the normal error falls as k⁻² instead of k⁻¹, and the
// figure settles at small k (docs/export.md measures it).
template <class PointFn>
ExportedGeometry smooth_geometry(const Scene& scene, const Heightmap& grid, int k, PointFn&& point) {
    ExportedGeometry g;
    g.smooth = true;
    if (const Lens* lens = std::get_if<Lens>(&scene.surface.material)) {
        g.mesh = lens_solid_of(grid, *lens, k, point, true, false);
        g.smooth_triangles = 2 * std::int64_t(k) * k * active_cell_count(grid);
        g.solid_ior = lens->ior;
    } else {
        detail::check_export_args(grid, 0.0, k);
        std::vector<std::int32_t> fine_index;
        g.mesh = detail::tessellate_local(grid, k, fine_index, point);
    }
    return g;
}

// Traces the rays of `setup` (aimed at the surface's aperture: make_trace_setup) through
// the exported geometry with the set-up's receiver (its deposit included).
template <HostPolicy P>
ExportedTrace trace_exported(P policy, const Scene& scene, const ExportedGeometry& geometry,
                             const TraceSetup& setup) {
    const RaySet& rays = setup.rays;
    PathParams pp = setup.params;
    pp.phong_alpha = 0.0f;  // flat facets: the mesh is its geometry
    pp.interpolated_normals = geometry.smooth;
    RaySet lens_rays;  // outlives the tracer, which refers to it
    std::optional<EmbreeTracer> tracer;
    if (geometry.solid_ior) {
        // The solid replaces the lens model; a collimated beam starts above its top.
        lens_rays = rays;
        start_above(scene.light, scene.surface.size, geometry.mesh, lens_rays);
        pp.material = MaterialView{};
        std::vector<ExtraMesh> meshes;
        meshes.push_back(
            ExtraMesh{geometry.mesh, MeshMaterial::refractive(*geometry.solid_ior), geometry.smooth_triangles});
        tracer.emplace(lens_rays, pp, std::move(meshes), thread_count(policy));
    } else {
        tracer.emplace(geometry.mesh, rays, pp, std::vector<ExtraMesh>{}, thread_count(policy));
    }
    ExportedTrace out{setup.empty_histogram(), {}};
    tracer->trace_all(policy, out.histogram, out.totals);
    return out;
}

template <HostPolicy P>
ExportedTrace trace_exported(P policy, const Scene& scene, const Heightmap& surface, double subdivisions,
                             const TraceSetup& setup) {
    return trace_exported(policy, scene, exported_geometry(scene, surface, subdivisions), setup);
}

// The cell means of the exported part (cell_means.hpp): what `error_physical` reports.
// `surface` places the rays (its aperture), `geometry` is what they meet.
template <HostPolicy P>
CellMeans exported_cell_means(P policy, const Scene& scene, const Heightmap& surface, const ExportedGeometry& geometry,
                              const ImageD* target, const CellMeanOptions& options) {
    return converged_cell_means(scene, surface, target, options,
                                [&](const Scene& s, const TraceSetup& batch, Histogram& h, TraceTotals& t) {
                                    ExportedTrace et = trace_exported(policy, s, geometry, batch);
                                    h = std::move(et.histogram);
                                    t = et.totals;
                                });
}

}  // namespace freeform
