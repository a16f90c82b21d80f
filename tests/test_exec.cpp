// Execution policies (docs/architecture.md §5): for_each runs a kernel written once as a FREEFORM_HD
// functor serially or with OpenMP (and, in CUDA builds, on the GPU: tests/cuda/), and the
// results do not depend on the policy.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include <freeform/core/exec.hpp>
#include <freeform/core/hd.hpp>
#include <freeform/cuda.hpp>  // a no-op for a host compiler
#include <freeform/cuda/kernels.hpp>
#include <freeform/trace/heightfield_kernel.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

static_assert(!FREEFORM_HAS_CUDA_POLICY, "a host compiler sees no CUDA policy");
static_assert(!FREEFORM_DEVICE_COMPILE);

struct WavyScene {
    Scene scene;
    Heightmap surface;
    RaySet rays;
};

// A wavy mirror under a point light; or (fresnel_lens) a wavy lens with Fresnel losses,
// the receiver below it.
WavyScene wavy_scene(Deposit d, bool fresnel_lens = false) {
    Scene s = basic_scene(80, 16);
    s.receiver.deposit = d;
    s.receiver.size = {0.4, 0.4};
    s.light.shape = PointLight{{0.01, 0.0, 0.3}, {}, {}};
    if (fresnel_lens) {
        s.surface.material = Lens{1.5, 0.01};
        s.receiver.frame = make_frame({0, 0, -0.3}, {0, 0, 1}, {0, 1, 0}, "receiver");
        s.trace.fresnel = true;
    }
    Heightmap hm = surface_for(s, 41);
    shape(hm, [](double u, double v) { return 0.003 * std::sin(60 * u) * std::cos(45 * v); });
    RaySet rays = generate_rays(s.light, hm, s.receiver, 3);
    return {s, std::move(hm), std::move(rays)};
}

}  // namespace

TEST_CASE("for_each visits every index exactly once under every policy") {
    for (const std::int64_t n : {0, 1, 7, 1000, 100003}) {
        std::vector<int> seen(std::size_t(n), 0);
        for_each(exec::seq, n, [&](std::int64_t i) { ++seen[std::size_t(i)]; });
        for (const int threads : {0, 1, 2, 3})
            for_each(exec::omp_t{threads}, n, [&](std::int64_t i) { ++seen[std::size_t(i)]; });
        bool all_five = true;
        for (const int s : seen) all_five = all_five && s == 5;
        CHECK(all_five);
    }
}

#if defined(_OPENMP)
// The design's thread count reaches every parallel loop through exec::omp_t (the tracers,
// the backends' full rebuilds): a team of exactly that size, whatever the machine has.
TEST_CASE("for_each under exec::omp_t{n} runs a team of n threads") {
    for (const int threads : {1, 2, 3}) {
        std::vector<int> team(64, 0);
        for_each(exec::omp_t{threads}, 64, [&](std::int64_t i) { team[std::size_t(i)] = omp_get_num_threads(); });
        CHECK(*std::min_element(team.begin(), team.end()) == threads);
        CHECK(*std::max_element(team.begin(), team.end()) == threads);
        CHECK(thread_count(exec::omp_t{threads}) == threads);
    }
}
#endif

TEST_CASE("for_each_chunk splits [0, n) into contiguous ranges fixed by n and chunks only") {
    for (const int chunks : {1, 2, 3, 8}) {
        const std::int64_t n = 1001;
        const auto size = static_cast<std::size_t>(chunks);
        std::vector<std::int64_t> begin_seq(size), end_seq(size), begin_omp(size), end_omp(size);
        for_each_chunk(exec::seq, n, chunks, [&](int c, std::int64_t b, std::int64_t e) {
            begin_seq[std::size_t(c)] = b, end_seq[std::size_t(c)] = e;
        });
        for_each_chunk(exec::omp_t{2}, n, chunks, [&](int c, std::int64_t b, std::int64_t e) {
            begin_omp[std::size_t(c)] = b, end_omp[std::size_t(c)] = e;
        });
        CHECK(begin_seq == begin_omp);
        CHECK(end_seq == end_omp);
        CHECK(begin_seq.front() == 0);
        CHECK(end_seq.back() == n);
        for (int c = 1; c < chunks; ++c) CHECK(begin_seq[std::size_t(c)] == end_seq[std::size_t(c - 1)]);
    }
}

TEST_CASE("for_each_worker_range gives each thread one contiguous range, never more ranges than items") {
    for (const int threads : {1, 2, 3}) {
        for (const std::int64_t n : {std::int64_t(0), std::int64_t(2), std::int64_t(1001)}) {
            std::vector<int> seen(static_cast<std::size_t>(n), 0);
            int calls = 0;
            for_each_worker_range(exec::omp_t{threads}, n, [&](std::int64_t b, std::int64_t e) {
#if defined(_OPENMP)
#pragma omp atomic
#endif
                ++calls;
                for (std::int64_t i = b; i < e; ++i) seen[std::size_t(i)] += 1;
            });
            // A team of `threads` (1 without OpenMP), never more ranges than items, at least one call.
            const std::int64_t expected = std::max<std::int64_t>(1, std::min<std::int64_t>(thread_count(exec::omp_t{threads}), n));
            CHECK(calls == expected);
            CHECK(std::all_of(seen.begin(), seen.end(), [](int v) { return v == 1; }));
        }
    }
}

