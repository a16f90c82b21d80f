// study_run: one run of the speed/accuracy study — one case, one method, one seed, one
// time budget — written as a JSON result. benchmarks/study/run_study.py runs it many
// times and turns the results into benchmarks/results/ (see benchmarks/study/README.md).
//
//   study_run --scene S.json --engine E --seed N --time-budget SEC --threads T --out R.json
//             [--case-patch JSON] [--patch JSON] [--label NAME] [--eval-seed N]
//             [--control N] [--kernel-supports K] [--mesh-scale K] [--rays-scale F]
//             [--check-render] [--compare-tracers] [--save-images PREFIX] [--start-only]
//
// Engines:
//   design        the library's design, freeform::design() as `freeform design` runs it
//                 (design/pipeline.hpp, without the export checks): ours and every variant
//                 of it (ablations, full-retrace evaluation, one kernel shape, ...) is a
//                 --patch of the scene's "optimise"/"surface"/"light" keys. With
//                 --start-only it makes the design's start alone (DesignSetup::start_only:
//                 the transport surface for a scene with a target, unless the patch asks
//                 for another start) with the run's seed, no annealing: "transport-only"
//   spsa          SPSA on the control grid (spsa.hpp)
//   pagmo-sa, pagmo-cmaes, pagmo-xnes, pagmo-sade   pagmo2 on the control grid (generic.hpp)
//   nlopt-bobyqa, nlopt-crs2                        NLopt on the control grid (generic.hpp)
//
// Result JSON: the final evaluation (error, energy, objective from one full render in the
// case: its receiver, its light, its seed; see common.hpp), the work done (iterations,
// evaluations, per second), the model the method used, the trace of its progress and
// engine-specific details. Exit code 2 on bad input, 3 when an engine is not built in.
#include <bit>
#include <cstdio>
#include <exception>
#include <iostream>
#include <string>

#include <CLI/CLI.hpp>

#include <freeform/design/pipeline.hpp>

#include "common.hpp"
#include "control_grid.hpp"
#include "generic.hpp"
#include "spsa.hpp"

