// Incremental evaluation must agree with a full retrace bit for bit, whatever the moves.
#include <doctest/doctest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <string_view>
#include <tuple>
#include <vector>

#include <freeform/anneal/annealer.hpp>
#include <freeform/design/problem.hpp>
#include <freeform/trace/incremental.hpp>
#include <freeform/trace/index_kernel.hpp>
#include <freeform/trace/window.hpp>
#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/design/embree_incremental.hpp>
#endif

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

// A random smooth bump (or single-vertex spike) written into an overlay.
void random_bump(const Heightmap& hm, CounterRng& rng, HeightOverlay& o) {
    const int r = int(rng.below(4));  // radius 0..3 (0: one vertex)
    const int ci = int(rng.below(std::uint64_t(hm.nx()))), cj = int(rng.below(std::uint64_t(hm.ny())));
    const double amp = rng.uniform(-1, 1) * 0.4 * (hm.h_max() - hm.h_min());
    o.patch = Patch{ci - r, cj - r, ci + r, cj + r}.clipped(hm.nx(), hm.ny());
    o.heights.clear();
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i) {
            const double d2 = double((i - ci) * (i - ci) + (j - cj) * (j - cj));
            const double w = r == 0 ? 1.0 : std::exp(-d2 / (0.5 * r * r));
            o.heights.push_back(hm.clamp_height(float(hm(i, j) + amp * w)));
        }
    o.finish(hm);
}

bool same_crossing(const CellCrossing& a, const CellCrossing& b) {
    return a.cell == b.cell && a.zlo == b.zlo && a.zhi == b.zhi;
}

// Rays whose cells (with their height ranges) differ between two traces of the same rays.
std::int64_t rays_with_other_cells(const IncrementalTrace& x, const IncrementalTrace& y) {
    std::int64_t differ = 0;
    for (std::int32_t r = 0; r < std::int32_t(x.rays().size()); ++r) {
        const auto a = x.index().cells_of(r), b = y.index().cells_of(r);
        differ += a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), same_crossing) ? 0 : 1;
    }
    return differ;
}

// Whether a change evaluated in parts (`split`) is the serial one (`serial`, one part):
// its parts, taken in order, hold the same rays, records and cells (height ranges
// included), and the totals are the same.
bool same_change(const TraceChange& split, const TraceChange& serial) {
    if (serial.split != 1 || split.status_delta != serial.status_delta || split.rays_moved != serial.rays_moved ||
        split.rays_culled != serial.rays_culled || split.histogram.value != serial.histogram.value)
        return false;
    std::size_t k = 0;  // position in the serial change
    for (int p = 0; p < split.split; ++p) {
        const TracePart& part = split.part(p);
        if (part.cell_begin.size() != part.rays.size() + 1 || part.records.size() != part.rays.size()) return false;
        for (std::size_t r = 0; r < part.rays.size(); ++r, ++k) {
            if (k >= serial.rays.size() || part.rays[r] != serial.rays[k] || !(part.records[r] == serial.records[k]))
                return false;
            const auto n = part.cell_begin[r + 1] - part.cell_begin[r];
            if (n != serial.cell_begin[k + 1] - serial.cell_begin[k]) return false;
            for (std::int32_t c = 0; c < n; ++c)
                if (!same_crossing(part.cells[std::size_t(part.cell_begin[r] + c)],
                                   serial.cells[std::size_t(serial.cell_begin[k] + c)]))
                    return false;
        }
    }
    return k == serial.rays.size() && split.ray_count() == serial.rays.size();
}

struct Case {
    const char* name;
    Scene scene;
    int mesh;
};

