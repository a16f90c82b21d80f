#pragma once
// The end-to-end designer: a multi-level schedule of annealing runs (reference §4.4,
// Algorithm 1) over mesh size × receiver resolution × kernel size.
//
// Levels pair a mesh with a receiver resolution, coarse to fine (each level doubles
// both, as in the reference's Table 6.1); inside a level the kernel support shrinks
// stage by stage (coarse shape first, then detail). Between levels the surface is
// refined so that it keeps its shading normals (surface/refine.hpp), which preserves
// its light better than bilinear interpolation of the heights. Each stage is one
// annealing run of the generic annealer on a SurfaceProblem; its initial temperature
// is calibrated from the
// objective changes of a few trial moves so that about `initial_acceptance` of uphill
// moves are accepted at the start, which keeps the defaults meaningful for any scene.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#include "../anneal/annealer.hpp"
#include "../objective/trace_setup.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/refine.hpp"
#include "../surface/tool.hpp"
#include "../trace/setup.hpp"
#include "device.hpp"
#include "held_out.hpp"
#include "options.hpp"
#include "problem.hpp"
#include "replicas.hpp"
#include "start.hpp"

namespace freeform {

// What a design reports at each progress call.
struct DesignProgress {
    int level = 0, levels = 0;
    int stage = 0, stages = 0;
    int mesh = 0, resolution = 0, kernel_support = 0;
    std::int64_t iteration = 0;        // over the whole design
    double temperature = 0;
    double error = 0, energy = 0, objective = 0;
    double iterations_per_second = 0;  // of the current stage
    double seconds = 0, time_left = 0;
};

struct StageReport {
    int level = 0, mesh_x = 0, mesh_y = 0, resolution_x = 0, resolution_y = 0, kernel_support = 0;
    std::int64_t iterations = 0, accepted = 0, proposals_evaluated = 0;
    double seconds = 0;
    double initial_temperature = 0;
    double error_start = 0, error_end = 0, energy_end = 0, objective_end = 0;
    std::int64_t rays = 0;
    std::vector<double> bandit_weights;
    StopReason stop_reason = StopReason::max_iterations;  // no_gain: StageGainWatch
    // Held-out checks (held_out.hpp; all -1 / 0 when optimise.held_out_checks is off).
    double held_out_start = -1;  // error of the stage's start on the held-out rays
    double held_out_end = -1;    // ... of the state the stage ends with
    std::int64_t held_out_checks = 0;
    std::int64_t held_out_kept = -1;  // stage iteration of the state kept instead of the
                                      // annealer's best (-1: the annealer's best was kept)
    std::int64_t merges = 0;  // replicas sharing one surface: merges made (replicas.hpp)
    // The trace's index at the stage's end: ray/cell crossings listed, and whether a reach
    // envelope kept them down (trace/incremental.hpp), re-centred how many times.
    std::int64_t crossings = 0;
    bool reach_envelope = false;
    std::int64_t reach_recentres = 0;
};

struct ConvergencePoint {
    double seconds;
    std::int64_t iteration;
    int level, stage;
    double error, energy, objective, temperature;
};

struct DesignResult {
    StartReport start;         // where the design started, and what the schedule made of it
    Heightmap surface;         // final design (final mesh)
    Histogram irradiance;      // at the final level's resolution
    Target target;             // the final level's target
    ObjectiveValue value;
    std::int64_t iterations = 0;
    std::int64_t accepted = 0;
    double seconds = 0;
    double tool_cut = 0;       // surface.tool_radius: the most height the tool's cut added (metres; set by finish_design)
    bool stopped_early = false;  // a callback stopped it (e.g. Ctrl-C): the best so far is kept
    std::vector<StageReport> stages;
    std::vector<ConvergencePoint> convergence;
    std::vector<KernelShape> kernel_bank;  // of the last stage
    std::vector<double> bandit_weights;    // of the last stage
    std::vector<double> preprocess_rates;  // reward per pull of each shape in the pre-process
    std::int64_t rays = 0;
    // The final design traced with the final level's held-out rays (held_out.hpp), which
    // it was not fitted to; held_out.total < 0 when the checks are off.
    ObjectiveValue held_out{-1, -1, -1, -1, -1};
    std::uint64_t held_out_seed = 0;  // the seed of those rays (generate_rays)
    // Where the annealing's windows were judged: "cpu", or "cuda (<device name>)"
    // (optimise.device; design/device.hpp).
    std::string device = "cpu";
    // The surface the annealing started from, on the final mesh: finish_design delivers
    // it instead of the annealed one when that traces better (optimise.keep_better_start,
    // DeliveredSurface in pipeline.hpp). Empty for the start alone, with keep_better_start
    // off, or where the start's mesh is not the final one.
    std::optional<Heightmap> start_surface;
    // Where and why the device failed, when it did ("level 2 stage 1: <error>"); the
    // design then went on on the CPU, the same bit for bit. Empty: it did not.
    std::string device_failure;
};

// Kernel supports of level k (reference §4.4, multi-level Gaussian kernels). The first
// level runs the whole sequence for its mesh, large to small. A finer level starts where
// the previous one stopped, at the same physical size (twice the support on a mesh with
// twice the vertices): larger kernels would redo the coarse shaping at a much higher
// cost per move. The finest level ends with support 5, the smallest that is still a
// smooth bump rather than a single-vertex spike.
inline std::vector<int> level_kernel_supports(const std::vector<LevelPlan>& levels, std::size_t k) {
    const int n = std::max(levels[k].mesh_x, levels[k].mesh_y);
    std::vector<int> all = kernel_support_levels(n);
    if (k == 0) return all;
    const auto& prev = levels[k - 1].kernel_supports;
    const int prev_smallest = prev.empty() ? 5 : prev.back();
    const int largest = 2 * prev_smallest + 1;
    std::vector<int> out;
    for (int s : all)
        if (s <= largest) out.push_back(s);
    if (out.empty()) out.push_back(std::max(5, (largest - 2) | 1));
    if (k + 1 == levels.size() && out.back() > 5) out.push_back(5);
    return out;
}

// Time shares of a schedule of n levels (15 / 30 / 55 % for three).
inline void assign_time_shares(std::vector<LevelPlan>& levels) {
    static const double shares[3][3] = {{1, 0, 0}, {0.35, 0.65, 0}, {0.15, 0.3, 0.55}};
    const std::size_t n = std::min<std::size_t>(levels.size(), 3);
    for (std::size_t k = 0; k < levels.size(); ++k)
        levels[k].time_share = n == 0 ? 1.0 : shares[n - 1][std::min(k, n - 1)];
}

// The receiver pixels that a surface axis (world direction `axis`) spans once the light
// fills the receiver: those along the receiver axis it lies closest to, projected onto
// the receiver's plane; the longer side's when it stands about upright on that plane
// (|cos| < 0.2 to both axes).
inline int receiver_pixels_along(const Receiver& receiver, Vec3d axis) {
    const double cu = std::abs(dot(axis, receiver.frame.u)), cv = std::abs(dot(axis, receiver.frame.v));
    if (std::max(cu, cv) < 0.2) return std::max(receiver.width, receiver.height);
    return cu >= cv ? receiver.width : receiver.height;
}

// Mesh "auto": cells per receiver pixel along each side, while the final mesh keeps within
// auto_mesh_max_vertices (above, fewer cells per pixel, down to one). Measured 2026-11-30
// (`freeform design`, seed 1, 2 cores, each scene's mesh set to one and to two cells a
// pixel; designed surface / the sag table, both converged cell means; docs/measures.md,
// "The mesh: two cells a pixel"):
//   letter E 60 s 0.0164 / 0.0172 on 201² against 0.0136 / 0.0141 on 401², V 0.0118 /
//   0.0123 against 0.0101 / 0.0104, @ 0.0271 / 0.0288 against 0.0200 / 0.0211, the camera
//   photograph 60 s 0.0164 / 0.0169 against 0.0132 / 0.0135, text on 300 × 100 in 30 s
//   0.0468 / 0.0497 on 301 × 151 against 0.0355 / 0.0355 on 601 × 301.
// Most of it is the transport start's (E 0.0214 → 0.0144): where the map jumps (between
// letters, the E's notches, a photograph's sharp edges) a smooth surface sweeps one
// mesh cell's light across the jump, and a cell half as wide sweeps half the light. At
// 512² it is too much model for 120 s: the camera photograph on 1025² ran its start and
// one level of three (0.0145 / 0.0134, holding about 8 GB) against 513²'s 0.0118 / 0.0117.
inline constexpr double auto_mesh_cells_per_pixel = 2;
inline constexpr double auto_mesh_max_vertices = 1 << 18;  // 512²

// The default schedule for a scene: no more model than the case needs.
//   final mesh: the scene's, or (mesh "auto") from the receiver resolution: c cells per
//   receiver pixel along the longer side (auto_mesh_cells_per_pixel, fewer where the mesh
//   would pass auto_mesh_max_vertices), 2m − 1 vertices with m = c·r/2 + 1 made odd for r
//   pixels (401 for a 200² receiver, 101 for the 50² headlight, where the reference used
//   13²; 513 for 512²); the shorter side follows the surface's aspect ratio, and each
//   side has at least the vertices of the pixels it spans (receiver_pixels_along). That
//   floor came in on 2026-11-30 (at one cell a pixel): a 20 × 4 cm mirror throwing a
//   checkerboard onto a 200² receiver got 201 × 41 vertices, five pixels a cell across
//   the strip; its start drew arcs in the dark squares (cell means 0.051, `design
//   --start-only`; 201 × 101 gave 0.029, 201 × 201 0.026) and a 30 s design ended at
//   0.0498, against 0.0231 on 201 × 201. Not the floor alone: text on a 300 × 100
//   receiver from a 120 × 60 mm mirror ended at 0.0492 on 301 × 101 against 0.0480 on
//   the aspect's 301 × 151 (30 s).
//   History: photographs used to get 2r + 1 (the reference's 401² for a 200² photo) and
//   lost to r + 1 in issue 22 (benchmarks/results/physical, seed 1 at 15 / 30 / 60 s: the
//   camera 0.0404 / 0.0378 / 0.0357 against 0.0454 / 0.0425 / 0.0404), judged then by the
//   exported facets at 4 rays per mesh cell: the finer mesh steered single rays and fit
//   fewer facet subdivisions. With 32 rays per mesh cell (min_rays_per_mesh_cell) and the
//   smooth part judged (STEP, the sag table), two cells a pixel win on photographs too
//   (above). Before issue 11 binary targets had half a cell a pixel (101² for 200²),
//   which ended above one cell a pixel on every seed of ten binary targets (docs/
//   performance.md, "The "auto" mesh rule (err measure)"); the earlier study found 13²
//   twice the error of 25² on the headlight.
//   levels: halve mesh and resolution down to 25 px / 7 vertices, at most 3 (a 200²
//   receiver: 101², 201², 401² on 50, 100, 200 px; the reference had 25² → 101²); one
//   level when `multilevel` is off.
//   budgets: 40 iterations per vertex of the level; time shares 15 / 30 / 55 %.
inline std::vector<LevelPlan> plan_levels(const Scene& scene, const DesignOptions& options) {
    const int rx = scene.receiver.width, ry = scene.receiver.height;
    int mx = scene.surface.nx, my = scene.surface.ny;
    if (mx <= 0 || my <= 0) {
        const auto auto_mesh = [&](double cells_per_pixel) {
            const auto vertices = [&](int pixels) {
                const int cells = int(cells_per_pixel * pixels + 1e-9);
                return std::max(5, (2 * ((cells / 2 + 1) | 1) - 1) | 1);
            };
            const int mesh = vertices(std::max(rx, ry));
            const Vec2d size = scene.surface.size;
            int x = size.x >= size.y ? mesh : std::max(3, int(std::lround((mesh - 1) * size.x / size.y)) + 1);
            int y = size.x >= size.y ? std::max(3, int(std::lround((mesh - 1) * size.y / size.x)) + 1) : mesh;
            x = std::max(x, vertices(receiver_pixels_along(scene.receiver, scene.surface.frame.u)));
            y = std::max(y, vertices(receiver_pixels_along(scene.receiver, scene.surface.frame.v)));
            return std::pair<int, int>{x, y};
        };
        std::tie(mx, my) = auto_mesh(auto_mesh_cells_per_pixel);
        const double count = double(mx) * double(my);
        if (count > auto_mesh_max_vertices)
            std::tie(mx, my) =
                auto_mesh(std::max(1.0, auto_mesh_cells_per_pixel * std::sqrt(auto_mesh_max_vertices / count)));
    }
    const auto coarser = [](int m) { return std::max(3, 2 * ((m - 1) / 4) + 1); };  // about half: 101, 51, 25, 13, 7
    std::vector<LevelPlan> levels;
    int x = rx, y = ry;
    while (true) {
        LevelPlan l;
        l.mesh_x = mx, l.mesh_y = my, l.resolution_x = x, l.resolution_y = y;
        levels.insert(levels.begin(), l);
        if (!options.multilevel || levels.size() >= 3 || std::min(x, y) / 2 < 25 ||
            coarser(std::max(mx, my)) < 7)
            break;
        mx = coarser(mx), my = coarser(my), x /= 2, y /= 2;
    }
    for (std::size_t k = 0; k < levels.size(); ++k) levels[k].kernel_supports = level_kernel_supports(levels, k);
    assign_time_shares(levels);
    for (auto& l : levels) l.iterations = std::int64_t(40) * l.mesh_x * l.mesh_y;
    return levels;
}

// The final mesh: the scene's, or the last of `levels` (plan_levels(scene, options)) when it is
// "auto".
inline std::pair<int, int> final_mesh(const Scene& scene, const std::vector<LevelPlan>& levels) {
    if (scene.surface.nx > 0) return {scene.surface.nx, scene.surface.ny};
    return {levels.back().mesh_x, levels.back().mesh_y};
}

inline std::pair<int, int> final_mesh(const Scene& scene, const DesignOptions& options) {
    return final_mesh(scene, plan_levels(scene, options));
}

// The scene's receiver at a level's resolution (the same plane: frame and size).
inline Receiver level_receiver(const Receiver& receiver, const LevelPlan& level) {
    Receiver r = receiver;
    r.width = level.resolution_x;
    r.height = level.resolution_y;
    return r;
}

// The rays per receiver cell a design fits its final level to: the light's own, raised
// so that every cell of the final mesh (nx × ny vertices) has at least
// `min_rays_per_mesh_cell` rays on average (optimise.min_rays_per_mesh_cell, 32 by default). A mesh with few rays
// per cell can steer single rays from cell to cell, and a design then fits the sampling
// noise of its rays rather than the light: judged by cell means (error_physical,
// docs/measures.md) the headlight (53² mesh on 50² px, 14 rays per mesh cell at 16 per
// receiver cell) ended at a fitted error of 0.005 against 0.015 and did not improve with
// time. A move's cost grows with the rays per mesh cell, so the floor is a trade: seed 1
// at three budgets (benchmarks/results/physical), 32 beat both no floor and 64 on the
// headlight (0.0129 / 0.0121 / 0.0116), the camera photograph (0.0412 / 0.0379 / 0.0349;
// 64: 0.0442 / 0.0405 / 0.0365, too few moves) and the grey landscape. Unchanged when the
// light gives a fixed `rays` count, and for meshes that are coarse for their receiver
// (101² on 200² px has 64 already).
inline double fitting_rays_per_cell(const Scene& scene, double min_rays_per_mesh_cell, int nx, int ny) {
    const Light& light = scene.light;
    if (light.rays > 0 || !(min_rays_per_mesh_cell > 0)) return light.rays_per_cell;
    const double mesh_cells = double(std::max(nx - 1, 1)) * double(std::max(ny - 1, 1));
    return std::max(light.rays_per_cell,
                    std::ceil(min_rays_per_mesh_cell * mesh_cells / double(scene.receiver.cells())));
}

// How many of the planned coarse levels a design starting at error `start_error` (the
// exact tracer's, at the final level) skips. Coarse levels move light across the
// receiver at low cost; a start that already has the light roughly in place only needs
// the finer ones, which keeps its detail instead of re-shaping it on a coarse mesh.
inline int coarse_levels_to_skip(double start_error, int planned) {
    if (planned <= 1 || !(start_error >= 0)) return 0;
    if (start_error <= 0.2) return planned - 1;
    if (start_error <= 0.35) return std::max(0, planned - 2);
    return 0;
}

// The start of a design with the schedule `levels` (planned, before any is skipped):
// the start itself (the transport start is solved and judged here), which of the
// planned levels it still needs, and, for a transport start, the surface fitted again
// on the first kept level's own mesh (not resampled). Replicas of one design compute
// this once and share it (replicas.hpp, share_start).
inline SharedStart prepare_start(const Scene& scene, Heightmap initial, const ImageD& target_image,
                                 const DesignOptions& options, const std::vector<LevelPlan>& levels, int threads) {
    DesignStart start = make_design_start(scene, std::move(initial), target_image, options, threads);
    SharedStart shared;
    shared.report = start.report;
    shared.transport = start.map.has_value();
    const int planned_count = int(levels.size());
    if (options.start_level >= 0) {
        shared.skip = std::min(options.start_level, planned_count - 1);
        shared.report.plan = "optimise.start_level = " + std::to_string(options.start_level);
    } else if (start.map && options.levels.empty()) {
        shared.skip = coarse_levels_to_skip(start.report.error, planned_count);
        shared.report.plan = "start error " + std::to_string(start.report.error) + ": " +
                             (shared.skip == 0 ? std::string("all planned levels run")
                                               : "the " + std::to_string(shared.skip) + " coarsest of " +
                                                     std::to_string(planned_count) + " planned levels skipped");
    } else {
        shared.report.plan = "all planned levels run";
    }
    if (options.keep_better_start) shared.final_surface = start.surface;  // finish_design compares with it
    shared.surface = std::move(start.surface);
    const LevelPlan& first = levels[std::size_t(shared.skip)];
    if (start.map && (first.mesh_x != shared.surface.nx() || first.mesh_y != shared.surface.ny())) {
        TransportReport fit = start.report.transport;
        shared.surface = surface_from_transport(scene, *start.map, first.mesh_x, first.mesh_y, fit);
    }
    return shared;
}

namespace design_detail {

// Metres of kernel amplitude per receiver cell of light displacement per grid unit.
inline double amplitude_unit(const Scene& scene, const Receiver& rec, const Heightmap& hm) {
    const double cell = std::min(rec.size.x / rec.width, rec.size.y / rec.height);
    const double distance = length(rec.frame.origin - scene.surface.frame.origin);
    const double factor = is_lens(scene.surface.material)
                              ? std::max(0.05, std::get<Lens>(scene.surface.material).ior - 1.0)
                              : 2.0;
    return cell * std::min(hm.du(), hm.dv()) / (factor * std::max(distance, 1e-6));
}


// The kernel bank of a stage; `kept` (when not empty) lists the shapes the bandit's
// pre-process kept (indices into default_kernel_bank, the same at every support).
inline ProposalSettings proposals_for(const ProposalOptions& o, int support, const std::vector<int>& kept = {}) {
    ProposalSettings p;
    p.single_vertex = o.single_vertex;
    p.error_guided = o.error_guided;
    p.max_shift_cells = o.max_shift_cells;
    p.min_shift_cells = o.min_shift_cells;
    if (!o.single_vertex) {
        auto bank = default_kernel_bank(std::max(3, support | 1));
        if (o.kernel_shapes == KernelShapes::isotropic) bank.resize(1);  // the reference's single-kernel baseline
        if (kept.empty() || bank.size() == 1) {
            p.bank = bank;
        } else {
            for (int k : kept) p.bank.push_back(bank[std::size_t(k)]);
        }
    }
    return p;
}

// The temperature T at which uphill moves of sizes `up` are accepted with mean
// probability p: mean(exp(-d / T)) = p, which lies between min(d) / ln(1/p) and
// max(d) / ln(1/p); solved by bisection on log T. 1e-12 when no move went uphill.
inline double acceptance_temperature(const std::vector<double>& up, double p) {
    if (up.empty()) return 1e-12;
    p = std::clamp(p, 1e-6, 0.999);
    const double l = -std::log(p);
    const auto [dmin, dmax] = std::minmax_element(up.begin(), up.end());
    double lo = std::max(*dmin / l, 1e-300), hi = std::max(*dmax / l, lo);
    for (int it = 0; it < 100 && hi > lo * (1 + 1e-12); ++it) {
        const double mid = std::sqrt(lo * hi);
        double mean = 0;
        for (double d : up) mean += std::exp(-d / mid);
        mean /= double(up.size());
        (mean > p ? hi : lo) = mid;
    }
    return std::max(std::sqrt(lo * hi), 1e-12);
}

struct Calibration {
    double temperature = 0;       // initial temperature of the stage
    double moves_per_second = 0;  // single-thread delta evaluations per second, measured
};

// Initial temperature from a few trial moves (evaluated, never applied): the T at which
// the uphill ones would be accepted with mean probability p, mean(exp(-delta / T)) = p
// (the acceptance ratio of the textbook initial-temperature rules, e.g. Ben-Ameur,
// Comput. Optim. Appl. 29, 2004); their timing estimates the speed.
//
// Until 2026-11 the rule was T = mean(delta) / ln(1/p), "a typical uphill move accepted
// with p". Uphill deltas are heavy-tailed (many nearly neutral moves, a few bad ones),
// so that T accepted most small uphill moves: from a transport start every stage first
// drifted up (letter E: error 0.0426 -> 0.0527 in its first stage, which then ended
// where it began) and spent most of its iterations coming back down. The acceptance
// ratio rule started 11 to 300,000 times colder on the example cases; at equal
// iterations every case ended 7-40 % lower (docs/performance.md, "After the calibration fix
// (err measure)"; git show ce210ae:benchmarks/results/calibration/REPORT.md). The
// temperature still sets the move amplitudes (ProposalSettings), which it scales from
// this reference.
//
// With `timed`, slow moves cut the trials short (a time-budgeted run must not spend its
// budget calibrating); otherwise there are always 48, so that the temperature, and with
// it the run, does not depend on the machine's speed or load.
template <class Problem>
Calibration calibrate(Problem& problem, std::uint64_t seed, double p, bool timed) {
    typename Problem::Move m;
    std::vector<double> up;
    const auto start = std::chrono::steady_clock::now();
    const auto seconds_since = [&] {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    };
    // 48 trial moves, or (timed) fewer when moves are slow, at least 8.
    int trials = 0;
    for (; trials < 48 && (!timed || trials < 8 || seconds_since() < 0.15); ++trials) {
        CounterRng rng(hash_combine(seed, 0xca11b7a7eULL), std::uint64_t(trials));
        problem.propose(rng, 1.0, m);
        const double d = problem.delta(m);
        if (d > 0) up.push_back(d);
    }
    const double speed = trials / std::max(seconds_since(), 1e-9);
    return {acceptance_temperature(up, p), speed};
}

}  // namespace design_detail

namespace design_detail {

// What a full rebuild of an incremental trace costs per cell a ray crosses, beyond the
// tracing itself: storing the crossing in both directions of the index, and the memory
// it faults in. Measured on the grazing-light stress case (2 cores, 2026-11-28: 57.7
// million crossings, 6.1 s a build on an idle machine, of which 0.5 s tracing; 12-14 s
// under a load of 7); coarse, and only used to decide whether a time budget affords a
// level (unaffordable_level).
inline constexpr double rebuild_seconds_per_crossing = 100e-9;

// A timed stage that is not the design's last ends when it has stopped paying: when its
// best fitted error fell by less than stage_gain_floor (relative) over the last
// stage_gain_window of the time budget. Its time passes to the next stage. From a
// transport start the large kernels of a level's first stage mostly re-shape what the
// start already has: on the lens example's two photographs and on the camera case that
// stage won under 1 % in a third of the budget while the small kernels after it went on
// winning (docs/performance.md, "Stages that stop paying"). Not for the design's last
// stage, with replicas (their stops are collective) or with an iteration cap.
inline constexpr double stage_gain_window = 0.1;
inline constexpr double stage_gain_floor = 0.01;

// The watch over one stage's gain: fed the fitted error at every progress report,
// stalled() once the best error of `window` seconds ago beats today's best by less than
// `floor` of itself. A default-constructed watch never stalls.
struct StageGainWatch {
    double window = 0, floor = 0, begin = 0;
    std::vector<std::pair<double, double>> best_by_time = {};  // (seconds, best error so far)
    bool gave_up = false;

