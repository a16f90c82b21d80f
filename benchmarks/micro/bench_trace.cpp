// Tracer throughput: rays per second of the whole path (hit, Phong correction, reflection,
// deposit into the receiver histogram) for HeightfieldTracer and EmbreeTracer, the cost
// of retracing rays against a proposed move (the incremental evaluation's kernel), and
// the cost of an Embree refit after a height change.
//
// Scene: docs/architecture.md §2 — a 0.1 m mirror at the origin facing +z, a 0.2 m receiver of
// 200 x 200 pixels at z = 0.5 facing it, 16 rays per receiver cell (640,000 rays), height
// bounds ±5 mm. The mirror is mildly curved: a fixed field of smooth random bumps within
// ±2 mm, so that reflected rays spread and some cross several cells.
//
// Names read tracer-or-operation/parameters/.../threads:N, for example
//   walk/side-lamp/401/tiles                   the walk's block skip against walk/side-lamp/401/cells
//   trace/heightfield/collimated/phong/101/threads:2   whole path, items = rays
//   retrace/heightfield/overlay/point/101              rays a 7 x 7 move retraces, items = rays
//   refit/embree/patch7x7/401                          surface_changed() of a 7 x 7 vertex patch
//
// Run: build/release/bin/bench_trace --benchmark_filter=trace/heightfield
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include <benchmark/benchmark.h>
#include <freeform/core/rng.hpp>
#include <freeform/scene/rays.hpp>
#include <freeform/scene/scene.hpp>
#include <freeform/surface/overlay.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>

#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/embree.hpp>
#endif

#if defined(_OPENMP)
#include <omp.h>
#endif

namespace {

using namespace freeform;

enum class LightKind { collimated, point };

const char* light_name(LightKind k) { return k == LightKind::collimated ? "collimated" : "point"; }

Scene bench_scene(LightKind light, double alpha) {
    Scene s;
    s.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    s.surface.phong_alpha = alpha;
    s.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    s.receiver.size = {0.2, 0.2};
    s.receiver.width = s.receiver.height = 200;
    s.light.rays_per_cell = 16;
    // A point source 0.6 m above the mirror: its reflection fills most of the receiver.
    if (light == LightKind::point) s.light.shape = PointLight{{0, 0, 0.6}, {}, {}};
    return s;
}

// Smooth random bumps (the same analytic field at every mesh size), clamped to ±2 mm.
void bumpy(Heightmap& hm) {
    CounterRng rng(20240601);
    std::vector<std::array<double, 4>> bumps;
    for (int k = 0; k < 16; ++k)
        bumps.push_back({rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-0.0012, 0.0012),
                         rng.uniform(0.008, 0.02)});
    std::vector<float> h(std::size_t(hm.nx()) * hm.ny());
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i) {
            const double u = hm.u_of(i), v = hm.v_of(j);
            double z = 0;
            for (const auto& b : bumps)
                z += b[2] * std::exp(-((u - b[0]) * (u - b[0]) + (v - b[1]) * (v - b[1])) / (2 * b[3] * b[3]));
            h[std::size_t(j) * hm.nx() + i] = float(std::clamp(z, -0.002, 0.002));
        }
    hm.set_heights(h);
}

// Surface and rays of one configuration, built once and shared by the benchmarks that use
// them (building 640,000 rays takes longer than tracing them).
struct Case {
    Scene scene;
    Heightmap surface;
    RaySet rays;
    PathParams params;
};

