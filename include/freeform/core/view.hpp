#pragma once
// Non-owning views (pointer + extents) passed to kernels instead of containers.
#include <cstddef>
#include <cstdint>

#include "hd.hpp"

namespace freeform {

template <class T>
struct View1D {
    T* data = nullptr;
    std::int64_t size = 0;
    FREEFORM_HD T& operator[](std::int64_t i) const { return data[i]; }
};

// Row-major 2-D view: element (x, y) lives at data[y * width + x]; y = 0 is the top row
// for images and the first grid row for height fields.
template <class T>
struct View2D {
    T* data = nullptr;
    int width = 0;
    int height = 0;
    FREEFORM_HD T& operator()(int x, int y) const {
        return data[static_cast<std::int64_t>(y) * width + x];
    }
    FREEFORM_HD std::int64_t size() const { return static_cast<std::int64_t>(width) * height; }
};

}  // namespace freeform
