#pragma once
// What a design is asked to do besides the scene: the optimiser's options. The scene
// (scene/scene.hpp) is the physics: light, surface, receiver, target. The options are
// the design's: its budget and seed, its levels, and the options each module owns,
// composed here: the objective's weights (objective/), the proposals' (propose/), the
// annealing schedule's (anneal/) and the export's (below). A scene file holds both: its
// "optimise" block is read into DesignOptions, one key per field (io/scene_json.hpp;
// docs/scene.md lists each key), and DesignJob keeps them together.
// Zero / empty fields mean "derive a default from the case".
#include <array>
#include <cstdint>
#include <string_view>
#include <vector>

#include "../anneal/schedule.hpp"
#include "../core/enum_names.hpp"
#include "../objective/objective.hpp"
#include "../objective/penalty.hpp"
#include "../propose/options.hpp"
#include "../scene/scene.hpp"

namespace freeform {

// One level of the multi-level schedule (design/designer.hpp).
struct LevelPlan {
    int mesh_x = 0, mesh_y = 0;              // surface vertices
    int resolution_x = 0, resolution_y = 0;  // receiver pixels
    std::vector<int> kernel_supports;        // one annealing stage per support, large to small
    double time_share = 1.0;                 // fraction of the time budget
    std::int64_t iterations = 0;             // iteration budget of the level (split over its stages)
};

// How a move is judged: incremental (only the rays the move can reach are retraced,
// docs/architecture.md §4) or full (every ray, for comparisons; the same trajectory).
enum class EvaluationMode { incremental, full };
inline constexpr std::array<EnumName<EvaluationMode>, 2> evaluation_names{
    {{"incremental", EvaluationMode::incremental}, {"full", EvaluationMode::full}}};
inline std::string_view to_string(EvaluationMode e) { return enum_name(e, evaluation_names); }

// Where a design's moves are judged (docs/cuda.md): on the CPU, or in speculative
// windows on a CUDA device that the program running the design offers (DesignSetup::cuda,
// design/device.hpp; the command line does in a build with CUDA). "auto": the device when
// one is offered and usable, the CPU otherwise. The design is the same bit for bit on
// either at fixed iterations; a timed design differs only in how many iterations fit.
enum class Device { cpu, cuda, automatic };
inline constexpr std::array<EnumName<Device>, 3> device_names{
    {{"cpu", Device::cpu}, {"cuda", Device::cuda}, {"auto", Device::automatic}}};
inline std::string_view to_string(Device d) { return enum_name(d, device_names); }

// The forms a design's surface is exported in (docs/export.md): the milled facets
// (surface.obj/.stl), the smooth B-spline part (surface.step, builds with Open CASCADE)
// and the grid sag table of the height map's vertices (surface.dat).
enum class ExportFormat { mesh, step, sag };
inline constexpr std::array<EnumName<ExportFormat>, 3> export_format_names{
    {{"mesh", ExportFormat::mesh}, {"step", ExportFormat::step}, {"sag", ExportFormat::sag}}};
inline std::string_view to_string(ExportFormat f) { return enum_name(f, export_format_names); }

// The spline the STEP part carries (design/pipeline.hpp, step_spline; docs/export.md):
// "auto" the Hermite one while it stays under about 50 MB, "hermite" the C¹ surface
// through the vertices and vertex normals (the grid sag table's), "least_squares" the C²
// fit of the Phong surface, one knot per grid line.
enum class SplineForm { automatic, hermite, least_squares };
inline constexpr std::array<EnumName<SplineForm>, 3> spline_form_names{{{"auto", SplineForm::automatic},
                                                                         {"hermite", SplineForm::hermite},
                                                                         {"least_squares", SplineForm::least_squares}}};

// The exported part (design/fabrication.hpp, io/forms.hpp).
struct ExportOptions {
    int subdivisions = 0;     // tessellation level k of the exported mesh; 0 = "auto"
    double tolerance = 0.05;  // "auto": light of a facet lands within this many receiver
                              // cells of where the simulated patch sends it
    std::int64_t max_triangles = 2'000'000;  // "auto": k no larger than this allows
    // What a design writes, the first leading its summary; empty: "auto" (STEP and the
    // mesh in builds with Open CASCADE, the mesh alone otherwise; io/forms.hpp).
    std::vector<ExportFormat> formats;
    SplineForm spline = SplineForm::automatic;  // the STEP part's spline
};

struct DesignOptions {
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
    EvaluationMode evaluation = EvaluationMode::incremental;
    // "cpu" by default until a device has measured the GPU path (docs/cuda.md, status).
    Device device = Device::cpu;
    std::int64_t progress_every = 2000;  // iterations between progress reports

    ObjectiveWeights objective{};  // objective/objective.hpp
    PenaltyWeights penalties{};    // objective/penalty.hpp
    ProposalOptions proposals{};   // propose/options.hpp
    ScheduleOptions schedule{};    // anneal/schedule.hpp

    int smooth_iterations = 0;  // post-processing passes of smooth_heights
    // Deliver the start instead of the annealed surface when the start's designed cell
    // means are lower (finish_design, design/pipeline.hpp; docs/measures.md, "Keeping the
    // start"). Costs one converged trace of the start after the budget.
    bool keep_better_start = true;
    ExportOptions exports{};
};

// A scene and the options to design it with: what a scene file holds (io::load_job).
struct DesignJob {
    Scene scene;
    DesignOptions options;
};

}  // namespace freeform