    StageGainWatch() = default;
    StageGainWatch(double window_seconds, double floor_fraction, double begin_seconds)
        : window(window_seconds), floor(floor_fraction), begin(begin_seconds) {}

    bool stalled(double now, double error) {
        if (!(window > 0)) return false;
        const double best = best_by_time.empty() ? error : std::min(error, best_by_time.back().second);
        best_by_time.push_back({now, best});
        if (now - begin < window) return false;
        // The best error one window ago: the last record at or before now - window.
        const auto it = std::upper_bound(best_by_time.begin(), best_by_time.end(), now - window,
                                         [](double t, const auto& p) { return t < p.first; });
        if (it == best_by_time.begin()) return false;
        const double then = std::prev(it)->second;
        return gave_up = then - best < floor * then;
    }
};

inline std::string one_decimal(double x) {
    char b[32];
    std::snprintf(b, sizeof b, "%.1f", x);
    return b;
}

// Seconds since a design started.
struct DesignClock {
    std::chrono::steady_clock::time_point start = std::chrono::steady_clock::now();
    double operator()() const {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    }
};

// The annealer's hooks during one stage: progress reports to the caller, held-out checks,
// and, with replicas, the exchanges and merges (replicas.hpp).
template <class Problem, class Callback, class Replicas>
struct StageHooks {
    Problem* problem;
    std::vector<ConvergencePoint>* convergence;
    Callback* user;
    DesignProgress info;
    std::int64_t base;
    const DesignClock* clock;
    double budget;
    bool stopped = false;
    Replicas* replicas = nullptr;  // set when replicas are active
    double stage_deadline = 0;     // seconds since the design started; 0 = none
    double target = 0;             // target error; 0 = none
    HeldOutCheck* held_out = nullptr;  // set when held-out checks are on
    HeldOutBest* held_best = nullptr;
    std::int64_t next_check = 0;
    // Replicas sharing one surface: the heights of the last merge, and when.
    std::vector<float> merge_base = {};
    std::int64_t merged_at = 0;
    std::int64_t merges = 0;
    std::int64_t merge_every = 0;
    StageGainWatch gain = {};  // off unless set (stage_hooks)
    // Held-out checks at the first sync point past each interval: sync points are fixed
    // iterations, so the checks do not change the run's course. Replicas that share a
    // surface check only merged states (the same on every replica), at merges.
    void batch(const BatchStats& b) {
        if (!held_out || b.iteration < next_check || (replicas && replicas->shares_surface())) return;
        check_held_out(b.iteration);
    }
    void check_held_out(std::int64_t iteration) {
        held_best->offer(problem->surface(), (*held_out)(problem->surface()), iteration);
        next_check = iteration + held_out->interval();
    }
    // Every replica's changes since the last merge, on every replica.
    void merge(std::int64_t iteration, bool check = true) {
        std::vector<float> h = problem->surface().heights();
        replicas->merge(h, merge_base);
        problem->replace_heights(h);
        merge_base = problem->surface().heights();
        merged_at = iteration;
        ++merges;
        if (check && held_out && iteration >= next_check) check_held_out(iteration);
    }
    bool exchange(AnnealExchange& x) {
        if (!replicas) return false;
        ReplicaExchange r;
        r.energy = x.state.energy;
        r.best_energy = x.state.best_energy;
        r.temperature = x.state.temperature;
        r.temperature_scale = x.temperature_scale;
        r.local_stop = stopped || (stage_deadline > 0 && (*clock)() >= stage_deadline) ||
                       (target > 0 && x.state.best_energy <= target);
        const bool stop_all = replicas->exchange(r);
        x.temperature_scale = r.temperature_scale;
        if (replicas->shares_surface() && (stop_all || x.state.iteration - merged_at >= merge_every)) {
            merge(x.state.iteration);
            x.state_replaced = true;
        }
        return stop_all;
    }
    bool progress(const AnnealState& s) {
        const ObjectiveValue& v = problem->value();
        const double now = (*clock)();
        convergence->push_back({now, base + s.iteration, info.level, info.stage, v.error, v.energy, v.total,
                                s.temperature});
        info.iteration = base + s.iteration;
        info.temperature = s.temperature;
        info.error = v.error;
        info.energy = v.energy;
        info.objective = v.total;
        info.iterations_per_second = s.iterations_per_second;
        info.seconds = now;
        info.time_left = budget > 0 ? std::max(0.0, budget - now) : 0.0;
        if ((*user)(info)) stopped = true;
        // With replicas, a stop is taken at the next exchange point, by all.
        return replicas ? false : stopped || gain.stalled(now, v.error);
    }
};

// What every stage of one level shares: its receiver, rays and physics, the move
// amplitude unit, and the held-out check of its rays.
struct LevelSetup {
    std::size_t index = 0;
    const LevelPlan* plan = nullptr;
    Receiver receiver;
    Light light;
    TraceSetup trace_setup;  // the level's rays, path parameters and target
    double unit = 1;
    std::optional<HeldOutCheck> held_out;
    std::size_t stages = 1;
    // The trace the level's last problem kept consistent with the surface, for the next
    // one (stateless backends: design/problem.hpp): one full trace per level, not per stage.
    std::optional<IncrementalTrace> trace;
};

// What the parts of one design share: what it was given, fixed for the run, and what it
// has made so far. Each part below owns one step, and Designer runs them in order:
//   make_level_setup      a level's receiver, light, rays and target
//   add_held_out          its held-out check
//   unaffordable_level    whether a timed level can afford to build its trace
//   make_problem          the problem a stage anneals (the level's trace passed on)
//   preprocess            the history bandit's pre-process (the first stage only)
//   stage_options         a stage's iteration budget, temperature and time
//   stage_hooks           what the annealer calls back during a stage
//   run_stage             one stage: calibrate, anneal, judge with held-out rays, keep
//   end_stage, keep_result, keep_judged     a stage's end
//   evaluate_on_final_mesh                   a design stopped before its last level
template <class Callback, class Replicas>
struct DesignState {
    using callback_type = Callback;
    using replicas_type = Replicas;

