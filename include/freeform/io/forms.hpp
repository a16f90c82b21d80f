#pragma once
// The smooth exported forms of a design, written and then judged from the files
// themselves (docs/export.md): surface.step read back by Open CASCADE, surface.dat read
// back by our grid sag reader, each tessellated and traced to converged cell means as
// error_physical is (design/exported.hpp, smooth_geometry). What is judged is what the
// file holds, not the spline it was written from.
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <variant>

#include "../design/pipeline.hpp"
#include "../scene/scene.hpp"
#include "../surface/bspline.hpp"
#include "sag.hpp"
#if defined(FREEFORM_WITH_OCCT)
#include "step.hpp"
#endif

namespace freeform::io {

// Facet pairs per grid cell and direction for tracing a smooth form: its vertex normals
// are interpolated, so the figure settles fast (docs/export.md: k = 2 and 4 differ by
// 0.0004 on a photograph); at most 6 million triangles.
inline int judge_subdivisions(const Heightmap& grid) {
    const double cells = double(grid.nx() - 1) * double(grid.ny() - 1);
    return std::clamp(int(std::floor(std::sqrt(6.0e6 / (2.0 * cells)))), 1, 4);
}

// How far under the lowest point of a mirror's face its STEP solid's flat back lies.
inline constexpr double mirror_step_thickness = 0.005;

// One smooth form written and judged.
struct FormCheck {
    ExportFormat format = ExportFormat::step;
    std::filesystem::path file;
    std::uintmax_t bytes = 0;
    double write_seconds = 0;       // writing the file
    double check_seconds = 0;       // reading it back, tessellating and tracing it
    int tessellation = 0;           // k of the traced tessellation
    std::int64_t triangles = 0;     // of the traced tessellation
    std::optional<CellMeans> cells;  // empty without Embree or without a target
    std::string valid = "yes";      // the file's own check (STEP: BRepCheck_Analyzer)
};

// Whether a build can write `f`.
inline bool format_available(ExportFormat f) {
#if defined(FREEFORM_WITH_OCCT)
    (void)f;
    return true;
#else
    return f != ExportFormat::step;
#endif
}

// The formats a scene asks for ("auto": the mesh, and STEP where Open CASCADE is built).
// Throws InputError naming the key for a format this build cannot write.
inline std::vector<ExportFormat> export_formats(const Scene& scene) {
    std::vector<ExportFormat> f = scene.optimise.export_formats;
    if (f.empty()) {
        f.push_back(ExportFormat::mesh);
        if (format_available(ExportFormat::step)) f.push_back(ExportFormat::step);
    }
    for (const ExportFormat x : f)
        if (!format_available(x))
            throw InputError("optimise.export_formats: \"" + std::string(to_string(x)) +
                             "\" needs a build with Open CASCADE (libocct-*-dev; see README)");
    return f;
}

namespace forms_detail {

// Traces a smooth form given by `at(u, v)` → (point, unit normal) over `grid`'s cells.
template <class At>
void judge(FormCheck& fc, const Scene& scene, const Heightmap& grid, const ImageD* target, int threads, At&& at) {
#if defined(FREEFORM_WITH_EMBREE)
    fc.tessellation = judge_subdivisions(grid);
    const ExportedGeometry g = smooth_geometry(scene, grid, fc.tessellation, [&](int ci, int cj, double a, double b) {
        return at(grid.u_of(ci) + a * grid.du(), grid.v_of(cj) + b * grid.dv());
    });
    fc.triangles = std::int64_t(g.mesh.triangles.size());
    if (target)
        fc.cells = exported_cell_means(exec::omp_t{threads}, scene, grid, g, target,
                                       physical_cell_mean_options(scene.optimise.seed));
#else
    (void)fc, (void)scene, (void)grid, (void)target, (void)threads, (void)at;
#endif
}

}  // namespace forms_detail

// Writes `format` (step or sag) of the design whose surface is `grid` and whose fitted
// spline is `spline` to `file`, reads the file back, and judges it against `target`
// (when given and the build has Embree). Throws IoError when the file cannot be written
// or read back, InputError for a format this build lacks or the mesh (written elsewhere).
inline FormCheck write_and_check_form(ExportFormat format, const std::filesystem::path& file, const Scene& scene,
                                      const Heightmap& grid, const BSplineSurface& spline, const ImageD* target,
                                      int threads) {
    FormCheck fc;
    fc.format = format;
    fc.file = file;
    const auto t0 = std::chrono::steady_clock::now();
    const auto since = [](std::chrono::steady_clock::time_point t) {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
    };
    if (format == ExportFormat::sag) {
        write_grid_sag(file, spline);
        fc.write_seconds = since(t0);
        fc.bytes = std::filesystem::file_size(file);
        const auto t1 = std::chrono::steady_clock::now();
        const GridSag g = read_grid_sag(file);
        forms_detail::judge(fc, scene, grid, target, threads, [&](double u, double v) {
            const SplineSample q = g.eval(u, v);
            return PhongVertex{{u, v, q.z}, q.normal()};
        });
        fc.check_seconds = since(t1);
        return fc;
    }
    if (format == ExportFormat::step) {
#if defined(FREEFORM_WITH_OCCT)
        double back = 0;
        if (const auto* lens = std::get_if<Lens>(&scene.surface.material))
            back = -lens->thickness;
        else
            back = *std::min_element(spline.z.begin(), spline.z.end()) - mirror_step_thickness;
        // Open CASCADE writes in place: write beside the file and rename, so that a failed
        // write never leaves a partial part under the file's name.
        std::filesystem::path partial = file;
        partial += ".partial";
        try {
            write_step(partial, spline, StepSolid{back, scene.name.empty() ? "freeform surface" : scene.name});
            std::filesystem::rename(partial, file);
        } catch (...) {
            std::error_code ignored;
            std::filesystem::remove(partial, ignored);
            throw;
        }
        fc.write_seconds = since(t0);
        fc.bytes = std::filesystem::file_size(file);
        const auto t1 = std::chrono::steady_clock::now();
        const StepPart part = read_step(file);
        fc.valid = !part.is_valid() ? "no: BRepCheck_Analyzer finds the shape invalid"
                   : part.solid_count() != 1 ? "no: " + std::to_string(part.solid_count()) + " solids"
                   : !part.closed() ? "no: the shell is open"
                                    : "yes";
        forms_detail::judge(fc, scene, grid, target, threads, [&](double u, double v) {
            return PhongVertex{part.point_m(u, v), part.normal(u, v)};
        });
        fc.check_seconds = since(t1);
        return fc;
#else
        throw InputError("surface.step needs a build with Open CASCADE (libocct-*-dev; see README)");
#endif
    }
    throw InputError("write_and_check_form: the mesh is written by io::write_obj / write_stl");
}

}  // namespace freeform::io