std::vector<Case> cases() {
    std::vector<Case> out;
    {
        Scene s = basic_scene(40, 8);
        out.push_back({"collimated mirror, Phong", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.surface.phong_alpha = 0;
        s.receiver.deposit = Deposit::bilinear;
        out.push_back({"collimated mirror, flat hits, bilinear", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.light.shape = PointLight{{0.01, -0.02, 0.3}, {}, {}};
        s.receiver.deposit = Deposit::fine_bilinear;  // the default deposit
        out.push_back({"point light mirror, fine_bilinear", s, 25});
    }
    {
        Scene s = basic_scene(40, 8);
        s.surface.material = Lens{1.49, 0.01};
        s.receiver.frame = make_frame({0, 0, -0.4}, {0, 0, 1}, {0, 1, 0}, "receiver");
        out.push_back({"collimated lens", s, 25});
    }
    {
        // A sun of 3 degrees' radius over a lens with Fresnel losses: every ray has its
        // own direction, and its own transmitted part of its weight.
        Scene s = basic_scene(40, 8);
        s.light.shape = CollimatedLight{{0.05, 0, -1}, 3.0};
        s.surface.material = Lens{1.49, 0.01};
        s.receiver.frame = make_frame({0, 0, -0.4}, {0, 0, 1}, {0, 1, 0}, "receiver");
        s.trace.fresnel = true;
        out.push_back({"sunlit lens, Fresnel", s, 25});
    }
    {
        // Grazing light (75 degrees): rays cross many cells inside the slab and
        // interreflect on the bumps.
        Scene s = basic_scene(40, 8);
        const double a = degrees_to_radians(75.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.1, -std::cos(a)}};
        s.receiver.frame = make_frame({0.3, 0, 0.3}, {-1, 0, -1}, {0, 1, 0}, "receiver");
        s.receiver.size = {0.4, 0.4};
        s.receiver.deposit = Deposit::bilinear;
        out.push_back({"grazing light", s, 31});
    }
    return out;
}

// A case's rippled surface, its rays and its path parameters.
struct Rippled {
    Heightmap hm;
    RaySet rays;
    PathParams pp;
};
Rippled rippled(const Case& c) {
    Heightmap hm = surface_for(c.scene, c.mesh);
    shape(hm, [](double u, double v) { return 0.001 * std::sin(80 * u) * std::cos(70 * v); });
    RaySet rays = generate_rays(c.scene.light, hm, c.scene.receiver, 5);
    return {std::move(hm), std::move(rays), make_path_params(c.scene)};
}

}  // namespace

TEST_CASE("incremental histogram equals a full retrace after thousands of mixed moves") {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        auto [hm, rays, pp] = rippled(c);
        IncrementalTrace inc(hm, rays, pp);
        Histogram hist = inc.rebuild(exec::seq);
        // A twin that evaluates and commits every move with three threads: its state must
        // stay the serial one, per-cell ray lists included.
        IncrementalTrace twin(hm, rays, pp);
        twin.rebuild(exec::seq);
        HeightOverlay o;
        TraceChange change, split, twin_change;
        TaskPool pool(3);
        CounterRng rng(99, 0);
        int accepted = 0, split_moves = 0, split_differ = 0, split_commits = 0;
        std::int64_t moved = 0, culled = 0, listed = 0;
        for (int it = 0; it < 2500; ++it) {
            random_bump(hm, rng, o);
            const bool accept = rng.uniform() < 0.4;
            inc.evaluate(o, change);
            if (accept) twin.evaluate(o, twin_change, &pool);  // the twin sees only the moves it commits
            if (it % 4 == 0) {
                // The same move retraced by three threads, each a range of its rays: the
                // same change bit for bit.
                inc.evaluate(o, split, &pool);
                split_moves += split.split > 1;
                split_differ += same_change(split, change) ? 0 : 1;
            }
            culled += change.rays_culled;
            listed += change.rays_culled + std::int64_t(change.rays.size());
            if (accept) {
                o.commit(hm);
                inc.commit(change);
                twin.commit(twin_change, &pool);
                split_commits += twin_change.split > 1;
                // Apply the sparse delta (cells may be listed twice: add each once).
                std::vector<char> done(hist.cells.size(), 0);
                for (auto cell : change.histogram.touched)
                    if (!done[std::size_t(cell)]) {
                        done[std::size_t(cell)] = 1;
                        hist.cells[std::size_t(cell)] += change.histogram.value[std::size_t(cell)];
                    }
                ++accepted;
                moved += change.rays_moved;
            }
        }
        CHECK(split_differ == 0);
        if (packet::use_packets(pp)) CHECK(split_moves > 50);  // the split really ran
        if (packet::use_packets(pp)) CHECK(split_commits > 50);
        CHECK(change.split == 1);  // evaluated without a pool: one part
        CHECK(accepted > 800);
        CHECK(moved > 1000);  // the moves really moved light
        const Traced full = trace_scene(c.scene, hm, rays);
        CHECK(hist == full.histogram);
        CHECK(inc.histogram() == full.histogram);
        // A rebuilt index and records agree with the maintained ones.
        IncrementalTrace fresh(hm, rays, pp);
        fresh.rebuild(exec::seq);
        CHECK(fresh.records() == inc.records());
        CHECK(fresh.weight_by_status() == inc.weight_by_status());
        // Both may trace in packets (trace/packet.hpp): the scalar kernel, ray by ray, is
        // the definition.
        std::int64_t off_scalar = 0;
        for (std::size_t r = 0; r < inc.records().size(); ++r)
            off_scalar += inc.records()[r] == trace_heightfield_ray(hm.view(), pp, rays.origin[r], rays.direction[r],
                                                                    NoCellVisitor{})
                              ? 0
                              : 1;
        CHECK(off_scalar == 0);
        // The rays left out as out of reach kept their cells and height ranges: the
        // maintained index is the rebuilt one, range for range.
        CHECK(rays_with_other_cells(fresh, inc) == 0);
        // The twin, committed in parts, holds the same records, cells and per-cell lists
        // (in the same order) as the serial commits.
        CHECK(twin.records() == inc.records());
        CHECK(twin.weight_by_status() == inc.weight_by_status());
        CHECK(rays_with_other_cells(twin, inc) == 0);
        std::int64_t lists_differ = 0;
        for (std::int32_t cell = 0; cell < std::int32_t((hm.nx() - 1) * (hm.ny() - 1)); ++cell)
            lists_differ += twin.index().rays_of(cell) == inc.index().rays_of(cell) ? 0 : 1;
        CHECK(lists_differ == 0);
        // The bumps (up to 40 % of the slab) leave paths above and below them: some rays
        // listed on a move's cells are out of its reach, and most are not.
        MESSAGE(std::string(c.name), ": ", culled, " of ", listed, " listed rays out of reach");
        CHECK(culled > 0);
        CHECK(culled < listed);
    }
}

namespace {

// Whether a window's change of one move is the one evaluate() gives it: the same rays
// selected, the same change of every histogram cell and of the weight per status.
bool same_totals(const WindowEvaluation& w, std::size_t p, const TraceChange& single) {
    const WindowChange& c = w.change(p);
    std::vector<std::pair<std::int32_t, Fixed>> window, expected;
    for (std::size_t k = 0; k < c.cells.size(); ++k) window.emplace_back(c.cells[k], c.values[k]);
    for (std::int32_t cell = 0; cell < std::int32_t(single.histogram.value.size()); ++cell) {
        const Fixed v = single.histogram.value[std::size_t(cell)];
        if (v != 0) expected.emplace_back(cell, v);
    }
    std::sort(window.begin(), window.end());
    const auto rays = w.rays_of(p);
    return std::equal(rays.begin(), rays.end(), single.rays.begin(), single.rays.end()) && window == expected &&
           c.status_delta == single.status_delta && c.rays_moved == single.rays_moved;
}

}  // namespace

TEST_CASE("a window of moves evaluated together gives each move evaluate()'s change, on one thread or two") {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        auto [hm, rays, pp] = rippled(c);
        IncrementalTrace inc(hm, rays, pp);
        inc.rebuild(exec::seq);
        CounterRng rng(7, 0);
        std::vector<HeightOverlay> window(8);
        WindowEvaluation serial, threaded;
        TraceChange single;
        int differ = 0, moving = 0, committed = 0;
        std::int64_t pairs = 0;
        for (int w = 0; w < 40; ++w) {
            for (HeightOverlay& o : window) random_bump(hm, rng, o);
            serial.evaluate(exec::seq, inc, window);
            threaded.evaluate(exec::omp_t{2}, inc, window);
            REQUIRE(serial.size() == window.size());
            pairs += std::int64_t(serial.pairs());
            int first_moving = -1;
            for (std::size_t p = 0; p < window.size(); ++p) {
                inc.evaluate(window[p], single);
                differ += same_totals(serial, p, single) && same_totals(threaded, p, single) ? 0 : 1;
                if (single.rays_moved > 0) ++moving, first_moving = first_moving < 0 ? int(p) : first_moving;
            }
            // The window's first move that moves light is accepted, as a window's first
            // accepted proposal is: the next window is judged against the new state.
            if (first_moving >= 0) {
                inc.evaluate(window[std::size_t(first_moving)], single);
                window[std::size_t(first_moving)].commit(hm);
                inc.commit(single);
                ++committed;
            }
        }
        CHECK(differ == 0);
        CHECK(moving > 100);  // the moves really moved light
        CHECK(committed > 20);
        CHECK(pairs > 1000);
        // After the commits the maintained trace is still a full retrace's.
        CHECK(inc.histogram() == trace_scene(c.scene, hm, rays).histogram);
    }
}