namespace {

using namespace study;

struct Args {
    fs::path scene, out;
    std::string engine = "design", label, case_patch, patch, save_images;
    std::uint64_t seed = 1;
    std::optional<std::uint64_t> eval_seed;
    double time_budget = 10;
    int threads = 0;
    int control = 13;
    int kernel_supports = 0;
    int mesh_scale = 1;
    double rays_scale = 1;
    bool check_render = false, compare_tracers = false, start_only = false;
    std::int64_t progress_every = 200;
    SpsaSettings spsa;
};

struct NotBuilt : std::runtime_error {
    using std::runtime_error::runtime_error;
};

json evaluation_json(const Evaluation& e) {
    return {{"error", e.error},     {"energy", e.energy}, {"objective", e.objective},
            {"sobel", e.sobel},     {"rays", e.rays},     {"render_seconds", e.seconds},
            {"rays_per_second", e.seconds > 0 ? double(e.rays) / e.seconds : 0.0}};
}

void save_images(const std::string& prefix, const Evaluation& e, const Heightmap& surface) {
    if (prefix.empty()) return;
    const fs::path p(prefix);
    if (p.has_parent_path()) fs::create_directories(p.parent_path());
    io::write_pfm(prefix + "-irradiance.pfm", e.histogram.to_image().cast<float>());
    io::write_pfm(prefix + "-target.pfm", target_image(e.target).cast<float>());
    io::write_heightmap(prefix + "-heightmap.pfm", surface);
}

// A fingerprint of the designed heights, bit for bit: two runs that followed the same
// trajectory (full against incremental evaluation, same seed) end with the same one.
std::string heights_fingerprint(const Heightmap& h) {
    std::uint64_t x = hash_combine(std::uint64_t(h.nx()), std::uint64_t(h.ny()));
    for (const float v : h.heights()) x = hash_combine(x, std::bit_cast<std::uint32_t>(v));
    char text[17];
    std::snprintf(text, sizeof text, "%016llx", (unsigned long long)x);
    return text;
}

std::vector<TracePoint> trace_of(const DesignResult& r) {
    std::vector<TracePoint> t;
    t.reserve(r.convergence.size());
    for (const auto& c : r.convergence) t.push_back({c.seconds, c.iteration, c.level, c.error, c.energy, c.objective});
    return t;
}

// The design engine: freeform::design() (design/pipeline.hpp) on the run's scene, as
// `freeform design` runs it (the plan raises the final level's rays to
// optimise.min_rays_per_mesh_cell per mesh cell, so that a design cannot fit its rays'
// noise; smoothing and the tool's cut as the scene asks), without the export checks: the
// surface is judged below like every other engine's. With --start-only the start alone
// (the transport surface for a scene with a target, unless the patch asks for another
// start): "transport-only". Fills `out`, `model` and the trace; returns the surface.
Heightmap run_design_engine(const Args& a, DesignJob job, const ImageD& target, json& out, json& model,
                            std::vector<TracePoint>& trace, int& trace_levels) {
    const Scene& scene = job.scene;
    DesignOptions& o = job.options;
    o.seed = a.seed;
    o.time_budget = a.time_budget;
    o.threads = a.threads;
    o.progress_every = a.progress_every;
    if (a.kernel_supports > 0) {
        o.levels = plan_levels(scene, o);
        for (auto& l : o.levels) l.kernel_supports = {a.kernel_supports};
    }
    DesignSetup setup;
    setup.initial = io::load_start_surface(scene, plan_levels(scene, o));
    setup.start_only = a.start_only;
    setup.export_checks = false;
    CompletedDesign d = design(job, target, setup);
    DesignResult& r = d.result;
    // The designer's own clock: the start (solve, fit and its exact-tracer check) and the
    // annealing, not the finish's traces.
    const double seconds = r.seconds;
    model["rays_per_cell"] = d.scene.light.rays_per_cell;
    model["start"] = to_string(r.start.used);
    out["seconds"] = seconds;
    out["iterations"] = r.iterations;
    out["evaluations"] = r.iterations;
    out["iterations_per_second"] = seconds > 0 ? double(r.iterations) / seconds : 0.0;
    out["start"] = io::start_report_json(r.start);
    if (a.start_only) {
        // One trace point: the start's error and energy as the library measured them (run
        // seed, final receiver resolution; the objective is not computed there: 0).
        if (r.start.error >= 0) trace.push_back({seconds, 0, 0, r.start.error, r.start.energy, 0.0});
        return std::move(r.surface);
    }
    trace = trace_of(r);
    std::int64_t proposals = 0;
    int levels = 0;
    for (const auto& s : r.stages) proposals += s.proposals_evaluated, levels = std::max(levels, s.level + 1);
    trace_levels = std::max(1, levels);
    out["proposals_evaluated"] = proposals;
    out["accepted"] = r.accepted;
    out["stages"] = io::stage_reports_json(r.stages);
    out["bandit"] = to_string(o.proposals.bandit);
    out["evaluation"] = to_string(o.evaluation);
    out["kernel_shapes"] = to_string(o.proposals.kernel_shapes);
    out["max_iterations"] = o.max_iterations;
    out["stop_reasons"] = json::array();
    for (const auto& s : r.stages) out["stop_reasons"].push_back(to_string(s.stop_reason));
    out["bandit_weights"] = r.bandit_weights;
    json bank = json::array();
    for (const auto& k : r.kernel_bank) {
        // Which shape of the standard bank this is (the history bandit's pre-process keeps
        // a subset), so that weights can be compared across runs and cases.
        int index = -1;
        const auto standard = default_kernel_bank(std::max(3, k.support | 1));
        for (std::size_t j = 0; j < standard.size(); ++j)
            if (standard[j].sigma_x == k.sigma_x && standard[j].sigma_y == k.sigma_y && standard[j].rho == k.rho)
                index = int(j);
        bank.push_back({{"sigma_x", k.sigma_x},
                        {"sigma_y", k.sigma_y},
                        {"rho", k.rho},
                        {"support", k.support},
                        {"standard_index", index}});
    }
    out["kernel_bank"] = bank;
    out["preprocess_rates"] = r.preprocess_rates;
    model["levels"] = json::array();
    for (const auto& s : r.stages)
        if (model["levels"].empty() || model["levels"].back()["level"] != s.level)
            model["levels"].push_back({{"level", s.level},
                                       {"mesh", json::array({s.mesh_x, s.mesh_y})},
                                       {"resolution", json::array({s.resolution_x, s.resolution_y})},
                                       {"rays", s.rays},
                                       {"kernels", json::array()}});
    for (const auto& s : r.stages) model["levels"][std::size_t(s.level)]["kernels"].push_back(s.kernel_support);
    model["rays"] = r.rays;
    return std::move(r.surface);
}

int run(const Args& a) {
    const json case_patch = parse_json_option(a.case_patch, "--case-patch");
    const json method_patch = parse_json_option(a.patch, "--patch");
    if (!(a.time_budget > 0)) throw InputError("--time-budget: must be > 0 seconds");
    if (a.mesh_scale < 1) throw InputError("--mesh-scale: must be >= 1");
    if (!(a.rays_scale > 0)) throw InputError("--rays-scale: must be > 0");
    if (a.kernel_supports != 0 && (a.kernel_supports < 1 || a.kernel_supports % 2 == 0))
        throw InputError("--kernel-supports: must be an odd number >= 1");

    const DesignJob judge_job = load_patched_job(a.scene, {case_patch});
    DesignJob run_job = load_patched_job(a.scene, {case_patch, method_patch});
    const Scene& judge = judge_job.scene;
    Scene& run_scene = run_job.scene;
    if (!judge.target) throw InputError(a.scene.string() + ": target: the study needs a target");
    const ImageD target = io::load_target_image(judge);
    const ImageD run_target = io::load_target_image(run_scene);
    const int threads = thread_count(exec::omp_t{a.threads});
    const std::uint64_t eval_seed = a.eval_seed ? *a.eval_seed : judge_job.options.seed;

    auto [nx, ny] = final_mesh_of(run_job);
    nx = (nx - 1) * a.mesh_scale + 1;
    ny = (ny - 1) * a.mesh_scale + 1;
    run_scene.surface.nx = nx;
    run_scene.surface.ny = ny;
    if (a.rays_scale != 1) {
        if (run_scene.light.rays > 0)
            run_scene.light.rays = std::max<std::int64_t>(1, std::llround(double(run_scene.light.rays) * a.rays_scale));
        else
            run_scene.light.rays_per_cell *= a.rays_scale;
    }
    const auto [case_nx, case_ny] = final_mesh_of(judge_job);

    json out;
    out["label"] = a.label.empty() ? a.engine : a.label;
    out["engine"] = a.engine;
    out["scene"] = a.scene.string();
    out["case_patch"] = case_patch;
    out["patch"] = method_patch;
    out["seed"] = a.seed;
    out["eval_seed"] = eval_seed;
    out["time_budget"] = a.time_budget;
    out["threads"] = threads;
    out["options"] = {{"control", a.control},         {"kernel_supports", a.kernel_supports},
                      {"mesh_scale", a.mesh_scale},   {"rays_scale", a.rays_scale},
                      {"progress_every", a.progress_every}};
    out["case_model"] = {{"tracer", "heightfield"},
                         {"mesh", json::array({case_nx, case_ny})},
                         {"resolution", json::array({judge.receiver.width, judge.receiver.height})},
                         {"rays_per_cell", judge.light.rays_per_cell},
                         {"rays", judge.light.rays},
                         {"phong_alpha", judge.surface.phong_alpha}};

    Heightmap result_surface;
    json model = {{"tracer", "heightfield"},
                  {"mesh", json::array({nx, ny})},
                  {"rays_per_cell", run_scene.light.rays_per_cell},
                  {"phong_alpha", run_scene.surface.phong_alpha}};
    std::vector<TracePoint> trace;
    int trace_levels = 1;
    const auto start = Clock::now();

    if (a.engine == "design") {
        result_surface = run_design_engine(a, run_job, run_target, out, model, trace, trace_levels);
    } else {
        if (a.start_only) throw InputError("--start-only: only with --engine design");
        const auto [cx, cy] = control_grid_for(a.control, nx, ny);
        ControlObjective f(run_job, run_target, cx, cy, nx, ny, a.seed, a.threads, a.time_budget, start);
        json details;
        if (a.engine == "spsa") {
            const SpsaSettings& s = a.spsa;
            const SpsaReport r = run_spsa(f, s, a.seed);
            details = {{"alpha", s.alpha},
                       {"gamma", s.gamma},
                       {"a", r.a},
                       {"c", r.c},
                       {"A", r.A},
                       {"c_cells", s.c_cells},
                       {"step_cells", s.step_cells},
                       {"mean_abs_gradient_at_start", r.g0},
                       {"expected_iterations", r.expected_iterations},
                       {"eval_every", s.eval_every}};
            out["iterations"] = r.iterations;
        } else if (a.engine.rfind("pagmo-", 0) == 0) {
#if defined(FREEFORM_HAVE_PAGMO)
            details = run_pagmo(a.engine, f, a.seed);
#else
            throw NotBuilt("this study_run was built without pagmo2 (install libpagmo-dev and rebuild)");
#endif
        } else if (a.engine.rfind("nlopt-", 0) == 0) {
#if defined(FREEFORM_HAVE_NLOPT)
            details = run_nlopt(a.engine, f);
#else
            throw NotBuilt("this study_run was built without NLopt (install libnlopt-cxx-dev and rebuild)");
#endif
        } else {
            throw InputError("--engine: unknown engine '" + a.engine +
                             "' (design, spsa, pagmo-sa, pagmo-cmaes, pagmo-xnes, pagmo-sade, nlopt-bobyqa, "
                             "nlopt-crs2)");
        }
        f.close_trace();
        const double seconds = seconds_since(start);
        trace = f.trace();
        out["seconds"] = seconds;
        out["evaluations"] = f.evaluations();
        if (!out.contains("iterations")) out["iterations"] = f.evaluations();
        out["iterations_per_second"] = seconds > 0 ? double(f.evaluations()) / seconds : 0.0;
        out["settings"] = details;
        out["shift_unit"] = f.shift_unit();
        model["control"] = json::array({cx, cy});
        model["dimension"] = f.dimension();
        model["rays"] = f.rays();
        result_surface = f.surface_of(f.best_point());
    }
    out["evaluations_per_second"] = out["seconds"].get<double>() > 0
                                        ? out["evaluations"].get<double>() / out["seconds"].get<double>()
                                        : 0.0;
    out["model"] = model;
    out["trace"] = trace_json(trace, trace_levels);

    const double alpha = run_scene.surface.phong_alpha;
    const Evaluation final_eval = evaluate(judge_job, result_surface, alpha, target, eval_seed, a.threads);
    out["final"] = evaluation_json(final_eval);
    out["final"]["heights_fingerprint"] = heights_fingerprint(result_surface);
#if defined(FREEFORM_WITH_EMBREE)
    {
        // What the milled part does: the exported mesh ("auto" subdivision, as `freeform
        // design` writes it) traced as flat triangles, same rays.
        Scene fab_scene = judge;
        fab_scene.surface.phong_alpha = alpha;
        const Fabrication fab = make_fabrication(fab_scene, judge_job.options.exports, result_surface);
        const ExportedGeometry geometry = exported_geometry(fab_scene, result_surface, fab.subdivisions);
        const TraceSetup setup = make_trace_setup(judge, result_surface, &target, eval_seed);
        const ExportedTrace e = trace_exported(exec::omp_t{a.threads}, judge, geometry, setup);
        out["final"]["error_exported"] = l1_error(e.histogram, setup.target);
        out["final"]["export_subdivisions"] = fab.subdivisions;
        // The figure that counts (docs/measures.md): cell means of the exported mesh.
        CellMeanOptions cm;
        cm.seed = hash_combine(eval_seed, 0x63656c6c6d65616eULL);
        const CellMeans cells = exported_cell_means(exec::omp_t{a.threads}, fab_scene, result_surface, geometry,
                                                    &target, cm);
        out["final"]["error_physical"] = cells.error;
        out["final"]["energy_physical"] = cells.totals.energy();
        out["final"]["physical_rays_per_cell"] = cells.rays_per_cell;
    }
#endif
    if (a.check_render) {
        // Judged again on 4x the rays with a fresh jitter: does the design fit the light,
        // or the particular rays it was optimised with?
        const Evaluation check = evaluate(judge_job, result_surface, alpha, target, eval_seed + 7919, a.threads, 4.0);
        out["check"] = evaluation_json(check);
        out["check"]["ray_factor"] = 4;
        out["check"]["seed"] = eval_seed + 7919;
    }
    if (a.compare_tracers) {
#if defined(FREEFORM_WITH_EMBREE)
        const Evaluation e = evaluate_embree(judge_job, result_surface, alpha, target, eval_seed, a.threads);
        out["embree"] = evaluation_json(e);
#else
        out["embree"] = nullptr;
#endif
    }
    save_images(a.save_images, final_eval, result_surface);

    if (a.out.has_parent_path()) fs::create_directories(a.out.parent_path());
    io::write_file_atomically(a.out, out.dump(1) + "\n");
    std::printf("%s %s seed %llu: error %.4f energy %.3f, %lld iterations in %.1f s (%.0f /s)\n",
                a.scene.filename().string().c_str(), out["label"].get<std::string>().c_str(),
                (unsigned long long)a.seed, final_eval.error, final_eval.energy,
                (long long)out["iterations"].get<std::int64_t>(), out["seconds"].get<double>(),
                out["iterations_per_second"].get<double>());
    return 0;
}

}  // namespace