    DesignState(const Scene& s, const ImageD& target, const DesignOptions& o, Callback& c, const Penalties& p,
                Replicas& r, const DeviceOffer* dev)
        : scene(s), target_image(target), options(o), callback(c), penalties(p), replicas(r), device(dev),
          timed(o.time_budget > 0 && o.max_iterations == 0),
          weights(o.objective) {}

    const Scene& scene;
    const ImageD& target_image;
    const DesignOptions& options;
    Callback& callback;
    const Penalties& penalties;
    Replicas& replicas;
    // The device the stages' windows run on (design/device.hpp); null: the CPU.
    const DeviceOffer* device;
    // How much faster than cpu_speed's estimate the device's stages ran, as the last
    // timed stage on it measured (1 until one has): a timed stage's iteration budget
    // is then fitted to the device's speed, not the host calibration's.
    double device_speedup = 1;
    // An iteration cap, or no time budget, makes a run reproducible bit for bit: nothing
    // may then depend on measured time (see calibrate()). Otherwise the run is timed: its
    // calibrations are cut short by slow moves and its stages' budgets fit the speed.
    bool timed;
    ObjectiveWeights weights;
    DesignClock clock;
    int threads = 1;
    std::vector<LevelPlan> levels;
    DesignOptions moves;  // the options the moves are made with (colder from a transport start)
    Heightmap surface;
    DesignResult result;
    std::int64_t total_iterations = 0;
    double share_used = 0;
    bool stop = false;
    std::vector<int> kept_arms;  // after the history bandit's pre-process

