#pragma once
// Shared pieces of the study driver (study_run): loading a case with JSON merge patches,
// the final evaluation every method is judged by, and the convergence trace.
//
// A run involves two scenes:
//   - the case: the scene file with the case's own patch (stress cases such as a grazing
//     light are patches of a public scene). Every method is judged on it: final error and
//     energy come from one full render at the case's receiver resolution, with the case's
//     light (rays per cell) and the case's seed, whatever the method used while running.
//   - the run scene: the case with the method's patch on top (fewer rays, flat triangles,
//     optimiser settings, ...). It is what the method optimises.
// The designed surface is judged as the method modelled it: its own mesh and its own Phong
// shape factor (a design made with flat triangles is fabricated with flat triangles).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include <freeform/design/designer.hpp>
#include <freeform/design/fabrication.hpp>
#include <freeform/io/report_json.hpp>
#include <freeform/io.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/target.hpp>
#include <freeform/objective/image_terms.hpp>
#include <freeform/objective/objective.hpp>
#include <freeform/objective/target.hpp>
#include <freeform/io/scene_json.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>
#if defined(FREEFORM_WITH_EMBREE)
#include <freeform/design/exported.hpp>
#include <freeform/trace/embree.hpp>
#endif

namespace study {

using namespace freeform;
using json = nlohmann::json;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

inline double seconds_since(Clock::time_point start) {
    return std::chrono::duration<double>(Clock::now() - start).count();
}

// Parses a JSON text given on the command line; names the option on error.
inline json parse_json_option(const std::string& text, const std::string& option) {
    if (text.empty()) return json::object();
    try {
        json j = json::parse(text);
        if (!j.is_object()) throw InputError(option + ": expected a JSON object, got " + text);
        return j;
    } catch (const json::exception& e) {
        throw InputError(option + ": invalid JSON (" + std::string(e.what()) + "): " + text);
    }
}

// A scene file with RFC 7396 merge patches applied in order, then parsed and checked like
// io::load_job does (relative file names resolve against the file's directory).
inline DesignJob load_patched_job(const fs::path& file, const std::vector<json>& patches) {
    const std::string text = io::read_file_bytes(file);
    json j;
    try {
        j = json::parse(text, nullptr, /*allow_exceptions=*/true, /*ignore_comments=*/true);
    } catch (const json::exception& e) {
        throw InputError(file.string() + ": invalid JSON: " + e.what());
    }
    for (const json& p : patches) j.merge_patch(p);
    try {
        DesignJob job = job_from_json(j, fs::absolute(file).parent_path());
        io::check_scene_files(job.scene);
        return job;
    } catch (const IoError& e) {
        throw IoError(file.string() + " (patched): " + e.what());
    } catch (const InputError& e) {
        throw InputError(file.string() + " (patched): " + e.what());
    }
}

// The final mesh the designer would end with for this scene (the scene's, or "auto").
inline std::pair<int, int> final_mesh_of(const DesignJob& job) { return final_mesh(job.scene, job.options); }

inline ImageD target_image(const Target& t) {
    ImageD img(t.height, t.width);
    for (int y = 0; y < t.height; ++y)
        for (int x = 0; x < t.width; ++x) img(y, x) = from_fixed(t.cells[std::size_t(y) * t.width + x]);
    return img;
}

// One full render of a surface judged against a case.
struct Evaluation {
    double error = 0, energy = 0, objective = 0, sobel = 0;
    double seconds = 0;
    std::int64_t rays = 0;
    Histogram histogram;
    Target target;
};

// Renders `surface` (with Phong shape factor `phong_alpha`) in the case `judge`: its light
// scaled by `ray_factor`, its receiver, its target, rays jittered with `seed`. The
// objective uses the case's Sobel weight and energy threshold, so it is the quantity our
// method minimises (image error, Sobel term, energy threshold and lost-light terms),
// comparable across methods.
template <class TracerFactory>
Evaluation evaluate_with(const DesignJob& judge_job, const Heightmap& surface, double phong_alpha,
                         const ImageD& target_image, std::uint64_t seed, int threads, double ray_factor,
                         TracerFactory&& make_tracer) {
    const Scene& judge = judge_job.scene;
    Light light = judge.light;
    if (light.rays > 0) light.rays = std::max<std::int64_t>(1, std::llround(double(light.rays) * ray_factor));
    else light.rays_per_cell *= ray_factor;
    const RaySet rays = generate_rays(light, surface, judge.receiver, seed);
    Scene s = judge;
    s.surface.phong_alpha = phong_alpha;
    const PathParams pp = make_path_params(s);
    Evaluation e;
    e.histogram = Histogram(judge.receiver.width, judge.receiver.height);
    TraceTotals totals;
    const auto start = Clock::now();
    {
        const auto tracer = make_tracer(surface, rays, pp);
        tracer.trace_all(exec::omp_t{threads}, e.histogram, totals);
    }
    e.seconds = seconds_since(start);
    e.rays = rays.size();
    e.target = make_target(target_image, judge.receiver.width, judge.receiver.height, rays.total);
    ImageState state(e.target);
    state.reset(e.histogram);
    const ObjectiveValue v = combine(state.sums(), rays.total, 0.0,
                                     judge_job.options.objective);
    e.error = v.error;
    e.energy = totals.energy();
    e.objective = v.total;
    e.sobel = v.sobel;
    return e;
}

inline Evaluation evaluate(const DesignJob& judge, const Heightmap& surface, double phong_alpha, const ImageD& target_image,
                           std::uint64_t seed, int threads, double ray_factor = 1.0) {
    return evaluate_with(judge, surface, phong_alpha, target_image, seed, threads, ray_factor,
                         [](const Heightmap& h, const RaySet& r, const PathParams& p) {
                             return HeightfieldTracer(h, r, p);
                         });
}

#if defined(FREEFORM_WITH_EMBREE)
inline Evaluation evaluate_embree(const DesignJob& judge, const Heightmap& surface, double phong_alpha,
                                  const ImageD& target_image, std::uint64_t seed, int threads) {
    return evaluate_with(judge, surface, phong_alpha, target_image, seed, threads, 1.0,
                         [](const Heightmap& h, const RaySet& r, const PathParams& p) {
                             return EmbreeTracer(h, r, p);
                         });
}
#endif

// One sample of a run's progress. `level` is the multi-level index (the last level is
// levels - 1); methods that always work at the case's resolution report level 0 of 1.
// For the generic optimisers error/energy/objective are those of the best point so far.
struct TracePoint {
    double seconds = 0;
    std::int64_t iterations = 0;
    int level = 0;
    double error = 0, energy = 0, objective = 0;
};

inline json trace_json(const std::vector<TracePoint>& trace, int levels, std::size_t max_points = 600) {
    json out = json::object();
    out["levels"] = levels;
    out["columns"] = json::array({"seconds", "iterations", "level", "error", "energy", "objective"});
    json rows = json::array();
    // Thin long traces evenly, keeping the first and last samples.
    const std::size_t n = trace.size();
    const std::size_t step = n > max_points ? (n + max_points - 1) / max_points : 1;
    for (std::size_t k = 0; k < n; ++k) {
        if (k % step != 0 && k + 1 != n) continue;
        const TracePoint& p = trace[k];
        rows.push_back(json::array({p.seconds, p.iterations, p.level, p.error, p.energy, p.objective}));
    }
    out["rows"] = rows;
    return out;
}

}  // namespace study