namespace {

// Whether two windows hold the same pairs in the same order and give each proposal the
// same change (cells compared as sets: the host lists them as first touched, the kernels
// in increasing order).
bool same_window(const WindowEvaluation& a, const WindowEvaluation& b) {
    if (a.size() != b.size() || !std::ranges::equal(a.proposals(), b.proposals()) ||
        !std::ranges::equal(a.rays(), b.rays()))
        return false;
    const auto sorted = [](const WindowChange& c) {
        std::vector<std::pair<std::int32_t, Fixed>> v;
        for (std::size_t k = 0; k < c.cells.size(); ++k) v.emplace_back(c.cells[k], c.values[k]);
        std::sort(v.begin(), v.end());
        return v;
    };
    for (std::size_t p = 0; p < a.size(); ++p) {
        const WindowChange &x = a.change(p), &y = b.change(p);
        if (sorted(x) != sorted(y) || x.status_delta != y.status_delta || x.rays_moved != y.rays_moved) return false;
    }
    return true;
}

}  // namespace

TEST_CASE("a window's kernel forms, selection from a flat index and atomic sums, give the host forms' pairs and "
          "changes") {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        auto [hm, rays, pp] = rippled(c);
        IncrementalTrace inc(hm, rays, pp);
        inc.rebuild(exec::seq);
        CounterRng rng(11, 0);
        std::vector<HeightOverlay> window(8);
        WindowEvaluation host, serial, threaded;
        FlatRayCellIndex flat;
        TraceChange single;
        int differ = 0, committed = 0;
        std::int64_t pairs = 0;
        for (int w = 0; w < 40; ++w) {
            for (HeightOverlay& o : window) random_bump(hm, rng, o);
            window[3] = HeightOverlay{};  // a proposal that changes nothing, among the others
            flatten(inc, flat);
            host.evaluate(exec::seq, inc, window);
            serial.select_flat(exec::seq, inc, flat.view(), window);
            serial.retrace(exec::seq, inc, window);
            serial.sum_atomic(exec::seq, inc);
            threaded.select_flat(exec::omp_t{2}, inc, flat.view(), window);
            threaded.retrace(exec::omp_t{2}, inc, window);
            threaded.sum_atomic(exec::omp_t{2}, inc);
            differ += same_window(host, serial) && same_window(host, threaded) ? 0 : 1;
            pairs += std::int64_t(host.pairs());
            // The first proposal that moves light is accepted: the index changes.
            for (std::size_t p = 0; p < window.size(); ++p)
                if (host.change(p).rays_moved > 0) {
                    inc.evaluate(window[p], single);
                    window[p].commit(hm);
                    inc.commit(single);
                    ++committed;
                    break;
                }
        }
        CHECK(differ == 0);
        CHECK(committed > 20);
        CHECK(pairs > 1000);
    }
}

