#pragma once
// Execution policies and the one parallel loop the library uses. Kernels are written
// once as callables taking an index; the policy decides where they run. The CUDA policy
// lives in freeform/cuda/exec_cuda.cuh and adds an overload for exec::cuda_t.
#include <algorithm>
#include <concepts>
#include <cstdint>

#if defined(_OPENMP)
#include <omp.h>
#endif

namespace freeform {
namespace exec {

struct seq_t {};
// OpenMP over the calling thread's team; threads == 0 means the OpenMP default.
struct omp_t {
    int threads = 0;
};

inline constexpr seq_t seq{};
inline constexpr omp_t omp{};

}  // namespace exec

template <class P>
concept HostPolicy = std::same_as<P, exec::seq_t> || std::same_as<P, exec::omp_t>;

inline int thread_count(exec::seq_t) { return 1; }
inline int thread_count(exec::omp_t p) {
#if defined(_OPENMP)
    return p.threads > 0 ? p.threads : omp_get_max_threads();
#else
    (void)p;
    return 1;
#endif
}

template <class F>
void for_each(exec::seq_t, std::int64_t n, F&& f) {
    for (std::int64_t i = 0; i < n; ++i) f(i);
}

template <class F>
void for_each(exec::omp_t p, std::int64_t n, F&& f) {
#if defined(_OPENMP)
    const int threads = thread_count(p);
#pragma omp parallel for schedule(static) num_threads(threads)
    for (std::int64_t i = 0; i < n; ++i) f(i);
#else
    (void)p;
    for (std::int64_t i = 0; i < n; ++i) f(i);
#endif
}

// Splits [0, n) into `chunks` contiguous ranges and calls f(chunk, begin, end) for each;
// used where each worker keeps private state (a private histogram, say). Which range a
// chunk covers depends only on n and chunks, never on the thread that runs it.
template <class P, class F>
void for_each_chunk(P p, std::int64_t n, int chunks, F&& f) {
    for_each(p, chunks, [&](std::int64_t c) {
        const std::int64_t begin = n * c / chunks;
        const std::int64_t end = n * (c + 1) / chunks;
        f(static_cast<int>(c), begin, end);
    });
}

// Splits [0, n) into one contiguous range per thread of `p` (fewer when n is smaller) and
// calls f(begin, end) for each: for loops over independent items whose workers keep
// scratch of their own (buffers, an FFT plan). The ranges depend on the thread count, so
// an item's result must not depend on which range it is in (no sums across items).
template <class P, class F>
void for_each_worker_range(P p, std::int64_t n, F&& f) {
    const std::int64_t workers = std::max<std::int64_t>(1, std::min<std::int64_t>(thread_count(p), n));
    for_each_chunk(p, n, int(workers), [&](int, std::int64_t begin, std::int64_t end) { f(begin, end); });
}

}  // namespace freeform
