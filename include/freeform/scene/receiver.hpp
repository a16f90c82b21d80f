#pragma once
// The receiving plane: a frame, a physical size and a pixel resolution. It records
// light that has left the surface, arriving on its front side; it does not block the
// light on its way to the surface.
#include "../core/math.hpp"
#include "frame.hpp"

namespace freeform {

enum class Deposit {
    nearest,   // all of a ray's weight goes to the cell it hits
    bilinear,  // weight is split among the four nearest cell centres (smoother objective)
};

struct Receiver {
    Frame frame;
    Vec2d size{0.2, 0.2};
    int width = 200;   // pixels along u
    int height = 200;  // pixels along v
    Deposit deposit = Deposit::bilinear;

    long long cells() const { return static_cast<long long>(width) * height; }
};

}  // namespace freeform