namespace {

// Whether a slotted index holds the incremental trace's index: each cell's rays (as a
// set: the slotted lists are sorted), each ray's crossings.
bool same_index(const SlottedRayCellIndex& s, const IncrementalTrace& inc) {
    const RayCellIndex& index = inc.index();
    for (std::int32_t c = 0; c < std::int32_t(index.cell_count()); ++c) {
        std::vector<std::int32_t> host = index.rays_of(c);
        std::sort(host.begin(), host.end());
        const auto first = s.cell_rays.begin() + s.cell_begin[std::size_t(c)];
        if (!std::equal(host.begin(), host.end(), first, first + s.cell_count[std::size_t(c)])) return false;
    }
    for (std::int32_t r = 0; r < std::int32_t(index.ray_count()); ++r) {
        const auto host = index.cells_of(r);
        const auto first = s.crossings.begin() + s.ray_begin[std::size_t(r)];
        if (std::int64_t(host.size()) != s.ray_count[std::size_t(r)] ||
            !std::equal(host.begin(), host.end(), first, [](const CellCrossing& a, const CellCrossing& b) {
                return a.cell == b.cell && a.zlo == b.zlo && a.zhi == b.zhi;
            }))
            return false;
    }
    return true;
}

// Whether two windows select the same rays for every proposal (in any order) and give it
// the same change.
bool same_sets(const WindowEvaluation& a, const WindowEvaluation& b) {
    if (a.size() != b.size()) return false;
    for (std::size_t p = 0; p < a.size(); ++p) {
        std::vector<std::int32_t> x(a.rays_of(p).begin(), a.rays_of(p).end()), y(b.rays_of(p).begin(), b.rays_of(p).end());
        std::sort(x.begin(), x.end()), std::sort(y.begin(), y.end());
        const WindowChange &u = a.change(p), &v = b.change(p);
        if (x != y || u.cells != v.cells || u.values != v.values || u.status_delta != v.status_delta ||
            u.rays_moved != v.rays_moved)
            return false;
    }
    return true;
}

}  // namespace

TEST_CASE("a slotted index committed by the kernels stays the incremental trace's, and windows select from it") {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        auto [hm, rays, pp] = rippled(c);
        IncrementalTrace inc(hm, rays, pp);
        inc.rebuild(exec::seq);
        FlatRayCellIndex flat;
        flatten(inc, flat);
        SlottedRayCellIndex serial, threaded;
        serial.assign(flat), threaded.assign(flat);
        std::vector<RayRecord> serial_records = inc.records(), threaded_records = inc.records();
        CounterRng rng(13, 0);
        std::vector<HeightOverlay> window(8);
        WindowEvaluation reference, selected;
        TraceChange single;
        int differ = 0, committed = 0, relisted = 0, overflowed = 0;
        for (int w = 0; w < 40; ++w) {
            for (HeightOverlay& o : window) random_bump(hm, rng, o);
            flatten(inc, flat);
            reference.select_flat(exec::seq, inc, flat.view(), window);
            reference.retrace(exec::seq, inc, window);
            reference.sum_atomic(exec::seq, inc);
            selected.select_flat(exec::omp_t{2}, inc, threaded.view().selection(), window);
            selected.retrace(exec::omp_t{2}, inc, window);
            selected.sum_atomic(exec::omp_t{2}, inc);
            differ += same_sets(reference, selected) ? 0 : 1;
            for (std::size_t p = 0; p < window.size(); ++p) {
                if (reference.change(p).rays_moved == 0) continue;
                inc.evaluate(window[p], single);
                for (std::size_t k = 0; k < single.rays.size(); ++k)
                    relisted += std::ranges::equal(inc.index().cells_of(single.rays[k]),
                                                   std::span(single.cells).subspan(std::size_t(single.cell_begin[k]),
                                                                                   std::size_t(single.cell_begin[k + 1] -
                                                                                               single.cell_begin[k])),
                                                   {}, &CellCrossing::cell, &CellCrossing::cell)
                                    ? 0
                                    : 1;
                window[p].commit(hm);
                inc.commit(single);
                const IndexChangeView change{single.rays.data(), single.records.data(), single.cell_begin.data(),
                                             single.cells.data()};
                const bool fits = serial.commit(exec::seq, change, std::int64_t(single.rays.size()), serial_records.data());
                CHECK(threaded.commit(exec::omp_t{2}, change, std::int64_t(single.rays.size()),
                                      threaded_records.data()) == fits);
                if (!fits) {  // a slot overflowed: the index is assigned again, with room to spare
                    ++overflowed;
                    flatten(inc, flat);
                    serial.assign(flat), threaded.assign(flat);
                }
                differ += same_index(serial, inc) && same_index(threaded, inc) ? 0 : 1;
                differ += serial_records == inc.records() && threaded_records == inc.records() ? 0 : 1;
                ++committed;
                break;
            }
        }
        CHECK(differ == 0);
        CHECK(committed > 20);
        CHECK(relisted > 20);  // the commits moved rays between cell lists, not only ranges
        MESSAGE(std::string(c.name), ": ", overflowed, " of ", committed, " commits ran a pool out of room");
        CHECK(overflowed * 4 < committed);
    }
}

