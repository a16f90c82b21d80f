#pragma once
// A whole design in one call (docs/architecture.md, "The path of a scene through a
// design"): plan the mesh and the rays, make the start, anneal, smooth, cut with the
// tool, and judge the result every way metrics.json reports it. The `freeform design`
// command is this call plus argument parsing and writing files; a program that includes
// the library gets the same design from the same scene.
//
//     const freeform::DesignJob job = freeform::io::load_job("letter-e.json");
//     const freeform::CompletedDesign d = freeform::design(job, freeform::io::load_target_image(job.scene));
//     freeform::io::write_stl("letter-e.stl", d.exported.fabrication.mesh);
//
// One entry point, design(job, target, setup), one result, CompletedDesign. A
// DesignSetup (below) carries what a caller may change: callbacks, penalty terms of its
// own, a start surface of its own, the start alone. mpi::design (freeform/mpi/design.hpp,
// freeform::mpi) is the same call over MPI ranks. Its parts, for callers that compose
// their own: plan_design, finish_design, and the annealing core (design/designer.hpp).
//
// A job is a scene and its design options (design/options.hpp). No I/O here: the job, its
// target image and (when the scene starts from a PFM file)
// the start surface come in loaded (io/scene_file.hpp, io/target.hpp, io/heightmap.hpp).
#include <chrono>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../objective/target.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/bspline.hpp"
#include "../surface/smooth.hpp"
#include "../surface/tool.hpp"
#include "../trace/heightfield.hpp"
#include "../trace/setup.hpp"
#include "cell_means.hpp"
#include "designer.hpp"
#include "device.hpp"
#include "fabrication.hpp"
#include "initial.hpp"
#include "machining.hpp"
#include "options.hpp"
#include "start.hpp"
#if defined(FREEFORM_WITH_EMBREE)
#include "exported.hpp"
#endif

