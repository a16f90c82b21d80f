#pragma once
// Height maps as PFM files (heightmap.pfm): one float per vertex, metres along the
// surface normal, image row 0 the surface's +v edge. Also the start surface a scene names
// as a PFM file, read onto the design's final mesh for design() (design/pipeline.hpp),
// which does no I/O of its own.
#include <filesystem>
#include <optional>
#include <string>

#include "../core/error.hpp"
#include "../core/limits.hpp"
#include "../design/designer.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"
#include "pfm.hpp"
#include "scene_file.hpp"

namespace freeform::io {

// The height map in `file` for `scene`'s surface, on the grid the file has.
inline Heightmap read_heightmap(Scene scene, const std::filesystem::path& file, const Limits& limits = {}) {
    const ImageF img = read_pfm(file, limits);
    if (img.cols() < 2 || img.rows() < 2)
        throw InputError(file.string() + ": a height map must be at least 2 x 2 pixels");
    // The file was read relative to the working directory; the scene resolves a relative
    // surface.initial against its own folder, so hand it the absolute path.
    scene.surface.initial_pfm = std::filesystem::absolute(file);
    scene.surface.initial_paraboloid.reset();
    return make_initial_heightmap(scene, int(img.cols()), int(img.rows()), limits);
}

// The heights as an image: row 0 the +v edge (grid row ny − 1), as read_heightmap reads them.
inline ImageF heightmap_image(const Heightmap& surface) {
    ImageF heights(surface.ny(), surface.nx());
    for (int j = 0; j < surface.ny(); ++j)
        for (int i = 0; i < surface.nx(); ++i) heights(surface.ny() - 1 - j, i) = surface(i, j);
    return heights;
}

inline void write_heightmap(const std::filesystem::path& file, const Heightmap& surface) {
    write_pfm(file, heightmap_image(surface));
}

// The start surface a scene names as a PFM file (surface.initial) on the final mesh of the
// design's `levels` (plan_levels); empty when it starts from no file (flat, a paraboloid,
// the transport start).
inline std::optional<Heightmap> load_start_surface(const Scene& scene, const std::vector<LevelPlan>& levels,
                                                   const Limits& limits = {}) {
    if (scene.surface.initial_pfm.empty()) return std::nullopt;
    const auto [nx, ny] = final_mesh(scene, levels);
    return make_initial_heightmap(scene, nx, ny, limits);
}

// The surface a render or a design begins with, before any transport start: the scene's
// PFM file, or its flat or paraboloid start, on the final mesh a design of the job plans.
inline Heightmap scene_surface(const DesignJob& job, const Limits& limits = {}) {
    const Scene& scene = job.scene;
    const auto [nx, ny] = final_mesh(scene, job.options);
    return make_initial_heightmap(scene, nx, ny, limits);
}

}  // namespace freeform::io
