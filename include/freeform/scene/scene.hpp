#pragma once
// A complete design problem as read from a scene file (see docs/scene.md): what emits
// light, the surface to design, where the light must land and what it should look like.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
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

struct TargetSpec {
    std::filesystem::path image;  // PNG/JPG/... or PFM, grey levels are relative irradiance
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

// One level of the multi-level schedule (design/designer.hpp).
struct LevelPlan {
    int mesh_x = 0, mesh_y = 0;        // surface vertices
    int resolution_x = 0, resolution_y = 0;  // receiver pixels
    std::vector<int> kernel_supports;  // one annealing stage per support, large to small
    double time_share = 1.0;           // fraction of the time budget
    std::int64_t iterations = 0;       // iteration budget of the level (split over its stages)
};

// How a move is judged: incremental (only the rays the move can reach are retraced,
// docs/architecture.md §4) or full (every ray, for comparisons; the same trajectory).
enum class EvaluationMode { incremental, full };
// The kernels moves are made of: the bank of shapes a bandit chooses from, or one round
// kernel (the reference's single-kernel baseline).
enum class KernelShapes { bank, isotropic };
// The bandit that picks a kernel shape (propose/bandit.hpp), in order of sophistication.
enum class BanditKind { uniform, history, ucb1, discounted_ucb };

// Their names in scene files and reports: the one mapping between the strings and the
// values (io/scene_json.hpp reads and writes with it).
inline constexpr std::array<EnumName<EvaluationMode>, 2> evaluation_names{
    {{"incremental", EvaluationMode::incremental}, {"full", EvaluationMode::full}}};
inline constexpr std::array<EnumName<KernelShapes>, 2> kernel_shape_names{
    {{"bank", KernelShapes::bank}, {"isotropic", KernelShapes::isotropic}}};
inline constexpr std::array<EnumName<BanditKind>, 4> bandit_kind_names{{{"uniform", BanditKind::uniform},
                                                                        {"history", BanditKind::history},
                                                                        {"ucb1", BanditKind::ucb1},
                                                                        {"discounted-ucb", BanditKind::discounted_ucb}}};
// The forms a design's surface is exported in (docs/export.md): the milled facets
// (surface.obj/.stl), the smooth B-spline part (surface.step, builds with Open CASCADE)
// and the grid sag table of the height map's vertices (surface.dat).
enum class ExportFormat { mesh, step, sag };
inline constexpr std::array<EnumName<ExportFormat>, 3> export_format_names{
    {{"mesh", ExportFormat::mesh}, {"step", ExportFormat::step}, {"sag", ExportFormat::sag}}};
inline std::string_view to_string(ExportFormat f) { return enum_name(f, export_format_names); }
inline std::string_view to_string(EvaluationMode e) { return enum_name(e, evaluation_names); }
inline std::string_view to_string(KernelShapes k) { return enum_name(k, kernel_shape_names); }
inline std::string_view to_string(BanditKind b) { return enum_name(b, bandit_kind_names); }

// Optimiser settings (the scene's "optimise" block; docs/scene.md lists each key).
// Zero / empty fields mean "derive a default from the case".
struct OptimiseSpec {
    double time_budget = 60;  // seconds for the whole design
    std::uint64_t seed = 1;
    std::int64_t max_iterations = 0;  // over all levels; 0: the plan's budgets
    double target_error = 0;          // stop when the objective reaches it; 0: off
    int threads = 0;                  // 0: all cores
    int speculative = 0;              // proposals evaluated at once; 0: one per thread
    std::vector<LevelPlan> levels;    // empty: planned from the case
    bool multilevel = true;           // false: only the final level
    int start_level = -1;             // first planned level to run; -1: decided from the start's error
    double coarse_rays_per_cell = 4;  // rays per receiver cell on levels before the last; 0: the light's
    double min_rays_per_mesh_cell = 32;  // the last level: at least this many rays per cell of the
                                         // final mesh (design/designer.hpp, fitting_rays_per_cell); 0: off
    bool held_out_checks = true;      // judge stages with held-out rays (design/held_out.hpp)

    // Objective.
    double sobel_weight = 0.1;
    double energy_threshold = 0.95;
    double lost_light_weight = 1.0;
    double height_bound_weight = 0;
    double valley_weight = 0;
    double valley_min_angle = 170;  // degrees
    double smoothness_weight = 0;

    // Proposals.
    EvaluationMode evaluation = EvaluationMode::incremental;
    KernelShapes kernel_shapes = KernelShapes::bank;
    BanditKind bandit = BanditKind::history;
    int bandit_sync = 64;
    std::int64_t preprocess_iterations = 1000;  // history bandit: trial run with all shapes (0: none)
    int preprocess_keep = 4;                    // ... after which the best shapes are kept
    bool error_guided = false;
    bool single_vertex = false;
    double max_shift_cells = 4.0;
    double min_shift_cells = 0.25;

    // Annealing schedule.
    double initial_acceptance = 0.03;  // of uphill moves at the start of each stage
    double refine_initial_acceptance = 0.001;  // ... at most, after a transport start
    double refine_max_shift_cells = 1.0;       // largest light shift of a move after a transport start
    double initial_temperature_scale = 1;  // multiplies every stage's calibrated initial temperature
    double cooling = 0.95;
    int temperature_steps = 120;      // cooling steps per stage
    double reheat_factor = 0.5;
    double patience_fraction = 0.08;  // re-heat after this fraction of a stage without a new best

    // Output.
    int smooth_iterations = 0;        // post-processing passes of smooth_heights
    int export_subdivisions = 0;      // tessellation level k of the exported mesh; 0 = "auto"
    double export_tolerance = 0.05;   // "auto": light of a facet lands within this many receiver
                                      // cells of where the simulated patch sends it
    std::int64_t export_max_triangles = 2'000'000;  // "auto": k no larger than this allows
    // What a design writes, the first leading its summary; empty: "auto" (STEP and the
    // mesh in builds with Open CASCADE, the mesh alone otherwise; io/forms.hpp).
    std::vector<ExportFormat> export_formats;
    std::int64_t progress_every = 2000;
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
    OptimiseSpec optimise{};
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
// of a ray from a corner of the face, at the top of the height bounds, to a corner of the
// receiver: the exit point on the back face that the back face's refraction aims at the
// receiver corner, solved by fixed point. A quarter more for the rays the design aims
// past the receiver's edge, rounded up to half a millimetre; 0 when no such ray drifts
// outwards (a receiver no wider than the face) and for an elliptical aperture (whose body
// is the rectangle around it).
inline double lens_rim(const Scene& scene) {
    const auto* lens = std::get_if<Lens>(&scene.surface.material);
    if (!lens) return 0;
    if (lens->rim >= 0) return lens->rim;
    const SurfaceSpec& sf = scene.surface;
    if (sf.aperture != Aperture::rect) return 0;
    const double hu = 0.5 * sf.size.x, hv = 0.5 * sf.size.y, n = lens->ior;
    const Receiver& r = scene.receiver;
    double drift = 0;
    for (int c = 0; c < 4; ++c) {
        const Vec3d q = sf.frame.to_local(r.frame.origin + (c & 1 ? 0.5 : -0.5) * r.size.x * r.frame.u +
                                          (c & 2 ? 0.5 : -0.5) * r.size.y * r.frame.v);
        for (int k = 0; k < 4; ++k) {
            const Vec3d s{k & 1 ? hu : -hu, k & 2 ? hv : -hv, sf.h_max};
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

}  // namespace freeform
