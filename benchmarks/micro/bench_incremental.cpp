// Iterations per second of the annealer's inner loop (propose, evaluate, accept/reject):
// full retrace (what the reference does) against incremental evaluation, serial and
// speculative, for both tracers, over mesh size, receiver resolution and kernel size.
//
//   build/release/bin/bench_incremental --benchmark_counters_tabular=true
//
// Counters: iterations_per_second (the figure to compare), acceptance (fraction of moves
// accepted; the speculative speed-up depends on it), rays_per_move (rays retraced per
// evaluated move). Ratios are meant to be read within one run: the machine is shared.
#include <benchmark/benchmark.h>

#include <chrono>
#include <cmath>
#include <memory>
#include <string>

#include <freeform/anneal/annealer.hpp>
#include <freeform/design/problem.hpp>
#include <freeform/io/font.hpp>
#include <freeform/objective/target.hpp>
#include <freeform/propose/kernel.hpp>
#include <freeform/scene/rays.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>
#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/design/embree_incremental.hpp>
#endif

using namespace freeform;

namespace {

// The docs/architecture.md §2 scene with the letter-E target, a mildly curved start (so that light
// is spread over the receiver as during a design) and 16 rays per receiver cell.
struct Bench {
    Scene scene;
    Heightmap surface;
    RaySet rays;
    PathParams params;
    Target target;
    Penalties penalties;

    // near_light: a point light 5 cm above the mirror's centre and height bounds of
    // +-15 mm (oblique light: rays run through the slab over many cells).
    Bench(int mesh, int resolution, bool near_light = false) {
        scene.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
        scene.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
        scene.receiver.width = scene.receiver.height = resolution;
        scene.light.rays_per_cell = 16;
        if (near_light) {
            scene.light.shape = PointLight{{0, 0, 0.05}, {}, {}};
            scene.surface.h_min = -0.015, scene.surface.h_max = 0.015;
        }
        surface = Heightmap(mesh, mesh, scene.surface.size, scene.surface.h_min, scene.surface.h_max,
                            scene.surface.frame);
        std::vector<float> h(std::size_t(mesh) * mesh);
        for (int j = 0; j < mesh; ++j)
            for (int i = 0; i < mesh; ++i) {
                const double u = surface.u_of(i), v = surface.v_of(j);
                h[std::size_t(j) * mesh + i] = float(-(u * u + v * v) * 0.1 + 0.0004 * std::sin(90 * u) * std::cos(70 * v));
            }
        surface.set_heights(h);
        rays = generate_rays(scene.light, surface, scene.receiver, 1);
        params = make_path_params(scene);
        const ImageD img = io::render_text("E", io::find_font("DejaVuSans-Bold"), 4 * resolution, 4 * resolution, 0.1)
                               .cast<double>();
        target = make_target(img, resolution, resolution, rays.total);
    }

