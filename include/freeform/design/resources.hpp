#pragma once
// The memory a render or a design will need, planned from the scene before anything is
// allocated, and the check against Limits::memory_bytes (core/limits.hpp). A scene may
// ask for 2^20 rays per cell on a 16384² receiver; without this check the process would
// start allocating terabytes and be killed by the system, possibly after minutes.
//
// The plan is an upper estimate from per-item costs measured on the release build
// (docs/limits.md gives the measurements): a design keeps about 165 bytes per ray (rays,
// incremental-evaluation records, held-out rays), a render about 55; each receiver cell
// costs a histogram per worker thread; the exported mesh about 250 bytes per triangle
// (tessellation, Embree's copy, OBJ/STL text). The figures below round these up.
#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <string>

#include "../core/limits.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "cell_means.hpp"
#include "designer.hpp"

namespace freeform {

enum class RunKind : std::uint8_t { render, design };

struct ResourcePlan {
    std::int64_t rays = 0;      // most rays traced at one time
    double bytes = 0;           // planned peak memory
    std::string largest;        // what the largest part of it is, in words
};

namespace detail {

inline constexpr double design_bytes_per_ray = 200;
inline constexpr double render_bytes_per_ray = 80;
inline constexpr double bytes_per_vertex = 512;       // heights, gradients, kernels' scratch
inline constexpr double bytes_per_export_triangle = 300;

// Rays of the light at a receiver of `cells` cells with `rays_per_cell` (light.rays wins).
inline double rays_at(const Light& light, double rays_per_cell, double cells) {
    return light.rays > 0 ? double(light.rays) : std::max(1.0, rays_per_cell * cells);
}

}  // namespace detail

// The plan of a `kind` run of the job's scene on `threads` workers (0: count them as 64). The
// design's levels are `levels` (plan_levels of the scene, PlannedDesign::levels) or, when
// null, planned here; a render traces the light's rays once and, when the scene has a
// target, the cell means of what it rendered (design/cell_means.hpp).
inline ResourcePlan plan_resources(const DesignJob& job, RunKind kind, int threads,
                                   const std::vector<LevelPlan>* levels = nullptr) {
    const Scene& scene = job.scene;
    const DesignOptions& options = job.options;
    const double min_rays = options.min_rays_per_mesh_cell;
    const double workers = threads > 0 ? threads : 64;
    const double cells = double(scene.receiver.width) * double(scene.receiver.height);
    ResourcePlan plan;
    double peak_rays = 0, mesh_vertices = double(std::max(scene.surface.nx, 3)) * double(std::max(scene.surface.ny, 3));
    if (kind == RunKind::design) {
        for (const LevelPlan& l : levels ? *levels : plan_levels(scene, options)) {
            const double level_cells = double(l.resolution_x) * double(l.resolution_y);
            const double per_cell = std::max({scene.light.rays_per_cell, options.coarse_rays_per_cell,
                                              fitting_rays_per_cell(scene, min_rays, l.mesh_x, l.mesh_y)});
            peak_rays = std::max(peak_rays, detail::rays_at(scene.light, per_cell, level_cells));
            mesh_vertices = std::max(mesh_vertices, double(l.mesh_x) * double(l.mesh_y));
        }
    } else {
        // A render of the surface uses the design's last-level rays (fitting_rays_per_cell).
        const double per_cell = scene.surface.nx > 0 && scene.surface.ny > 0
                                    ? fitting_rays_per_cell(scene, min_rays, scene.surface.nx, scene.surface.ny)
                                    : scene.light.rays_per_cell;
        peak_rays = detail::rays_at(scene.light, std::max(per_cell, scene.light.rays_per_cell), cells);
    }
    const CellMeanOptions cell_means{};
    const double cell_mean_rays =
        cells * (scene.target || kind == RunKind::design ? cell_means.rays_per_cell : cell_means.max_rays_per_cell);
    const double export_triangles =
        kind == RunKind::design
            ? std::min(double(options.exports.max_triangles), 2.0 * mesh_vertices * 16.0 * 16.0)
            : 0.0;

    struct Part {
        double bytes;
        const char* what;
    };
    const double per_ray = kind == RunKind::design ? detail::design_bytes_per_ray : detail::render_bytes_per_ray;
    const Part parts[] = {
        {peak_rays * per_ray, "rays"},
        {cell_mean_rays * detail::render_bytes_per_ray, "rays of the cell means"},
        {cells * 8.0 * (workers + 8.0), "receiver histograms"},
        {mesh_vertices * detail::bytes_per_vertex, "surface mesh"},
        {export_triangles * detail::bytes_per_export_triangle, "exported mesh"},
    };
    const Part* largest = &parts[0];
    for (const Part& p : parts) {
        plan.bytes += p.bytes;
        if (p.bytes > largest->bytes) largest = &p;
    }
    plan.rays = std::int64_t(std::min(std::max(peak_rays, cell_mean_rays), 9.0e18));
    char count[32];
    std::snprintf(count, sizeof count, "%.3g rays", peak_rays);
    plan.largest = (largest == &parts[0] ? std::string(count) : std::string(largest->what)) + ": " +
                   format_bytes(largest->bytes);
    return plan;
}

// Throws InputError when the plan needs more than limits.memory_bytes, naming the
// largest part (and so the scene key to change).
inline ResourcePlan check_resources(const DesignJob& job, RunKind kind, int threads, const Limits& limits,
                                    const std::vector<LevelPlan>* levels = nullptr) {
    const ResourcePlan plan = plan_resources(job, kind, threads, levels);
    if (plan.bytes > double(limits.memory_bytes))
        over_limit(std::string(kind == RunKind::design ? "the design" : "the render") + " would need about " +
                       format_bytes(plan.bytes) + " of memory (" + plan.largest +
                       "; light.rays_per_cell, light.rays, receiver.resolution and surface.mesh set it)",
                   "memory_bytes", format_bytes(double(limits.memory_bytes)));
    return plan;
}

}  // namespace freeform
