// nvcc compile check (ctest `cuda_compile`): every header that holds FREEFORM_HD code is
// compiled as CUDA, and __global__ kernels call the hot functions on the device, so a
// function that lacks FREEFORM_HD or uses something the device cannot run fails here
// even on machines without a GPU. Compiled only (-c); nothing is launched.
#include <cstdint>

#include <freeform/core/exec.hpp>
#include <freeform/core/fixed_point.hpp>
#include <freeform/core/hd.hpp>
#include <freeform/core/histogram.hpp>
#include <freeform/core/math.hpp>
#include <freeform/core/rng.hpp>
#include <freeform/core/view.hpp>
#include <freeform/cuda/kernels.hpp>
#include <freeform/surface/heightmap.hpp>
#include <freeform/trace/heightfield_kernel.hpp>
#include <freeform/trace/path.hpp>
#if __has_include(<freeform/cuda.hpp>)
#include <freeform/cuda.hpp>
#endif

#if !FREEFORM_DEVICE_COMPILE
#error "FREEFORM_DEVICE_COMPILE must be 1 when compiling with nvcc"
#endif

namespace freeform::cuda_check {

// Records which surface cells a ray crosses, as the incremental bookkeeping does.
struct CountCells {
    int* count;
    FREEFORM_HD void operator()(int, int) const { ++*count; }
};

// One thread per ray: trace, then deposit into a fixed-point histogram with atomics.
__global__ void trace_and_deposit(HeightfieldView hf, PathParams pp, const Vec3* origin, const Vec3* direction,
                                  const Fixed* weight, std::int64_t n, RayRecord* records,
                                  unsigned long long* cells, int* crossed) {
    const std::int64_t k = std::int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
    if (k >= n) return;
    int count = 0;
    const RayRecord rec = trace_heightfield_ray(hf, pp, origin[k], direction[k], CountCells{&count});
    records[k] = rec;
    crossed[k] = count;
    if (rec.status != RayStatus::receiver) return;
    deposit(pp.receiver, rec.px, rec.py, weight[k], [cells](std::int64_t c, Fixed w) {
        // Two's-complement wrap-around makes unsigned atomics exact for signed sums.
        atomicAdd(cells + c, static_cast<unsigned long long>(w));
    });
}

// The remaining FREEFORM_HD building blocks, each called from device code once.
__global__ void building_blocks(HeightfieldView hf, PathParams pp, SurfaceHit hit, Vec3* out, double* values,
                                std::uint64_t seed) {
    out[0] = phong_point(hit, Vec3{0.1f, 0.2f, 0.0f}, pp.phong_alpha);
    out[1] = shading_normal(hit);
    const SurfaceHit h = find_heightfield_hit(hf, Vec3{0, 0, 1}, Vec3{0, 0, -1}, -1, true, NoCellVisitor{});
    out[2] = Vec3{h.t, float(h.tri), float(int(h.kind))};
    PathState s;
    RayRecord rec;
    out[3] = Vec3{float(advance(pp, s, h, rec)), float(rec.px), float(rec.py)};
    Vec3 refracted{};
    out[4] = refract(Vec3{0, 0, -1}, Vec3{0, 0, 1}, 1.0f, 1.5f, refracted) ? refracted
                                                                             : reflect(Vec3{0, 0, -1}, Vec3{0, 0, 1});
    out[5] = normalize(cross(Vec3{1, 0, 0}, Vec3{0, 1, 0}));
    out[6] = hf.vertex(1, 1) - hf.normal(0, 0);
    int i[3], j[3];
    triangle_vertices(hf.nx, 1, i, j);
    values[0] = double(i[0] + j[2]) + double(hf.cell_active(0, 0));
    CounterRng rng(seed, std::uint64_t(threadIdx.x));
    values[1] = rng.uniform() + rng.normal() + double(rng.below(10)) + rng.uniform(-1.0, 1.0);
    values[2] = from_fixed(Fixed(hash_combine(seed, mix64(seed))));
    values[3] = double(rec == RayRecord{});
    const View2D<double> img{values + 4, 2, 2};
    img(1, 1) = double(img.size());
    const View1D<const Vec3> v1{out, 7};
    values[8] = double(length(v1[3]));
}

// A host-side extended lambda run by a generic kernel: the shape of the CUDA
// for_each policy (needs --extended-lambda).
template <class F>
__global__ void for_each_kernel(std::int64_t n, F f) {
    const std::int64_t i = std::int64_t(blockIdx.x) * blockDim.x + threadIdx.x;
    if (i < n) f(i);
}

void launch_all(const HeightfieldView& hf, const PathParams& pp, RayRecord* records, std::int64_t n) {
    const Vec3 o{0, 0, 1}, d{0, 0, -1};
    for_each_kernel<<<unsigned(n + 255) / 256, 256>>>(n, [=] __device__(std::int64_t k) {
        records[k] = trace_heightfield_ray(hf, pp, o, d, NoCellVisitor{});
    });
}

}  // namespace freeform::cuda_check
