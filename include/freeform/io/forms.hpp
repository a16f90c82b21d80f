#pragma once
// The smooth exported forms of a design, written and then judged from the files
// themselves (docs/export.md): surface.step (the fitted B-spline) read back by Open
// CASCADE, surface.dat (a Hermite table of the height map's vertices) read back by our
// grid sag reader, each tessellated and traced to converged cell means as error_physical
// is (design/exported.hpp, smooth_geometry). What is judged is what the file holds, not
// what it was written from. With freeform::step this header brings in Open CASCADE's
// headers (io/step.hpp): the io umbrella leaves it out, include it where forms are written.
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
#include "form_check.hpp"
#include "sag.hpp"
#if defined(FREEFORM_WITH_OCCT)
#include "step.hpp"
#endif

namespace freeform::io {

namespace forms_detail {

// Traces a smooth form given by `at(u, v)` → (point, unit normal) over the cells of the
// exported top of `grid` (export_blank: a lens's rim too); `grid` places the rays.
template <class At>
void judge(FormCheck& fc, const Scene& scene, std::uint64_t seed, const Heightmap& grid, const ImageD* target,
           int threads, At&& at) {
#if defined(FREEFORM_WITH_EMBREE)
    const Heightmap top = export_blank(scene, grid);
    fc.tessellation = judge_subdivisions(top);
    const ExportedGeometry g = smooth_geometry(scene, top, fc.tessellation, [&](int ci, int cj, double a, double b) {
        return at(top.u_of(ci) + a * top.du(), top.v_of(cj) + b * top.dv());
    });
    fc.triangles = std::int64_t(g.mesh.triangles.size());
    if (target)
        fc.cells = exported_cell_means(exec::omp_t{threads}, scene, grid, g, target,
                                       physical_cell_mean_options(seed));
#else
    (void)fc, (void)scene, (void)seed, (void)grid, (void)target, (void)threads, (void)at;
#endif
}

}  // namespace forms_detail

namespace forms_detail {

// Writes the smooth form `format` to `file`: the grid sag from the exported top of the
// height map `grid` itself (its vertices and vertex normals), STEP from `spline`.
inline void write_form(ExportFormat format, const std::filesystem::path& file, const Scene& scene,
                       const Heightmap& grid, const BSplineSurface& spline) {
    if (format == ExportFormat::sag) return write_grid_sag(file, export_blank(scene, grid));
#if defined(FREEFORM_WITH_OCCT)
    const auto* lens = std::get_if<Lens>(&scene.surface.material);
    const double back =
        lens ? -lens->thickness : *std::min_element(spline.z.begin(), spline.z.end()) - mirror_step_thickness;
    write_step(file, spline, StepSolid{back, scene.name.empty() ? "freeform surface" : scene.name});
#else
    (void)file, (void)scene, (void)grid, (void)spline;
    throw InputError("surface.step needs a build with Open CASCADE (libocct-*-dev; see README)");
#endif
}

// Reads `file` back and judges what it holds.
inline void check_form(FormCheck& fc, const Scene& scene, std::uint64_t seed, const Heightmap& grid,
                       const ImageD* target, int threads) {
    if (fc.format == ExportFormat::sag) {
        const GridSag g = read_grid_sag(fc.file);
        return judge(fc, scene, seed, grid, target, threads, [&](double u, double v) {
            const SplineSample q = g.eval(u, v);
            return PhongVertex{{u, v, q.z}, q.normal()};
        });
    }
#if defined(FREEFORM_WITH_OCCT)
    const StepPart part = read_step(fc.file);
    fc.valid = !part.is_valid()             ? "no: BRepCheck_Analyzer finds the shape invalid"
               : part.solid_count() != 1    ? "no: " + std::to_string(part.solid_count()) + " solids"
               : !part.closed()             ? "no: the shell is open"
                                            : "yes";
    judge(fc, scene, seed, grid, target, threads, [&](double u, double v) { return part.sample_m(u, v); });
#endif
}

}  // namespace forms_detail

// Writes `format` (step or sag) of the design whose surface is `grid` and whose fitted
// spline is `spline` (used by STEP only: the sag table carries `grid`'s vertices) to `file`, reads the file back, and judges it against `target`
// (when given and the build has Embree). Throws IoError when the file cannot be written
// or read back, InputError for a format this build lacks or the mesh (written elsewhere).
inline FormCheck write_and_check_form(ExportFormat format, const std::filesystem::path& file, const Scene& scene,
                                      const Heightmap& grid, const BSplineSurface& spline, const ImageD* target,
                                      std::uint64_t seed, int threads) {
    if (format == ExportFormat::mesh)
        throw InputError("write_and_check_form: the mesh is written by io::write_obj / write_stl");
    FormCheck fc;
    fc.format = format;
    fc.file = file;
    const auto since = [](std::chrono::steady_clock::time_point t) {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
    };
    const auto t0 = std::chrono::steady_clock::now();
    forms_detail::write_form(format, file, scene, grid, spline);
    fc.write_seconds = since(t0);
    fc.bytes = std::filesystem::file_size(file);
    const auto t1 = std::chrono::steady_clock::now();
    forms_detail::check_form(fc, scene, seed, grid, target, threads);
    fc.check_seconds = since(t1);
    return fc;
}

}  // namespace freeform::io
