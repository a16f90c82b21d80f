// The transport start's cost: the grid OT solve (back-and-forth method) and the surface
// fit, on the docs/architecture.md §2 scene (0.1 m mirror, 200² receiver 0.5 m away, collimated
// light), for two targets made in code so that the benchmark needs no files:
//   letter  a block letter E (three bars and a spine; large empty regions, sharp edges)
//   smooth  a smooth positive image (a sum of broad Gaussians on a grey floor)
// Counters: ot_iterations, ot_residual (the solver's own, on its grid), and for the
// whole start the exact tracer's error of the fitted surface (start_error).
//
// Names: transport/solve/<target>/<receiver px>, transport/fit/<target>/<mesh>,
//        transport/start/<target>/<mesh> (solve + fit + exact evaluation), and
//        transport/start-morphing/<target>/<mesh>: the same with Poisson mesh morphing
//        (transport/morph.hpp) in place of the OT solver, the alternative it is measured against.
// Run: build/release/bin/bench_transport
#include <cmath>
#include <string>

#include <benchmark/benchmark.h>
#include <freeform/design/start.hpp>
#include <freeform/transport/start.hpp>

namespace {

using namespace freeform;

Scene bench_scene(int px) {
    Scene s;
    s.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    s.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.2, 0.2};
    s.receiver.width = s.receiver.height = px;
    s.light.rays_per_cell = 16;
    s.target = TargetSpec{};
    return s;
}

ImageD letter_target(int px) {
    ImageD t = ImageD::Zero(px, px);
    for (int y = 0; y < px; ++y)
        for (int x = 0; x < px; ++x) {
            const double u = (x + 0.5) / px, v = (y + 0.5) / px;
            const bool spine = u > 0.2 && u < 0.42 && v > 0.1 && v < 0.9;
            const bool bar = u > 0.2 && u < 0.8 && ((v > 0.1 && v < 0.27) || (v > 0.42 && v < 0.58) || (v > 0.73 && v < 0.9));
            if (spine || bar) t(y, x) = 1;
        }
    return t;
}

ImageD smooth_target(int px) {
    ImageD t(px, px);
    for (int y = 0; y < px; ++y)
        for (int x = 0; x < px; ++x) {
            const double u = (x + 0.5) / px, v = (y + 0.5) / px;
            t(y, x) = 0.2 + std::exp(-((u - 0.3) * (u - 0.3) + (v - 0.4) * (v - 0.4)) / 0.02) +
                      0.6 * std::exp(-((u - 0.7) * (u - 0.7) + (v - 0.65) * (v - 0.65)) / 0.04);
        }
    return t;
}

ImageD target_of(int which, int px) { return which == 0 ? letter_target(px) : smooth_target(px); }
const char* target_name(int which) { return which == 0 ? "letter" : "smooth"; }

void solve(benchmark::State& state, int which, int px) {
    const Scene s = bench_scene(px);
    const ImageD t = target_of(which, px);
    const Heightmap flat(101, 101, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
    TransportMap m;
    for (auto _ : state) {
        m = solve_transport(s, flat, t, 1);
        benchmark::DoNotOptimize(m.ot.psi.data());
    }
    state.counters["ot_iterations"] = m.report.ot_iterations;
    state.counters["ot_residual"] = m.report.ot_residual;
    state.counters["grid_cells"] = m.report.grid_x * m.report.grid_y;
}

void fit(benchmark::State& state, int which, int mesh) {
    const Scene s = bench_scene(200);
    const ImageD t = target_of(which, 200);
    const Heightmap flat(mesh, mesh, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
    const TransportMap m = solve_transport(s, flat, t, 1);
    TransportReport r = m.report;
    for (auto _ : state) {
        Heightmap h = surface_from_transport(s, m, mesh, mesh, r);
        benchmark::DoNotOptimize(h.heights().data());
    }
    state.counters["fit_iterations"] = r.fit_iterations;
}

// The alternative: Poisson mesh morphing, then the same fit and the same exact judge.
void morph_start(benchmark::State& state, int which, int mesh) {
    const Scene s = bench_scene(200);
    const ImageD t = target_of(which, 200);
    const Heightmap flat(mesh, mesh, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
    TransportOptions o;
    o.method = TransportMethod::morphing;
    double error = 0, residual = 0;
    for (auto _ : state) {
        const TransportMap m = solve_transport(s, flat, t, 1, o);
        TransportReport r = m.report;
        const Heightmap h = surface_from_transport(s, m, mesh, mesh, r, o);
        error = evaluate_surface(s, h, t, 1, 0).error;
        residual = r.ot_residual;
    }
    state.counters["start_error"] = error;
    state.counters["ot_residual"] = residual;
}

void start(benchmark::State& state, int which, int mesh) {
    const Scene s = bench_scene(200);
    const ImageD t = target_of(which, 200);
    const Heightmap flat(mesh, mesh, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
    StartReport r;
    for (auto _ : state) {
        DesignStart d = make_design_start(s, flat, t, 1, 0);
        r = d.report;
        benchmark::DoNotOptimize(d.surface.heights().data());
    }
    state.counters["start_error"] = r.error;
    state.counters["flat_error"] = r.flat_error;
}

const int registered = [] {
    for (int which : {0, 1}) {
        for (int px : {100, 200})
            benchmark::RegisterBenchmark(("transport/solve/" + std::string(target_name(which)) + "/" + std::to_string(px)).c_str(),
                                         [=](benchmark::State& st) { solve(st, which, px); })
                ->Unit(benchmark::kMillisecond)
                ->UseRealTime();
        for (int mesh : {101, 401})
            benchmark::RegisterBenchmark(("transport/fit/" + std::string(target_name(which)) + "/" + std::to_string(mesh)).c_str(),
                                         [=](benchmark::State& st) { fit(st, which, mesh); })
                ->Unit(benchmark::kMillisecond)
                ->UseRealTime();
        benchmark::RegisterBenchmark(("transport/start/" + std::string(target_name(which)) + "/101").c_str(),
                                     [=](benchmark::State& st) { start(st, which, 101); })
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
        benchmark::RegisterBenchmark(("transport/start-morphing/" + std::string(target_name(which)) + "/101").c_str(),
                                     [=](benchmark::State& st) { morph_start(st, which, 101); })
            ->Unit(benchmark::kMillisecond)
            ->UseRealTime();
    }
    return 0;
}();

}  // namespace

BENCHMARK_MAIN();
