#pragma once
// A render in one call: trace what a scene's light does to a surface (a height map or a
// triangle mesh in its place, and the scene's extra meshes), and judge it against the
// scene's target the way a design is judged (the error with the scene's deposit, and the
// converged cell means: error_physical, docs/measures.md). `freeform render` is this
// call plus argument parsing and writing files.
//
//     const freeform::Heightmap h = freeform::io::read_heightmap(scene, "heightmap.pfm");
//     const freeform::RenderResult r = freeform::render(scene, h, freeform::io::load_target_image(scene));
//     // r.error_physical(), r.histogram, r.totals.energy() ...
//
// A RenderRequest says more: a mesh in the surface's place, the scene's extra meshes, the
// tracer, the thread count.
//
// No I/O here: the surface, meshes and target come in loaded (io/heightmap.hpp,
// io/mesh.hpp, io/target.hpp).
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../objective/trace_setup.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/export.hpp"
#include "../surface/heightmap.hpp"
#include "../surface/triangle_mesh.hpp"
#include "../trace/heightfield.hpp"
#include "../trace/select.hpp"
#include "../trace/setup.hpp"
#include "cell_means.hpp"
#include "initial.hpp"
#include "options.hpp"
#include "pipeline.hpp"
#include "start.hpp"
#if defined(FREEFORM_WITH_EMBREE)
#include "../trace/embree.hpp"
#endif

namespace freeform {

inline constexpr bool embree_available =
#if defined(FREEFORM_WITH_EMBREE)
    true;
#else
    false;
#endif

// What to render. Meshes are in world coordinates, as read from their files.
struct RenderRequest {
    Scene scene;
    // The height field traced; with `mesh`, only the grid that places the rays.
    Heightmap surface;
    // `surface` is the scene's own start (io::scene_surface), not a given height map: a
    // scene that starts from the transport solution (and has a target) renders that start,
    // found as a design would find it.
    bool surface_is_scene_start = false;
    std::optional<ImageD> target;                 // the scene's target image: error and cell means
    std::optional<TriangleMesh> mesh;             // traced in the surface's place (Embree)
    std::string mesh_name = "the mesh";           // how errors name `mesh` (its file, say)
    // `mesh` is a refractive solid of this material: one closed surface, its corners shared
    // between faces (io::welded merges the corners that OBJ and STL files repeat).
    std::optional<MeshMaterial> mesh_material;
    std::vector<TriangleMesh> scene_meshes;       // scene.meshes[k] loaded, in order (refractive ones welded)
    TracerChoice tracer = TracerChoice::automatic;
    bool mesh_normals = false;  // shade meshes with interpolated vertex normals (not physical)
    int threads = 0;            // 0: every core
    // The scene file's design options (its "optimise" block). A render reads two: `seed`
    // (the rays' jitter, the start) and `min_rays_per_mesh_cell` (a surface is rendered
    // with the rays a design on its grid fits, fitting_rays_per_cell); the result keeps
    // all of them, so that its effective scene reads back as the same job.
    DesignOptions options;
};

// Rays traced so far of those the current pass traces; a render makes one pass for its
// image and, with a target, a few more for the cell means.
struct RenderCallbacks {
    std::function<void(std::int64_t traced, std::int64_t total)> progress;
    // Before a long step that reports no progress of its own ("finding the start").
    std::function<void(const std::string&)> phase;
};

struct RenderResult {
    Scene scene;            // the effective scene: rays per cell as traced
    DesignOptions options;  // RenderRequest::options
    TracerDecision decision;
    Heightmap surface;                 // what was traced (the start, when it was found)
    std::optional<StartReport> start;  // the scene's start was found (transport)
    std::int64_t rays = 0;
    Histogram histogram;  // with the scene's deposit
    TraceTotals totals;
    double seconds = 0;                  // tracing the image (the tracer's set-up excluded)
    std::optional<double> error;         // against the target, the scene's deposit
    std::optional<CellMeans> cells;      // converged cell means (with a target)
    int threads = 1;

