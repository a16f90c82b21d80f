// GPU against CPU, bit for bit (ctest `cuda_gpu_vs_cpu`, run by tests/cuda/run.cmake
// only where `nvidia-smi -L` lists a device; `cuda_compile` compiles it everywhere).
//
// Several scenes (flat mirror, paraboloid, point light, lens, interreflecting bumps under
// a disk light; gpu_vs_cpu_host.cpp) are traced by the CPU HeightfieldTracer, compiled by
// the host compiler in gpu_vs_cpu_host.cpp, and by the GPU DeviceHeightfieldTracer;
// histograms, totals and per-ray records must be equal to the last bit. Neither side may
// contract a*b+c into an FMA (--fmad=false here, -ffp-contract=off there). The device
// functors are also run on the host first, over host memory, so their logic is checked
// even on a machine without a GPU.
//
// Exit status: 0 all equal, 1 a mismatch or an error, 77 no CUDA device (after the host
// checks passed), printed as "no CUDA device: skipped".
#include <cstdint>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include <freeform/core/rng.hpp>
#include <freeform/cuda.hpp>
#include <freeform/trace/setup.hpp>

#include "gpu_vs_cpu.hpp"

namespace {

using namespace freeform;
using namespace freeform::gpu_test;

constexpr int exit_skipped = 77;

int failures = 0;

void expect(bool ok, const std::string& what) {
    if (ok) return;
    ++failures;
    std::fprintf(stderr, "FAIL: %s\n", what.c_str());
}

bool same_totals(const TraceTotals& a, const TraceTotals& b) {
    return a.rays == b.rays && a.rays_hit_receiver == b.rays_hit_receiver && a.emitted == b.emitted &&
           a.weight_by_status == b.weight_by_status;
}

// The GPU's deposit functor run on the host over host memory.
template <class P>
Reference host_run_of_device_kernel(const Case& c, const PathParams& pp, P policy) {
    const RaySet& r = c.rays;
    std::vector<unsigned long long> cells(std::size_t(pp.receiver.width) * pp.receiver.height, 0);
    std::vector<unsigned long long> lanes(std::size_t(cuda::totals_lanes) * cuda::totals_slots, 0);
    for_each(policy, r.size(),
             cuda::TraceDepositKernel<HeightfieldView>{c.surface.view(), pp, r.origin.data(), r.direction.data(),
                                                       r.weight.data(), cells.data(), lanes.data()});
    Reference t{Histogram(pp.receiver.width, pp.receiver.height), cuda::fold_totals(lanes, r.size())};
    t.totals.emitted = r.total;
    for (std::size_t k = 0; k < cells.size(); ++k) t.histogram.cells[k] = Fixed(cells[k]);
    return t;
}

std::vector<std::int32_t> every_ray(const RaySet& r) {
    std::vector<std::int32_t> ids(std::size_t(r.size()));
    for (std::size_t k = 0; k < ids.size(); ++k) ids[k] = std::int32_t(k);
    return ids;
}

void host_checks(const Case& c) {
    const PathParams pp = make_path_params(c.scene);
    const Reference ref = cpu_trace_all(c);
    expect(ref.totals.rays_hit_receiver > 0, c.name + ": some rays reach the receiver");
    for (const bool omp : {false, true}) {
        const Reference h =
            omp ? host_run_of_device_kernel(c, pp, exec::omp) : host_run_of_device_kernel(c, pp, exec::seq);
        const std::string how = omp ? " (exec::omp)" : " (exec::seq)";
        expect(h.histogram == ref.histogram, c.name + ": device functor on the host, histogram" + how);
        expect(same_totals(h.totals, ref.totals), c.name + ": device functor on the host, totals" + how);
    }
    // Where the weight went (receiver, missed receiver, missed surface, TIR, depth,
    // absorbed), to show what the scene exercises.
    std::string split;
    for (const Fixed w : ref.totals.weight_by_status) {
        char share[16];
        std::snprintf(share, sizeof share, " %.1f%%", 100.0 * double(w) / double(ref.totals.emitted));
        split += share;
    }
    std::printf("%-43s %7lld rays, weight by status%s: host run of the device functor == CPU\n", c.name.c_str(),
                static_cast<long long>(ref.totals.rays), split.c_str());
}

// Whether a window evaluated on the device gave the host's pairs and changes.
bool same_result(const cuda::DeviceWindowEvaluation& dw, const WindowResult& r) {
    std::vector<std::int32_t> proposals, rays;
    dw.download_pairs(proposals, rays);
    bool same = proposals == r.proposals && rays == r.rays && dw.size() == r.changes.size();
    for (std::size_t p = 0; same && p < dw.size(); ++p) {
        const WindowChange &a = dw.change(p), &b = r.changes[p];
        same = a.cells == b.cells && a.values == b.values && a.status_delta == b.status_delta &&
               a.rays_moved == b.rays_moved;
    }
    return same;
}

// A window of moves in one launch (trace_window, trace/window.hpp): each move with every
// other ray, the pairs interleaved; then the whole window on the device, selection to sums
// (cuda::DeviceWindowEvaluation), against the host's kernel forms.
void window_checks(const Case& c, const cuda::DeviceHeightfieldTracer& gpu, std::span<const HeightOverlay> moves,
                   const WindowReference& ref, cudaStream_t stream) {
    std::vector<std::int32_t> proposal, ray;
    for (std::int32_t k = 0; k < std::int32_t(c.rays.size()); k += 2)
        for (std::int32_t p = 0; p < 3; ++p) proposal.push_back(p), ray.push_back(k);
    std::vector<RayRecord> on_gpu(ray.size()), on_host(ray.size());
    gpu.trace_window(exec::cuda_t{stream}, moves, proposal, ray, on_gpu);
    gpu.trace_window(exec::omp, moves, proposal, ray, on_host);
    std::vector<RayRecord> expected(ray.size());
    for (std::int32_t p = 0; p < 3; ++p) {
        std::vector<std::int32_t> ids;
        for (std::size_t k = std::size_t(p); k < ray.size(); k += 3) ids.push_back(ray[k]);
        const std::vector<RayRecord> one = cpu_trace(c, ids, moves[std::size_t(p)]);
        for (std::size_t m = 0; m < one.size(); ++m) expected[std::size_t(p) + 3 * m] = one[m];
    }
    expect(on_gpu == expected, c.name + ": GPU window of three moves");
    expect(on_host == expected, c.name + ": host window of three moves");
    expect(!(on_gpu == cpu_trace(c, ray)), c.name + ": the window's moves change some records");

    cuda::DeviceWindowEvaluation dw;
    dw.upload_state(ref.index, ref.maintained);
    dw.evaluate(exec::cuda_t{stream}, gpu, moves, ref.before.patches, ref.before.slot_proposal, ref.pad);
    expect(same_result(dw, ref.before), c.name + ": GPU window, selection to sums");
}

// The window's first move committed on the device (cuda::DeviceWindowEvaluation::commit)
// and the others evaluated again. Called once that move is committed to c.surface and to
// the GPU tracer (surface_changed).
void device_commit_checks(const Case& c, const cuda::DeviceHeightfieldTracer& gpu, const WindowReference& ref,
                          std::span<const HeightOverlay> moves, cudaStream_t stream) {
    cuda::DeviceWindowEvaluation dw;
    dw.upload_state(ref.index, ref.maintained);
    bool moved = false;
    for (const WindowChange& change : ref.before.changes) moved = moved || change.rays_moved > 0;
    expect(moved, c.name + ": the window's moves move light");
    expect(dw.commit(exec::cuda_t{stream}, ref.commit_rays, ref.commit_records, ref.commit_begin, ref.commit_cells),
           c.name + ": GPU commit");
    dw.evaluate(exec::cuda_t{stream}, gpu, moves.subspan(1), ref.after.patches, ref.after.slot_proposal, ref.pad);
    expect(same_result(dw, ref.after), c.name + ": GPU window after a GPU commit");
}

void gpu_checks(Case& c, cudaStream_t stream) {
    const PathParams pp = make_path_params(c.scene);
    cuda::DeviceHeightfieldTracer gpu(c.surface, c.rays, pp);
    const int w = c.scene.receiver.width, h = c.scene.receiver.height;

    const Reference ref = cpu_trace_all(c);
    for (const exec::cuda_t policy : {exec::cuda, exec::cuda_t{stream, 128, true}, exec::cuda_t{stream, 64, false}}) {
        Reference g{Histogram(w, h), {}};
        gpu.trace_all(policy, g.histogram, g.totals);
        const std::string how = " (block_size " + std::to_string(policy.block_size) + ")";
        expect(g.histogram == ref.histogram, c.name + ": GPU histogram" + how);
        expect(same_totals(g.totals, ref.totals), c.name + ": GPU totals" + how);
    }

    // Records of a subset, in a scrambled order with repeats.
    std::vector<std::int32_t> ids;
    for (std::int64_t k = c.rays.size() - 1; k >= 0; k -= 3) ids.push_back(std::int32_t(k));
    ids.push_back(0);
    ids.push_back(0);
    std::vector<RayRecord> on_gpu(ids.size());
    gpu.trace(exec::cuda, ids, on_gpu);
    expect(on_gpu == cpu_trace(c, ids), c.name + ": GPU records of a subset");

    // A proposed move, traced through an overlay, then committed.
    const HeightOverlay o = bump_overlay(c.surface);
    const std::vector<std::int32_t> all = every_ray(c.rays);
    std::vector<RayRecord> preview_gpu(all.size()), preview_host(all.size());
    gpu.trace(exec::cuda_t{stream}, all, preview_gpu, o);
    gpu.trace(exec::seq, all, preview_host, o);
    const std::vector<RayRecord> preview_cpu = cpu_trace(c, all, o);
    expect(preview_gpu == preview_cpu, c.name + ": GPU records through an overlay");
    expect(preview_host == preview_cpu, c.name + ": host records through an overlay");
    // A window: `o`, the same move a little higher, and an empty one.
    std::vector<HeightOverlay> moves{o, o, HeightOverlay{}};
    for (float& height : moves[1].heights) height = c.surface.clamp_height(height + 1e-5f);
    moves[1].finish(c.surface);
    const WindowReference window = cpu_window(c, moves);
    window_checks(c, gpu, moves, window, stream);
    o.commit(c.surface);
    gpu.surface_changed(o.patch);
    device_commit_checks(c, gpu, window, moves, stream);
    expect(preview_cpu == cpu_trace(c, all), c.name + ": overlay preview equals the committed surface");
    const Reference after_cpu = cpu_trace_all(c);
    Reference after_gpu{Histogram(w, h), {}};
    gpu.trace_all(exec::cuda, after_gpu.histogram, after_gpu.totals);
    expect(after_gpu.histogram == after_cpu.histogram, c.name + ": GPU histogram after surface_changed");
    expect(same_totals(after_gpu.totals, after_cpu.totals), c.name + ": GPU totals after surface_changed");
    expect(!(after_cpu.histogram == ref.histogram), c.name + ": the move changed the histogram");
    std::printf("%-43s GPU == CPU (histogram, totals, records, overlay, window, surface_changed)\n", c.name.c_str());
}

}  // namespace

