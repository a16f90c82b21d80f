#pragma once
// What a design exports and how each smooth form's check is reported: the formats a
// scene asks for, and FormCheck (io/forms.hpp writes and judges the forms; this header
// does not bring in Open CASCADE, so the io umbrella and report_json can include it).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "../core/error.hpp"
#include "../design/cell_means.hpp"
#include "../design/options.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"

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

// The file(s) a design writes for `f`.
inline const char* export_file_name(ExportFormat f) {
    return f == ExportFormat::mesh ? "surface.obj/.stl" : f == ExportFormat::step ? "surface.step" : "surface.dat";
}

// Whether a build can write `f`.
inline bool format_available(ExportFormat f) {
#if defined(FREEFORM_WITH_OCCT)
    (void)f;
    return true;
#else
    return f != ExportFormat::step;
#endif
}

// The formats a job asks for (optimise.export_formats). "auto": STEP and the mesh where Open CASCADE is built,
// STEP first (the part that keeps the designed surface leads the summary and gives
// error_physical), else the mesh alone. Throws InputError naming the key for a format
// this build cannot write.
inline std::vector<ExportFormat> export_formats(const ExportOptions& options) {
    std::vector<ExportFormat> f = options.formats;
    if (f.empty()) {
        if (format_available(ExportFormat::step)) f.push_back(ExportFormat::step);
        f.push_back(ExportFormat::mesh);
    }
    for (const ExportFormat x : f)
        if (!format_available(x))
            throw InputError("optimise.export_formats: \"" + std::string(to_string(x)) +
                             "\" needs a build with Open CASCADE (libocct-*-dev; see README)");
    return f;
}

}  // namespace freeform::io
