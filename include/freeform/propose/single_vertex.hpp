#pragma once
// The plain baseline move of the reference's chapter 3: displace one vertex.
//
// Kept to measure what the Gaussian kernels buy: a single vertex changes the light too
// little to be judged reliably on a fine mesh and leaves spikes behind (reference §4.2).
#include <cstddef>

#include "../surface/heightmap.hpp"
#include "../surface/overlay.hpp"
#include "kernel.hpp"

namespace freeform {

// Fills `out` with the surface after moving vertex (ci, cj), which must lie on the grid,
// by `amplitude` (clamped to the height bounds, and to `limits` where given): a 1 × 1
// patch and the normals it changes.
inline void apply_single_vertex(const Heightmap& base, int ci, int cj, float amplitude, HeightOverlay& out,
                                VertexBounds limits = {}) {
    FREEFORM_KERNEL_ASSERT(ci >= 0 && ci < base.nx() && cj >= 0 && cj < base.ny());
    out.patch = {ci, cj, ci, cj};
    out.heights.resize(1);
    // Same rounding as a kernel whose only weight is 1 at the centre.
    out.heights[0] = limits.clamp(std::size_t(cj) * std::size_t(base.nx()) + std::size_t(ci),
                                  base.clamp_height(kernel_height(base(ci, cj), amplitude, 1.0f)));
    out.finish(base);
}

}  // namespace freeform