namespace freeform {

// What a caller hears during a design. Both may be empty.
struct DesignCallbacks {
    // Every optimise.progress_every iterations; returning true stops the design (the best
    // surface so far is kept and finished like a complete one).
    std::function<bool(const DesignProgress&)> progress;
    // Before each long step that reports no progress of its own: "finding the start" (the
    // first, once plan_design has accepted the scene), "tracing the annealed surface
    // against its start" (optimise.keep_better_start), "exporting the surface and tracing
    // the exported mesh".
    std::function<void(const std::string&)> phase;
};

// A job made ready to design: its levels, planned once, its rays raised for the final
// mesh (optimise.min_rays_per_mesh_cell) and the surface the design starts from.
struct PlannedDesign {
    Scene scene;  // the effective scene: what metrics.json records
    DesignOptions options;
    Heightmap initial;
    std::vector<LevelPlan> levels;  // plan_levels(scene, options): the final mesh and the designer's schedule
};

// Throws InputError, naming the key, for a scene that cannot be designed.
inline void check_designable(const Scene& scene) {
    if (!scene.target) throw InputError("target: a design needs a \"target\" block");
    if (!scene.meshes.empty())
        throw InputError("meshes: designing with extra meshes is not supported yet (render them with the Embree tracer)");
}

// Checks that the job's scene can be designed and plans it. `initial` replaces the scene's
// start (a surface read from a file); without it a scene whose start is a PFM file is
// refused. `levels`: plan_levels(scene, options), when the caller has planned them
// already (to check the memory they need before any surface is made, as the command
// line does).
inline PlannedDesign plan_design(const DesignJob& job, std::optional<Heightmap> initial = {},
                                 std::optional<std::vector<LevelPlan>> levels = {}) {
    const Scene& scene = job.scene;
    check_designable(scene);
    PlannedDesign p{scene, job.options, Heightmap{},
                    levels ? std::move(*levels) : plan_levels(scene, job.options)};
    const auto [nx, ny] = final_mesh(scene, p.levels);
    // Enough rays for the final mesh: the design, its checks and its final render use them.
    p.scene.light.rays_per_cell = fitting_rays_per_cell(scene, job.options.min_rays_per_mesh_cell, nx, ny);
    if (initial) {
        p.initial = std::move(*initial);
    } else {
        if (!scene.surface.initial_pfm.empty())
            throw InputError("surface.initial: the start is a PFM file; load it (io::load_start_surface) and "
                             "pass it to design() (DesignSetup::initial)");
        p.initial = initial_surface(p.scene, nx, ny);
    }
    // A transport start the scene asks for by name must be possible: say so before any work.
    if (scene.surface.initial_shape == InitialShape::transport && requested_start(scene) == StartKind::transport)
        flat_footprint(p.scene, p.initial);
    return p;
}

// A surface traced with one set of rays at the receiver's resolution (its set-up: rays,
// path parameters, the target scaled to the rays), and what they did.
struct TracedDesign : TraceSetup {
    Histogram histogram;
    TraceTotals totals;
    double error = -1;  // l1_error(histogram, target)
};

inline TracedDesign trace_design(const Scene& scene, const Heightmap& surface, const ImageD& target, std::uint64_t seed,
                                 int threads) {
    TracedDesign t{make_trace_setup(scene, surface, &target, seed), {}, {}, -1};
    t.histogram = t.empty_histogram();
    HeightfieldTracer(surface, t.rays, t.params).trace_all(exec::omp_t{threads}, t.histogram, t.totals);
    t.error = l1_error(t.histogram, t.target);
    return t;
}

// The exported part and what it does (docs/measures.md).
struct ExportChecks {
    Fabrication fabrication;    // the mesh that is milled (surface.obj / .stl)
    MachiningReport machining;  // metrics.json's "fabrication" block
    // Traced as flat triangles (Embree builds only; empty without Embree):
    std::optional<double> error_exported;   // with the design's rays and deposit (a diagnostic)
    std::optional<double> energy_exported;
    std::optional<double> l1_to_design;     // between its irradiance and the design's
    std::optional<CellMeans> cells;         // converged cell means: error_physical
    // The smooth form of surface.step: the B-spline fitted to the designed surface, and
    // how closely it follows it (docs/export.md). surface.dat carries the height map's
    // own vertices instead (io/sag.hpp).
    BSplineSurface spline;
    SplineFitReport spline_fit;
    // The designed surface itself (the Phong height field the design simulated), traced
    // the same way: what every exported form is compared with.
    std::optional<CellMeans> designed;
};

// Samples per cell and direction of the spline fit: the fit's height error is about a
// nanometre at 2 and does not improve beyond 4 (docs/export.md).
inline constexpr int spline_samples_per_cell = 4;

// The most poles for which "auto" gives the STEP part the Hermite spline
// (hermite_bspline, surface/bspline.hpp): about 94 bytes a pole in the file, so under
// 50 MB (docs/export.md's size goal). Grids up to 353 x 353 vertices fit; larger ones get
// the least-squares spline, a quarter of the poles.
inline constexpr std::int64_t hermite_max_poles = 500000;

// The spline the STEP part of `top` (export_blank) carries (optimise.export_spline;
// docs/export.md, "Which spline"). The Hermite surface keeps the designed cell means
// better on sharp designs (the vertex normals are the design's own), the least-squares one
// keeps curvature continuous and has a quarter of the poles.
inline BSplineSurface step_spline(const Heightmap& top, double alpha, SplineForm form) {
    const bool fits = std::int64_t(2 * top.nx()) * std::int64_t(2 * top.ny()) <= hermite_max_poles;
    if (form == SplineForm::hermite || (form == SplineForm::automatic && fits)) return hermite_bspline(top);
    return fit_bspline(top, alpha, spline_samples_per_cell);
}

// Cell means for error_physical: rays of their own jitter, not the design's, so the figure
// is not the one the design was fitted to.
inline CellMeanOptions physical_cell_mean_options(std::uint64_t seed) {
    CellMeanOptions o;
    o.seed = hash_combine(seed, 0x63656c6c6d65616eULL);
    return o;
}

// The designed surface's cell means as error_physical's "designed" figure traces them.
inline CellMeans designed_physical_cell_means(const Scene& scene, const DesignOptions& options,
                                              const Heightmap& surface, const ImageD& target, int threads) {
    return designed_cell_means(scene, surface, target, physical_cell_mean_options(options.seed), threads);
}

// `designed`: the surface's designed cell means when the caller has traced them already
// (designed_physical_cell_means).
inline ExportChecks check_export(const Scene& scene, const DesignOptions& options, const Heightmap& surface,
                                 const TracedDesign& fitted, const ImageD& target, int threads,
                                 std::optional<CellMeans> designed = {}) {
    ExportChecks c{make_fabrication(scene, options.exports, surface), {}, {}, {}, {}, {}, {}, {}, {}};
    c.machining = machining_report(scene, surface, c.fabrication.mesh);
    // The smooth forms cover the exported top: a lens's rim too (export_blank).
    const Heightmap top = export_blank(scene, surface);
    c.spline = step_spline(top, scene.surface.phong_alpha, options.exports.spline);
    c.spline_fit = check_spline_fit(c.spline, top, scene.surface.phong_alpha, spline_samples_per_cell);
    c.designed = designed ? std::move(designed) : designed_physical_cell_means(scene, options, surface, target, threads);
#if defined(FREEFORM_WITH_EMBREE)
    const ExportedGeometry geometry = exported_geometry(scene, surface, c.fabrication.subdivisions);
    const ExportedTrace et = trace_exported(exec::omp_t{threads}, scene, geometry, fitted);
    c.error_exported = l1_error(et.histogram, fitted.target);
    c.energy_exported = et.totals.energy();
    c.l1_to_design = l1_error(et.histogram.cells, fitted.histogram.cells, fitted.rays.total);
    c.cells = exported_cell_means(exec::omp_t{threads}, scene, surface, geometry, &target,
                                  physical_cell_mean_options(options.seed));
#else
    (void)fitted;
#endif
    return c;
}

// Which surface a design delivers (optimise.keep_better_start; docs/measures.md, "Keeping
// the start"): the annealed one, or its start where the start's designed cell means are
// lower. Annealing minimises its objective on the design's rays; the cell means are what
// the part is judged by, and the two can part ways (a mesh much finer than its receiver's
// pixels, a short budget whose first stage has not yet recovered), so both surfaces are
// finished alike and traced as error_physical's "designed" figure is.
struct DeliveredSurface {
    bool start = false;          // the start was delivered
    double annealed_error = -1;  // designed cell means of the annealed surface, finished
    double start_error = -1;     // ... of the start, finished alike
};

// A finished design: the surface as it is milled, and every figure metrics.json reports.
struct CompletedDesign {
    Scene scene;           // the effective scene (rays per cell raised for the final mesh)
    DesignOptions options;  // the options it was designed with
    DesignResult result;   // result.surface: after smoothing and the tool's cut
    TracedDesign fitted;   // traced with the scene's seed: the rays it was fitted to
    std::optional<double> error_held_out;  // with the final level's held-out rays (checks on)
    ExportChecks exported;
    // The annealed surface against its start (empty: keep_better_start off, or no start to
    // compare with). When the start was delivered, result.surface is the start, finished;
    // the annealing's own figures (result.value, stages, convergence) stay the annealing's.
    std::optional<DeliveredSurface> delivered;
    // Wall time after the annealing (result.seconds, the start included, is what
    // optimise.time_budget bounds): smoothing, the tool's cut, the final traces and the
    // export checks. The summary states it beside the budget.
    double finish_seconds = 0;