TEST_CASE("the GPU tracer's record kernel gives HeightfieldTracer's records under exec::seq and exec::omp") {
    const WavyScene w = wavy_scene(Deposit::bilinear);
    const PathParams pp = make_path_params(w.scene);
    const auto n = std::size_t(w.rays.size());
    // Every other ray, backwards: the kernel follows the ids it is given.
    std::vector<std::int32_t> ids;
    for (std::size_t k = n; k-- > 0;)
        if (k % 2 == 0) ids.push_back(std::int32_t(k));
    std::vector<RayRecord> seq(ids.size()), omp(ids.size()), tracer(ids.size());
    const auto kernel = [&](RayRecord* out) {
        return cuda::TraceRecordsKernel<HeightfieldView>{w.surface.view(), pp, w.rays.origin.data(),
                                                         w.rays.direction.data(), ids.data(), out};
    };
    for_each(exec::seq, std::int64_t(ids.size()), kernel(seq.data()));
    for_each(exec::omp_t{2}, std::int64_t(ids.size()), kernel(omp.data()));
    CHECK(seq == omp);
    const HeightfieldTracer t(w.surface, w.rays, pp);
    t.trace(exec::seq, ids, tracer);
    CHECK(seq == tracer);

    // Records deposited one by one give trace_all's histogram and totals.
    std::vector<std::int32_t> all(n);
    std::vector<RayRecord> records(n);
    for (std::size_t k = 0; k < n; ++k) all[k] = std::int32_t(k);
    t.trace(exec::omp_t{2}, all, records);
    Histogram from_records(w.scene.receiver.width, w.scene.receiver.height);
    TraceTotals totals_from_records;
    for (std::size_t k = 0; k < n; ++k) {
        totals_from_records.add(records[k], w.rays.weight[k]);
        deposit_record(pp.receiver, records[k], w.rays.weight[k], from_records.cells);
    }
    const Traced full = trace_scene(w.scene, w.surface, w.rays, exec::seq);
    CHECK(from_records == full.histogram);
    CHECK(totals_from_records.weight_by_status == full.totals.weight_by_status);
    CHECK(totals_from_records.rays_hit_receiver == full.totals.rays_hit_receiver);
    CHECK(full.totals.rays_hit_receiver > 1000);  // the scene does reach the receiver
}

TEST_CASE("the GPU tracer's trace-and-deposit kernel equals HeightfieldTracer::trace_all, serial and parallel") {
    const std::pair<Deposit, bool> cases[] = {
        {Deposit::nearest, false}, {Deposit::bilinear, false}, {Deposit::fine_bilinear, false}, {Deposit::bilinear, true}};
    for (const auto& c : cases) {
        const bool lens = c.second;  // a lens with Fresnel losses
        CAPTURE(lens);
        const WavyScene w = wavy_scene(c.first, lens);
        const PathParams pp = make_path_params(w.scene);
        const Traced full = trace_scene(w.scene, w.surface, w.rays, exec::omp);
        const std::size_t cells = full.histogram.cells.size();
        const std::size_t lanes = std::size_t(cuda::totals_lanes) * cuda::totals_slots;
        std::vector<unsigned long long> seq(cells, 0), omp(cells, 0), seq_totals(lanes, 0), omp_totals(lanes, 0);
        const auto kernel = [&](unsigned long long* out, unsigned long long* totals) {
            return cuda::TraceDepositKernel<HeightfieldView>{w.surface.view(),       pp, w.rays.origin.data(),
                                                             w.rays.direction.data(), w.rays.weight.data(), out,
                                                             totals};
        };
        for_each(exec::seq, w.rays.size(), kernel(seq.data(), seq_totals.data()));
        for_each(exec::omp_t{2}, w.rays.size(), kernel(omp.data(), omp_totals.data()));
        CHECK(seq == omp);
        CHECK(seq_totals == omp_totals);
        Histogram h(w.scene.receiver.width, w.scene.receiver.height);
        for (std::size_t k = 0; k < cells; ++k) h.cells[k] = Fixed(seq[k]);
        CHECK(h == full.histogram);
        const TraceTotals t = cuda::fold_totals(seq_totals, w.rays.size());
        CHECK(t.weight_by_status == full.totals.weight_by_status);
        CHECK(t.rays_hit_receiver == full.totals.rays_hit_receiver);
        CHECK(t.rays == full.totals.rays);
        if (lens) CHECK(full.totals.fresnel_reflected() > 0);
    }
}

TEST_CASE("unsigned 64-bit sums of signed fixed-point amounts wrap to the signed sum") {
    // What the GPU histogram relies on: atomicAdd exists for unsigned long long only.
    const std::vector<Fixed> amounts{to_fixed(1.5), to_fixed(-2.25), to_fixed(-1e6), to_fixed(3e5), -1, 1};
    unsigned long long u = 0;
    Fixed s = 0;
    for (const Fixed a : amounts) {
        u += static_cast<unsigned long long>(a);
        s += a;
        CHECK(Fixed(u) == s);
    }
    CHECK(s < 0);
}
