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

// Assertions inside kernels: checked in debug builds on both host and device.
#define FREEFORM_KERNEL_ASSERT(cond) assert(cond)
