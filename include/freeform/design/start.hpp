#pragma once
// Where a design starts: the caller's surface (flat, a heightmap, a paraboloid) or the
// transport surface (transport/start.hpp), judged by the exact tracer. The designer uses
// the measured error to decide how much coarse work the schedule still needs.
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "../core/exec.hpp"
#include "../objective/trace_setup.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../trace/heightfield.hpp"
#include "../trace/setup.hpp"
#include "../transport/landing.hpp"
#include "../transport/start.hpp"
#include "cell_means.hpp"
#include "options.hpp"

namespace freeform {

// What a design starts from; metrics.json names it (start_kind_names).
enum class StartKind { flat, transport, heightmap, paraboloid };
inline constexpr std::array<const char*, 4> start_kind_names{"flat", "transport", "heightmap", "paraboloid"};
inline const char* to_string(StartKind k) { return start_kind_names[std::size_t(k)]; }

struct StartReport {
    StartKind requested = StartKind::flat;  // what the scene asked for
    StartKind used = StartKind::flat;       // what the design started from
    std::string fallback_reason;     // why a requested transport start was not used
    TransportReport transport;       // when a transport start was attempted
    double error = -1, energy = -1;  // of the start, exact tracer at the final level (-1: not measured)
    double flat_error = -1;          // of a flat surface, for comparison (transport starts only)
    // A transport start's first solve and its reweighted second one (reweighted_transport_start),
    // exact tracer; the start is the better of the two (-1: not solved).
    double unreweighted_error = -1, reweighted_error = -1;
    // Before that, the start whose source was weighed by the flat surface's power and the
    // one solved again with it weighed by the fitted surface's (surface_weighted_start);
    // the better goes on to the reweighting (-1: not solved, as under light along the
    // surface's normal, where both weigh the same, or where the budget chose the
    // reweighting). `lit_power_change`: the share of the light the fitted surface's power
    // moves (transport/start.hpp), which made that choice (-1: not measured).
    double plane_weighted_error = -1, surface_weighted_error = -1, lit_power_change = -1;
    // Where the first start's surface lands its vertices' light, against their goals: the
    // mean offset in receiver pixels (LandingOffsets, transport/landing.hpp; -1: not
    // measured), and whether the surface-weighted solve was solved for the target moved
    // against the offsets (offset_target: a mean of at least landing_offset_threshold).
    double landing_offset = -1;
    bool target_offset = false;
    double seconds = 0;              // solve, fit and evaluation
    int levels_planned = 0, levels_used = 0;
    std::string plan;                // the schedule's decision, in words
    std::string left_out;            // a level the time budget could not afford, in words
                                     // (also at the end of `plan`); empty when none
};

struct SurfaceEvaluation {
    double error = 0, energy = 0;
};

// Error and energy of `surface` under the exact height-field tracer at the scene's own
// receiver resolution, with the rays of `seed`.
inline SurfaceEvaluation evaluate_surface(const Scene& scene, const Heightmap& surface, const ImageD& target_image,
                                          std::uint64_t seed, int threads) {
    const TraceSetup setup = make_trace_setup(scene, surface, &target_image, seed);
    Histogram hist = setup.empty_histogram();
    TraceTotals totals;
    HeightfieldTracer(surface, setup.rays, setup.params).trace_all(exec::omp_t{threads}, hist, totals);
    return {l1_error(hist, setup.target), totals.energy()};
}

inline StartKind requested_start(const Scene& scene) {
    const SurfaceSpec& s = scene.surface;
    if (!s.initial_pfm.empty()) return StartKind::heightmap;
    if (s.initial_paraboloid) return StartKind::paraboloid;
    return starts_from_transport(scene) ? StartKind::transport : StartKind::flat;
}

// What a long step reports while it finds the start: "finding the start (transport)".
inline std::string finding_the_start(const Scene& scene) {
    return std::string("finding the start (") + to_string(requested_start(scene)) + ")";
}

// The start of a design on the final mesh of `initial` (the caller's surface). For a
// transport start, `map` keeps the transport map so that coarser meshes can be fitted
// to it. A transport start that cannot be made, or that is no better than a flat
// surface, falls back to `initial` with the reason in the report; a scene that asked
// for "transport" explicitly gets an InputError instead when its light never reaches
// the receiver.
struct DesignStart {
    Heightmap surface;
    std::optional<TransportMap> map;
    StartReport report;
};

// The start as the designer uses it, once the schedule has judged it: the surface on
// the mesh of the first level that runs, the report (with the schedule's plan) and how
// many coarse planned levels the start makes unnecessary. It is what replicas of one
// design share (replicas.hpp: one replica computes it, the others receive it), so it
// holds values only, no transport map.
struct SharedStart {
    Heightmap surface;       // on the first level's mesh
    Heightmap final_surface;  // the start on the mesh it was made on (the final one), when
                              // optimise.keep_better_start: the maker's alone, not sent to
                              // other replicas (replicas.hpp)
    StartReport report;      // plan filled in; levels_planned and levels_used are not
    bool transport = false;  // the surface was fitted to a transport map (the annealer refines)
    int skip = 0;            // coarse planned levels skipped
};

// The transport grids a design's start tries, in cells per receiver pixel. Each start is
// judged by the exact tracer and the better one kept (docs/architecture.md §4b): three
// cells per pixel resolve the map at the sub-pixel positions where a letter's edges and a
// photograph's detail lie (the E and the camera start far lower); one per pixel may be
// better where the mesh is coarse for the fine grid, its vertices sampling a map finer
// than their spacing. Where the footprint, not the pixels, sets the cell (the headlight's
// 4 mm pixels), both give the same grid and it is solved once.
inline constexpr std::array<double, 2> start_grid_cells_per_pixel{3.0, 1.0};

// The largest side of the transport grid a design of `scene` with `time_budget` seconds
// (0: none) solves its start on. The start's error is set by the map at sub-pixel scale,
// so the grid asks for three cells per receiver pixel (start_grid_cells_per_pixel); above
// 256² pixels a fixed cap of 768 cells cut that to 1.5 at 512² and 0.75 at 1024², and the
// start paid: a 512² photograph (Grace Hopper, the camera geometry, `design --start-only`)
// starts at a cell-mean error (error_physical) of 0.0415 on 768², 0.0356 on 1024² and
// 0.0300 on 1536², its bottom row, where the photograph is dark, getting 5 %, 18 % and
// 44 % of its light. Finer grids cost time, and the start counts against the budget. So
// the cap is the largest side whose start is estimated at two fifths of the budget or
// less: about 12 µs per cell of the two grids solved (the fine one and the one of the
// pixels; 6.1, 9.7 and 31 s for the three grids above on 2 cores) and 1 µs per ray the
// level traces (the rays made, the fits judged by the exact tracer), never below 768 (the
// former cap: short budgets and large receivers start as before) nor above 2048 (no
// budget). A 512² receiver gets 1019 cells at 60 s and its full 1536 at 120 s; a 1024²
// one 768 at 60 s. The rates are fixed, not measured, so the grid, and with it the
// design, depends on the scene and the options alone.
// The reweighted second solve (reweighted_transport_start) is not in this estimate: it
// adds about as much again as the fine grid's solve (the start's time roughly doubles),
// and a 512² start gains more from it on the full grid than from the budget it leaves.
inline constexpr int min_start_grid = 768, max_start_grid = 2048;
inline constexpr double start_seconds_per_cell = 12e-6, start_seconds_per_ray = 1e-6, start_budget_share = 0.4;
inline int start_grid_limit(const Scene& scene, double time_budget) {
    if (!(time_budget > 0)) return max_start_grid;
    const double rays = double(ray_budget(scene.light, scene.receiver));
    const double pixels_side = double(std::max(scene.receiver.width, scene.receiver.height));
    const double cells = (start_budget_share * time_budget - start_seconds_per_ray * rays) / start_seconds_per_cell;
    // side² + min(side, pixels_side)² ≤ cells: the fine grid and the grid of the pixels.
    double side = std::sqrt(std::max(0.0, cells - pixels_side * pixels_side));
    if (side < pixels_side) side = std::sqrt(std::max(0.0, cells / 2));
    return int(std::clamp(side, double(min_start_grid), double(max_start_grid)));
}

struct TransportStart {
    TransportMap map;  // report: the grid used, and the other grid's start error
    Heightmap surface;
    SurfaceEvaluation eval;
    std::shared_ptr<const Heightmap> lit;  // the surface whose power weighed μ (TransportOptions::lit)
    std::shared_ptr<const ImageD> solved_for;  // the target its map was solved for, where not the scene's
};

// One transport start of `initial`'s mesh: the map of `target_image` on the grid of
// `cells_per_pixel` (a lens's wall strips `walls`: WallStrips), the surface fitted to it,
// and that surface judged by the exact tracer against `judged_by`.
inline TransportStart transport_start_on(const Scene& scene, const Heightmap& initial, const ImageD& target_image,
                                         const ImageD& judged_by, std::uint64_t seed, int threads, int max_grid,
                                         double cells_per_pixel, const WallStrips& walls,
                                         std::shared_ptr<const Eigen::ArrayXXd> warm_phi = {},
                                         std::shared_ptr<const Heightmap> lit = {}) {
    TransportOptions options;
    options.lit = lit;
    options.ot.warm_phi = std::move(warm_phi);
    options.ot.threads = threads;
    options.cells_per_pixel = cells_per_pixel;
    options.max_grid = max_grid;
    options.strips = walls;
    TransportMap map = solve_transport(scene, initial, target_image, seed, options);
    TransportReport fitted = map.report;
    Heightmap surface = surface_from_transport(scene, map, initial.nx(), initial.ny(), fitted, options);
    map.report = fitted;
    const SurfaceEvaluation eval = evaluate_surface(scene, surface, judged_by, seed, threads);
    return TransportStart{std::move(map), std::move(surface), eval, std::move(lit), nullptr};
}

// The transport start of `initial`'s mesh on each grid of start_grid_cells_per_pixel (a
// grid that max_grid makes equal to the one before is not solved twice), the better one
// under the exact tracer, with the same rays for both: the choice depends on the scene
// alone. A lens whose plain map still sends light into its side walls (a rim narrower
// than lens_rim's "auto") is also started with wall strips (WallStrips, measured on the
// plain start of the cheaper grid) on each grid, and the exact tracer judges those starts
// with the plain ones: the strips remove the cross the walls throw, but their mirrored
// light lands where the target may be black (a letter), and there the plain start can be
// the better one. `max_grid`: the grids' largest side (start_grid_limit). An InputError on
// the first grid (no light reaches the receiver) propagates.
inline TransportStart best_transport_start(const Scene& scene, const Heightmap& initial, const ImageD& target_image,
                                           std::uint64_t seed, int threads, int max_grid = min_start_grid) {
    std::optional<TransportStart> best;
    const FlatFootprint fp = flat_footprint(scene, initial);
    const auto grid_of = [&](double cells_per_pixel) {
        TransportOptions options;
        options.cells_per_pixel = cells_per_pixel;
        options.max_grid = max_grid;
        return transport_grid(scene, fp, options);
    };
    const auto same = [](const OtGrid& a, const OtGrid& b) { return a.nx == b.nx && a.ny == b.ny && a.hx == b.hx; };
    const OtGrid strip_grid = grid_of(start_grid_cells_per_pixel.back());
    WallStrips strips;  // measured on the plain start of strip_grid (a lens's)
    const auto candidate = [&](double cells_per_pixel, const WallStrips& walls, bool measure) {
        TransportStart c = transport_start_on(scene, initial, target_image, target_image, seed, threads, max_grid,
                                              cells_per_pixel, walls);
        if (measure) strips = measure_wall_strips(scene, c.map, c.surface);
        if (!best) {
            best = std::move(c);
        } else if (c.eval.error < best->eval.error) {
            c.map.report.other_cells_per_pixel = best->map.report.cells_per_pixel;
            c.map.report.other_error = best->eval.error;
            best = std::move(c);
        } else {
            best->map.report.other_cells_per_pixel = cells_per_pixel;
            best->map.report.other_error = c.eval.error;
        }
    };
    OtGrid tried{};
    std::vector<double> solved;
    for (const double cells_per_pixel : start_grid_cells_per_pixel) {
        const OtGrid g = grid_of(cells_per_pixel);
        if (same(g, tried)) continue;
        tried = g;
        solved.push_back(cells_per_pixel);
        candidate(cells_per_pixel, WallStrips{}, is_lens(scene.surface.material) && same(g, strip_grid));
    }
    if (strips.any())
        for (const double cells_per_pixel : solved) candidate(cells_per_pixel, strips, false);
    best->map.report.wall_fraction = strips.wall_fraction;
    return std::move(*best);
}

// Of a start and its solve again (surface_weighted_start, reweighted_transport_start), the
// better under the exact tracer; the second keeps the first's record of the grids tried.
inline TransportStart better_start(TransportStart first, TransportStart second) {
    if (!(second.eval.error < first.eval.error)) return first;
    second.map.report.other_cells_per_pixel = first.map.report.other_cells_per_pixel;
    second.map.report.other_error = first.map.report.other_error;
    second.map.report.wall_fraction = first.map.report.wall_fraction;
    return second;
}

// The start's second solve (docs/architecture.md §4b, step 5). The
// fitted surface does not put its light exactly where the map sends it: the least-squares
// fit keeps only the part of the map a surface can make, and a near receiver, a point
// light or a large deflection bends the rest (a round mirror 16° off a point light,
// deflecting 22°: 0.049 at the start against 0.016 on axis). Where it lands too much or
// too little light, a slightly different map lands about as much too much or too little.
// So the map is solved once more for the target weighted, cell by cell, by (target /
// start's irradiance)^reweight_exponent, the ratio clamped to [1/reweight_clamp,
// reweight_clamp] (a damped step: the full ratio overshoots on sharp edges, the letter E
// 0.0220 → 0.0273), on the winning grid with its wall strips, and the new surface is kept
// when the exact tracer, against the real target, finds it better. The irradiance is the
// start's cell means from reweight_rays_per_cell rays of their own jitter (neither the
// design's rays nor the judge's, docs/measures.md).
inline constexpr double reweight_exponent = 0.5, reweight_clamp = 2.0, reweight_rays_per_cell = 256;

// `target` (image rows, row 0 the top) times the factor of the receiver cell each pixel
// falls in: (target / lit)^reweight_exponent over `lit`'s cells, both normalised to one.
inline ImageD reweighted_target(const ImageD& target, const CellMeans& lit) {
    const int w = lit.histogram.width, h = lit.histogram.height;
    double lit_sum = 0, target_sum = 0;
    for (std::size_t k = 0; k < lit.histogram.cells.size(); ++k)
        lit_sum += from_fixed(lit.histogram.cells[k]), target_sum += from_fixed(lit.target.cells[k]);
    ImageD factor = ImageD::Ones(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const std::size_t k = std::size_t(y) * std::size_t(w) + std::size_t(x);
            const double a = from_fixed(lit.histogram.cells[k]) / lit_sum, t = from_fixed(lit.target.cells[k]) / target_sum;
            if (a > 0 && t > 0)
                factor(y, x) = std::pow(std::clamp(t / a, 1 / reweight_clamp, reweight_clamp), reweight_exponent);
        }
    ImageD out = target;
    const Eigen::Index rows = target.rows(), cols = target.cols();
    for (Eigen::Index py = 0; py < rows; ++py)
        for (Eigen::Index px = 0; px < cols; ++px)
            out(py, px) *= factor(std::min<Eigen::Index>(h - 1, (2 * py + 1) * h / (2 * rows)),
                                  std::min<Eigen::Index>(w - 1, (2 * px + 1) * w / (2 * cols)));
    return out;
}

// Whether the fitted surface may land its light away from its goals by more than a
// sliver: wherever the power depends on the shape, or the receiver is not parallel to the
// surface (its lever arm changes across the surface; transport/landing.hpp).
inline bool may_land_off_goals(const Scene& scene) {
    const transport_detail::Optics optics(scene);
    return power_depends_on_shape(scene) || std::abs(optics.rn.z) < 1 - 1e-9;
}

// Which of the start's second solves a design of `scene` with `time_budget` seconds (0:
// none) affords on a grid of at most `max_grid` a side: the first solves and the second
// ones, by start_grid_limit's fixed rates, within reweight_budget_share of the budget. A
// second solve starts from the first's potential (OtOptions::warm_phi: 6 to 11 iterations
// where a cold solve takes 14 to 18), so its grid is counted at warm_solve_fraction of a
// cold solve. The surface-weighted solve (surface_weighted_start) adds the exact tracer's
// judgement of its surface at the tracer's rate, and is counted only where it runs
// (power_depends_on_shape); the reweighted one (reweighted_transport_start) adds its
// irradiance at a quarter of that rate per ray (cell means, no objective). The share is
// larger than the grid's (start_budget_share): the reweighted start gains on every scene
// measured, and on a large receiver it is worth more than the annealing it displaces (a
// 512² photograph in 120 s: 68 s of start, designed surface 0.0146 against 0.0169 for the
// first start, which annealing did not improve on; docs/performance.md, "The reweighted
// start"). The letter E at 20 s (a 9 s start, 19 s on a loaded machine, where annealing
// then never ran) still goes without. Fixed rates, so the decision depends on the scene
// and options alone.
inline constexpr double warm_solve_fraction = 0.55, reweight_budget_share = 2.0 / 3.0;
struct SecondSolves {
    bool surface_weighted = true;  // the first solves and the surface-weighted one fit
    bool reweighted = true;        // the first solves and the reweighted one fit
    bool both = true;              // all of them fit
};
inline constexpr SecondSolves no_second_solves{false, false, false};
inline SecondSolves start_second_solves(const Scene& scene, double time_budget, int max_grid) {
    if (!(time_budget > 0)) return {};
    const double pixels_side = double(std::max(scene.receiver.width, scene.receiver.height));
    const double fine = std::min(double(max_grid), start_grid_cells_per_pixel[0] * pixels_side);
    const double coarse = std::min(fine, start_grid_cells_per_pixel[1] * pixels_side);
    const double rays = double(ray_budget(scene.light, scene.receiver));
    const double lit_rays = reweight_rays_per_cell * double(scene.receiver.cells());
    const double first = start_seconds_per_cell * (fine * fine + coarse * coarse) + start_seconds_per_ray * rays;
    const double warm = warm_solve_fraction * start_seconds_per_cell * fine * fine;
    const double weighted = may_land_off_goals(scene) ? warm + start_seconds_per_ray * rays : 0;
    const double reweighted = warm + 0.25 * start_seconds_per_ray * lit_rays;
    const double budget = reweight_budget_share * time_budget;
    return {first + weighted <= budget, first + reweighted <= budget, first + weighted + reweighted <= budget};
}

// Where only one second solve fits, the surface-weighted one is solved when the fitted
// surface's power moves at least this share of the first start's error (lit_power_change
// against that error, both Σ|R − T| / 2N), the reweighted one otherwise. The
// surface-weighted solve takes off what the power moved; the reweighted one's damped step
// (the square root of the ratio) about half of an error of smooth brightness, the power's
// included. The side lamp (a point light beside a tilted mirror) gained 0.12 from the
// first and 0.004 from the second, the point-light example 0.001 and 0.003
// (docs/performance.md, "Where the rays are aimed").
inline constexpr double surface_weight_share = 0.5;

// The designed surface's cell means: the height field traced with its Phong patches.
inline CellMeans designed_cell_means(const Scene& scene, const Heightmap& surface, const ImageD& target,
                                     const CellMeanOptions& options, int threads) {
    return converged_cell_means(scene, surface, &target, options,
                                [&](const Scene&, const TraceSetup& batch, Histogram& h, TraceTotals& t) {
                                    HeightfieldTracer(surface, batch.rays, batch.params)
                                        .trace_all(exec::omp_t{threads}, h, t);
                                });
}

// `start` solved again for its reweighted target (above); the better of the two under the
// exact tracer. `reweighted_error` gets the second solve's error.
inline TransportStart reweighted_transport_start(const Scene& scene, const Heightmap& initial, const ImageD& target_image,
                                                 TransportStart start, std::uint64_t seed, int threads, int max_grid,
                                                 double& reweighted_error) {
    CellMeanOptions lit_options;
    lit_options.rays_per_cell = reweight_rays_per_cell / 4;
    lit_options.max_rays_per_cell = reweight_rays_per_cell;
    lit_options.tolerance = 0;  // all four batches
    lit_options.seed = hash_combine(seed, 0x7265776569676874ULL);
    const CellMeans lit = designed_cell_means(scene, start.surface, target_image, lit_options, threads);
    const ImageD& solved_for = start.solved_for ? *start.solved_for : target_image;
    TransportStart second =
        transport_start_on(scene, initial, reweighted_target(solved_for, lit), target_image, seed, threads, max_grid,
                           start.map.report.cells_per_pixel, start.map.strips,
                           std::make_shared<const Eigen::ArrayXXd>(start.map.ot.phi), start.lit);
    reweighted_error = second.eval.error;
    return better_start(std::move(start), std::move(second));
}

// The start solved again for its own surface (docs/architecture.md §4b, step 4), in two
// ways that one solve carries. (1) Its source weighed by the surface: the map is solved for
// the power a flat surface receives at each source point; the fitted surface receives a
// different power there wherever the light is not along its normal: a point light's
// distance and angle change with the height, and a tilted face catches more or less of
// it. A mirror 6 cm above and 9 cm beside a point light, tilted 51 mm towards it, started
// with its picture brighter at one end and darker at the other (error 0.080). So μ is
// weighed by the power the fitted surface receives (TransportOptions::lit) where
// power_depends_on_shape. (2) With `offsets` (landing_offsets of the start, at least
// landing_offset_threshold), the target moved against where the surface lands its light
// (offset_target): the letter E lit at 70° landed everything inside it 3.5 px towards its
// top. The solve is warm from the first potential, the surface fitted again, and the
// better of the two kept under the exact tracer against the scene's target.
inline TransportStart surface_weighted_start(const Scene& scene, const Heightmap& initial, const ImageD& target_image,
                                             TransportStart start, std::uint64_t seed, int threads, int max_grid,
                                             double& surface_weighted_error, const LandingOffsets* offsets = nullptr) {
    std::shared_ptr<const ImageD> moved;
    if (offsets) moved = std::make_shared<const ImageD>(offset_target(target_image, *offsets, scene.receiver));
    TransportStart second = transport_start_on(
        scene, initial, moved ? *moved : target_image, target_image, seed, threads, max_grid,
        start.map.report.cells_per_pixel, start.map.strips, std::make_shared<const Eigen::ArrayXXd>(start.map.ot.phi),
        power_depends_on_shape(scene) ? std::make_shared<const Heightmap>(start.surface) : nullptr);
    second.solved_for = std::move(moved);
    surface_weighted_error = second.eval.error;
    return better_start(std::move(start), std::move(second));
}

// The start a design begins from: the scene's own, or the best transport start
// (best_transport_start) on grids of at most `max_grid` cells a side (start_grid_limit of
// the design's time budget), solved again with its source weighed by its own surface
// (surface_weighted_start) and for its reweighted target (reweighted_transport_start) as
// `solves` affords (start_second_solves of the budget; where only one fits, the choice of
// surface_weight_share), judged against the flat surface.
inline DesignStart make_design_start(const Scene& scene, Heightmap initial, const ImageD& target_image,
                                     std::uint64_t seed, int threads, int max_grid = min_start_grid,
                                     SecondSolves solves = {}) {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    DesignStart start;
    start.report.requested = requested_start(scene);
    start.report.used = start.report.requested;
    if (start.report.requested != StartKind::transport) {
        start.surface = std::move(initial);
        return start;
    }
    const auto fall_back = [&](std::string why) {
        start.report.used = StartKind::flat;
        start.report.fallback_reason = std::move(why);
        start.map.reset();
        start.surface = std::move(initial);
    };
    if (const std::string why = transport_unsupported_reason(scene); !why.empty()) {
        fall_back(why);
        start.report.seconds = std::chrono::duration<double>(clock::now() - t0).count();
        return start;
    }
    std::optional<TransportStart> best;
    try {
        best = best_transport_start(scene, initial, target_image, seed, threads, max_grid);
        bool weighed = false;
        if (solves.surface_weighted && may_land_off_goals(scene)) {
            StartReport& r = start.report;
            const LandingOffsets offsets = landing_offsets(scene, best->map, best->surface);
            r.landing_offset = offsets.mean_pixels;
            const bool offset = offsets.mean_pixels >= landing_offset_threshold;
            if (power_depends_on_shape(scene))
                r.lit_power_change = lit_power_change(scene, initial, best->surface, hash_combine(seed, 0x6c6974ULL));
            weighed = offset || (r.lit_power_change >= 0 &&
                                 (solves.both || r.lit_power_change >= surface_weight_share * best->eval.error));
            r.plane_weighted_error = best->eval.error;
            r.target_offset = weighed && offset;
            if (weighed)
                best = surface_weighted_start(scene, initial, target_image, std::move(*best), seed, threads, max_grid,
                                              r.surface_weighted_error, offset ? &offsets : nullptr);
        }
        start.report.unreweighted_error = best->eval.error;
        if (solves.both || (solves.reweighted && !weighed))
            best = reweighted_transport_start(scene, initial, target_image, std::move(*best), seed, threads, max_grid,
                                              start.report.reweighted_error);
    } catch (const InputError& e) {
        if (scene.surface.initial_shape == InitialShape::transport) throw;
        fall_back(e.what());
        start.report.seconds = std::chrono::duration<double>(clock::now() - t0).count();
        return start;
    }
    start.map = std::move(best->map);
    start.surface = std::move(best->surface);
    const SurfaceEvaluation mine = best->eval;
    start.report.transport = start.map->report;
    const SurfaceEvaluation flat = evaluate_surface(scene, initial, target_image, seed, threads);
    start.report.error = mine.error;
    start.report.energy = mine.energy;
    start.report.flat_error = flat.error;
    // Judged by the exact model: a start that is not better than flat is no start.
    if (!(mine.error < flat.error)) {
        fall_back("the transport surface was no better than flat under the exact tracer (error " +
                  std::to_string(mine.error) + " against " + std::to_string(flat.error) + ")");
        start.report.error = flat.error;
        start.report.energy = flat.energy;
    }
    start.report.seconds = std::chrono::duration<double>(clock::now() - t0).count();
    return start;
}

// The start of a design with `options`: its seed, and the transport grid and second solve
// its time budget affords (start_grid_limit, start_second_solves). The designer, a
// start-only design and a render of a scene's start all make it here, so that they make
// the same start.
inline DesignStart make_design_start(const Scene& scene, Heightmap initial, const ImageD& target_image,
                                     const DesignOptions& options, int threads) {
    const int max_grid = start_grid_limit(scene, options.time_budget);
    return make_design_start(scene, std::move(initial), target_image, options.seed, threads, max_grid,
                             start_second_solves(scene, options.time_budget, max_grid));
}

}  // namespace freeform