namespace {

// A problem over one of the scenes above, with a receiver and ray budget small enough
// for 10,000 proposals, and a target so that every objective term is live.
struct Setup {
    Scene scene;
    Heightmap hm;
    RaySet rays;
    PathParams pp;
    Target target;
    Penalties penalties;
};

Setup make_setup(const Case& c) {
    Setup s{c.scene, surface_for(c.scene, 33), {}, {}, {}, {}};
    s.scene.receiver.width = s.scene.receiver.height = 16;
    s.scene.light.rays_per_cell = 8;
    shape(s.hm, [](double u, double v) { return 0.001 * std::sin(80 * u) * std::cos(70 * v); });
    s.rays = generate_rays(s.scene.light, s.hm, s.scene.receiver, 5);
    s.pp = make_path_params(s.scene);
    ImageD img(16, 16);
    for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) img(y, x) = 1.0 + 0.8 * std::sin(0.7 * x) * std::cos(0.4 * y);
    s.target = make_target(img, 16, 16, s.rays.total);
    s.penalties.add(HeightBoundTerm{}, 0.01);
    s.penalties.add(ValleyTerm{175}, 0.01);
    s.penalties.add(SmoothnessTerm{}, 0.001);
    return s;
}

ProposalSettings proposals() {
    ProposalSettings p;
    p.bank = default_kernel_bank(5);
    p.max_shift_cells = 3;
    return p;
}

// `moves` proposals (10,000 unless told) at `temperature`, accepted at random (40 %),
// then compared with a full recompute.
template <class Problem, class Fresh>
void check_problem(Problem& problem, Fresh&& fresh_value, std::uint64_t moves = 10000, double temperature = 1.0) {
    typename Problem::Move m;
    CounterRng pick(1234, 0);
    std::uint64_t accepted = 0;
    for (std::uint64_t it = 0; it < moves; ++it) {
        CounterRng rng(77, it);
        problem.propose(rng, temperature, m);
        const double before = problem.energy();
        const double d = problem.delta(m);
        CHECK(problem.energy() == before);  // delta() changes nothing visible
        if (pick.uniform() < 0.4) {
            problem.accept(m);
            ++accepted;
            CHECK(problem.energy() == doctest::Approx(before + d).epsilon(1e-9));
        } else {
            problem.reject(m);
        }
        if ((it + 1) % 64 == 0) problem.sync();
    }
    CHECK(accepted > moves * 35 / 100);
    const ObjectiveValue recomputed = fresh_value();
    CHECK(std::abs(problem.value().total - recomputed.total) <= 1e-12 * std::abs(recomputed.total));
    CHECK(problem.value().total == recomputed.total);  // exact: every term is an integer sum
    CHECK(problem.value().energy == recomputed.energy);
}

}  // namespace

// The cases in the doctest suite "serial" run on one thread: the ThreadSanitizer run leaves
// them out (CMakePresets.json's tsan test preset; tests/main.cpp).
TEST_CASE("maintained histogram and objective equal a full recompute after 10,000 proposals" *
          doctest::test_suite("serial")) {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        Setup s = make_setup(c);
        SurfaceProblem problem(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                 make_bandit(BanditKind::history, 7), 1e-4, 1.0);
        check_problem(problem, [&] {
            SurfaceProblem fresh(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                   make_bandit(BanditKind::history, 7), 1e-4, 1.0);
            return fresh.value();
        });
        const Traced full = trace_scene(s.scene, s.hm, s.rays);
        CHECK(problem.histogram() == full.histogram);
    }
}

namespace {

// `steps` proposals from `seed`, accepted at random (40 %), on each problem alike; their
// objectives must agree exactly after every step.
template <class... Problems>
void same_moves(std::uint64_t seed, int steps, Problems&... problems) {
    std::array<SurfaceProblem::Move, sizeof...(Problems)> moves;
    CounterRng pick(seed, 1);
    for (std::uint64_t it = 0; it < std::uint64_t(steps); ++it) {
        const bool take = pick.uniform() < 0.4;
        std::size_t k = 0;
        std::array<double, sizeof...(Problems)> totals{};
        (
            [&](auto& p) {
                CounterRng rng(seed, 1000 + it);
                auto& m = moves[k];
                p.propose(rng, 1.0, m);
                p.delta(m);
                if (take)
                    p.accept(m);
                else
                    p.reject(m);
                if ((it + 1) % 64 == 0) p.sync();
                totals[k++] = p.value().total;
            }(problems),
            ...);
        for (std::size_t j = 1; j < totals.size(); ++j) REQUIRE(totals[j] == totals[0]);
    }
}

// A seeded run of `iterations` with speculative windows of `speculative` moves always on
// (not adapted to the measured speed), on `threads` threads.
AnnealOptions fixed_windows(std::int64_t iterations, int speculative, int threads) {
    AnnealOptions o;
    o.seed = 11;
    o.max_iterations = iterations;
    o.speculative = speculative;
    o.threads = threads;
    o.adaptive_speculation = false;
    return o;
}

}  // namespace

