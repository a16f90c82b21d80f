#pragma once
// A run's result folder, as `freeform design` writes it (the Python module's
// Design.write is the same call), and the metrics.json of a render. Every file of a
// design is staged and moved into place together, metrics.json last
// (io/staged_output.hpp). With freeform::step this header brings in Open CASCADE's
// headers (through io/forms.hpp): the io umbrella leaves it out, include it where a
// design's files are written.
#include <algorithm>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "../core/fixed_point.hpp"
#include "../core/histogram.hpp"
#include "../design/cell_means.hpp"
#include "../design/pipeline.hpp"
#include "../design/render.hpp"
#include "../objective/target.hpp"
#include "scene_json.hpp"
#include "../scene/scene.hpp"
#include "../trace/select.hpp"
#include "file.hpp"
#include "form_check.hpp"
#include "forms.hpp"
#include "heightmap.hpp"
#include "image.hpp"
#include "mesh.hpp"
#include "pfm.hpp"
#include "report_json.hpp"
#include "staged_output.hpp"

namespace freeform::io {

// A target's cells as an image, row 0 the receiver's first row (as Histogram::to_image).
inline ImageD target_image_of(const Target& t) {
    ImageD img(t.height, t.width);
    for (int y = 0; y < t.height; ++y)
        for (int x = 0; x < t.width; ++x) img(y, x) = from_fixed(t.cells[std::size_t(y) * t.width + x]);
    return img;
}

// An image of the receiver's cells as the PNGs show it: with square pixels on the
// receiver, so that a picture keeps its shape where the receiver's own pixels are not
// square (200 x 200 of them on a 0.3 x 0.2 m receiver are shown 300 x 200). The axis
// with the longer pitch is resampled up by area (resample_area); within 1 % nothing is
// changed. The PFMs keep the receiver's own cells.
inline ImageD shown_square(const ImageD& img, const Receiver& r) {
    const double ratio = r.pitch().x / r.pitch().y;  // pixel width / height
    if (std::abs(ratio - 1.0) <= 0.01 || img.size() == 0) return img;
    const auto longer = [](Eigen::Index n, double f) {
        return int(std::clamp<double>(std::round(double(n) * f), 1, 16384));
    };
    if (ratio > 1) return resample_area(img, longer(img.cols(), ratio), int(img.rows()));
    return resample_area(img, int(img.cols()), longer(img.rows(), 1.0 / ratio));
}

// target | result | difference (blue: too little light, red: too much), same exposure.
inline RgbImage comparison_image(const ImageD& result, const ImageD& target) {
    const double peak = std::max(target.maxCoeff(), 1e-300);
    const ImageF t = (target / peak).min(1.0).cast<float>();
    const ImageF r = (result / peak).min(1.0).cast<float>();
    const ImageD diff = result - target;
    return hconcat({grey_to_rgb(t), grey_to_rgb(r), diverging(diff, peak)});
}

inline void write_json(const std::filesystem::path& file, const nlohmann::json& j) {
    write_file_atomically(file, j.dump(2) + "\n");
}

// What a design's images (irradiance.pfm/.png, target.png, comparison.png) show: the
// cell means of the form that leads (optimise.export_formats), else of the mesh, else
// (no Embree) the design's own irradiance against its target.
struct DesignImages {
    ImageD irradiance;
    ImageD target;
    std::string what;  // metrics.json's export.images_show
};

// A design's files in `out` (io/staged_output.hpp: a run killed while writing leaves no
// metrics.json beside a partial result, and a failed write leaves the previous results
// as they were). `m` comes in as io::design_metrics_json(d) with the caller's own keys
// (command, scene) and goes out as the metrics.json written: the smooth forms
// (surface.step, surface.dat) are written first, read back from the staging folder and
// judged, and their figures go into export.forms (the leading form's into
// error_physical). `formats`: io::export_formats(d.options.exports). `phase` hears each long step.
inline DesignImages write_design_outputs(const std::filesystem::path& out, nlohmann::json& m, const CompletedDesign& d,
                                         const ImageD& target, const std::vector<ExportFormat>& formats,
                                         const std::function<void(const std::string&)>& phase = {}) {
    StagedOutput staged(out);
    const TriangleMesh& fab = d.exported.fabrication.mesh;
    std::optional<CellMeans> shown;
    std::string shown_what = "the design's own irradiance (a build without Embree)";
    for (const ExportFormat format : formats) {
        if (format == ExportFormat::mesh) {
            staged.write("surface.obj", [&](const std::filesystem::path& f) { write_obj(f, fab); });
            staged.write("surface.stl", [&](const std::filesystem::path& f) { write_stl(f, fab); });
            continue;
        }
        const char* name = export_file_name(format);
        if (phase) phase(std::string("writing ") + name + ", reading it back and tracing it");
        staged.write(name, [&](const std::filesystem::path& f) {
            FormCheck fc = write_and_check_form(format, f, d.scene, d.result.surface, d.exported.spline, &target,
                                                d.options.seed, d.options.threads);
            m["export"]["forms"][std::string(to_string(format))] = form_json(fc);
            if (format == formats.front() && fc.cells) {
                // The form the scene exports first is the part judged: error_physical is its figure.
                m["error_physical"] = fc.cells->error;
                m["energy_physical"] = fc.cells->totals.energy();
                m["error_physical_form"] = std::string(to_string(format));
                shown = std::move(fc.cells);
                shown_what = std::string("the cell means of ") + name + ", read back and traced";
            }
        });
    }
    if (!shown && d.exported.cells) {
        shown = d.exported.cells;
        shown_what = "the cell means of surface.obj, traced as flat triangles";
    }
    DesignImages images{shown ? shown->histogram.to_image() : d.fitted.histogram.to_image(),
                        shown ? target_image_of(shown->target) : target_image_of(d.fitted.target), shown_what};
    const ImageD& irradiance = images.irradiance;
    const ImageD& target_img = images.target;
    const ImageD irradiance_shown = shown_square(irradiance, d.scene.receiver);
    const ImageD target_shown = shown_square(target_img, d.scene.receiver);
    staged.write("convergence.csv",
                 [&](const std::filesystem::path& f) { write_file_atomically(f, convergence_csv(d.result)); });
    staged.write("heightmap.pfm", [&](const std::filesystem::path& f) { write_heightmap(f, d.result.surface); });
    staged.write("irradiance.pfm", [&](const std::filesystem::path& f) { write_pfm(f, irradiance.cast<float>()); });
    staged.write("irradiance.png", [&](const std::filesystem::path& f) { write_png(f, tone_map(irradiance_shown)); });
    staged.write("target.png", [&](const std::filesystem::path& f) { write_png(f, tone_map(target_shown)); });
    staged.write("comparison.png", [&](const std::filesystem::path& f) {
        write_png(f, comparison_image(irradiance_shown, target_shown));
    });
    nlohmann::json formats_json = nlohmann::json::array(), files_json = nlohmann::json::array();
    for (const ExportFormat format : formats) {
        formats_json.push_back(std::string(to_string(format)));
        files_json.push_back(export_file_name(format));
    }
    m["export"]["formats"] = formats_json;
    m["export"]["files"] = files_json;
    m["export"]["images_show"] = shown_what;
    staged.write("metrics.json", [&](const std::filesystem::path& f) { write_json(f, m); });
    staged.commit("metrics.json");
    return images;
}

// A render's metrics.json, but for what only its caller knows (the command, the scene's
// path). `mesh`: a mesh was traced in the surface's place, of `mesh_material` when one
// was given, shaded with interpolated vertex normals when `mesh_normals`.
inline nlohmann::json render_metrics_json(const RenderResult& r, bool mesh,
                                          const std::optional<MeshMaterial>& mesh_material, bool mesh_normals) {
    using json = nlohmann::json;
    const Scene& scene = r.scene;
    json m;
    m["tracer"] = to_string(r.decision.tracer);
    m["tracer_reason"] = r.decision.reason;
    m["threads"] = r.threads;
    m["seed"] = r.options.seed;
    m["rays"] = r.rays;
    m["rays_hit_receiver"] = r.totals.rays_hit_receiver;
    m["energy"] = r.totals.energy();
    m["where_light_went"] = totals_json(r.totals);
    m["seconds"] = r.seconds;
    m["rays_per_second"] = r.seconds > 0 ? double(r.rays) / r.seconds : 0.0;
    m["mesh"] = json::array({r.surface.nx(), r.surface.ny()});
    m["receiver_resolution"] = json::array({scene.receiver.width, scene.receiver.height});
    if (mesh || !scene.meshes.empty())
        m["mesh_shading"] = mesh_normals ? "interpolated vertex normals (not physical)" : "flat facets (geometry)";
    if (mesh)
        m["mesh_material"] =
            mesh_material ? json{{"refractive", mesh_material->ior}} : json("the scene's surface material");
    if (r.cells) {
        m["error"] = *r.error;
        m["error_physical"] = r.cells->error;
        m["energy_physical"] = r.cells->totals.energy();
        m["cell_means"] = cell_means_json(*r.cells, mesh ? "the mesh, as rendered" : "the surface, as rendered");
    }
    if (r.start) m["start"] = start_report_json(*r.start);
    m["effective_scene"] = job_to_json(DesignJob{scene, r.options});
    return m;
}

}  // namespace freeform::io