int main(int argc, char** argv) {
    Args a;
    CLI::App app{"study_run: one run of the freeform speed/accuracy study (see benchmarks/study/README.md)"};
    app.add_option("--scene", a.scene, "case scene file");
    app.add_option("--engine", a.engine, "design, spsa, pagmo-*, nlopt-*");
    app.add_option("--label", a.label, "method name recorded in the result");
    app.add_option("--case-patch", a.case_patch, "JSON merge patch that defines the case (stress cases)");
    app.add_option("--patch", a.patch, "JSON merge patch of the method (applies to the run only)");
    app.add_option("--seed", a.seed, "seed of the run (optimiser and ray jitter while optimising)");
    app.add_option("--eval-seed", a.eval_seed, "seed of the final render (default: the case's optimise.seed)");
    app.add_option("--time-budget", a.time_budget, "seconds");
    app.add_option("--threads", a.threads, "threads (0: all cores)");
    app.add_option("--control", a.control, "control grid vertices along the longer side (generic optimisers, SPSA); 0: final mesh");
    app.add_option("--kernel-supports", a.kernel_supports, "use only this kernel support on every level (odd)");
    app.add_option("--mesh-scale", a.mesh_scale, "final mesh with (n-1)*K+1 vertices per side");
    app.add_option("--rays-scale", a.rays_scale, "multiply the light's rays");
    app.add_option("--progress-every", a.progress_every, "designer trace sample interval (iterations)");
    app.add_option("--spsa-c", a.spsa.c_cells, "SPSA perturbation c, in shift units (default 2)");
    app.add_option("--spsa-step", a.spsa.step_cells, "SPSA first step per variable, in shift units (default 2)");
    app.add_flag("--check-render", a.check_render, "also judge on 4x rays with a fresh jitter");
    app.add_flag("--compare-tracers", a.compare_tracers, "also render the result with the Embree tracer");
    app.add_flag("--start-only", a.start_only, "engine design: make the design's start alone, no annealing");
    app.add_option("--save-images", a.save_images, "write PREFIX-{irradiance,target,heightmap}.pfm");
    app.add_option("--out", a.out, "result JSON file");
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError& e) {
        return app.exit(e) == 0 ? 0 : 2;
    }
    try {
        if (a.scene.empty() || a.out.empty()) throw InputError("--scene and --out are required");
        return run(a);
    } catch (const NotBuilt& e) {
        std::fprintf(stderr, "study_run: %s\n", e.what());
        return 3;
    } catch (const InputError& e) {
        std::fprintf(stderr, "study_run: %s\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "study_run: error: %s\n", e.what());
        return 1;
    }
}