namespace freeform::gpu_test {
std::unique_ptr<WindowBackend> make_device_backend(const Heightmap& surface, const RaySet& rays,
                                                   const PathParams& params) {
    return std::make_unique<cuda::DeviceWindowBackend>(surface, rays, params);
}
}  // namespace freeform::gpu_test

namespace {

// for_each(exec::cuda) itself: every index exactly once for n far beyond one grid, the
// same __host__ __device__ lambda on both sides, and launch errors as exceptions.
void policy_checks() {
    const std::int64_t n = 5'000'003;
    cuda::DeviceBuffer<std::uint64_t> d_out{static_cast<std::size_t>(n)};
    d_out.zero();
    std::uint64_t* out = d_out.data();
    const std::uint64_t seed = 42;
    const auto f = [=] __host__ __device__(std::int64_t i) {
        CounterRng rng(seed, std::uint64_t(i));
        out[i] += std::uint64_t(rng.below(1000)) + 1000 * std::uint64_t(i);
    };
    for_each(exec::cuda, n, f);
    const std::vector<std::uint64_t> gpu = d_out.to_host();
    std::vector<std::uint64_t> cpu(std::size_t(n), 0);
    out = cpu.data();
    const auto g = [=] __host__ __device__(std::int64_t i) {
        CounterRng rng(seed, std::uint64_t(i));
        out[i] += std::uint64_t(rng.below(1000)) + 1000 * std::uint64_t(i);
    };
    for_each(exec::seq, n, g);
    expect(gpu == cpu, "for_each(exec::cuda) visits every index once and matches exec::seq");

    bool threw = false;
    std::uint64_t* dev = d_out.data();
    try {
        for_each(exec::cuda_t{nullptr, 4096, true}, 10, [=] __device__(std::int64_t i) { dev[i] = 0; });
    } catch (const CudaError& e) {
        threw = true;
        std::printf("expected error: %s\n", e.what());
    }
    expect(threw, "an impossible block size is reported as CudaError");
    expect(cudaGetLastError() == cudaSuccess, "a failed launch leaves no sticky error");
    std::printf("for_each(exec::cuda): grid-stride coverage, host/device lambda, launch errors: ok\n");
}

}  // namespace