    // Whether stage si of level L is the design's last.
    bool design_last(const LevelSetup& L, std::size_t si) const {
        return L.index + 1 == levels.size() && si + 1 == L.stages;
    }
};

// Level li's set-up on the design's surface (refined to the level's mesh already), but for
// its held-out check (add_held_out): a level the time budget cannot afford is judged on
// the final mesh instead (evaluate_on_final_mesh), and its held-out rays would be made
// for nothing (at 1024^2, 33 million rays and their target).
template <class State>
LevelSetup make_level_setup(const State& d, std::size_t li) {
    LevelSetup L;
    L.index = li;
    L.plan = &d.levels[li];
    L.receiver = level_receiver(d.scene.receiver, *L.plan);
    // Coarse levels only shape the light roughly: fewer rays per cell make their moves
    // cheaper without changing what they can see. The last level uses the light's own.
    L.light = d.scene.light;
    if (li + 1 < d.levels.size() && d.options.coarse_rays_per_cell > 0 && L.light.rays == 0)
        L.light.rays_per_cell = std::min(L.light.rays_per_cell, d.options.coarse_rays_per_cell);
    L.trace_setup = make_trace_setup(d.scene, L.light, L.receiver, d.surface, &d.target_image, d.options.seed);
    L.unit = amplitude_unit(d.scene, L.receiver, d.surface);
    L.stages = L.plan->kernel_supports.empty() ? 1 : L.plan->kernel_supports.size();
    return L;
}

// The level's held-out check (optimise.held_out_checks): its light and receiver, rays of
// another jitter.
template <class State>
void add_held_out(const State& d, LevelSetup& L) {
    if (!d.options.held_out_checks) return;
    const std::uint64_t seed = HeldOutCheck::seed_for(d.options.seed, L.index);
    L.held_out.emplace(make_trace_setup(d.scene, L.light, L.receiver, d.surface, &d.target_image, seed), d.weights,
                       d.penalties, d.threads);
}

// A time-budgeted level is annealed only when building its trace (the first problem's
// full rebuild, estimated from a sample of its rays) leaves at least as long again for
// its moves. Under grazing light every ray crosses some 45 cells and the build alone
// can outlast a short budget: the letter E lit at 70 degrees from the normal, 10 s,
// spent 25 s, most of it building traces, for 24 iterations that changed nothing
// (docs/performance.md, "The time budget"). Returns, in words, why the level and those
// after it are left out; nothing when it can be afforded.
//
// The crossings counted are those the trace will list: under oblique light its reach
// envelope (trace/incremental.hpp) leaves out most of the slab's, with the first
// stage's margin (the widest kernels the level uses).
template <class State>
std::optional<std::string> unaffordable_level(const State& d, const LevelSetup& L) {
    const RaySet& rays = L.trace_setup.rays;
    const int support = L.plan->kernel_supports.empty() ? 3 : L.plan->kernel_supports.front();
    ReachEnvelope reach;
    reach.margin = float(reach_margin(proposals_for(d.moves.proposals, support), L.unit));
    if (std::isfinite(reach.margin)) reach.centre_on(d.surface);
    const RebuildSample sample = sample_rebuild(d.surface, rays, L.trace_setup.params, 64, reach.view());
    if (sample.rays == 0) return std::nullopt;
    const double scale = double(rays.size()) / double(sample.rays);
    const double build = sample.seconds * scale / double(d.threads) +
                         double(sample.listed()) * scale * rebuild_seconds_per_crossing;
    const double left = d.options.time_budget - d.clock();
    if (2 * build <= left) return std::nullopt;
    const std::size_t after = d.levels.size() - L.index - 1;
    return "the " + std::to_string(L.plan->mesh_x) + " x " + std::to_string(L.plan->mesh_y) + " level" +
           (after > 0 ? " and the " + std::to_string(after) + " after it" : "") +
           " not annealed: building its trace would take about " + one_decimal(build) + " s of the " +
           one_decimal(std::max(left, 0.0)) + " s left";
}

// Stopped early: the surface is at this level's mesh; refine it to the final mesh so
// that exports have the size the user asked for, and evaluate it there, so that the
// result's irradiance, target and value describe it.
template <class State>
void evaluate_on_final_mesh(State& d) {
    const LevelPlan& final_level = d.levels.back();
    d.surface = refine_preserving_normals(d.surface, final_level.mesh_x, final_level.mesh_y);
    const Receiver receiver = level_receiver(d.scene.receiver, final_level);
    const auto setup = [&](std::uint64_t seed) {
        return make_trace_setup(d.scene, d.scene.light, receiver, d.surface, &d.target_image, seed);
    };
    // One plain trace of the design's own rays (the judge of held_out.hpp with the
    // design's seed): the problem's trace, its rays' cells indexed too, costs many
    // times more under grazing light and gives the same histogram.
    HeldOutCheck fitted(setup(d.options.seed), d.weights, d.penalties, d.threads);
    d.result.value = fitted(d.surface);
    d.result.irradiance = fitted.histogram();
    d.result.target = fitted.target();
    d.result.rays = fitted.rays();
    if (d.options.held_out_checks) {
        // ... and on the final level's held-out rays.
        HeldOutCheck check(setup(HeldOutCheck::seed_for(d.options.seed, d.levels.size() - 1)), d.weights,
                           d.penalties, d.threads);
        d.result.held_out = check(d.surface);
        d.result.held_out_seed = check.seed();
    }
}

// The backend, held to the design's thread count (its full rebuilds included).
template <class Backend>
Backend backend_for(int threads) {
    Backend b{};
    if constexpr (requires { b.threads; }) b.threads = threads;
    return b;
}

// A stage's problem on the design's surface. The level's trace, if an earlier problem
// left one, passes to the new problem.
template <class Backend, class State>
BasicSurfaceProblem<Backend> make_problem(State& d, LevelSetup& L, ProposalSettings ps, AnyBandit bandit) {
    std::optional<IncrementalTrace> reuse = std::exchange(L.trace, std::nullopt);
    const TraceSetup& t = L.trace_setup;
    return BasicSurfaceProblem<Backend>(d.surface, t.rays, t.params, t.target, d.weights, d.penalties, std::move(ps),
                                        std::move(bandit), L.unit, 1.0, backend_for<Backend>(d.threads),
                                        reuse ? &*reuse : nullptr);
}

// What a problem leaves for the next one on this level (see make_problem).
template <class Backend>
void keep_trace(LevelSetup& L, BasicSurfaceProblem<Backend>& problem) {
    if constexpr (requires { requires Backend::stateless; }) L.trace.emplace(problem.take_trace());
}

template <class State>
bool wants_preprocess(const State& d, std::size_t li, std::size_t si) {
    const ProposalOptions& p = d.options.proposals;
    return li == 0 && si == 0 && p.bandit == BanditKind::history && !p.single_vertex &&
           p.kernel_shapes != KernelShapes::isotropic && p.preprocess_iterations > 0 && p.preprocess_keep > 0;
}

// The history bandit's pre-process (reference §4.3.2): a short run with every shape
// equally likely, then only the shapes that paid best are kept (d.kept_arms).
template <class Backend, class State>
void preprocess(State& d, LevelSetup& L, int support, std::uint64_t stage_seed) {
    ProposalSettings all = proposals_for(d.moves.proposals, support);
    const int arms = int(all.bank.size());
    auto pre =
        make_problem<Backend>(d, L, std::move(all),
                              make_bandit(BanditKind::uniform, arms, d.options.proposals.bandit_sync));
    const auto cal = calibrate(pre, hash_combine(stage_seed, 1), d.moves.schedule.initial_acceptance, d.timed);
    pre.set_reference_temperature(cal.temperature);
    AnnealOptions po;
    po.seed = hash_combine(stage_seed, 2);
    po.initial_temperature = cal.temperature;
    po.cooling = 1.0;
    po.max_iterations = d.options.proposals.preprocess_iterations;
    po.time_budget = d.options.time_budget > 0 ? 0.05 * d.options.time_budget : 0;
    po.threads = 1;
    const AnnealResult pr = anneal(pre, po);
    d.total_iterations += pr.iterations;
    d.result.accepted += pr.accepted;
    std::vector<double> rate(std::size_t(arms), 0.0);
    for (int a = 0; a < arms; ++a) {
        const auto pulls = pre.bandit().pulls()[std::size_t(a)];
        rate[std::size_t(a)] = pulls > 0 ? pre.bandit().total_rewards()[std::size_t(a)] / double(pulls) : 0.0;
    }
    d.kept_arms = HistoryBandit::preselect(rate, std::min(d.options.proposals.preprocess_keep, arms));
    std::sort(d.kept_arms.begin(), d.kept_arms.end());
    d.result.preprocess_rates = rate;
    keep_trace(L, pre);
}

// Iterations per second a stage would make on the CPU, from the calibration's speed
// (moves judged one by one on the host): speculative windows on the CPU's threads gain
// about 60 % per extra thread.
template <class State>
double cpu_speed(const State& d, double moves_per_second, int speculative) {
    return moves_per_second * (1.0 + 0.6 * (std::min(speculative, d.threads) - 1));
}

// ... and what it is expected to make: on a device, that times what the design's earlier
// stages on it measured (device_speedup).
template <class State>
double expected_speed(const State& d, double moves_per_second, int speculative) {
    return cpu_speed(d, moves_per_second, speculative) * (d.device ? d.device_speedup : 1.0);
}

// The stage's iteration budget: with a time budget and no iteration cap, as many
// iterations as the measured speed fits in the stage's time (so that the temperature
// schedule completes); otherwise the plan's, which makes the run reproducible.
template <class State>
std::int64_t stage_budget(const State& d, const LevelSetup& L, std::size_t si, double moves_per_second,
                          double stage_time, int speculative) {
    const double level_share = L.plan->time_share;
    std::int64_t budget = std::max<std::int64_t>(1, L.plan->iterations / std::int64_t(L.stages));
    if (d.timed)
        budget = std::max<std::int64_t>(
            500, std::int64_t(0.9 * expected_speed(d, moves_per_second, speculative) * stage_time));
    if (d.options.max_iterations > 0) {
        // The cap is shared by every stage still to run, in proportion to the levels'
        // time shares, so that no level is starved by an earlier one.
        double remaining_share = level_share / double(L.stages);
        for (std::size_t lk = L.index + 1; lk < d.levels.size(); ++lk) remaining_share += d.levels[lk].time_share;
        remaining_share += level_share * double(L.stages - si - 1) / double(L.stages);
        const std::int64_t left = d.options.max_iterations - d.total_iterations;
        const double mine = remaining_share > 0 ? (level_share / double(L.stages)) / remaining_share : 1.0;
        budget = std::max<std::int64_t>(1, std::int64_t(double(left) * mine));
    }
    return d.replicas.common_budget(budget);
}

// Proposals per speculative window when optimise.speculative leaves it open: one per
// thread on the CPU, the device's own count on a device.
template <class State>
int stage_window(const State& d) {
    if (!d.device) return d.threads;
    return d.device->window > 0 ? d.device->window : default_device_window;
}

// The device failed (its backend could not be made, or a window or commit threw,
// BasicSurfaceProblem::window_failure): the design goes on on the CPU, said in the result.
template <class State>
void device_failed(State& d, const LevelSetup& L, std::size_t si, const std::string& why) {
    d.result.device_failure =
        "level " + std::to_string(L.index + 1) + " stage " + std::to_string(si + 1) + ": " + why;
    d.device = nullptr;
}

// The stage's windows on the design's device, if it has one: the device's backend over
// the stage's surface and rays, kept current by CopiedStateWindowEvaluator
// (trace/window.hpp). Only the height-field backend judges windows.
template <class Backend, class State>
void use_device(State& d, const LevelSetup& L, std::size_t si, BasicSurfaceProblem<Backend>& problem) {
    if constexpr (std::is_same_v<Backend, HeightfieldBackend>) {
        if (!d.device) return;
        const TraceSetup& t = L.trace_setup;
        try {
            problem.set_window_evaluator(
                std::make_unique<CopiedStateWindowEvaluator>(d.device->make(d.surface, t.rays, t.params)));
        } catch (const std::exception& e) {
            device_failed(d, L, si, e.what());
        }
    }
}

// The annealer's options for stage si of level L, from initial temperature t0, the
// calibration's speed and the stage's time.
template <class State>
AnnealOptions stage_options(const State& d, const LevelSetup& L, std::size_t si, int support,
                            std::uint64_t stage_seed, double t0, double moves_per_second, double stage_time) {
    const DesignOptions& o = d.options;
    AnnealOptions ao;
    ao.seed = d.replicas.anneal_seed(stage_seed);
    ao.initial_temperature = t0;
    ao.cooling = o.schedule.cooling;
    const int speculative = o.speculative > 0 ? o.speculative : stage_window(d);
    const std::int64_t budget = stage_budget(d, L, si, moves_per_second, stage_time, speculative);
    ao.max_iterations = budget;
    ao.iterations_per_temperature = std::max<std::int64_t>(1, budget / std::max(1, o.schedule.temperature_steps));
    // The last stage of a time-budgeted run goes on until the time is up: its budget,
    // fitted to the speed the calibration measured, often runs out first (letter E,
    // 20 s: at 17.9 s), and the schedule simply cools on past it.
    if (d.timed && d.design_last(L, si)) ao.max_iterations = std::numeric_limits<std::int64_t>::max() / 4;
    ao.patience = std::max<std::int64_t>(100, std::int64_t(o.schedule.patience_fraction * double(budget)));
    ao.reheat_factor = o.schedule.reheat_factor;
    ao.time_budget = o.time_budget > 0 ? stage_time : 0;
    if (o.target_error > 0) ao.target_energy = o.target_error;
    ao.speculative = speculative;
    ao.threads = d.threads;
    ao.progress_every = std::max<std::int64_t>(1, o.progress_every);
    if (d.replicas.active()) {
        // Every stop that could differ between replicas is decided together at the
        // exchange points (replicas.hpp); the annealer itself stops only at the common
        // iteration budget.
        ao.time_budget = 0;
        ao.target_energy = std::numeric_limits<double>::quiet_NaN();
        ao.temperature_scale = d.replicas.stage_temperature_scale();
        ao.exchange_every =
            std::max<std::int64_t>(1, d.replicas.exchange_every(L.plan->mesh_x, L.plan->mesh_y, support));
    }
    return ao;
}

// What the annealer calls back during stage si: progress, held-out checks, and with
// replicas their exchanges and merges.
template <class State, class Problem>
auto stage_hooks(State& d, Problem& problem, const LevelSetup& L, std::size_t si, const StageReport& report,
                 HeldOutCheck* held_out, HeldOutBest& held_best, int support, double stage_time) {
    using Hooks = StageHooks<Problem, typename State::callback_type, typename State::replicas_type>;
    Hooks hooks{&problem, &d.result.convergence, &d.callback, {}, d.total_iterations, &d.clock, d.options.time_budget};
    hooks.info.level = int(L.index);
    hooks.info.levels = int(d.levels.size());
    hooks.info.stage = int(si);
    hooks.info.stages = int(L.stages);
    hooks.info.mesh = std::max(L.plan->mesh_x, L.plan->mesh_y);
    hooks.info.resolution = std::max(L.receiver.width, L.receiver.height);
    hooks.info.kernel_support = report.kernel_support;
    if (held_out) {
        hooks.held_out = held_out;
        hooks.held_best = &held_best;
        hooks.next_check = held_out->interval();
    }
    if (d.timed && !d.design_last(L, si) && !d.replicas.active())
        hooks.gain = StageGainWatch(stage_gain_window * d.options.time_budget, stage_gain_floor, d.clock());
    if (d.replicas.active()) {
        hooks.replicas = &d.replicas;
        hooks.stage_deadline = d.options.time_budget > 0 ? d.clock() + stage_time : 0;
        hooks.target = d.options.target_error;
        if (d.replicas.shares_surface()) {
            hooks.merge_base = d.surface.heights();
            hooks.merge_every = d.replicas.merge_every(L.plan->mesh_x, L.plan->mesh_y, support);
        }
    }
    return hooks;
}

template <class State, class Problem>
StageReport stage_report_start(const State& d, const LevelSetup& L, int support, double t0, const Problem& problem) {
    StageReport report;
    report.level = int(L.index);
    report.mesh_x = L.plan->mesh_x;
    report.mesh_y = L.plan->mesh_y;
    report.resolution_x = L.receiver.width;
    report.resolution_y = L.receiver.height;
    report.kernel_support = d.options.proposals.single_vertex ? 1 : support;
    report.initial_temperature = t0;
    report.error_start = problem.value().error;
    report.rays = L.trace_setup.rays.size();
    return report;
}

// The stage's end when the annealer left its current state in place: its best state on
// the fitted rays is judged with the held-out rays on a copy of the surface, and the
// problem goes to the state the judge keeps (that one, or an earlier held-out best) with
// one full retrace, where restoring and then replacing took two. The same heights, and
// so the same design, as restoring first: under grazing light a retrace takes seconds.
template <class State, class Problem>
void keep_judged(const State& d, Problem& problem, HeldOutCheck& held_out, HeldOutBest& held_best,
                 std::int64_t iteration, StageReport& report) {
    const std::vector<float>* fitted = problem.best_heights();  // null: the current state is the best
    Heightmap probe;
    if (fitted) {
        probe = d.surface;
        probe.set_heights(*fitted);
    }
    const Heightmap& best = fitted ? probe : d.surface;
    if (held_best.offer(best, held_out(best), iteration)) {
        if (fitted) problem.replace_heights(held_best.heights);
    } else {
        problem.replace_heights(held_best.heights);
        report.held_out_kept = held_best.iteration;
    }
}

template <class State, class Problem>
void end_stage(State& d, const Problem& problem, const AnnealResult& ar, StageReport& report, double stage_start,
               bool stopped) {
    d.total_iterations += ar.iterations;
    d.result.accepted += ar.accepted;
    report.iterations = ar.iterations;
    report.accepted = ar.accepted;
    report.proposals_evaluated = ar.proposals_evaluated;
    report.seconds = d.clock() - stage_start;
    report.error_end = problem.value().error;
    report.energy_end = problem.value().energy;
    report.objective_end = problem.value().total;
    report.bandit_weights = d.options.proposals.single_vertex ? std::vector<double>{} : problem.bandit().weights();
    d.result.stages.push_back(report);
    // With replicas, every replica goes on to the next stage, or none does.
    d.result.stopped_early = d.replicas.any(stopped);
    d.stop = d.replicas.any(stopped ||
                            (d.options.target_error > 0 && problem.value().total <= d.options.target_error));
}

template <class State, class Problem>
void keep_result(State& d, const Problem& problem, const ProposalSettings& ps, const StageReport& report,
                 const LevelSetup& L, const HeldOutCheck* held_out, const HeldOutBest& held_best) {
    d.result.irradiance = problem.histogram();
    d.result.target = problem.image().target();
    d.result.value = problem.value();
    d.result.kernel_bank = ps.bank;
    d.result.bandit_weights = report.bandit_weights;
    d.result.rays = L.trace_setup.rays.size();
    if (held_out) d.result.held_out = held_best.value, d.result.held_out_seed = held_out->seed();
}

// Stage si of level L: its problem, calibrated temperature and budget, the annealing
// with held-out checks, and its end (the state kept, the report, the trace or result).
template <class Backend, class State>
void run_stage(State& d, LevelSetup& L, std::size_t si) {
    const int support = L.plan->kernel_supports.empty() ? 3 : L.plan->kernel_supports[si];
    const std::uint64_t stage_seed = hash_combine(d.options.seed, L.index * 16 + si);
    if (wants_preprocess(d, L.index, si)) preprocess<Backend>(d, L, support, stage_seed);
    ProposalSettings ps = proposals_for(d.moves.proposals, support, d.kept_arms);
    const int arms = std::max<int>(1, int(ps.bank.size()));
    const ProposalOptions& prop = d.options.proposals;
    auto problem = make_problem<Backend>(d, L, ps, make_bandit(prop.bandit, arms, prop.bandit_sync));
    use_device(d, L, si, problem);
    const Calibration cal = calibrate(problem, stage_seed, d.moves.schedule.initial_acceptance, d.timed);
    // Identity for one replica.
    const double t0 = d.replicas.common_temperature(cal.temperature * d.options.schedule.initial_temperature_scale);
    problem.set_reference_temperature(t0);
    // Replicas that share one surface each move their own strip of it (after the
    // calibration, which every replica makes on the whole surface alike).
    if (d.replicas.shares_surface()) {
        const auto [j0, j1] = d.replicas.centre_rows(d.surface.ny());
        problem.set_centre_rows(j0, j1);
    }
    StageReport report = stage_report_start(d, L, support, t0, problem);
    HeldOutCheck* held_out = L.held_out ? &*L.held_out : nullptr;
    HeldOutBest held_best;
    if (held_out) {
        const ObjectiveValue v = (*held_out)(d.surface);
        held_best.offer(d.surface, v, 0);
        report.held_out_start = v.error;
    }
    // Time: this stage's share of what is left of this level's share.
    const double level_end = d.options.time_budget * (d.share_used + L.plan->time_share);
    const double stage_time = std::max(0.05, (level_end - d.clock()) / double(L.stages - si));
    AnnealOptions ao = stage_options(d, L, si, support, stage_seed, t0, cal.moves_per_second, stage_time);
    // With held-out checks (and no replicas, whose merges read the restored state), the
    // stage's end judges the fitted best before the problem is retraced: see keep_judged.
    const bool judge_first = held_out && !d.replicas.active();
    ao.restore_best = !judge_first;
    const auto stage_start = d.clock();
    auto hooks = stage_hooks(d, problem, L, si, report, held_out, held_best, support, stage_time);
    const AnnealResult ar = anneal(problem, ao, hooks);
    if constexpr (std::is_same_v<Backend, HeightfieldBackend>)
        if (!problem.window_failure().empty()) device_failed(d, L, si, problem.window_failure());
    // Sharing replicas end the stage on one surface: each holds its best since the last
    // merge, and these are merged (unless nothing ran since; every replica ran the same
    // iterations, so all decide alike).
    if (d.replicas.shares_surface() && hooks.merged_at != ar.iterations)
        hooks.merge(ar.iterations, false);  // the stage's end checks it (below)
    report.merges = hooks.merges;
    report.crossings = problem.trace().index().crossings();
    report.reach_envelope = problem.trace().reach().active();
    report.reach_recentres = problem.reach_recentres();
    if (judge_first) {
        keep_judged(d, problem, *held_out, held_best, ar.iterations, report);
    } else if (held_out) {
        // The annealer ends holding its best state on the fitted rays; a state the
        // held-out rays judged better replaces it.
        if (!held_best.offer(d.surface, (*held_out)(d.surface), ar.iterations)) {
            problem.replace_heights(held_best.heights);
            report.held_out_kept = held_best.iteration;
        }
    }
    if (held_out) {
        report.held_out_end = held_best.value.error;
        report.held_out_checks = held_best.checks;
    }
    report.stop_reason = hooks.gain.gave_up && !hooks.stopped ? StopReason::no_gain : ar.reason;
    end_stage(d, problem, ar, report, stage_start, hooks.stopped);
    if (d.device && d.timed && ar.iterations > 0 && report.seconds > 0)
        d.device_speedup = std::max(0.1, double(ar.iterations) / report.seconds /
                                             cpu_speed(d, cal.moves_per_second, ao.speculative));
    if (d.design_last(L, si) || d.stop)
        keep_result(d, problem, ps, report, L, held_out, held_best);
    else
        keep_trace(L, problem);
}

// The multi-level schedule of one design (docs/architecture.md, "The path of a scene
// through a design"): schedule and start, then per level its stages (the first one
// after the history bandit's pre-process), then the result. A stopped design is
// evaluated on the final mesh. The steps are the parts above; this class orders them.
template <class Backend, class Callback, class Replicas>
class Designer {
  public:
    // `planned`: plan_levels of the scene with these options, when the caller has them
    // (plan_design); null: planned here.
    // `device`: where the stages' windows run (null: the CPU).
    Designer(const Scene& scene, const ImageD& target_image, const DesignOptions& options, Callback& callback,
             const Penalties& penalties, Replicas& replicas, const std::vector<LevelPlan>* planned = nullptr,
             const DeviceOffer* device = nullptr)
        : d_(scene, target_image, options, callback, penalties, replicas, device), planned_(planned) {
        if (device) d_.result.device = "cuda (" + device->name + ")";
    }

