#pragma once
// Surface materials. A mirror reflects on its front side (the side its normal faces, where
// the light comes from). A lens is a solid: the height field is its front face, a flat
// back face lies `thickness` below the surface plane (at height -thickness), and light
// refracts at both faces by Snell's law; total internal reflection is counted as lost.
// Fresnel partial reflection is neglected (all light that can be transmitted is).
#include <variant>

namespace freeform {

struct Mirror {};

struct Lens {
    double ior = 1.49;        // refractive index of the lens material (PMMA by default)
    double thickness = 0.01;  // metres from the surface plane to the flat back face
};

using Material = std::variant<Mirror, Lens>;

inline bool is_lens(const Material& m) { return std::holds_alternative<Lens>(m); }

}  // namespace freeform
