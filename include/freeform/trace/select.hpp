#pragma once
// Which tracer a scene needs: the smallest exact model, and why.
#include <string>

#include "../core/error.hpp"
#include "../scene/scene.hpp"

namespace freeform {

struct TracerDecision {
    TracerChoice tracer = TracerChoice::heightfield;
    std::string reason;
};

// `imported_mesh`: the designed surface is replaced by a triangle mesh (render --mesh).
// `requested`: automatic, or a user override that is refused when it cannot be exact.
inline TracerDecision choose_tracer(const Scene& scene, bool imported_mesh, TracerChoice requested,
                                    bool embree_available) {
    TracerDecision d;
    const bool needs_triangles = imported_mesh || !scene.meshes.empty();
    std::string why_triangles;
    if (imported_mesh) why_triangles = "the surface is an imported triangle mesh";
    else if (!scene.meshes.empty())
        why_triangles = "the scene has " + std::to_string(scene.meshes.size()) + " extra mesh(es) besides the height field";

    if (requested == TracerChoice::heightfield && needs_triangles)
        throw InputError("--tracer heightfield cannot be exact for this scene: " + why_triangles +
                         ", and the height-field tracer only traverses one height field (use --tracer embree)");
    if ((requested == TracerChoice::embree || (requested == TracerChoice::automatic && needs_triangles)) &&
        !embree_available)
        throw InputError("this scene needs the Embree tracer (" +
                         (needs_triangles ? why_triangles : std::string("--tracer embree was requested")) +
                         "), but this build has no Embree support (rebuild with Embree 3 installed)");
    if (requested == TracerChoice::heightfield) {
        d.tracer = TracerChoice::heightfield;
        d.reason = "requested with --tracer heightfield";
    } else if (requested == TracerChoice::embree) {
        d.tracer = TracerChoice::embree;
        d.reason = needs_triangles ? "requested with --tracer embree; needed anyway: " + why_triangles
                                   : "requested with --tracer embree (the height-field tracer would be exact too)";
    } else if (needs_triangles) {
        d.tracer = TracerChoice::embree;
        d.reason = why_triangles + ": only Embree traces arbitrary triangles";
    } else {
        d.tracer = TracerChoice::heightfield;
        d.reason = "one height field and nothing else: the exact height-field traversal needs no BVH "
                   "(interreflections on the field included)";
    }
    return d;
}

}  // namespace freeform