    DesignResult run(Heightmap initial) {
        schedule(std::move(initial));
        for (std::size_t li = 0; li < d_.levels.size() && !d_.stop; ++li) run_level(li);
        // The annealed surface, as the annealer left it: smoothing and the milling tool's
        // cut are finishing, done once, by finish_design (pipeline.hpp), which then judges
        // the finished surface for every figure it reports.
        d_.result.surface = std::move(d_.surface);
        d_.result.iterations = d_.total_iterations;
        d_.result.seconds = d_.clock();
        return std::move(d_.result);
    }

  private:
    // The levels plan_levels gives the scene with these options.
    std::vector<LevelPlan> plan_here() const { return plan_levels(d_.scene, d_.options); }

    // The levels, the start, and the levels the start leaves to run.
    void schedule(Heightmap initial) {
        const DesignOptions& o = d_.options;
        d_.levels = !o.levels.empty() ? o.levels : planned_ ? *planned_ : plan_here();
        d_.threads = thread_count(exec::omp_t{o.threads});
        // Where to start and which of the planned levels that start still needs, computed
        // once: with replicas, one computes it and hands it to the others (replicas.hpp).
        const int planned_count = int(d_.levels.size());
        SharedStart start = d_.replicas.share_start(
            [&] { return prepare_start(d_.scene, std::move(initial), d_.target_image, o, d_.levels, d_.threads); });
        d_.result.start = start.report;
        const LevelPlan& last = d_.levels.back();
        if (start.final_surface.nx() == last.mesh_x && start.final_surface.ny() == last.mesh_y)
            d_.result.start_surface = std::move(start.final_surface);
        if (start.skip > 0) {
            // The schedule goes on as planned from the first level kept (its kernels too:
            // the large ones of the coarse levels would only re-shape what the start has).
            d_.levels.erase(d_.levels.begin(), d_.levels.begin() + start.skip);
            assign_time_shares(d_.levels);
        }
        for (std::size_t k = 0; k < d_.levels.size(); ++k)
            if (d_.levels[k].kernel_supports.empty())
                d_.levels[k].kernel_supports = level_kernel_supports(d_.levels, k);
        d_.result.start.levels_planned = planned_count;
        d_.result.start.levels_used = int(d_.levels.size());
        // From a transport start the annealer refines: moves shift light by at most
        // refine_max_shift_cells and start colder (refine_initial_acceptance), so that its
        // first, hottest iterations do not undo the layout the start already has.
        d_.moves = o;
        if (start.transport) {
            ProposalOptions& p = d_.moves.proposals;
            p.max_shift_cells = std::min(o.proposals.max_shift_cells, o.proposals.refine_max_shift_cells);
            p.min_shift_cells = std::min(o.proposals.min_shift_cells, p.max_shift_cells);
            d_.moves.schedule.initial_acceptance =
                std::min(o.schedule.initial_acceptance, o.schedule.refine_initial_acceptance);
        }
        d_.surface = std::move(start.surface);
    }

