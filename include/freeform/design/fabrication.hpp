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
// scene's optimise.export_tolerance in receiver cells (0.25 by default) and cell the
// receiver's smaller cell size. Not 100 %: a designed surface's curvature has a long
// tail (the letter E's transport start: 90th percentile 0.85 mrad at k = 1, maximum
// 20 mrad), on the few cells where the map tears the light apart, and those cells spread
// their light thinly, so their facets' errors weigh little on the receiver. Measured on
// that start (/tmp experiment recorded in README "What gets milled"): k = 1, 2, 4, 8 give
// an exported error of 0.076, 0.061, 0.052, 0.051 against the simulated 0.050, and the
// rule picks 4. The check that matters is the traced one: design/exported.hpp gives the
// error a user's milled part will have (error_exported in metrics.json).
#include <algorithm>
#include <cmath>
#include <variant>

#include "../scene/scene.hpp"
#include "../surface/export.hpp"
#include "../surface/heightmap.hpp"

namespace freeform {

// δ_max of the header (radians) for a scene.
inline double facet_normal_tolerance(const Scene& scene) {
    const Receiver& r = scene.receiver;
    const double cell = std::min(r.size.x / r.width, r.size.y / r.height);
    const double distance = std::max(length(r.frame.origin - scene.surface.frame.origin), 1e-9);
    const auto* lens = std::get_if<Lens>(&scene.surface.material);
    const double gain = lens ? std::max(lens->ior - 1.0, 0.05) : 2.0;
    return scene.optimise.export_tolerance * cell / (gain * distance);
}

struct Fabrication {
    TriangleMesh mesh;          // world frame: the sheet (mirror) or the solid (lens)
    int subdivisions = 1;       // k: k² facet pairs per grid cell
    bool automatic = true;      // k chosen from the tolerance (export_subdivisions "auto")
    double normal_error = 0;    // tessellation_normal_error at k (90 % of facets), radians
    double normal_tolerance = 0;  // δ_max, radians
};

// Upper bound of the "auto" level: 128 facets per cell, 1.3 million for a 101 × 101
// design (a 64 MB binary STL). A surface that needs more says so in normal_error, and
// error_exported shows what it costs. Measured on the example cases' transport starts
// (Phong α ½, `freeform design CASE --start-only`): "auto" picks k = 2 (camera) to 5
// (point light), and the exported mesh's irradiance is within L1 0.005-0.014 of the
// design's.
inline constexpr int max_auto_subdivisions = 8;

inline Fabrication make_fabrication(const Scene& scene, const Heightmap& surface) {
    Fabrication f;
    const double alpha = scene.surface.phong_alpha;
    f.normal_tolerance = facet_normal_tolerance(scene);
    f.automatic = scene.optimise.export_subdivisions <= 0;
    if (f.automatic) {
        const SubdivisionChoice c =
            subdivisions_for_tolerance(surface, alpha, f.normal_tolerance, max_auto_subdivisions);
        f.subdivisions = c.k;
        f.normal_error = c.normal_error;
    } else {
        f.subdivisions = scene.optimise.export_subdivisions;
        f.normal_error = tessellation_normal_error(surface, alpha, f.subdivisions, 0.9);
    }
    if (const auto* lens = std::get_if<Lens>(&scene.surface.material))
        f.mesh = lens_solid(surface, *lens, float(alpha), f.subdivisions);
    else
        f.mesh = tessellate_surface(surface, float(alpha), f.subdivisions);
    return f;
}

}  // namespace freeform
