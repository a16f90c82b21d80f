#pragma once
// Post-processing of a designed surface before fabrication.
//
// An annealed height field carries high-frequency ripples that the light pattern does
// not need but a cutter or a print has to follow. Smoothing removes them at a price:
// the surface no longer is the one the optimiser found, so the light pattern gets
// blurrier and the error rises (the reference's Fig. 4.19 shows this trade: smoother,
// more manufacturable surfaces for a somewhat worse image). Re-trace after smoothing to
// see what was given up.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "../core/error.hpp"
#include "heightmap.hpp"

namespace freeform {

// Applies `iterations` passes of a 3 × 3 binomial filter ([1 2 1]/4 along u, then along v).
// Each pass moves every height the fraction `strength` (in [0, 1]) of the way to its
// filtered value. Along the border the filter only acts along the border: a ghost vertex
// extrapolated linearly (h[-1] = 2h[0] - h[1]) makes the filter across the border the
// identity, so a plane stays a plane (up to float rounding) and the outline does not sag.
// The filter is a convex combination, so heights stay inside [h_min, h_max]; they are
// clamped again for rounding and all normals are recomputed. The whole grid is filtered,
// also cells outside an elliptical aperture (they are never traced).
// Throws InputError for iterations < 0 or strength outside [0, 1].
inline void smooth_heights(Heightmap& hm, int iterations, double strength = 1.0) {
    if (iterations < 0) throw InputError("smoothing iterations must be >= 0, got " + std::to_string(iterations));
    if (!(strength >= 0.0 && strength <= 1.0))
        throw InputError("smoothing strength must be in [0, 1], got " + std::to_string(strength));
    if (iterations == 0 || strength == 0.0) return;
    const int nx = hm.nx(), ny = hm.ny();
    const std::size_t n = std::size_t(nx) * ny;
    std::vector<double> h(hm.heights().begin(), hm.heights().end()), along_u(n), filtered(n);
    const auto at = [nx](int i, int j) { return std::size_t(j) * nx + i; };
    for (int it = 0; it < iterations; ++it) {
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
                along_u[at(i, j)] = (i == 0 || i == nx - 1)
                                        ? h[at(i, j)]
                                        : 0.25 * (h[at(i - 1, j)] + 2.0 * h[at(i, j)] + h[at(i + 1, j)]);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
                filtered[at(i, j)] =
                    (j == 0 || j == ny - 1)
                        ? along_u[at(i, j)]
                        : 0.25 * (along_u[at(i, j - 1)] + 2.0 * along_u[at(i, j)] + along_u[at(i, j + 1)]);
        for (std::size_t k = 0; k < n; ++k)
            h[k] = std::clamp(h[k] + strength * (filtered[k] - h[k]), double(hm.h_min()), double(hm.h_max()));
    }
    std::vector<float> out(n);
    for (std::size_t k = 0; k < n; ++k) out[k] = float(h[k]);
    hm.set_heights(out);  // clamps to the bounds and recomputes every normal
}

}  // namespace freeform
