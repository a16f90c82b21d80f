#pragma once
// Irradiance is accumulated as 64-bit fixed-point integers: a ray of weight w adds
// round(w * 2^32). Integer sums are exact, so a histogram does not depend on the order
// of deposits, the thread count, or whether it was built in full or incrementally.
#include <cmath>
#include <cstdint>

#include "hd.hpp"

namespace freeform {

using Fixed = std::int64_t;

inline constexpr int fixed_fraction_bits = 32;
inline constexpr double fixed_one = 4294967296.0;  // 2^32

inline Fixed to_fixed(double w) { return static_cast<Fixed>(std::llround(w * fixed_one)); }
FREEFORM_HD constexpr double from_fixed(Fixed f) { return static_cast<double>(f) / fixed_one; }

// The part `fraction` (in [0, 1]) of a non-negative weight, rounded to the nearest unit:
// one multiplication and one rounding, so host and device agree to the bit. A fraction
// of exactly 1 returns w itself.
FREEFORM_HD inline Fixed fixed_part(Fixed w, float fraction) {
    if (fraction == 1.0f) return w;
#if defined(__CUDA_ARCH__)
    return static_cast<Fixed>(llrint(static_cast<double>(w) * static_cast<double>(fraction)));
#else
    return static_cast<Fixed>(std::llrint(static_cast<double>(w) * static_cast<double>(fraction)));
#endif
}

}  // namespace freeform
