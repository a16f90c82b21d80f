#pragma once
// Surface materials. A mirror reflects on its front side (the side its normal faces, where
// the light comes from). A lens is a solid: the height field is its front face, a flat
// back face lies `thickness` below the surface plane (at height -thickness), and light
// refracts at both faces by Snell's law; total internal reflection at a face is counted
// as lost. Its side walls (vertical, `rim` beyond the edges of the surface's rectangle:
// the blank the face is milled into is that much wider) are glass too: light that meets
// them is reflected inside or refracted out, as in the solid.
// Fresnel partial reflection is neglected (all light that can be transmitted is).
#include <array>
#include <cstdint>
#include <variant>

#include "enum_names.hpp"

namespace freeform {

struct Mirror {};

struct Lens {
    double ior = 1.49;        // refractive index of the lens material (PMMA by default)
    double thickness = 0.01;  // metres from the surface plane to the flat back face
    // How far the glass body reaches beyond the designed face on every side (metres); the
    // light falls on the face only. < 0: "auto", the drift a ray needs inside the glass to
    // reach the receiver's far edge (lens_rim in scene/scene.hpp; docs/architecture.md §4b).
    double rim = -1;
};

using Material = std::variant<Mirror, Lens>;

inline bool is_lens(const Material& m) { return std::holds_alternative<Lens>(m); }

// What an extra mesh of a scene (its "meshes") does with the light that meets it. An
// absorber blocks it; a mirror reflects it on both sides; a refractive mesh is the
// closed, outward-oriented boundary of a solid of index `ior` in air: Snell's law at
// every crossing, total internal reflection followed (not lost), Fresnel neglected as
// for the lens. Refractive solids must not overlap or nest.
enum class MeshKind : std::uint8_t { absorber, mirror, refractive };
// The kinds a scene file names (meshes[].material); a refractive solid is written as an
// object with its index ({"refractive": ior}).
inline constexpr std::array<EnumName<MeshKind>, 2> mesh_material_names{
    {{"absorber", MeshKind::absorber}, {"mirror", MeshKind::mirror}}};

struct MeshMaterial {
    MeshKind kind = MeshKind::absorber;
    double ior = 1.49;  // refractive only

    static MeshMaterial absorber() { return {MeshKind::absorber, 1.49}; }
    static MeshMaterial mirror() { return {MeshKind::mirror, 1.49}; }
    static MeshMaterial refractive(double n) { return {MeshKind::refractive, n}; }
    bool is_mirror() const { return kind == MeshKind::mirror; }
    bool is_refractive() const { return kind == MeshKind::refractive; }
};

}  // namespace freeform
