#pragma once
// The surface a design starts from when the scene names no file: flat, or the
// paraboloid of surface.initial. A start read from a PFM file is
// io::make_initial_heightmap's (io/scene_file.hpp), which builds on this one.
#include <cmath>
#include <cstddef>
#include <vector>

#include "../core/error.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"

namespace freeform {

// The scene's own start on an nx × ny grid: flat, or the paraboloid it names.
inline Heightmap initial_surface(const Scene& scene, int nx, int ny) {
    const SurfaceSpec& s = scene.surface;
    Heightmap h(nx, ny, s.size, s.h_min, s.h_max, s.frame, s.aperture);
    if (!s.initial_paraboloid) return h;
    if (!s.initial_pfm.empty()) throw InputError("surface.initial: both a PFM file and a paraboloid are set");
    const double f = s.initial_paraboloid->focal_length;
    if (!(f > 0) || !std::isfinite(f)) throw InputError("surface.initial.paraboloid.focal_length: must be > 0");
    std::vector<float> heights(std::size_t(nx) * std::size_t(ny));
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const double u = h.u_of(i), v = h.v_of(j);
            heights[std::size_t(j) * std::size_t(nx) + std::size_t(i)] = float((u * u + v * v) / (4 * f));
        }
    h.set_heights(heights);
    return h;
}

}  // namespace freeform
