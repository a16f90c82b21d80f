#pragma once
// One annotation for code that must run on the host and, under nvcc, on the device.
// Hot kernels (ray tracing, Phong correction, deposits, kernel application) are written
// as FREEFORM_HD functions over plain views: no virtual calls, no exceptions, no
// allocation, so the same source serves exec::seq, exec::omp and exec::cuda.
#include <cassert>

#if defined(__CUDACC__)
#define FREEFORM_HD __host__ __device__
#define FREEFORM_DEVICE_COMPILE 1
#else
#define FREEFORM_HD
#define FREEFORM_DEVICE_COMPILE 0
#endif

// Small hot helpers that must be inlined: at -O2 GCC's size heuristics keep some out of
// line, and passing a dozen floats (and spilling the caller's registers) costs more than
// they compute.
#if defined(__CUDACC__)
#define FREEFORM_FORCE_INLINE __forceinline__
#elif defined(__GNUC__)
#define FREEFORM_FORCE_INLINE inline __attribute__((always_inline))
#else
#define FREEFORM_FORCE_INLINE inline
#endif

// Assertions inside kernels: checked in debug builds on both host and device.
#define FREEFORM_KERNEL_ASSERT(cond) assert(cond)

namespace freeform {
// A hint that `p` will be read soon (host code that walks scattered indices). No effect
// on results; a no-op where the compiler has no such builtin.
FREEFORM_FORCE_INLINE void prefetch([[maybe_unused]] const void* p) {
#if defined(__GNUC__) && !defined(__CUDA_ARCH__)
    __builtin_prefetch(p);
#endif
}
}  // namespace freeform
