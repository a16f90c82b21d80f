#pragma once
// The physics of a design problem as read from a scene file (see docs/scene.md): what
// emits light, the surface to design, where the light must land and what it should look
// like. How the design is searched for (the file's "optimise" block) is not the scene's:
// design/options.hpp holds those options, and DesignJob keeps the two together.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <numbers>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "../core/enum_names.hpp"
#include "../core/material.hpp"
#include "../surface/heightmap.hpp"
#include "light.hpp"
#include "receiver.hpp"

namespace freeform {

// Analytic starting shapes, handy for tests and demos.
struct InitialParaboloid {
    double focal_length = 0.5;  // metres; h = r^2 / (4 f), lowest point at the centre
};

// Where the design starts when no heightmap or paraboloid is given: "auto" is the
// transport start for a scene with a target (flat otherwise).
enum class InitialShape { automatic, flat, transport };

struct SurfaceSpec {
    Frame frame{};
    Vec2d size{0.1, 0.1};
    int nx = 0, ny = 0;  // final mesh (vertices); 0 = "auto": chosen from the case
    double h_min = -0.005, h_max = 0.005;
    Aperture aperture = Aperture::rect;
    Material material = Mirror{};
    // Phong tessellation shape factor; 0 = flat triangles. 1/2 reproduces a quadratic
    // height field exactly from its vertices and central-difference normals (the edge
    // offset is 2α·c·t(1−t)L² against the parabola's c·t(1−t)L²): README "What gets milled".
    double phong_alpha = 0.5;
    // Radius (metres) of the ball-end mill that will cut the surface; 0: no constraint.
    // The design keeps every concave radius (seen from the front) at least this large
    // (surface/tool.hpp; docs/scene.md).
    double tool_radius = 0;
    // Initial shape: a PFM heightmap, a paraboloid, or else `initial_shape`.
    InitialShape initial_shape = InitialShape::automatic;
    std::filesystem::path initial_pfm;
    std::optional<InitialParaboloid> initial_paraboloid;
};

// How an image with fewer pixels than the receiver is brought up to it (objective/target.hpp):
// the linear reconstruction through its pixel centres, or its pixels as blocks.
enum class TargetUpsample { bilinear, box };
inline constexpr std::array<EnumName<TargetUpsample>, 2> target_upsample_names{
    {{"bilinear", TargetUpsample::bilinear}, {"box", TargetUpsample::box}}};

// How a picture whose aspect ratio differs from the receiver's is laid on it
// (objective/target.hpp, frame_to_aspect): stretched to fill it, kept whole with dark
// bars, or cropped to fill it.
enum class TargetFit { stretch, contain, cover };
inline constexpr std::array<EnumName<TargetFit>, 3> target_fit_names{
    {{"stretch", TargetFit::stretch}, {"contain", TargetFit::contain}, {"cover", TargetFit::cover}}};

struct TargetSpec {
    std::filesystem::path image;  // PNG/JPG/... or PFM, grey levels are relative irradiance
    TargetUpsample upsample = TargetUpsample::bilinear;  // an image coarser than the receiver
    TargetFit fit = TargetFit::stretch;                  // an image of another aspect ratio
    std::string text;             // or a text rendered with a TrueType font
    std::string font = "DejaVuSans-Bold";
    double margin = 0.1;  // fraction of the receiver left dark around the text
};

// An extra triangle mesh in world coordinates (needs the Embree tracer).
struct MeshSpec {
    std::filesystem::path file;
    MeshMaterial material{};  // absorber (default), mirror or refractive solid
};

enum class TracerChoice { automatic, heightfield, embree };
// Their names in scene files (trace.tracer), the command line (--tracer) and reports.
inline constexpr std::array<EnumName<TracerChoice>, 3> tracer_names{
    {{"auto", TracerChoice::automatic}, {"heightfield", TracerChoice::heightfield}, {"embree", TracerChoice::embree}}};
inline std::string_view to_string(TracerChoice t) { return enum_name(t, tracer_names); }

struct TraceSpec {
    TracerChoice tracer = TracerChoice::automatic;
    int max_depth = 8;  // surface interactions per ray before it is counted as lost
    // Fresnel losses at refractive faces (PathParams::fresnel; docs/scene.md "trace").
    bool fresnel = false;
};

struct Scene;
inline bool starts_from_transport(const Scene& scene);

struct Scene {
    Light light{};
    SurfaceSpec surface{};
    Receiver receiver{};
    std::optional<TargetSpec> target;
    std::vector<MeshSpec> meshes;
    TraceSpec trace{};
    std::filesystem::path base_dir;  // relative file names in the scene resolve here
    std::string name;                // free text for reports (scene key "name")
    std::string description;         // free text (scene key "description")
};

}  // namespace freeform

