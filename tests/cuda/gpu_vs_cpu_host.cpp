// The CPU half of the GPU-against-CPU test (see gpu_vs_cpu.cu), compiled by the host
// compiler with the flags of a CPU build, and without FMA contraction.
#include "gpu_vs_cpu.hpp"

#include <cmath>
#include <tuple>
#include <utility>

#include <freeform/anneal/annealer.hpp>
#include <freeform/design/problem.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/heightfield_kernel.hpp>
#include <freeform/trace/setup.hpp>
#include <freeform/trace/window.hpp>

#include "../support.hpp"

namespace freeform::gpu_test {

using testing::basic_scene;

namespace {

Case make_case(std::string name, Scene s, int n, double (*h)(double, double)) {
    Heightmap hm = testing::surface_for(s, n);
    if (h) testing::shape(hm, [h](double u, double v) { return h(u, v); });
    RaySet rays = generate_rays(s.light, hm, s.receiver, 7);
    return Case{std::move(name), std::move(s), std::move(hm), std::move(rays)};
}

}  // namespace

std::vector<Case> make_cases() {
    std::vector<Case> cases;
    {
        Scene s = basic_scene(64, 16);  // nearest-cell deposit
        cases.push_back(make_case("flat mirror, collimated", s, 33, nullptr));
    }
    {
        Scene s = basic_scene(128, 16);
        s.receiver.deposit = Deposit::bilinear;
        s.surface.aperture = Aperture::ellipse;  // exercises the device copy of the mask
        cases.push_back(make_case("paraboloid, elliptical aperture", s, 65,
                                  [](double u, double v) { return (u * u + v * v) / 2.0; }));
    }
    {
        Scene s = basic_scene(96, 16);
        s.receiver.deposit = Deposit::bilinear;
        s.receiver.size = {0.4, 0.4};
        s.light.shape = PointLight{{0.01, -0.02, 0.3}, {}, {}};
        cases.push_back(make_case("point light, wavy mirror", s, 41, [](double u, double v) {
            return 0.003 * std::sin(60 * u) * std::cos(45 * v);
        }));
    }
    {
        Scene s = basic_scene(96, 16);
        s.surface.material = Lens{1.49, 0.01};
        s.receiver.frame = make_frame({0, 0, -0.5}, {0, 0, 1}, {0, 1, 0}, "receiver");
        s.receiver.size = {1.2, 1.2};
        // Light at 45 degrees on steep ripples: many rays are lost to total internal
        // reflection, some to the side walls.
        s.light.shape = CollimatedLight{{1.0, 0.1, -1}};
        cases.push_back(make_case("lens, tilted collimated (TIR)", s, 81, [](double u, double v) {
            return 0.002 - (u * u + v * v) * 0.4 + 0.0025 * std::sin(400 * u);
        }));
    }
    {
        Scene s = basic_scene(80, 16);
        s.surface.h_min = -0.02;
        s.surface.h_max = 0.02;
        s.receiver.size = {1.5, 1.5};
        s.receiver.deposit = Deposit::bilinear;
        s.light.shape = DiskLight{{0, 0, 0.3}, {0, 0, -1}, 0.01};
        s.trace.max_depth = 1;  // rays meeting the surface twice are lost to depth
        cases.push_back(make_case("steep bumps (interreflections), disk light", s, 61, [](double u, double v) {
            return 0.015 * std::sin(80 * u) * std::sin(70 * v);
        }));
    }
    return cases;
}

Reference cpu_trace_all(const Case& c) {
    const testing::Traced t = testing::trace_scene(c.scene, c.surface, c.rays, exec::seq);
    return {t.histogram, t.totals};
}

std::vector<RayRecord> cpu_trace(const Case& c, std::span<const std::int32_t> ids) {
    std::vector<RayRecord> records(ids.size());
    HeightfieldTracer(c.surface, c.rays, make_path_params(c.scene)).trace(exec::seq, ids, records);
    return records;
}

namespace {
WindowResult evaluate_window(const IncrementalTrace& trace, SlottedRayCellIndex& index,
                             std::span<const HeightOverlay> moves) {
    WindowResult r;
    WindowEvaluation w;
    w.select_flat(exec::seq, trace, index.view().selection(), moves);
    w.retrace(exec::seq, trace, moves);
    w.sum_atomic(exec::seq, trace);
    window_slots(trace, moves, r.patches, r.slot_proposal);
    r.proposals.assign(w.proposals().begin(), w.proposals().end());
    r.rays.assign(w.rays().begin(), w.rays().end());
    for (std::size_t p = 0; p < w.size(); ++p) r.changes.push_back(w.change(p));
    return r;
}
}  // namespace

WindowReference cpu_window(const Case& c, std::span<const HeightOverlay> moves) {
    Heightmap surface = c.surface;  // a copy: the first move is committed to it
    IncrementalTrace trace(surface, c.rays, make_path_params(c.scene));
    trace.rebuild(exec::seq);
    WindowReference r;
    FlatRayCellIndex flat;
    flatten(trace, flat);
    r.index.assign(flat);
    r.maintained = trace.records();
    r.pad = hf_detail::grid_of(surface.view()).z_pad;
    r.before = evaluate_window(trace, r.index, moves);
    TraceChange single;
    trace.evaluate(moves[0], single);
    r.commit_rays = single.rays, r.commit_records = single.records;
    r.commit_begin = single.cell_begin, r.commit_cells = single.cells;
    moves[0].commit(surface);
    trace.commit(single);
    SlottedRayCellIndex after = r.index;
    std::vector<RayRecord> records = r.maintained;
    after.commit(exec::seq, {single.rays.data(), single.records.data(), single.cell_begin.data(), single.cells.data()},
                 std::int64_t(single.rays.size()), records.data());
    r.after = evaluate_window(trace, after, moves.subspan(1));
    return r;
}

std::vector<std::string> design_checks(const Case& c) {
    const int w = c.scene.receiver.width, h = c.scene.receiver.height;
    ImageD image(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) image(y, x) = 1.0 + 0.8 * std::sin(0.7 * x) * std::cos(0.4 * y);
    const auto run = [&](bool device) {
        Heightmap surface = c.surface;
        const PathParams pp = make_path_params(c.scene);
        Penalties penalties;
        penalties.add(HeightBoundTerm{}, 0.01);
        penalties.add(SmoothnessTerm{}, 0.001);
        ProposalSettings proposals;
        proposals.bank = default_kernel_bank(5);
        proposals.max_shift_cells = 3;
        SurfaceProblem problem(surface, c.rays, pp, make_target(image, w, h, c.rays.total), {}, penalties, proposals,
                               make_bandit(BanditKind::history, 7), 1e-4, 1.0);
        if (device)
            problem.set_window_evaluator(
                std::make_unique<CopiedStateWindowEvaluator>(make_device_backend(surface, c.rays, pp)));
        AnnealOptions o;
        o.seed = 11;
        o.max_iterations = 400;
        o.speculative = device ? 8 : 1;
        o.threads = 1;
        o.adaptive_speculation = false;
        const AnnealResult r = anneal(problem, o);
        return std::make_tuple(r.accepted, r.final_energy, surface.heights());
    };
    const auto cpu = run(false), gpu = run(true);
    std::vector<std::string> failures;
    if (std::get<0>(cpu) == 0) failures.push_back(c.name + ": the design accepted no move");
    if (std::get<0>(gpu) != std::get<0>(cpu)) failures.push_back(c.name + ": GPU design accepted other moves");
    if (std::get<1>(gpu) != std::get<1>(cpu)) failures.push_back(c.name + ": GPU design's energy differs");
    if (std::get<2>(gpu) != std::get<2>(cpu)) failures.push_back(c.name + ": GPU design's heights differ");
    return failures;
}

std::vector<RayRecord> cpu_trace(const Case& c, std::span<const std::int32_t> ids, const HeightOverlay& o) {
    const OverlayView view = overlay_view(c.surface, o);
    const PathParams pp = make_path_params(c.scene);
    std::vector<RayRecord> records(ids.size());
    for (std::size_t k = 0; k < ids.size(); ++k) {
        const auto id = std::size_t(ids[k]);
        records[k] = trace_heightfield_ray(view, pp, c.rays.origin[id], c.rays.direction[id], NoCellVisitor{});
    }
    return records;
}

HeightOverlay bump_overlay(const Heightmap& hm) {
    HeightOverlay o;
    o.patch = Patch{hm.nx() / 3, hm.ny() / 4, hm.nx() / 2, hm.ny() / 2};
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i)
            o.heights.push_back(hm.clamp_height(hm(i, j) + 0.002f * float((i + 2 * j) % 5 - 2)));
    o.finish(hm);
    return o;
}

}  // namespace freeform::gpu_test
