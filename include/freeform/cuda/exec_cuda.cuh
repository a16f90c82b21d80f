#pragma once
// The CUDA execution policy (docs/architecture.md §5): `for_each(exec::cuda, n, f)` runs f(i) for
// every i in [0, n) on the GPU, like `for_each(exec::seq, ...)` and
// `for_each(exec::omp, ...)` do on the CPU (core/exec.hpp). f is any functor whose call
// operator is device-callable: a struct with a FREEFORM_HD operator(), or an extended
// lambda (`[=] __device__ (std::int64_t i) {...}` or `[=] __host__ __device__ ...`,
// compiled with --extended-lambda). f is copied to the device by value, so it must
// capture views (pointer + extents into device memory), never host references.
//
// Compile with nvcc only (this header needs the CUDA runtime); include
// <freeform/cuda.hpp> from code that is also compiled by a host compiler.
#include <cuda_runtime.h>

#include <algorithm>
#include <cstdint>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>

#include "../core/exec.hpp"

namespace freeform {

// A CUDA runtime call or a kernel failed. Not an InputError: nothing the user wrote is
// wrong, the device (or the driver, or an out-of-memory condition) is.
class CudaError : public std::runtime_error {
public:
    CudaError(cudaError_t code, const std::string& what)
        : std::runtime_error(what + ": " + cudaGetErrorName(code) + " (" + cudaGetErrorString(code) + ")"),
          code_(code) {}
    cudaError_t code() const noexcept { return code_; }

private:
    cudaError_t code_;
};

namespace cuda {

// Turns a CUDA status into an exception naming the call that failed. The runtime's
// "last error" is cleared: the failure is reported once, by the exception, and not again
// by the next cudaGetLastError of an unrelated call. (Errors that corrupt the context
// are sticky regardless and fail every later call.)
inline void check(cudaError_t status, const std::string& what) {
    if (status == cudaSuccess) return;
    (void)cudaGetLastError();
    throw CudaError(status, what);
}

// Number of usable CUDA devices; 0 (never an exception) when there is no device or no
// driver, so that callers can fall back to the CPU policies.
inline int device_count() {
    int n = 0;
    if (cudaGetDeviceCount(&n) != cudaSuccess) {
        (void)cudaGetLastError();  // do not leave the failure for the next check to find
        return 0;
    }
    return n;
}

}  // namespace cuda

namespace exec {

// Runs the loop as a grid-stride kernel on `stream` (nullptr: the default stream).
// block_size 0 lets the occupancy calculator choose threads per block for the kernel at
// hand. With synchronize (the default) for_each returns when the kernel has finished, as
// the CPU policies do, and reports errors raised while it ran; without it, only launch
// errors are reported and the caller synchronises the stream.
struct cuda_t {
    cudaStream_t stream = nullptr;
    int block_size = 0;
    bool synchronize = true;
};

inline constexpr cuda_t cuda{};

}  // namespace exec

namespace cuda_detail {

// Grid-stride loop: a grid sized to what the device can hold at once walks all of
// [0, n), so n is not limited by the maximum grid size and blocks are never idle
// waiting to be scheduled.
template <class F>
__global__ void grid_stride_kernel(std::int64_t n, F f) {
    const std::int64_t stride = std::int64_t(gridDim.x) * blockDim.x;
    for (std::int64_t i = std::int64_t(blockIdx.x) * blockDim.x + threadIdx.x; i < n; i += stride) f(i);
}

// Threads per block and the number of blocks for a launch of `kernel` over n items.
struct LaunchShape {
    int blocks = 1;
    int threads = 1;
};

template <class Kernel>
LaunchShape launch_shape(Kernel kernel, int block_size, std::int64_t n) {
    LaunchShape s;
    int resident_blocks = 0;
    if (block_size <= 0) {
        cuda::check(cudaOccupancyMaxPotentialBlockSize(&resident_blocks, &s.threads, kernel, 0, 0),
                    "for_each(exec::cuda): cudaOccupancyMaxPotentialBlockSize");
    } else {
        s.threads = block_size;
        int device = 0, sms = 0, per_sm = 0;
        cuda::check(cudaGetDevice(&device), "for_each(exec::cuda): cudaGetDevice");
        cuda::check(cudaDeviceGetAttribute(&sms, cudaDevAttrMultiProcessorCount, device),
                    "for_each(exec::cuda): cudaDeviceGetAttribute(MultiProcessorCount)");
        cuda::check(cudaOccupancyMaxActiveBlocksPerMultiprocessor(&per_sm, kernel, block_size, 0),
                    "for_each(exec::cuda): cudaOccupancyMaxActiveBlocksPerMultiprocessor (block_size " +
                        std::to_string(block_size) + ")");
        resident_blocks = sms * per_sm;
    }
    s.threads = std::max(s.threads, 1);
    const std::int64_t needed = (n + s.threads - 1) / s.threads;
    s.blocks = int(std::clamp<std::int64_t>(needed, 1, std::max(resident_blocks, 1)));
    return s;
}

}  // namespace cuda_detail

// for_each on the GPU: f(i) for i in [0, n), in no particular order and concurrently, so
// f must write disjoint outputs or use atomics. Throws CudaError when the launch (or,
// with p.synchronize, the kernel) fails; an invalid block_size is reported that way too.
template <class F>
void for_each(exec::cuda_t p, std::int64_t n, F&& f) {
    using Fn = std::remove_cvref_t<F>;
    static_assert(std::is_copy_constructible_v<Fn>, "for_each(exec::cuda): the functor is copied to the device");
    if (n <= 0) return;
    const auto kernel = &cuda_detail::grid_stride_kernel<Fn>;
    const cuda_detail::LaunchShape s = cuda_detail::launch_shape(kernel, p.block_size, n);
    kernel<<<unsigned(s.blocks), unsigned(s.threads), 0, p.stream>>>(n, Fn(std::forward<F>(f)));
    const auto fail = [&](cudaError_t status, const char* stage) {
        (void)cudaGetLastError();
        throw CudaError(status, std::string("for_each(exec::cuda): ") + stage + " (" + std::to_string(s.blocks) +
                                    " blocks of " + std::to_string(s.threads) + " threads, n = " + std::to_string(n) +
                                    ")");
    };
    if (const cudaError_t status = cudaGetLastError(); status != cudaSuccess) fail(status, "kernel launch");
    if (!p.synchronize) return;
    if (const cudaError_t status = cudaStreamSynchronize(p.stream); status != cudaSuccess)
        fail(status, "kernel execution");
}

}  // namespace freeform
