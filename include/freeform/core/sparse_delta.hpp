#pragma once
// A sparse change of a histogram: what one move does to the received irradiance. The
// incremental tracer fills it (trace/incremental.hpp); the image terms apply it
// (objective/image_terms.hpp).
#include <cstddef>
#include <cstdint>
#include <vector>

#include "fixed_point.hpp"
#include "hd.hpp"

namespace freeform {

// A sparse change of the histogram: dense values (zero where untouched) plus the list of
// touched cells. Reused between moves; clear() resets only what was touched.
struct SparseDelta {
    std::vector<Fixed> value;
    std::vector<std::int32_t> touched;

    void resize(std::size_t cells) {
        value.assign(cells, 0);
        touched.clear();
    }
    // Inlined: a move's retrace calls it four to eight times a ray.
    FREEFORM_FORCE_INLINE void add(std::int64_t cell, Fixed v) {
        Fixed& x = value[std::size_t(cell)];
        if (x == 0) touched.push_back(std::int32_t(cell));  // may list a cell twice if it returns to 0: harmless
        x += v;
    }
    void clear() {
        for (auto c : touched) value[std::size_t(c)] = 0;
        touched.clear();
    }
    // Calls f(cell, value) once for every cell whose value is not zero, in the order the
    // cells were first touched (a cell listed twice is taken once), and empties the delta.
    template <class F>
    void drain(F&& f) {
        for (auto c : touched) {
            Fixed& v = value[std::size_t(c)];
            if (v != 0) f(c, v);
            v = 0;
        }
        touched.clear();
    }
};

}  // namespace freeform
