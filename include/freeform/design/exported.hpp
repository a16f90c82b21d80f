#pragma once
// The irradiance of a design's exported geometry (design/fabrication.hpp), traced with
// Embree as the flat triangles a mill produces: no Phong correction, no vertex normals.
// Needs freeform::embree.
//
// A mirror's sheet is traced in place of the height field. A lens's solid is its
// tessellated front face over the flat back face and absorbing side walls of the lens
// model; the front face is traced as a mesh and the model supplies the rest, so the
// comparison isolates what the export changes: the facets of the front face.
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
    const TriangleMesh front = tessellate_surface(surface, float(scene.surface.phong_alpha), subdivisions, false);
    PathParams pp = make_path_params(scene);
    pp.phong_alpha = 0.0f;  // flat facets: the mesh is its geometry
    pp.interpolated_normals = false;
    EmbreeTracer tracer(front, rays, pp);
    ExportedTrace out{Histogram(scene.receiver.width, scene.receiver.height), {}};
    tracer.trace_all(policy, out.histogram, out.totals);
    return out;
}

}  // namespace freeform
