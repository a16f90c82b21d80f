#pragma once
// The receiving plane: a frame, a physical size and a pixel resolution. It records
// light that has left the surface, arriving on its front side; it does not block the
// light on its way to the surface.
#include "../core/deposit.hpp"
#include "../core/math.hpp"
#include "../core/frame.hpp"

namespace freeform {

struct Receiver {
    Frame frame;
    Vec2d size{0.2, 0.2};
    int width = 200;   // pixels along u
    int height = 200;  // pixels along v
    Deposit deposit = Deposit::fine_bilinear;  // core/deposit.hpp

    long long cells() const { return static_cast<long long>(width) * height; }
    double aspect() const { return size.x / size.y; }                 // width / height, metres
    Vec2d pitch() const { return {size.x / width, size.y / height}; }  // a pixel's extent, metres
};

}  // namespace freeform
