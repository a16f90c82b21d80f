#pragma once
// The objective: image error, energy conservation and penalties, combined from exact
// integer sums (image_terms.hpp, penalty.hpp) so that a maintained value and a full
// recompute agree bit for bit.
//
//   error    = sum |R - T| / 2N                      (reference eq. 3.3; 0 = identical, 1 = disjoint)
//   image    = error + sobel_weight * sum |Sobel(R - T)| / 8 / 2N    (eq. 4.5)
//   energy   = weight on the receiver / N
//   total    = image / energy if energy < threshold else image       (eq. 4.4)
//              + lost_light_weight * (1 - energy) / 2
//              + mean weighted penalty per vertex
//
// The lost-light term is ours. With T scaled to N, light put in a wrong cell costs its
// weight twice in sum |R - T| (too much here, too little there), light thrown off the
// receiver only once: left alone, the optimiser discards misplaced light down to the
// energy threshold and beyond, since eq. 4.4 barely resists. Charging lost light the
// missing half (weight 1) makes discarding no cheaper than misplacing.
#include <algorithm>
#include <cstdint>

#include "../core/fixed_point.hpp"
#include "image_terms.hpp"
#include "penalty.hpp"

namespace freeform {

struct ObjectiveWeights {
    double sobel = 0.1;              // alpha of the Sobel term
    double energy_threshold = 0.95;  // below this energy the image error is divided by it
    double lost_light = 1.0;         // weight of (1 - energy) / 2
};

struct ObjectiveValue {
    double error = 0;    // the L1 error alone (what the reference and our reports call "error")
    double sobel = 0;    // sum |Sobel(R - T)| / 8 / 2N: the gradient error, in the units of `error`
    double energy = 0;   // fraction of N on the receiver
    double penalty = 0;  // mean weighted penalty per vertex
    double total = 0;    // what the annealer minimises
};

inline ObjectiveValue combine(const ImageSums& s, Fixed n, double penalty, const ObjectiveWeights& w) {
    ObjectiveValue v;
    const double two_n = 2.0 * double(n);
    v.error = double(s.l1) / two_n;
    // The 3 x 3 Sobel stencils weigh a unit step by up to 8 (1+2+1 on each side): dividing
    // by 8 makes them a per-cell gradient estimate, so sobel_weight compares like with like.
    v.sobel = double(s.sobel) / (8.0 * two_n);
    v.energy = double(s.on_receiver) / double(n);
    v.penalty = penalty;
    double image = v.error + w.sobel * v.sobel;
    if (v.energy < w.energy_threshold) image /= std::max(v.energy, 1e-3);
    v.total = image + w.lost_light * 0.5 * (1.0 - v.energy) + penalty;
    return v;
}

}  // namespace freeform