    ProposalSettings proposals(int support) const {
        ProposalSettings p;
        p.bank = default_kernel_bank(support);
        return p;
    }
    double unit() const {
        return 0.2 / scene.receiver.width * surface.du() / (2 * 0.5);
    }
};

// Anneals at a fixed temperature (no cooling) for a fixed number of iterations.
template <class Problem>
void run_annealer(benchmark::State& state, Problem& problem, int speculative, int threads, std::int64_t iterations) {
    AnnealOptions o;
    o.seed = 3;
    o.cooling = 1.0;  // hold the temperature: a steady acceptance rate
    o.max_iterations = iterations;
    o.speculative = speculative;
    o.threads = threads;
    o.adaptive_speculation = false;
    // Temperature: the mean uphill delta of a few trial moves.
    typename Problem::Move m;
    double up = 0;
    int n = 0;
    for (std::uint64_t k = 0; k < 32; ++k) {
        CounterRng rng(99, k);
        problem.propose(rng, 1.0, m);
        const double d = problem.delta(m);
        if (d > 0) up += d, ++n;
    }
    // A tenth of the mean uphill delta. The start surface is far from the target, so most
    // small moves still improve it: about 0.8 of the moves are accepted (the `acceptance`
    // counter), more than late in a design.
    o.initial_temperature = n > 0 ? 0.1 * up / n : 1e-6;
    std::int64_t done = 0, accepted = 0, evaluated = 0;
    double seconds = 0;
    for (auto _ : state) {
        const AnnealResult r = anneal(problem, o);
        done += r.iterations;
        accepted += r.accepted;
        evaluated += r.proposals_evaluated;
        seconds += r.seconds;
    }
    state.counters["iterations_per_second"] = double(done) / seconds;
    state.counters["acceptance"] = double(accepted) / double(done);
    state.counters["evaluated_per_iteration"] = double(evaluated) / double(done);
}

// Rays retraced per move, the mean over a few proposals.
template <class Problem>
double rays_per_move(Problem& problem) {
    typename Problem::Move m;
    std::int64_t rays = 0;
    for (std::uint64_t k = 0; k < 32; ++k) {
        CounterRng rng(5, k);
        problem.propose(rng, 1.0, m);
        (void)problem.delta(m);
        rays += std::int64_t(m.change.ray_count());
    }
    return double(rays) / 32;
}

void incremental(benchmark::State& state) {
    const int mesh = int(state.range(0)), resolution = int(state.range(1)), support = int(state.range(2));
    const int speculative = int(state.range(3)), threads = int(state.range(4));
    Bench b(mesh, resolution);
    SurfaceProblem problem(b.surface, b.rays, b.params, b.target, {}, b.penalties, b.proposals(support),
                             make_bandit(BanditKind::uniform, 7), b.unit(), 1.0);
    const double rays = rays_per_move(problem);
    run_annealer(state, problem, speculative, threads, 2000);
    state.counters["rays_per_move"] = rays;
    state.counters["rays"] = double(b.rays.size());
}

// The batch logic of a design on a GPU (trace/window.hpp), on the CPU: every window of
// `speculative` moves handed to delta_window, its rays retraced by one kernel call on
// `threads` OpenMP threads, the accepted move retraced again to commit it. The same
// trajectory as `incremental` with the same arguments.
void window_evaluation(benchmark::State& state) {
    const int mesh = int(state.range(0)), resolution = int(state.range(1)), support = int(state.range(2));
    const int speculative = int(state.range(3)), threads = int(state.range(4));
    Bench b(mesh, resolution);
    SurfaceProblem problem(b.surface, b.rays, b.params, b.target, {}, b.penalties, b.proposals(support),
                           make_bandit(BanditKind::uniform, 7), b.unit(), 1.0);
    problem.set_window_evaluation(true);
    run_annealer(state, problem, speculative, threads, 2000);
}

// The reach envelope (docs/architecture.md §4) against the plain index, under a point
// light 5 cm above the mirror, with the margin `reach_moves` (0: no envelope; 16: the
// default): the same moves and the same trajectory (the limits never bind), so the rows
// differ only in speed. Counters: build_seconds (the problem's first full trace),
// crossings_per_ray (the index's), envelope_kept, recentres (full rebuilds round new
// heights), iterations_per_second.
void reach_envelope(benchmark::State& state) {
    const int mesh = int(state.range(0));
    Bench b(mesh, 100, true);
    ProposalSettings p = b.proposals(5);
    p.reach_moves = double(state.range(1));
    const auto t0 = std::chrono::steady_clock::now();
    SurfaceProblem problem(b.surface, b.rays, b.params, b.target, {}, b.penalties, p,
                           make_bandit(BanditKind::uniform, 7), b.unit(), 1.0);
    const double build = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    run_annealer(state, problem, 1, 1, 2000);
    state.counters["build_seconds"] = build;
    state.counters["crossings_per_ray"] = double(problem.trace().index().crossings()) / double(b.rays.size());
    state.counters["envelope_kept"] = problem.trace().reach().active() ? 1 : 0;
    state.counters["recentres"] = double(problem.reach_recentres());
}

// The reference's loop: every move retraces every ray (with the height-field tracer, or
// with Embree after a refit of the tiles the move touched).
template <class Tracer>
void full_retrace_with(benchmark::State& state) {
    const int mesh = int(state.range(0)), resolution = int(state.range(1)), support = int(state.range(2));
    Bench b(mesh, resolution);
    Tracer tracer(b.surface, b.rays, b.params);
    const auto changed = [&](const Patch& p) {
        if constexpr (requires { tracer.surface_changed(p); }) tracer.surface_changed(p);
    };
    ImageState image(b.target);
    Histogram h(resolution, resolution);
    TraceTotals totals;
    tracer.trace_all(exec::omp, h, totals);
    image.reset(h);
    const ObjectiveWeights w;
    double value = combine(image.sums(), b.rays.total, 0, w).total;
    const Kernel kernel(b.proposals(support).bank[0]);
    HeightOverlay overlay;
    std::int64_t iterations = 0, accepted = 0;
    for (auto _ : state) {
        CounterRng rng(7, std::uint64_t(iterations));
        const int ci = int(rng.below(std::uint64_t(mesh))), cj = int(rng.below(std::uint64_t(mesh)));
        apply_kernel(b.surface, kernel, ci, cj, float(rng.uniform(-4, 4) * b.unit() * 2), overlay);
        const HeightSnapshot before = b.surface.snapshot(overlay.patch);
        overlay.commit(b.surface);
        changed(overlay.patch);
        tracer.trace_all(exec::omp, h, totals);
        image.reset(h);
        const double now = combine(image.sums(), b.rays.total, 0, w).total;
        if (now <= value) {
            value = now;
            ++accepted;
        } else {
            b.surface.restore(before);
            changed(overlay.patch);
        }
        ++iterations;
    }
    state.counters["iterations_per_second"] = benchmark::Counter(double(iterations), benchmark::Counter::kIsRate);
    state.counters["acceptance"] = double(accepted) / double(iterations);
    state.counters["rays_per_move"] = double(b.rays.size());
}

void full_retrace(benchmark::State& state) { full_retrace_with<HeightfieldTracer>(state); }

#if defined(FREEFORM_WITH_EMBREE)
void embree_full_retrace(benchmark::State& state) { full_retrace_with<EmbreeTracer>(state); }

void embree_incremental(benchmark::State& state) {
    const int mesh = int(state.range(0)), resolution = int(state.range(1)), support = int(state.range(2));
    Bench b(mesh, resolution);
    EmbreeTracer tracer(b.surface, b.rays, b.params);
    EmbreeSurfaceProblem problem(b.surface, b.rays, b.params, b.target, {}, b.penalties, b.proposals(support),
                                   make_bandit(BanditKind::uniform, 7), b.unit(), 1.0, EmbreeBackend{&tracer, &b.surface});
    const double rays = rays_per_move(problem);
    run_annealer(state, problem, 1, 1, 300);
    state.counters["rays_per_move"] = rays;
}

// Cost of refitting the Embree tiles after a kernel move, against the mesh size.
void embree_refit(benchmark::State& state) {
    const int mesh = int(state.range(0));
    Bench b(mesh, 100);
    EmbreeTracer tracer(b.surface, b.rays, b.params);
    std::int64_t k = 0, tiles = 0;
    for (auto _ : state) {
        const int ci = int((k * 7919) % (mesh - 6)), cj = int((k * 104729) % (mesh - 6));
        tracer.surface_changed(Patch{ci, cj, ci + 6, cj + 6});
        tiles += tracer.tiles_touched_last_update();
        ++k;
    }
    state.counters["tiles_per_refit"] = double(tiles) / double(k);
}
#endif

// Rows: one thread; two threads judging one proposal at a time, its rays split between
// them (split); two threads judging windows of two proposals (speculative).
void sizes(benchmark::internal::Benchmark* b, bool parallel) {
    for (int resolution : {100, 200})
        for (int mesh : {51, 101, 201, 401}) {
            b->Args({mesh, resolution, 5, 1, 1});
            if (parallel) b->Args({mesh, resolution, 5, 1, 2});
            if (parallel) b->Args({mesh, resolution, 5, 2, 2});
        }
    // The cost of a move follows the kernel's footprint, not the mesh.
    for (int support : {3, 9, 17}) b->Args({101, 100, support, 1, 1});
}

// Windows of 8 and 32 moves on two threads, for window_evaluation and for incremental's
// speculative windows (the per-move evaluation) side by side.
void windows(benchmark::internal::Benchmark* b) {
    for (int mesh : {101, 201})
        for (int window : {8, 32}) b->Args({mesh, 200, 5, window, 2});
}

}  // namespace

BENCHMARK(window_evaluation)
    ->Apply(windows)
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(incremental)
    ->Apply(windows)
    ->Name("incremental_windows")
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(incremental)
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, true); })
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(reach_envelope)
    ->ArgsProduct({{101, 201, 401}, {0, 4, 16, 64}})
    ->ArgNames({"mesh", "reach_moves"})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(full_retrace)
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, false); })
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(10)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
#if defined(FREEFORM_WITH_EMBREE)
// Embree deltas run one at a time (the move is written into the heights and the tiles
// refitted for each), so there are no speculative rows.
BENCHMARK(embree_incremental)
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, false); })
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(embree_full_retrace)
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, false); })
    ->ArgNames({"mesh", "receiver", "kernel", "speculative", "threads"})
    ->Iterations(5)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(embree_refit)->Arg(51)->Arg(101)->Arg(201)->Arg(401)->ArgNames({"mesh"})->Unit(benchmark::kMicrosecond);
#endif