    // A level: the surface refined to its mesh, its set-up, and its stages, unless a
    // timed design cannot afford its trace (the design then ends there, said in the
    // start's plan).
    void run_level(std::size_t li) {
        const LevelPlan& plan = d_.levels[li];
        d_.surface = refine_preserving_normals(d_.surface, plan.mesh_x, plan.mesh_y);
        LevelSetup L = make_level_setup(d_, li);
        if (d_.timed) {
            if (std::optional<std::string> left_out = unaffordable_level(d_, L)) {
                d_.result.start.levels_used = int(li);
                d_.result.start.left_out = *left_out;
                d_.result.start.plan += "; " + *left_out;
                d_.stop = true;
                evaluate_on_final_mesh(d_);
                return;
            }
        }
        add_held_out(d_, L);
        for (std::size_t si = 0; si < L.stages && !d_.stop; ++si) run_stage<Backend>(d_, L, si);
        d_.share_used += plan.time_share;
        if (d_.stop && li + 1 < d_.levels.size()) evaluate_on_final_mesh(d_);
    }

    DesignState<std::remove_reference_t<Callback>, Replicas> d_;
    const std::vector<LevelPlan>* planned_;
};

template <class Backend, class Callback, class Replicas>
DesignResult design_with(const Scene& scene, Heightmap initial, const ImageD& target_image,
                         const DesignOptions& options, Callback&& callback, const Penalties& penalties,
                         Replicas& replicas, const std::vector<LevelPlan>* planned, const DeviceOffer* device) {
    Designer<Backend, Callback, Replicas> designer(scene, target_image, options, callback, penalties, replicas,
                                                   planned, device);
    return designer.run(std::move(initial));
}

}  // namespace design_detail

// Designs the surface of `scene` so that its irradiance matches `target_image`
// (relative irradiance, any resolution). `callback(const DesignProgress&)` is called
// every options.progress_every iterations and may return true to stop (the best state
// so far is kept). options.evaluation picks incremental (default) or full retraces.
// `penalties` replaces the height terms the options ask for (default_penalties(options.penalties))
// when a caller adds terms of its own.
//
// `replicas` makes this design one replica of several (replicas.hpp); SingleReplica, the
// default, is the plain design. `planned`, when given, is plan_levels(scene, options)
// (PlannedDesign::levels): the levels are then not
// planned again; options.levels, when set, still replaces them. `device`, when given,
// judges the stages' speculative windows (design/device.hpp; choose_device in
// pipeline.hpp picks it from optimise.device); only incremental evaluation uses it.
template <class Callback, ReplicaCoordinator Replicas>
DesignResult design(const Scene& scene, Heightmap initial, const ImageD& target_image, const DesignOptions& options,
                    Callback&& callback, const Penalties& penalties, Replicas& replicas,
                    const std::vector<LevelPlan>* planned = nullptr, const DeviceOffer* device = nullptr) {
    if (options.evaluation == EvaluationMode::full)
        return design_detail::design_with<FullRetraceBackend>(scene, std::move(initial), target_image, options,
                                                              std::forward<Callback>(callback), penalties, replicas,
                                                              planned, nullptr);
    return design_detail::design_with<HeightfieldBackend>(scene, std::move(initial), target_image, options,
                                                          std::forward<Callback>(callback), penalties, replicas,
                                                          planned, device);
}

template <class Callback>
DesignResult design(const Scene& scene, Heightmap initial, const ImageD& target_image, const DesignOptions& options,
                    Callback&& callback, const Penalties& penalties) {
    SingleReplica single;
    return design(scene, std::move(initial), target_image, options, std::forward<Callback>(callback), penalties,
                  single);
}

template <class Callback>
DesignResult design(const Scene& scene, Heightmap initial, const ImageD& target_image, const DesignOptions& options,
                    Callback&& callback) {
    return design(scene, std::move(initial), target_image, options, std::forward<Callback>(callback),
                  default_penalties(options.penalties, scene.surface.tool_radius));
}

}  // namespace freeform