TEST_CASE("a problem built on the trace of the one before it follows a rebuilt one move for move" *
          doctest::test_suite("serial")) {
    // The designer hands a level's trace from stage to stage instead of tracing every ray
    // again (design/designer.hpp, make_problem): the result must not change.
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        Setup s = make_setup(c);
        SurfaceProblem first(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(), make_bandit(BanditKind::history, 7),
                             1e-4, 1.0);
        same_moves(5, 1500, first);
        IncrementalTrace handed = first.take_trace();
        Heightmap copy = s.hm;
        const ProposalSettings next = proposals();
        SurfaceProblem reused(s.hm, s.rays, s.pp, s.target, {}, s.penalties, next, make_bandit(BanditKind::uniform, 7), 1e-4,
                              1.0, {}, &handed);
        CHECK(handed.records().empty());  // moved in, not traced again
        SurfaceProblem rebuilt(copy, s.rays, s.pp, s.target, {}, s.penalties, next, make_bandit(BanditKind::uniform, 7), 1e-4,
                               1.0);
        CHECK(reused.value().total == rebuilt.value().total);
        CHECK(reused.histogram() == rebuilt.histogram());
        same_moves(9, 1500, reused, rebuilt);
        CHECK(s.hm.heights() == copy.heights());
        CHECK(reused.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
        // A trace of another surface is not taken: that problem traces its rays itself.
        IncrementalTrace other = rebuilt.take_trace();
        const std::size_t records = other.records().size();
        SurfaceProblem elsewhere(s.hm, s.rays, s.pp, s.target, {}, s.penalties, next, make_bandit(BanditKind::uniform, 7), 1e-4,
                                 1.0, {}, &other);
        CHECK(other.records().size() == records);
        CHECK(elsewhere.histogram() == reused.histogram());
    }
}

TEST_CASE("an annealing run whose windows are evaluated together is the per-move run bit for bit") {
    // The batch logic of a design on a GPU (trace/window.hpp), run by the annealer on the
    // CPU: speculative windows of 8 moves, their rays retraced by one kernel call; in the
    // host forms, and in the kernel forms with the state kept apart as a device keeps it.
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        // windows: 0 off, 1 the host forms, 2 the kernel forms over a slotted index kept
        // apart and updated by the commit kernels (what a device does).
        const auto run = [&](int windows, int speculative, int threads) {
            Setup s = make_setup(c);
            SurfaceProblem problem(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                   make_bandit(BanditKind::history, 7), 1e-4, 1.0);
            problem.set_window_evaluation(windows == 1);
            if (windows == 2)
                problem.set_window_evaluator(std::make_unique<CopiedStateWindowEvaluator>(
                    std::make_unique<HostKernelWindowBackend<exec::omp_t>>(exec::omp_t{threads})));
            const AnnealResult r = anneal(problem, fixed_windows(600, speculative, threads));
            CHECK(problem.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
            if (windows == 2) {  // the state was copied once and then kept by the commit kernels
                const auto& e = dynamic_cast<const CopiedStateWindowEvaluator&>(*problem.window_evaluator());
                CHECK(e.commits() > 20);
                CHECK(e.copies() * 10 < e.commits());
            }
            return std::make_pair(r, s.hm.heights());
        };
        const auto serial = run(0, 1, 1);
        CHECK(serial.first.accepted > 20);
        for (const int windows : {1, 2})
            for (const int threads : {1, 2}) {
                CAPTURE(windows);
                const auto together = run(windows, 8, threads);
                CHECK(together.first.accepted == serial.first.accepted);
                CHECK(together.first.final_energy == serial.first.final_energy);
                CHECK(together.second == serial.second);
                CHECK(together.first.proposals_evaluated > together.first.iterations);  // windows really ran
            }
    }
}

namespace {

// The grazing-light case with a reach envelope of one proposal's room: re-centred often,
// its limits binding (the default room is 16).
struct TightReach {
    Case c = cases().back();
    ProposalSettings settings = proposals();
    static constexpr double unit = 2e-5;
    TightReach() {
        REQUIRE(std::string_view(c.name) == "grazing light");
        settings.reach_moves = 1;
    }
    SurfaceProblem problem(Setup& s) const {
        return SurfaceProblem(s.hm, s.rays, s.pp, s.target, {}, s.penalties, settings,
                              make_bandit(BanditKind::history, 7), unit, 1.0);
    }
};

}  // namespace

