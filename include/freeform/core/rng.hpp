#pragma once
// Counter-based random numbers: a value is a pure function of (key, counter), so any
// ray, proposal or iteration can draw its numbers independently of the order in which
// work is scheduled. This is what makes results independent of the thread count.
#include <cstdint>

#include "hd.hpp"

namespace freeform {

// 64-bit avalanche mix (the SplitMix64 finaliser; its constants are published).
FREEFORM_HD constexpr std::uint64_t mix64(std::uint64_t z) {
    z ^= z >> 30;
    z *= 0xbf58476d1ce4e5b9ULL;
    z ^= z >> 27;
    z *= 0x94d049bb133111ebULL;
    z ^= z >> 31;
    return z;
}

// Derives one key from several integers (seed, stream, index...).
FREEFORM_HD constexpr std::uint64_t hash_combine(std::uint64_t a, std::uint64_t b) {
    return mix64(a ^ mix64(b + 0x9e3779b97f4a7c15ULL));
}

// A stream of random numbers identified by a key. Two generators with the same key
// produce the same sequence; keys made with hash_combine(seed, index) are independent.
class CounterRng {
public:
    FREEFORM_HD constexpr explicit CounterRng(std::uint64_t key) : key_(mix64(key)) {}
    FREEFORM_HD constexpr CounterRng(std::uint64_t seed, std::uint64_t stream)
        : key_(hash_combine(seed, stream)) {}

    FREEFORM_HD constexpr std::uint64_t next_u64() {
        return mix64(key_ ^ mix64(++counter_ * 0x9e3779b97f4a7c15ULL));
    }
    // Uniform in [0, 1) with 53 random bits.
    FREEFORM_HD constexpr double uniform() {
        return static_cast<double>(next_u64() >> 11) * (1.0 / 9007199254740992.0);
    }
    FREEFORM_HD constexpr double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
    // Uniform integer in [0, n), n > 0 (bias below 2^-20 for n < 2^32).
    FREEFORM_HD constexpr std::uint64_t below(std::uint64_t n) {
        const auto k = static_cast<std::uint64_t>(uniform() * static_cast<double>(n));
        return k < n ? k : n - 1;
    }
    // Standard normal (Box-Muller; one value per call keeps the stream stateless).
    FREEFORM_HD double normal();

private:
    std::uint64_t key_;
    std::uint64_t counter_ = 0;
};

}  // namespace freeform

#include <cmath>

namespace freeform {
FREEFORM_HD inline double CounterRng::normal() {
    double u1 = uniform();
    const double u2 = uniform();
    if (u1 < 1e-300) u1 = 1e-300;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2);
}
}  // namespace freeform
