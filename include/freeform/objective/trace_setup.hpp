#pragma once
// What one trace of a design needs, built in one place: the rays a light sends at the
// surface, the kernel's path parameters (material, receiver, Phong α, deposit) and the
// target scaled to those rays (docs/measures.md: N, the weight the faces can pass).
//
// Every trace that judges a surface against its target starts here: the designer's levels
// and their held-out checks (design/designer.hpp, design/held_out.hpp), the start's
// evaluation (design/start.hpp), the finished design's fitted and held-out traces
// (design/pipeline.hpp), a render (design/render.hpp) and the cell means' batches
// (design/cell_means.hpp). One function, so that they cannot drift apart: the same seed,
// light and receiver give the same rays and the same target everywhere.
#include <cstdint>

#include "../core/histogram.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"
#include "../trace/setup.hpp"
#include "target.hpp"

namespace freeform {

struct TraceSetup {
    RaySet rays;
    PathParams params;
    Target target;  // empty when the set-up was made without a target image
    std::uint64_t seed = 0;  // the rays' jitter (generate_rays)

    // An empty histogram of the set-up's receiver.
    Histogram empty_histogram() const { return Histogram(params.receiver.width, params.receiver.height); }
};

// The rays of `light` at `receiver` (the scene's, or a design level's: trace/setup.hpp)
// aimed at `surface`'s aperture with jitter `seed`, and, when `target_image` is given, the
// target at the receiver's resolution scaled to them.
inline TraceSetup make_trace_setup(const Scene& scene, const Light& light, const Receiver& receiver,
                                   const Heightmap& surface, const ImageD* target_image, std::uint64_t seed) {
    TraceSetup s{generate_rays(light, surface, receiver, seed), make_path_params(scene, receiver), {}, seed};
    if (target_image)
        s.target = make_target(*target_image, receiver.width, receiver.height, target_total(s.rays, s.params));
    return s;
}

// The scene's own light and receiver.
inline TraceSetup make_trace_setup(const Scene& scene, const Heightmap& surface, const ImageD* target_image,
                                   std::uint64_t seed) {
    return make_trace_setup(scene, scene.light, scene.receiver, surface, target_image, seed);
}

}  // namespace freeform
