// The CPU half of the GPU tracing benchmark (see trace_bench.cu and run.sh), compiled by
// the host compiler with the flags of a CPU build and without FMA contraction.
#include <algorithm>
#include <chrono>
#include <utility>

#include <freeform/design/designer.hpp>
#include <freeform/design/start.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/target.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/heightfield_kernel.hpp>
#include <freeform/trace/incremental.hpp>
#include <freeform/trace/setup.hpp>
#include <freeform/trace/window.hpp>

#include "trace_bench.hpp"

namespace freeform::gpu_bench {

namespace {

// A move in the middle of the surface: 5 × 5 vertices raised by a few micrometres, and
// the rays that enter over its cells (the rays a move's retrace starts from).
void add_move(BenchCase& c) {
    const Heightmap& hm = c.surface;
    HeightOverlay& o = c.move;
    const int i0 = hm.nx() / 2 - 2, j0 = hm.ny() / 2 - 2;
    o.patch = Patch{i0, j0, i0 + 4, j0 + 4};
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i)
            o.heights.push_back(hm.clamp_height(hm(i, j) + 2e-6f * float((i + 2 * j) % 5 - 2)));
    o.finish(hm);
    // Surface frame: a ray's path meets the plane w = 0 over the patch's cells.
    const double u0 = hm.u_of(i0 - 1), u1 = hm.u_of(i0 + 5), v0 = hm.v_of(j0 - 1), v1 = hm.v_of(j0 + 5);
    for (std::int64_t k = 0; k < c.rays.size(); ++k) {
        const Vec3d org(c.rays.origin[std::size_t(k)]), d(c.rays.direction[std::size_t(k)]);
        if (d.z == 0) continue;
        const Vec3d p = org + d * (-org.z / d.z);
        if (p.x >= u0 && p.x <= u1 && p.y >= v0 && p.y <= v1) c.move_rays.push_back(std::int32_t(k));
    }
}

// A window of 64 moves like add_move's, on an 8 × 8 lattice over the middle half of the
// surface, raised or lowered by turns.
void add_window(BenchCase& c) {
    const Heightmap& hm = c.surface;
    for (int b = 0; b < 8; ++b)
        for (int a = 0; a < 8; ++a) {
            HeightOverlay o;
            const int i0 = hm.nx() / 4 + a * (hm.nx() / 2) / 8, j0 = hm.ny() / 4 + b * (hm.ny() / 2) / 8;
            o.patch = Patch{i0, j0, i0 + 4, j0 + 4}.clipped(hm.nx(), hm.ny());
            const float step = (a + b) % 2 == 0 ? 2e-6f : -2e-6f;
            for (int j = o.patch.j0; j <= o.patch.j1; ++j)
                for (int i = o.patch.i0; i <= o.patch.i1; ++i) o.heights.push_back(hm.clamp_height(hm(i, j) + step));
            o.finish(hm);
            c.window.push_back(std::move(o));
        }
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

BenchCase make_case(const std::string& scene_file, int resolution, int threads) {
    DesignJob job = io::load_job(scene_file);
    Scene& s = job.scene;
    if (resolution > 0) s.receiver.width = s.receiver.height = resolution;
    const ImageD target = io::load_target_image(s);
    const auto [nx, ny] = final_mesh(s, job.options);
    Heightmap flat(nx, ny, s.surface.size, s.surface.h_min, s.surface.h_max, s.surface.frame, s.surface.aperture);
    DesignStart start = make_design_start(s, std::move(flat), target, job.options, threads);
    BenchCase c;
    c.name = s.name + " " + std::to_string(s.receiver.width) + "x" + std::to_string(s.receiver.height);
    c.rays = generate_rays(s.light, start.surface, s.receiver, 7);
    c.params = make_path_params(s);
    c.surface = std::move(start.surface);
    c.scene = std::move(s);
    add_move(c);
    add_window(c);
    return c;
}

double median(std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.empty() ? 0.0 : v[v.size() / 2];
}

CpuTiming time_cpu(const BenchCase& c, int threads, int repeats) {
    using clock = std::chrono::steady_clock;
    const HeightfieldTracer tracer(c.surface, c.rays, c.params);
    CpuTiming t{Histogram(c.scene.receiver.width, c.scene.receiver.height), {}, 0, 0, {}};
    std::vector<double> full, move;
    for (int r = 0; r < repeats; ++r) {
        Histogram h(c.scene.receiver.width, c.scene.receiver.height);
        TraceTotals totals;
        const auto t0 = clock::now();
        if (threads == 1)
            tracer.trace_all(exec::seq, h, totals);
        else
            tracer.trace_all(exec::omp_t{threads}, h, totals);
        full.push_back(seconds_since(t0));
        t.histogram = std::move(h), t.totals = totals;
    }
    const OverlayView view = overlay_view(c.surface, c.move);
    std::vector<RayRecord> records(c.move_rays.size());
    for (int r = 0; r < std::max(repeats, 20); ++r) {
        const auto t0 = clock::now();
        for (std::size_t k = 0; k < c.move_rays.size(); ++k) {
            const auto id = std::size_t(c.move_rays[k]);
            records[k] =
                trace_heightfield_ray(view, c.params, c.rays.origin[id], c.rays.direction[id], NoCellVisitor{});
        }
        move.push_back(seconds_since(t0));
    }
    t.move_records = std::move(records);
    t.full_seconds = median(full);
    t.move_seconds = median(move);
    return t;
}

WindowTiming time_window_cpu(const BenchCase& c, int repeats) {
    using clock = std::chrono::steady_clock;
    IncrementalTrace trace(c.surface, c.rays, c.params);
    trace.rebuild(exec::omp_t{2});
    WindowTiming t;
    std::vector<double> per_move, window, select, retrace, sum;
    std::vector<TraceChange> single(c.window.size());
    WindowEvaluation w;
    for (int r = 0; r < std::max(repeats, 10); ++r) {
        auto t0 = clock::now();
        for (std::size_t p = 0; p < c.window.size(); ++p) trace.evaluate(c.window[p], single[p]);
        per_move.push_back(seconds_since(t0));
        t0 = clock::now();
        w.evaluate(exec::omp_t{2}, trace, c.window);
        window.push_back(seconds_since(t0));
        t0 = clock::now();
        w.select(trace, c.window);
        select.push_back(seconds_since(t0));
        t0 = clock::now();
        w.retrace(exec::omp_t{2}, trace, c.window);
        retrace.push_back(seconds_since(t0));
        t0 = clock::now();
        w.sum(exec::omp_t{2}, trace);
        sum.push_back(seconds_since(t0));
    }
    t.same_changes = true;
    for (std::size_t p = 0; p < c.window.size(); ++p) {
        const WindowChange& a = w.change(p);
        const TraceChange& b = single[p];
        const auto rays = w.rays_of(p);
        bool same = std::equal(rays.begin(), rays.end(), b.rays.begin(), b.rays.end()) &&
                    a.status_delta == b.status_delta && a.rays_moved == b.rays_moved;
        std::int64_t nonzero = 0;
        for (const Fixed v : b.histogram.value) nonzero += v != 0;
        same = same && nonzero == std::int64_t(a.cells.size());
        for (std::size_t k = 0; k < a.cells.size(); ++k)
            same = same && b.histogram.value[std::size_t(a.cells[k])] == a.values[k];
        t.same_changes = t.same_changes && same;
    }
    // The kernel forms, a device's steps, here on 2 threads.
    WindowEvaluation k;
    std::vector<double> flat_select, atomic_sum, flat;
    for (int r = 0; r < std::max(repeats, 10); ++r) {
        auto t0 = clock::now();
        flatten(trace, t.index);
        flat.push_back(seconds_since(t0));
        t0 = clock::now();
        k.select_flat(exec::omp_t{2}, trace, t.index.view(), c.window);
        flat_select.push_back(seconds_since(t0));
        k.retrace(exec::omp_t{2}, trace, c.window);
        t0 = clock::now();
        k.sum_atomic(exec::omp_t{2}, trace);
        atomic_sum.push_back(seconds_since(t0));
    }
    t.flat_select_seconds = median(flat_select);
    t.atomic_sum_seconds = median(atomic_sum);
    t.flatten_seconds = median(flat);
    t.same_kernel_forms = std::ranges::equal(k.rays(), w.rays()) && std::ranges::equal(k.proposals(), w.proposals());
    for (std::size_t p = 0; p < c.window.size(); ++p) {
        t.changes.push_back(k.change(p));
        std::vector<std::pair<std::int32_t, Fixed>> a, b;
        for (std::size_t j = 0; j < w.change(p).cells.size(); ++j) a.emplace_back(w.change(p).cells[j], w.change(p).values[j]);
        for (std::size_t j = 0; j < k.change(p).cells.size(); ++j) b.emplace_back(k.change(p).cells[j], k.change(p).values[j]);
        std::sort(a.begin(), a.end());
        t.same_kernel_forms = t.same_kernel_forms && a == b && w.change(p).status_delta == k.change(p).status_delta &&
                              w.change(p).rays_moved == k.change(p).rays_moved;
    }
    t.maintained = trace.records();
    t.slotted.assign(t.index);
    k.select_flat(exec::seq, trace, t.slotted.view().selection(), c.window);
    t.slotted_proposals.assign(k.proposals().begin(), k.proposals().end());
    t.slotted_rays.assign(k.rays().begin(), k.rays().end());
    const TraceChange& first = single[0];
    t.commit_rays = first.rays, t.commit_records = first.records;
    t.commit_begin = first.cell_begin, t.commit_cells = first.cells;
    window_slots(trace, c.window, t.patches, t.slot_proposal);
    t.pad = hf_detail::grid_of(c.surface.view()).z_pad;
    t.per_move_seconds = median(per_move);
    t.window_seconds = median(window);
    t.select_seconds = median(select);
    t.retrace_seconds = median(retrace);
    t.sum_seconds = median(sum);
    t.proposals.assign(w.proposals().begin(), w.proposals().end());
    t.rays.assign(w.rays().begin(), w.rays().end());
    t.records.assign(w.records().begin(), w.records().end());
    return t;
}

}  // namespace freeform::gpu_bench
