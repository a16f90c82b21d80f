#pragma once
// Light sources. Each emits a deterministic, stratified set of rays aimed at the surface
// aperture; rays that could not reach the aperture are never generated.
#include <array>
#include <cstddef>
#include <cstdint>
#include <string_view>
#include <utility>
#include <variant>
#include <vector>

#include "../core/enum_names.hpp"
#include "../core/math.hpp"

namespace freeform {

// Light from a source at infinity travelling along `direction`, filling the aperture.
// `angular_radius` (degrees) is the source's apparent radius: 0 is exactly parallel
// light; the sun's disc is 0.266 (a half-angle of 4.65 mrad: at 1 m every image point is
// smeared over a disc of 4.6 mm radius). A disc of uniform radiance: directions are
// spread uniformly over the cone's solid angle (no limb darkening; see docs/scene.md).
struct CollimatedLight {
    Vec3d direction{0, 0, -1};
    double angular_radius = 0;  // degrees, in [0, max_angular_radius]
};
inline constexpr double max_angular_radius = 45.0;  // degrees; wider is no longer a distant source

// Isotropic (or profiled) point source. The intensity profile, if given, is a table of
// (angle from `axis` in degrees, relative intensity), linearly interpolated and zero
// outside the table. When `axis` is zero it points at the surface centre.
struct PointLight {
    Vec3d position{0, 0, 0.3};
    Vec3d axis{0, 0, 0};
    std::vector<std::pair<double, double>> profile;  // empty: isotropic
};

// Lambertian disk emitter (an extended source: LED die, lamp aperture).
struct DiskLight {
    Vec3d center{0, 0, 0.3};
    Vec3d normal{0, 0, -1};
    double radius = 0.005;
};

using LightShape = std::variant<CollimatedLight, PointLight, DiskLight>;

struct Light {
    LightShape shape = CollimatedLight{};
    // Ray budget: `rays` if non-zero, otherwise rays_per_cell × receiver cells.
    double rays_per_cell = 16;
    std::int64_t rays = 0;
};

// Their names in scene files (light.type), keyed by the index in LightShape.
inline constexpr std::array<EnumName<std::size_t>, 3> light_type_names{
    {{"collimated", 0}, {"point", 1}, {"disk", 2}}};
static_assert(std::variant_size_v<LightShape> == light_type_names.size());

inline std::string_view light_type_name(const LightShape& s) { return enum_name(s.index(), light_type_names); }

// Relative intensity of a profile at `deg` degrees off axis.
inline double profile_intensity(const std::vector<std::pair<double, double>>& profile, double deg) {
    if (profile.empty()) return 1.0;
    if (deg < profile.front().first || deg > profile.back().first) return 0.0;
    for (std::size_t k = 1; k < profile.size(); ++k) {
        const auto& [a0, i0] = profile[k - 1];
        const auto& [a1, i1] = profile[k];
        if (deg <= a1) {
            const double t = a1 > a0 ? (deg - a0) / (a1 - a0) : 0.0;
            return i0 + t * (i1 - i0);
        }
    }
    return profile.back().second;
}

}  // namespace freeform