int main() {
    try {
        std::vector<Case> cases = make_cases();
        for (const Case& c : cases) host_checks(c);
        if (failures) {
            std::fprintf(stderr, "%d check(s) failed\n", failures);
            return 1;
        }
        if (cuda::device_count() == 0) {
            std::printf("no CUDA device: skipped\n");
            return exit_skipped;
        }
        cudaDeviceProp prop{};
        cuda::check(cudaGetDeviceProperties(&prop, 0), "cudaGetDeviceProperties");
        std::printf("device 0: %s (sm_%d%d)\n", prop.name, prop.major, prop.minor);
        cudaStream_t stream = nullptr;
        cuda::check(cudaStreamCreate(&stream), "cudaStreamCreate");
        policy_checks();
        for (Case& c : cases) gpu_checks(c, stream);
        for (const Case& c : cases) {
            const std::vector<std::string> differ = design_checks(c);
            for (const std::string& d : differ) expect(false, d);
            if (differ.empty())
                std::printf("%-43s GPU design == CPU design (400 iterations, windows of 8)\n", c.name.c_str());
        }
        cuda::check(cudaStreamDestroy(stream), "cudaStreamDestroy");
    } catch (const std::exception& e) {
        std::fprintf(stderr, "error: %s\n", e.what());
        return 1;
    }
    if (failures) {
        std::fprintf(stderr, "%d check(s) failed\n", failures);
        return 1;
    }
    std::printf("all GPU results equal the CPU bit for bit\n");
    return 0;
}
