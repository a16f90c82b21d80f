#pragma once
// A complete design problem as read from a scene file (see docs/scene.md): what emits
// light, the surface to design, where the light must land and what it should look like.
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "../surface/heightmap.hpp"
#include "light.hpp"
#include "material.hpp"
#include "receiver.hpp"

namespace freeform {

// Analytic starting shapes, handy for tests and demos.
struct InitialParaboloid {
    double focal_length = 0.5;  // metres; h = r^2 / (4 f), lowest point at the centre
};

struct SurfaceSpec {
    Frame frame{};
    Vec2d size{0.1, 0.1};
    int nx = 101, ny = 101;  // final mesh (vertices); coarser levels are derived from it
    double h_min = -0.005, h_max = 0.005;
    Aperture aperture = Aperture::rect;
    Material material = Mirror{};
    double phong_alpha = 0.75;  // Phong tessellation shape factor; 0 = flat triangles
    // Initial shape: flat (empty path and no paraboloid), a PFM heightmap, or a paraboloid.
    std::filesystem::path initial_pfm;
    std::optional<InitialParaboloid> initial_paraboloid;
};

struct TargetSpec {
    std::filesystem::path image;  // PNG/JPG/... or PFM, grey levels are relative irradiance
    std::string text;             // or a text rendered with a TrueType font
    std::string font = "DejaVuSans-Bold";
    double margin = 0.1;  // fraction of the receiver left dark around the text
};

// An extra triangle mesh in world coordinates (needs the Embree tracer).
struct MeshSpec {
    std::filesystem::path file;
    bool mirror = false;  // mirror, or an absorber that blocks light
};

enum class TracerChoice { automatic, heightfield, embree };

struct TraceSpec {
    TracerChoice tracer = TracerChoice::automatic;
    int max_depth = 8;  // surface interactions per ray before it is counted as lost
};

// Optimiser settings; zero / empty fields mean "derive a default from the case".
struct OptimiseSpec {
    double time_budget = 60;  // seconds
    std::uint64_t seed = 1;
    std::int64_t max_iterations = 0;
    double target_error = 0;
    int threads = 0;
};

struct Scene {
    Light light{};
    SurfaceSpec surface{};
    Receiver receiver{};
    std::optional<TargetSpec> target;
    std::vector<MeshSpec> meshes;
    TraceSpec trace{};
    OptimiseSpec optimise{};
    std::filesystem::path base_dir;  // relative file names in the scene resolve here
    std::string name;                // free text for reports (scene key "name")
    std::string description;         // free text (scene key "description")
};

}  // namespace freeform
