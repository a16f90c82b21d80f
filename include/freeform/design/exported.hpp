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

#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/export.hpp"
#include "../trace/embree.hpp"
#include "../trace/setup.hpp"

namespace freeform {

struct ExportedTrace {
    Histogram histogram;
    TraceTotals totals;
};

template <HostPolicy P>
ExportedTrace trace_exported(P policy, const Scene& scene, const Heightmap& surface, int subdivisions,
                             const RaySet& rays) {
    PathParams pp = make_path_params(scene);
    pp.phong_alpha = 0.0f;  // flat facets: the mesh is its geometry
    pp.interpolated_normals = false;
    const float alpha = float(scene.surface.phong_alpha);
    RaySet lens_rays;  // outlives the tracer, which refers to it
    std::optional<EmbreeTracer> tracer;
    if (const Lens* lens = std::get_if<Lens>(&scene.surface.material)) {
        // The solid replaces the lens model; a collimated beam starts above its top.
        TriangleMesh solid = lens_solid(surface, *lens, alpha, subdivisions, false);
        lens_rays = rays;
        start_above(scene.light, scene.surface.size, solid, lens_rays);
        pp.material = MaterialView{};
        std::vector<ExtraMesh> meshes;
        meshes.push_back(ExtraMesh{std::move(solid), MeshMaterial::refractive(lens->ior)});
        tracer.emplace(lens_rays, pp, std::move(meshes));
    } else {
        tracer.emplace(tessellate_surface(surface, alpha, subdivisions, false), rays, pp);
    }
    ExportedTrace out{Histogram(scene.receiver.width, scene.receiver.height), {}};
    tracer->trace_all(policy, out.histogram, out.totals);
    return out;
}

}  // namespace freeform