TEST_CASE("the reach envelope lists a ray only where a move can reach it, and the state stays a full retrace's" *
          doctest::test_suite("serial")) {
    // Under grazing light a ray runs through the height slab over many cells; with the
    // envelope (trace/incremental.hpp) the index keeps only the cells whose heights can
    // come near its path before the next re-centring, and proposals keep to its limits.
    const TightReach tight;
    Setup s = make_setup(tight.c);
    SurfaceProblem problem = tight.problem(s);
    REQUIRE(problem.trace().reach().active());
    IncrementalTrace plain(s.hm, s.rays, s.pp);  // no margin: every crossing of the slab
    plain.rebuild(exec::seq);
    CHECK_FALSE(plain.reach().active());
    const std::int64_t kept = problem.trace().index().crossings(), all = plain.index().crossings();
    MESSAGE("crossings kept by the envelope: " << kept << " of " << all);
    CHECK(2 * kept <= all);
    // What it keeps is the plain trace's (the walk is the same).
    for (std::int32_t r = 0; r < std::int32_t(s.rays.size()); ++r) {
        const auto a = problem.trace().index().cells_of(r), b = plain.index().cells_of(r);
        const auto by_cell = [](const CellCrossing& x, const CellCrossing& y) { return x.cell < y.cell; };
        CHECK(std::includes(b.begin(), b.end(), a.begin(), a.end(), by_cell));
        for (const CellCrossing& x : a) {  // a part of its path where pieces were left out
            const auto y = std::lower_bound(b.begin(), b.end(), x, by_cell);
            REQUIRE(y != b.end());
            CHECK((x.zlo >= y->zlo && x.zhi <= y->zhi));
        }
    }
    // At 25 times the reference temperature a proposal may shift the light five times as
    // far as at the reference: 2.5 margins, more than the envelope holds. Its limits
    // must then bind, or rays it does not list would meet the moved cells.
    check_problem(problem, [&] { return tight.problem(s).value(); }, 4000, 25.0);
    MESSAGE("re-centred " << problem.reach_recentres() << " times");
    CHECK(problem.reach_recentres() >= 3);
    CHECK(problem.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
    // Every vertex inside the limits of the envelope now in force.
    const ReachEnvelope& e = problem.trace().reach();
    for (std::size_t k = 0; k < s.hm.heights().size(); ++k) {
        CHECK(s.hm.heights()[k] >= e.vertex_lo[k]);
        CHECK(s.hm.heights()[k] <= e.vertex_hi[k]);
    }
}

TEST_CASE("under the reach envelope, windows evaluated together are still the per-move run bit for bit") {
    const TightReach tight;
    const auto run = [&](int windows, int speculative, int threads) {
        Setup s = make_setup(tight.c);
        SurfaceProblem problem = tight.problem(s);
        REQUIRE(problem.trace().reach().active());
        problem.set_window_evaluation(windows == 1);
        if (windows == 2)
            problem.set_window_evaluator(std::make_unique<CopiedStateWindowEvaluator>(
                std::make_unique<HostKernelWindowBackend<exec::omp_t>>(exec::omp_t{threads})));
        const AnnealResult r = anneal(problem, fixed_windows(1500, speculative, threads));
        CHECK(problem.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
        CHECK(problem.reach_recentres() > 0);
        return std::make_tuple(r.accepted, r.final_energy, s.hm.heights(), problem.reach_recentres());
    };
    const auto serial = run(0, 1, 1);
    CHECK(std::get<0>(serial) > 20);
    for (const int windows : {1, 2}) {
        CAPTURE(windows);
        CHECK(run(windows, 8, 2) == serial);
    }
}

#if defined(FREEFORM_WITH_EMBREE)
TEST_CASE("an Embree problem annealed with speculative windows on 2 threads follows the serial run") {
    // The Embree backend shows each move to its acceleration structure to evaluate it, so
    // its deltas must run one at a time (concurrent_deltas = false): speculative windows
    // then evaluate their proposals in turn, and the run is the serial one bit for bit.
    static_assert(!EmbreeSurfaceProblem::concurrent_deltas && SurfaceProblem::concurrent_deltas);
    const Case c = cases().front();
    const auto run = [&](int speculative, int threads) {
        Setup s = make_setup(c);
        EmbreeTracer tracer(s.hm, s.rays, s.pp, {}, 8);
        EmbreeSurfaceProblem problem(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                       make_bandit(BanditKind::history, 7), 1e-4, 1.0, EmbreeBackend{&tracer, &s.hm});
        const AnnealResult r = anneal(problem, fixed_windows(400, speculative, threads));
        return std::make_pair(r, s.hm.heights());
    };
    const auto serial = run(1, 1), speculative = run(4, 2);
    CHECK(serial.first.accepted > 0);
    CHECK(speculative.first.accepted == serial.first.accepted);
    CHECK(speculative.first.final_energy == serial.first.final_energy);
    CHECK(speculative.second == serial.second);
    CHECK(speculative.first.proposals_evaluated > speculative.first.iterations);
}

TEST_CASE("the Embree backend keeps the same invariant, refitting only touched tiles" *
          doctest::test_suite("serial")) {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        Setup s = make_setup(c);
        EmbreeTracer tracer(s.hm, s.rays, s.pp, {}, 8);
        EmbreeSurfaceProblem problem(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                       make_bandit(BanditKind::history, 7), 1e-4, 1.0, EmbreeBackend{&tracer, &s.hm});
        // A quarter of the proposals under the sanitizers (in release this case is half the file's time).
        check_problem(
            problem,
            [&] {
                EmbreeTracer t2(s.hm, s.rays, s.pp, {}, 8);
                EmbreeSurfaceProblem fresh(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(),
                                             make_bandit(BanditKind::history, 7), 1e-4, 1.0,
                                             EmbreeBackend{&t2, &s.hm});
                return fresh.value();
            },
            testing::sanitized ? 2500 : 10000);
        // Against a fresh Embree full trace of the final surface.
        EmbreeTracer fresh(s.hm, s.rays, s.pp, {}, 8);
        Histogram h(s.scene.receiver.width, s.scene.receiver.height);
        TraceTotals t;
        fresh.trace_all(exec::seq, h, t);
        CHECK(problem.histogram() == h);
        CHECK(tracer.tiles_touched_last_update() <= 4);
    }
}
#endif

TEST_CASE(
    "set_centre_rows: moves change only the strip's rows and a kernel's reach; the whole mesh changes nothing" *
    doctest::test_suite("serial")) {
    for (const bool guided : {false, true}) {
        CAPTURE(guided);
        const auto all = cases();
        Setup s = make_setup(all.front());
        ProposalSettings ps = proposals();
        ps.error_guided = guided;
        SurfaceProblem strip(s.hm, s.rays, s.pp, s.target, {}, s.penalties, ps, make_bandit(BanditKind::uniform, 7), 1e-4, 1.0);
        SurfaceProblem whole(s.hm, s.rays, s.pp, s.target, {}, s.penalties, ps, make_bandit(BanditKind::uniform, 7), 1e-4, 1.0);
        SurfaceProblem plain(s.hm, s.rays, s.pp, s.target, {}, s.penalties, ps, make_bandit(BanditKind::uniform, 7), 1e-4, 1.0);
        strip.set_centre_rows(10, 20);
        whole.set_centre_rows(0, s.hm.ny());
        const int reach = 5 / 2;  // default_kernel_bank(5): 5 × 5 vertices around the centre
        int lowest = s.hm.ny(), highest = -1;
        SurfaceProblem::Move a, b, p;
        bool same = true;
        for (std::uint64_t it = 0; it < 2000; ++it) {
            CounterRng r1(91, it), r2(91, it), r3(91, it);
            strip.propose(r1, 1.0, a);
            whole.propose(r2, 1.0, b);
            plain.propose(r3, 1.0, p);
            same = same && b.overlay.patch.i0 == p.overlay.patch.i0 && b.overlay.patch.j0 == p.overlay.patch.j0 &&
                   b.overlay.patch.i1 == p.overlay.patch.i1 && b.overlay.patch.j1 == p.overlay.patch.j1 &&
                   b.overlay.heights == p.overlay.heights;
            if (a.noop) continue;
            lowest = std::min(lowest, a.overlay.patch.j0);
            highest = std::max(highest, a.overlay.patch.j1);
        }
        CHECK(same);  // the whole mesh as the strip draws exactly the moves of no strip
        CHECK(lowest >= 10 - reach);
        CHECK(highest <= 19 + reach);
        CHECK(lowest <= 10);  // the strip's edge rows are drawn as centres
        CHECK(highest >= 19);
    }
}

TEST_CASE("heights put back inside a small box are applied like a move: the problem follows a rebuilt one" *
          doctest::test_suite("serial")) {
    // A stage that ends by putting its best state back (design/problem.hpp,
    // replace_heights) retraces only the rays the changed box can affect when the box is
    // small, and every ray otherwise; both must leave the state a full rebuild gives.
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        Setup s = make_setup(c);
        SurfaceProblem kept(s.hm, s.rays, s.pp, s.target, {}, s.penalties, proposals(), make_bandit(BanditKind::uniform, 7),
                            1e-4, 1.0);
        same_moves(5, 400, kept);
        // A bump inside a 5 x 4 box of vertices: the small-box path.
        std::vector<float> bumped = s.hm.heights();
        const int nx = s.hm.nx(), ny = s.hm.ny();
        for (int j = ny / 2; j < ny / 2 + 4; ++j)
            for (int i = nx / 3; i < nx / 3 + 5; ++i) bumped[std::size_t(j) * std::size_t(nx) + std::size_t(i)] += 2e-5f;
        const std::vector<float> before = s.hm.heights();
        const Histogram histogram_before = kept.histogram();
        kept.replace_heights(bumped);
        CHECK(kept.histogram() != histogram_before);  // the bump moved some light
        Heightmap copy = s.hm;
        SurfaceProblem rebuilt(copy, s.rays, s.pp, s.target, {}, s.penalties, proposals(), make_bandit(BanditKind::uniform, 7),
                               1e-4, 1.0);
        CHECK(s.hm.heights() == bumped);
        CHECK(kept.value().total == rebuilt.value().total);
        CHECK(kept.histogram() == rebuilt.histogram());
        CHECK(kept.best_heights() == nullptr);
        // Its index too: the same moves keep both alike.
        same_moves(9, 600, kept, rebuilt);
        CHECK(kept.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
        // Every height changed: the full rebuild's path, to the same end.
        kept.replace_heights(before);
        rebuilt.replace_heights(before);
        CHECK(s.hm.heights() == before);
        CHECK(kept.value().total == rebuilt.value().total);
        CHECK(kept.histogram() == trace_scene(s.scene, s.hm, s.rays).histogram);
    }
}
