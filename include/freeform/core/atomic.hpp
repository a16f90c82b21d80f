#pragma once
// The atomics of kernels that run under exec::omp as well as exec::cuda (core/exec.hpp):
// the device's intrinsics under nvcc's device pass, std::atomic_ref on the host. Only
// integer operations, whose result does not depend on the order threads arrive in
// (fixed-point sums, claims, counters), so the kernels that use them stay deterministic.
#include <atomic>
#include <cstdint>

#include "hd.hpp"

namespace freeform {

// Adds v to *p. Fixed amounts are added as unsigned: two's complement addition wraps to
// the same bits as the signed sum.
FREEFORM_HD inline void atomic_add(unsigned long long* p, unsigned long long v) {
#if defined(__CUDA_ARCH__)
    atomicAdd(p, v);
#else
    std::atomic_ref<unsigned long long>(*p).fetch_add(v, std::memory_order_relaxed);
#endif
}

// Adds v to *p and returns the value before (a counter handing out places in a list).
FREEFORM_HD inline unsigned long long atomic_fetch_add(unsigned long long* p, unsigned long long v) {
#if defined(__CUDA_ARCH__)
    return atomicAdd(p, v);
#else
    return std::atomic_ref<unsigned long long>(*p).fetch_add(v, std::memory_order_relaxed);
#endif
}

FREEFORM_HD inline unsigned int atomic_fetch_add(unsigned int* p, unsigned int v) {
#if defined(__CUDA_ARCH__)
    return atomicAdd(p, v);
#else
    return std::atomic_ref<unsigned int>(*p).fetch_add(v, std::memory_order_relaxed);
#endif
}

// A plain load and store of an int that other threads may store to at the same time
// (relaxed: no ordering, only no torn or racing access).
FREEFORM_HD inline std::int32_t atomic_load(std::int32_t* p) {
#if defined(__CUDA_ARCH__)
    return *static_cast<volatile std::int32_t*>(p);
#else
    return std::atomic_ref<std::int32_t>(*p).load(std::memory_order_relaxed);
#endif
}
FREEFORM_HD inline void atomic_store(std::int32_t* p, std::int32_t v) {
#if defined(__CUDA_ARCH__)
    *static_cast<volatile std::int32_t*>(p) = v;
#else
    std::atomic_ref<std::int32_t>(*p).store(v, std::memory_order_relaxed);
#endif
}

// Sets *p to 1 and says whether this call was the one that did (it was 0 before).
FREEFORM_HD inline bool atomic_claim(unsigned int* p) {
#if defined(__CUDA_ARCH__)
    return atomicExch(p, 1u) == 0u;
#else
    return std::atomic_ref<unsigned int>(*p).exchange(1u, std::memory_order_relaxed) == 0u;
#endif
}

}  // namespace freeform