    // The figure a design is judged by: the cell-mean error of the exported mesh
    // (docs/measures.md); empty in a build without Embree.
    std::optional<double> error_physical() const {
        if (!exported.cells) return std::nullopt;
        return exported.cells->error;
    }
};

// Smooths (optimise.smooth_iterations) and cuts with the tool (surface.tool_radius) a
// surface as it is delivered; `tool_cut` gets the most height the cut added.
inline void finish_surface(const Scene& scene, const DesignOptions& options, Heightmap& surface, double& tool_cut) {
    if (options.smooth_iterations > 0) smooth_heights(surface, options.smooth_iterations);
    // The tool's cut last of all: every figure describes what the mill leaves.
    if (scene.surface.tool_radius > 0)
        tool_cut = std::max(tool_cut, cut_with_ball(surface, scene.surface.tool_radius));
}

// Finishes `result`'s surface, and its start alike where options.keep_better_start asks to
// compare them (DeliveredSurface); result.surface becomes the start where that traces
// better. Returns the delivered surface's designed cell means when they were traced.
inline std::optional<CellMeans> deliver_surface(const Scene& scene, const DesignOptions& options,
                                                DesignResult& result, const ImageD& target,
                                                std::optional<DeliveredSurface>& delivered) {
    std::optional<Heightmap> start = std::move(result.start_surface);
    result.start_surface.reset();
    const bool compare = options.keep_better_start && start && start->nx() == result.surface.nx() &&
                         start->ny() == result.surface.ny();
    // Nothing annealed (a budget the start used up): the two are one surface, traced once.
    const bool unchanged = compare && start->heights() == result.surface.heights();
    finish_surface(scene, options, result.surface, result.tool_cut);
    if (!compare) return std::nullopt;
    CellMeans annealed = designed_physical_cell_means(scene, options, result.surface, target, options.threads);
    if (unchanged) {
        delivered = DeliveredSurface{false, annealed.error, annealed.error};
        return annealed;
    }
    double start_cut = 0;
    finish_surface(scene, options, *start, start_cut);
    CellMeans from_start = designed_physical_cell_means(scene, options, *start, target, options.threads);
    delivered = DeliveredSurface{from_start.error < annealed.error, annealed.error, from_start.error};
    if (!delivered->start) return annealed;
    result.surface = std::move(*start);
    result.tool_cut = start_cut;
    return from_start;
}

// Smooths (optimise.smooth_iterations), cuts with the tool (surface.tool_radius), keeps the
// start where it traces better (optimise.keep_better_start) and judges an annealed design:
// the fitted and held-out errors, the export and its cell means (`export_checks`:
// DesignSetup::export_checks).
inline CompletedDesign finish_design(const Scene& scene, const DesignOptions& options, DesignResult result,
                                     const ImageD& target, const DesignCallbacks& callbacks = {},
                                     bool export_checks = true) {
    const auto t0 = std::chrono::steady_clock::now();
    std::optional<DeliveredSurface> delivered;
    if (options.keep_better_start && result.start_surface && callbacks.phase)
        callbacks.phase("tracing the annealed surface against its start");
    std::optional<CellMeans> designed = deliver_surface(scene, options, result, target, delivered);
    const int threads = options.threads;
    CompletedDesign d{scene, options, std::move(result), {}, std::nullopt, {}, delivered};
    d.fitted = trace_design(scene, d.result.surface, target, options.seed, threads);
    if (d.result.held_out.total >= 0)
        d.error_held_out = trace_design(scene, d.result.surface, target, d.result.held_out_seed, threads).error;
    if (export_checks) {
        if (callbacks.phase) callbacks.phase("exporting the surface and tracing the exported mesh");
        d.exported = check_export(scene, options, d.result.surface, d.fitted, target, threads, std::move(designed));
    }
    d.finish_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return d;
}

// How a design runs: what the caller hears, and what it changes. Every field may be left
// as it is: `design(job, target)` is `freeform design`.
struct DesignSetup {
    DesignCallbacks callbacks;
    // The height terms of the objective (objective/penalty.hpp). Empty: the terms the
    // job's options ask for, default_penalties(options.penalties, scene.surface.tool_radius).
    // To add a term of your own, start from those and add it (docs/library.md, "A custom
    // term"); a Penalties given here replaces them whole.
    std::optional<Penalties> penalties;
    // The surface the design starts from, on the final mesh (io::load_start_surface reads
    // the PFM file a scene names as its start). Empty: the scene's own start (flat, a
    // paraboloid, the transport start); a scene whose start is a PFM file is then refused.
    std::optional<Heightmap> initial;
    // true: the start alone (the transport surface, or whatever the scene starts from),
    // judged and finished like a design but not annealed; the penalties are then unused.
    // What `freeform design --start-only` writes.
    bool start_only = false;
    // false: the finish leaves out the export and its checks (CompletedDesign::exported
    // stays empty, error_physical() too): for a caller that judges the surface its own way
    // and needs neither the part nor its figures, such as the study (benchmarks/study).
    // Smoothing, the tool's cut and the fitted and held-out traces still run.
    bool export_checks = true;
    // The CUDA device this program can offer for optimise.device "cuda" or "auto"
    // (design/device.hpp): the command line's in a build with CUDA. Empty: none, and a
    // job that asks for "cuda" is refused (choose_device).
    std::optional<DeviceOffer> cuda;
};

// The device a job's windows run on: null for the CPU, or the offered device.
// optimise.device "cuda" with no usable device offered, or with full retraces, throws an
// InputError that names `key` ("optimise.device"; the command line's "--device" when it
// set the value); "auto" then quietly takes the CPU. Cheap: call it before any work.
inline const DeviceOffer* choose_device(const DesignOptions& options, const std::optional<DeviceOffer>& offer,
                                        const std::string& key = "optimise.device") {
    if (options.device == Device::cpu) return nullptr;
    const bool usable = offer && offer->usable();
    if (options.device == Device::automatic)
        return usable && options.evaluation == EvaluationMode::incremental ? &*offer : nullptr;
    if (!usable)
        throw InputError(key + ": \"cuda\" asked for, but " +
                         (!offer ? std::string("the program running this design offers no CUDA device (the "
                                               "freeform command line does when built with CUDA; docs/cuda.md)")
                                 : offer->unavailable.empty() ? std::string("the offered device cannot make a backend")
                                                              : offer->unavailable));
    if (options.evaluation != EvaluationMode::incremental)
        throw InputError(key + ": \"cuda\" judges moves incrementally; optimise.evaluation \"full\" runs on the CPU only");
    return &*offer;
}

namespace pipeline_detail {

// The start of a planned design alone, as a DesignResult of no iterations.
inline DesignResult start_only(PlannedDesign& plan, const ImageD& target) {
    const auto t0 = std::chrono::steady_clock::now();
    DesignStart start = make_design_start(plan.scene, std::move(plan.initial), target, plan.options,
                                          thread_count(exec::omp_t{plan.options.threads}));
    DesignResult result;
    result.start = start.report;
    result.start.plan = "the start only: no annealing";
    result.surface = std::move(start.surface);
    result.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return result;
}

// Anneals a planned design, its start included, as one replica of `replicas`
// (design/replicas.hpp; SingleReplica: the plain design), with the setup's penalties and
// progress callback.
template <ReplicaCoordinator Replicas>
DesignResult anneal(PlannedDesign& plan, const ImageD& target, const DesignSetup& setup, Replicas& replicas) {
    const DesignCallbacks& callbacks = setup.callbacks;
    const auto progress = [&](const DesignProgress& p) { return callbacks.progress ? callbacks.progress(p) : false; };
    const DesignOptions& options = plan.options;
    return freeform::design(plan.scene, std::move(plan.initial), target, options, progress,
                            setup.penalties ? *setup.penalties
                                            : default_penalties(options.penalties, plan.scene.surface.tool_radius),
                            replicas, &plan.levels, choose_device(options, setup.cuda));
}

// The finish the setup asks for (finish_design).
inline CompletedDesign finish(const PlannedDesign& plan, DesignResult result, const ImageD& target,
                              const DesignSetup& setup) {
    return finish_design(plan.scene, plan.options, std::move(result), target, setup.callbacks, setup.export_checks);
}

}  // namespace pipeline_detail

// The design of a scene its caller has planned already (plan_design), to read the plan
// first: the command line prints the final mesh and checks the memory the levels need
// before it designs, and plans the scene once for all three. The start surface is the
// plan's (setup.initial is not read). The start, the annealing unless setup.start_only,
// the finish.
inline CompletedDesign design(PlannedDesign plan, const ImageD& target, const DesignSetup& setup = {}) {
    if (!setup.start_only) choose_device(plan.options, setup.cuda);  // a refused device: before any work
    if (setup.callbacks.phase) setup.callbacks.phase(finding_the_start(plan.scene));
    DesignResult result;
    if (setup.start_only) {
        result = pipeline_detail::start_only(plan, target);
    } else {
        SingleReplica single;
        result = pipeline_detail::anneal(plan, target, setup, single);
    }
    return pipeline_detail::finish(plan, std::move(result), target, setup);
}

// Designs the job's scene with its options so that its light matches `target` (relative irradiance, any
// resolution, area-averaged to each level: io::load_target_image makes it from the scene's target block,
// brought up smoothly to the receiver's pixels where it has fewer, upsample_linear): plans it
// (plan_design), makes the start, anneals, and finishes the result (finish_design). The
// one entry point of a design (the overload above is it with the plan made by the
// caller); mpi::design (freeform/mpi/design.hpp) is the same over MPI ranks. Throws
// InputError for a scene that cannot be designed.
inline CompletedDesign design(const DesignJob& job, const ImageD& target, const DesignSetup& setup = {}) {
    return design(plan_design(job, setup.initial), target, setup);
}

}  // namespace freeform