const Case& get_case(LightKind light, double alpha, int mesh) {
    static std::map<std::tuple<int, double, int>, std::unique_ptr<Case>> cache;
    auto& slot = cache[{int(light), alpha, mesh}];
    if (!slot) {
        auto c = std::make_unique<Case>();
        c->scene = bench_scene(light, alpha);
        const Scene& s = c->scene;
        c->surface = Heightmap(mesh, mesh, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
        bumpy(c->surface);
        c->rays = generate_rays(s.light, c->surface, s.receiver, 1);
        c->params = make_path_params(s);
        slot = std::move(c);
    }
    return *slot;
}

int all_threads() {
#if defined(_OPENMP)
    return omp_get_max_threads();
#else
    return std::max(1, int(std::thread::hardware_concurrency()));
#endif
}

// Not inlined, so that callgrind can count instructions inside it alone
// (--toggle-collect='*trace_all_loop*'; see docs/performance.md).
#if defined(_MSC_VER)
#define FREEFORM_BENCH_NOINLINE __declspec(noinline)
#else
#define FREEFORM_BENCH_NOINLINE __attribute__((noinline))
#endif
template <class T>
FREEFORM_BENCH_NOINLINE void trace_all_loop(benchmark::State& state, const T& tracer, const Case& c, int threads) {
    Histogram hist(c.scene.receiver.width, c.scene.receiver.height);
    TraceTotals totals;
    for (auto _ : state) {
        if (threads == 1)
            tracer.trace_all(exec::seq, hist, totals);
        else
            tracer.trace_all(exec::omp_t{threads}, hist, totals);
        benchmark::DoNotOptimize(hist.cells.data());
        benchmark::ClobberMemory();
    }
    state.SetItemsProcessed(state.iterations() * c.rays.size());
    state.counters["energy"] = totals.energy();
}

void trace_heightfield(benchmark::State& state, LightKind light, double alpha, int mesh, int threads) {
    const Case& c = get_case(light, alpha, mesh);
    const HeightfieldTracer tracer(c.surface, c.rays, c.params);
    trace_all_loop(state, tracer, c, threads);
}

#if defined(FREEFORM_WITH_EMBREE)
void trace_embree(benchmark::State& state, LightKind light, double alpha, int mesh, int threads) {
    const Case& c = get_case(light, alpha, mesh);
    const EmbreeTracer tracer(c.surface, c.rays, c.params);
    trace_all_loop(state, tracer, c, threads);
}

// surface_changed() after a change of a `patch` x `patch` vertex patch (0: the whole
// surface), at a different place every iteration. Embree's refit cost does not depend on
// the new heights, so the heights stay as they are.
void refit_embree(benchmark::State& state, int mesh, int patch) {
    const Case& c = get_case(LightKind::collimated, 0.75, mesh);
    EmbreeTracer tracer(c.surface, c.rays, c.params);
    CounterRng rng(7);
    for (auto _ : state) {
        Patch p = c.surface.full_patch();
        if (patch > 0) {
            const int i0 = int(rng.below(std::uint64_t(mesh - patch + 1)));
            const int j0 = int(rng.below(std::uint64_t(mesh - patch + 1)));
            p = Patch{i0, j0, i0 + patch - 1, j0 + patch - 1};
        }
        tracer.surface_changed(p);
    }
    state.counters["tiles"] = double(tracer.tiles_touched_last_update());
}
#endif

// The kernel of the incremental evaluation: the rays whose paths cross a 7 x 7 vertex
// move (found by a full trace with a cell visitor, outside the timing) retraced whole
// against an OverlayView of the move, recording the cells they cross.
void retrace_overlay(benchmark::State& state, LightKind light, int mesh) {
    const Case& c = get_case(light, 0.75, mesh);
    const Heightmap& hm = c.surface;
    const HeightfieldView base = hm.view();
    // Moves at a few fixed places; each with the rays its cells (dilated by the normal
    // stencil) hold.
    struct Move {
        HeightOverlay overlay;
        std::vector<std::int32_t> rays;
    };
    std::vector<Move> moves;
    CounterRng rng(11);
    const int r = 3;
    for (int m = 0; m < 8; ++m) {
        const int ci = r + int(rng.below(std::uint64_t(mesh - 2 * r))),
                  cj = r + int(rng.below(std::uint64_t(mesh - 2 * r)));
        Move mv;
        HeightOverlay& o = mv.overlay;
        o.patch = Patch{ci - r, cj - r, ci + r, cj + r};
        for (int j = o.patch.j0; j <= o.patch.j1; ++j)
            for (int i = o.patch.i0; i <= o.patch.i1; ++i) {
                const double d2 = double((i - ci) * (i - ci) + (j - cj) * (j - cj));
                o.heights.push_back(hm.clamp_height(float(hm(i, j) + 2e-4 * std::exp(-d2 / 4.5))));
            }
        o.finish(hm);
        const Patch cells =
            Patch{o.normal_patch.i0 - 1, o.normal_patch.j0 - 1, o.normal_patch.i1, o.normal_patch.j1}.clipped(mesh - 1,
                                                                                                              mesh - 1);
        for (std::int64_t k = 0; k < c.rays.size(); ++k) {
            bool crosses = false;
            trace_heightfield_ray(
                base, c.params, c.rays.origin[std::size_t(k)], c.rays.direction[std::size_t(k)],
                [&](int i, int j) { crosses |= i >= cells.i0 && i <= cells.i1 && j >= cells.j0 && j <= cells.j1; });
            if (crosses) mv.rays.push_back(std::int32_t(k));
        }
        moves.push_back(std::move(mv));
    }
    std::vector<std::int32_t> crossed;
    crossed.reserve(256);
    std::int64_t rays = 0;
    std::size_t m = 0;
    for (auto _ : state) {
        const Move& mv = moves[m];
        m = (m + 1) % moves.size();
        const OverlayView view = overlay_view(hm, mv.overlay);
        for (const std::int32_t id : mv.rays) {
            crossed.clear();
            const RayRecord rec =
                trace_heightfield_ray(view, c.params, c.rays.origin[std::size_t(id)], c.rays.direction[std::size_t(id)],
                                      [&](int i, int j) { crossed.push_back(j * (mesh - 1) + i); });
            benchmark::DoNotOptimize(rec);
        }
        rays += std::int64_t(mv.rays.size());
    }
    state.SetItemsProcessed(rays);
    state.counters["rays_per_move"] = double(rays) / double(state.iterations());
}

// The walk's block skip (heightfield_kernel.hpp, skip_tile): every ray of a deep, oblique
// case traced through the plain view (every cell tested) and through the tiled one
// (TileRanges attached, as HeightfieldTracer traces), one thread, the packet path where
// the build has it. The side lamp's geometry (benchmarks/results/reach_envelope/side-lamp.json):
// a point light at (0, -9, 6) cm beside a 0.1 m mirror that tilts 51 mm towards it,
// ±30 mm of bounds, the bumps on top; the same records either way (tests/test_packet.cpp).
struct DeepCase {
    Scene scene;
    Heightmap surface;
    RaySet rays;
    PathParams params;
};

const DeepCase& deep_case(int mesh) {
    static std::map<int, std::unique_ptr<DeepCase>> cache;
    auto& slot = cache[mesh];
    if (!slot) {
        auto c = std::make_unique<DeepCase>();
        Scene& s = c->scene;
        s = bench_scene(LightKind::point, 0.75);
        s.light.shape = PointLight{{0, -0.09, 0.06}, {}, {}};
        s.surface.h_min = -0.03, s.surface.h_max = 0.03;
        c->surface = Heightmap(mesh, mesh, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame);
        bumpy(c->surface);
        std::vector<float> h = c->surface.heights();
        for (int j = 0; j < mesh; ++j)  // rising away from the light: the face turns to it
            for (int i = 0; i < mesh; ++i) h[std::size_t(j) * mesh + i] += float(0.51 * c->surface.v_of(j));
        c->surface.set_heights(h);
        c->rays = generate_rays(s.light, c->surface, s.receiver, 1);
        c->params = make_path_params(s);
        slot = std::move(c);
    }
    return *slot;
}

void walk_deep(benchmark::State& state, int mesh, bool tiles) {
    const DeepCase& c = deep_case(mesh);
    const HeightfieldView plain = c.surface.view();
    for (auto _ : state) {
        const TileRanges ranges(plain);  // built each time, as each trace builds its own
        const HeightfieldView hf = tiles ? ranges.attach(plain) : plain;
        std::int64_t depth = 0;
        if (packet::use_packets(c.params)) {
            const hf_detail::Grid g = hf_detail::grid_of(hf);
            RayRecord rec[packet::width];
            packet::NoLaneVisitor none;
            for (std::int64_t k0 = 0; k0 < c.rays.size(); k0 += packet::width) {
                const int n = int(std::min<std::int64_t>(packet::width, c.rays.size() - k0));
                packet::trace_rays(hf, g, c.params, c.rays.origin.data() + k0, c.rays.direction.data() + k0, n, rec,
                                   none);
                for (int l = 0; l < n; ++l) depth += rec[l].depth;
            }
        } else {
            for (std::int64_t k = 0; k < c.rays.size(); ++k)
                depth += trace_heightfield_ray(hf, c.params, c.rays.origin[std::size_t(k)],
                                               c.rays.direction[std::size_t(k)], NoCellVisitor{})
                             .depth;
        }
        benchmark::DoNotOptimize(depth);
    }
    state.SetItemsProcessed(state.iterations() * c.rays.size());
}

void register_all() {
    const int threads = all_threads();
    std::vector<int> thread_counts{1};
    if (threads > 1) thread_counts.push_back(threads);
    const int meshes[] = {51, 101, 201, 401};
    for (const char* tracer : {"heightfield", "embree"}) {
#if !defined(FREEFORM_WITH_EMBREE)
        if (std::string(tracer) == "embree") continue;
#endif
        for (LightKind light : {LightKind::collimated, LightKind::point})
            for (double alpha : {0.75, 0.0})
                for (int mesh : meshes)
                    for (int t : thread_counts) {
                        const std::string name = std::string("trace/") + tracer + "/" + light_name(light) + "/" +
                                                 (alpha != 0 ? "phong" : "flat") + "/" + std::to_string(mesh) +
                                                 "/threads:" + std::to_string(t);
                        benchmark::internal::Benchmark* b = nullptr;
                        if (std::string(tracer) == "heightfield") {
                            b = benchmark::RegisterBenchmark(name.c_str(), trace_heightfield, light, alpha, mesh, t);
                        }
#if defined(FREEFORM_WITH_EMBREE)
                        else {
                            b = benchmark::RegisterBenchmark(name.c_str(), trace_embree, light, alpha, mesh, t);
                        }
#endif
                        // Wall time: with OpenMP the work runs on other threads too.
                        b->UseRealTime()->Unit(benchmark::kMillisecond);
                    }
    }
    for (LightKind light : {LightKind::collimated, LightKind::point})
        for (int mesh : meshes) {
            const std::string name =
                std::string("retrace/heightfield/overlay/") + light_name(light) + "/" + std::to_string(mesh);
            benchmark::RegisterBenchmark(name.c_str(), retrace_overlay, light, mesh)
                ->UseRealTime()
                ->Unit(benchmark::kMicrosecond);
        }
    for (int mesh : {201, 401})
        for (const bool tiles : {false, true}) {
            const std::string name = "walk/side-lamp/" + std::to_string(mesh) + (tiles ? "/tiles" : "/cells");
            benchmark::RegisterBenchmark(name.c_str(), walk_deep, mesh, tiles)
                ->UseRealTime()
                ->Unit(benchmark::kMillisecond);
        }
#if defined(FREEFORM_WITH_EMBREE)
    for (int mesh : meshes)
        for (int patch : {7, 0}) {
            const std::string name =
                std::string("refit/embree/") +
                (patch > 0 ? "patch" + std::to_string(patch) + "x" + std::to_string(patch) : "full") + "/" +
                std::to_string(mesh);
            benchmark::RegisterBenchmark(name.c_str(), refit_embree, mesh, patch)
                ->UseRealTime()
                ->Unit(benchmark::kMicrosecond);
        }
#endif
}

}  // namespace

int main(int argc, char** argv) {
    register_all();
    benchmark::Initialize(&argc, argv);
    if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    return 0;
}