namespace freeform {

// True when the design starts from the transport surface (transport/start.hpp): the
// scene asks for it, or leaves "initial" out and has a target.
inline bool starts_from_transport(const Scene& scene) {
    const SurfaceSpec& s = scene.surface;
    if (!s.initial_pfm.empty() || s.initial_paraboloid) return false;
    return s.initial_shape == InitialShape::transport ||
           (s.initial_shape == InitialShape::automatic && scene.target.has_value());
}

// How far a lens's glass body reaches beyond its face on every side (metres; 0 for a
// mirror): Lens::rim, or for "auto" (rim < 0) the rim that keeps the light away from the
// side walls (docs/architecture.md §4b). A face that throws its light wider than itself
// tilts its edge rays outwards inside the glass; in a body no wider than the face they
// meet a side wall, which mirrors them back across the receiver (the bright cross of a
// lens whose receiver is larger than it). "auto" takes the largest drift inside the glass
// of a ray from the face's edge, at the top of the height bounds, to a corner of the
// receiver: the exit point on the back face that the back face's refraction aims at the
// receiver corner, solved by fixed point. The face's edge is its four corners, or for an
// elliptical aperture 16 points around the ellipse (its body is the rectangle around it,
// which the ellipse meets at the ends of its axes: there its rays drift into the walls as
// a rectangular face's do, and the start aimed wall strips whose light drew a square
// outline on a round lens's uniform target). A quarter more for the rays the design aims
// past the receiver's edge, rounded up to half a millimetre; 0 when no such ray drifts
// outwards (a receiver no wider than the face).
inline double lens_rim(const Scene& scene) {
    const auto* lens = std::get_if<Lens>(&scene.surface.material);
    if (!lens) return 0;
    if (lens->rim >= 0) return lens->rim;
    const SurfaceSpec& sf = scene.surface;
    const double hu = 0.5 * sf.size.x, hv = 0.5 * sf.size.y, n = lens->ior;
    const Receiver& r = scene.receiver;
    std::vector<Vec3d> edge;
    if (sf.aperture == Aperture::rect) {
        for (int k = 0; k < 4; ++k) edge.push_back({k & 1 ? hu : -hu, k & 2 ? hv : -hv, sf.h_max});
    } else {
        constexpr int points = 16;
        for (int k = 0; k < points; ++k) {
            const double a = 2 * std::numbers::pi * k / points;
            edge.push_back({hu * std::cos(a), hv * std::sin(a), sf.h_max});
        }
    }
    double drift = 0;
    for (int c = 0; c < 4; ++c) {
        const Vec3d q = sf.frame.to_local(r.frame.origin + (c & 1 ? 0.5 : -0.5) * r.size.x * r.frame.u +
                                          (c & 2 ? 0.5 : -0.5) * r.size.y * r.frame.v);
        for (const Vec3d& s : edge) {
            Vec3d e{s.x, s.y, -lens->thickness};
            for (int it = 0; it < 8; ++it) {
                const Vec3d out = normalize(q - e);
                const double gx = out.x / n, gy = out.y / n;
                const double gz = std::sqrt(std::max(1e-12, 1.0 - gx * gx - gy * gy));
                const double depth = (s.z + lens->thickness) / gz;
                e = {s.x + gx * depth, s.y + gy * depth, -lens->thickness};
            }
            drift = std::max({drift, std::abs(e.x) - hu, std::abs(e.y) - hv});
        }
    }
    if (!(drift > 1e-9)) return 0;
    const double step = 0.0005;
    return step * std::ceil(1.25 * drift / step - 1e-9);
}

// Whether every point light can leave the surface from lies behind the receiver's plane
// (on the side its normal points away from), so that no light can reach its front: the
// corners of the surface's body (its rectangle, a lens's rim included, from the top of
// the height bounds down to the lowest point light leaves from: the bottom of the bounds
// for a mirror, the back face for a lens). Extra meshes ("meshes") could fold light
// round to the front, so the caller asks only where there are none.
inline bool surface_behind_receiver(const Scene& scene) {
    const SurfaceSpec& sf = scene.surface;
    const auto* lens = std::get_if<Lens>(&sf.material);
    const double lens_body_rim = lens_rim(scene);
    const double rim = std::isfinite(lens_body_rim) ? lens_body_rim : 0.0;
    const double hu = 0.5 * sf.size.x + rim, hv = 0.5 * sf.size.y + rim;
    const double low = lens ? std::min(sf.h_min, -lens->thickness) : sf.h_min;
    const Frame& r = scene.receiver.frame;
    for (const double u : {-hu, hu})
        for (const double v : {-hv, hv})
            for (const double w : {low, sf.h_max})
                if (dot(r.w, sf.frame.to_world({u, v, w}) - r.origin) > 0) return false;
    return true;
}

}  // namespace freeform