    std::optional<double> error_physical() const {
        if (!cells) return std::nullopt;
        return cells->error;
    }
};

namespace render_detail {

// Traces every ray of `rays` in chunks, so that a long trace can report progress.
// Returns the seconds spent tracing (the tracer's set-up, a BVH build say, excluded).
template <class Tracer>
double trace_in_chunks(const Tracer& tracer, const RaySet& rays, int threads, const RenderCallbacks& callbacks,
                       Histogram& histogram, TraceTotals& totals) {
    const auto t0 = std::chrono::steady_clock::now();
    const PathParams& pp = tracer.params();
    histogram = Histogram(pp.receiver.width, pp.receiver.height);
    totals = TraceTotals{};
    totals.emitted = rays.total;
    const std::int64_t n = rays.size();
    const int chunks = int(std::clamp<std::int64_t>(n / 65536, 1, 64));
    std::vector<std::int32_t> ids;
    std::vector<RayRecord> records;
    for (int c = 0; c < chunks; ++c) {
        const std::int64_t begin = n * c / chunks, end = n * (c + 1) / chunks;
        ids.resize(std::size_t(end - begin));
        for (std::int64_t k = begin; k < end; ++k) ids[std::size_t(k - begin)] = std::int32_t(k);
        records.resize(ids.size());
        tracer.trace(exec::omp_t{threads}, ids, records);
        for (std::size_t k = 0; k < ids.size(); ++k) {
            const Fixed w = rays.weight[std::size_t(ids[k])];
            totals.add(records[k], w);
            deposit_record(pp.receiver, records[k], w, histogram.cells);
        }
        if (callbacks.progress) callbacks.progress(end, n);
    }
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Traces the rays of `setup` through what `job` renders, with the set-up's receiver (the
// scene's, or its nearest-deposit twin for the cell means); `sc` places the meshes and
// the light. Returns the seconds spent tracing.
inline double trace_job(const RenderRequest& job, TracerChoice tracer, const Scene& sc, const TraceSetup& setup,
                        int threads, const RenderCallbacks& callbacks, Histogram& histogram, TraceTotals& totals) {
    const RaySet& rays = setup.rays;
    PathParams pp = setup.params;
    // A mesh is its geometry: flat facets, stored normals unused, unless asked otherwise.
    if (job.mesh && !job.mesh_normals) pp.phong_alpha = 0.0f;
    // A refractive solid is the whole lens: the scene's lens model (its flat back face)
    // does not apply.
    if (job.mesh_material) pp.material = MaterialView{};
    pp.interpolated_normals = job.mesh_normals;
    if (tracer == TracerChoice::heightfield)
        return trace_in_chunks(HeightfieldTracer(job.surface, rays, pp), rays, threads, callbacks, histogram,
                               totals);
#if defined(FREEFORM_WITH_EMBREE)
    std::vector<ExtraMesh> extras;
    for (std::size_t k = 0; k < job.scene_meshes.size(); ++k)
        extras.push_back(to_surface_frame(job.scene_meshes[k], sc.surface.frame, sc.meshes[k].material));
    if (job.mesh && job.mesh_material) {
        // A collimated beam starts above the solid, which may rise above the surface's bounds.
        ExtraMesh solid = to_surface_frame(*job.mesh, sc.surface.frame, *job.mesh_material);
        RaySet lifted = rays;
        start_above(sc.light, sc.surface.size, solid.mesh, lifted);
        extras.insert(extras.begin(), std::move(solid));
        return trace_in_chunks(EmbreeTracer(lifted, pp, std::move(extras), threads), lifted, threads, callbacks,
                               histogram, totals);
    }
    if (job.mesh) {
        const ExtraMesh local = to_surface_frame(*job.mesh, sc.surface.frame, true);
        return trace_in_chunks(EmbreeTracer(local.mesh, rays, pp, std::move(extras), threads), rays, threads,
                               callbacks, histogram, totals);
    }
    return trace_in_chunks(
        EmbreeTracer(job.surface, rays, pp, std::move(extras), 32, EmbreeTileLayout::instanced, threads), rays,
        threads, callbacks, histogram, totals);
#else
    (void)sc, (void)rays, (void)threads, (void)callbacks, (void)histogram, (void)totals;
    throw InputError("the Embree tracer is not in this build");  // choose_tracer refuses it first
#endif
}

// Checks what the request asks for against the scene (InputError names the part).
inline void check_render(const RenderRequest& job) {
    if (job.scene_meshes.size() != job.scene.meshes.size())
        throw InputError("meshes: " + std::to_string(job.scene.meshes.size()) + " in the scene, " +
                         std::to_string(job.scene_meshes.size()) + " loaded");
    if (job.mesh_material && !job.mesh)
        throw InputError("mesh material: applies to a mesh traced in the surface's place, and none was given");
    if (job.mesh_material) check_refractive_solid(*job.mesh, job.mesh_name);
    for (std::size_t k = 0; k < job.scene_meshes.size(); ++k)
        if (job.scene.meshes[k].material.is_refractive())
            check_refractive_solid(job.scene_meshes[k], job.scene.meshes[k].file.string());
    if (job.mesh_normals && !job.mesh && job.scene.meshes.empty())
        throw InputError("mesh normals: the scene has no mesh to shade");
}

}  // namespace render_detail

// Renders `job`: the image with the scene's rays and deposit, and with a target its error
// and converged cell means. Throws InputError for a request that cannot be traced.
inline RenderResult render(RenderRequest job, const RenderCallbacks& callbacks = {}) {
    render_detail::check_render(job);
    RenderResult r;
    r.threads = thread_count(exec::omp_t{job.threads});
    r.decision = choose_tracer(job.scene, job.mesh.has_value(), job.tracer, embree_available);
    Scene& scene = job.scene;
    // The scene's start as a design would begin; not needed when a mesh replaces the
    // surface (the grid only places the rays).
    if (job.surface_is_scene_start && job.target && !job.mesh && starts_from_transport(scene) &&
        scene.meshes.empty()) {
        if (callbacks.phase) callbacks.phase(finding_the_start(scene));
        if (scene.surface.initial_shape == InitialShape::transport) flat_footprint(scene, job.surface);
        DesignStart st = make_design_start(scene, std::move(job.surface), *job.target, job.options, r.threads);
        r.start = st.report;
        job.surface = std::move(st.surface);
    }
    // A surface (the scene's or a height map) is traced with the rays a design on its grid
    // fits (optimise.min_rays_per_mesh_cell), so a design's height map renders to its error.
    if (!job.mesh)
        scene.light.rays_per_cell =
            fitting_rays_per_cell(scene, job.options.min_rays_per_mesh_cell, job.surface.nx(), job.surface.ny());

    const TraceSetup setup =
        make_trace_setup(scene, job.surface, job.target ? &*job.target : nullptr, job.options.seed);
    r.rays = setup.rays.size();
    r.seconds =
        render_detail::trace_job(job, r.decision.tracer, scene, setup, r.threads, callbacks, r.histogram, r.totals);
    if (job.target) {
        r.error = l1_error(r.histogram, setup.target);
        r.cells = converged_cell_means(
            scene, job.surface, &*job.target, physical_cell_mean_options(job.options.seed),
            [&](const Scene& sc, const TraceSetup& batch, Histogram& h, TraceTotals& tt) {
                render_detail::trace_job(job, r.decision.tracer, sc, batch, r.threads, callbacks, h, tt);
            });
    }
    r.scene = std::move(job.scene);
    r.options = std::move(job.options);
    r.surface = std::move(job.surface);
    return r;
}

// A height map under the scene's light, judged against `target` when one is given, with
// the seed and the rays per mesh cell of `options` (a design's: CompletedDesign::options).
inline RenderResult render(const Scene& scene, const DesignOptions& options, Heightmap surface,
                           std::optional<ImageD> target = {}, const RenderCallbacks& callbacks = {}) {
    RenderRequest job;
    job.scene = scene;
    job.options = options;
    job.surface = std::move(surface);
    job.target = std::move(target);
    return render(std::move(job), callbacks);
}

}  // namespace freeform
