// JSON for what a design reports: one object per annealing stage (level, model, work
// done, temperatures, errors, why it stopped, the bandit's weights), the start, where the
// light went, the cell means, the machinist's figures, and a whole design's metrics.json
// (docs/measures.md says what each figure is). Used by the command line and by the
// study's result files, so both read alike.
#pragma once

#include <cstddef>
#include <cstdint>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "../design/designer.hpp"
#include "../design/pipeline.hpp"
#include "scene_json.hpp"
#include "form_check.hpp"

namespace freeform::io {

inline nlohmann::json stage_report_json(const StageReport& s) {
    nlohmann::json j{{"level", s.level},
            {"mesh", nlohmann::json::array({s.mesh_x, s.mesh_y})},
            {"resolution", nlohmann::json::array({s.resolution_x, s.resolution_y})},
            {"kernel_support", s.kernel_support},
            {"rays", s.rays},
            {"iterations", s.iterations},
            {"accepted", s.accepted},
            {"proposals_evaluated", s.proposals_evaluated},
            {"seconds", s.seconds},
            {"initial_temperature", s.initial_temperature},
            {"error_start", s.error_start},
            {"error_end", s.error_end},
            {"energy_end", s.energy_end},
            {"stop", to_string(s.stop_reason)},
            {"bandit_weights", s.bandit_weights}};
    if (s.held_out_start >= 0)
        j["held_out"] = {{"error_start", s.held_out_start},
                         {"error_end", s.held_out_end},
                         {"checks", s.held_out_checks},
                         {"kept_iteration", s.held_out_kept}};
    if (s.merges > 0) j["merges"] = s.merges;
    if (s.rays > 0 && s.crossings > 0) j["crossings_per_ray"] = double(s.crossings) / double(s.rays);
    if (s.reach_envelope) j["reach_envelope"] = {{"recentres", s.reach_recentres}};
    return j;
}

// Where the design started (metrics.json "start"): the shape asked for and used, the
// transport solve and fit, the start's error under the exact tracer, and the schedule's
// decision.
inline nlohmann::json start_report_json(const StartReport& s) {
    nlohmann::json j{{"requested", to_string(s.requested)},
                     {"used", to_string(s.used)},
                     {"seconds", s.seconds},
                     {"levels_planned", s.levels_planned},
                     {"levels_used", s.levels_used},
                     {"plan", s.plan}};
    if (!s.fallback_reason.empty()) j["fallback_reason"] = s.fallback_reason;
    if (s.error >= 0) j["error"] = s.error, j["energy"] = s.energy;
    if (s.flat_error >= 0) j["flat_error"] = s.flat_error;
    if (s.landing_offset >= 0) {
        // design/start.hpp, surface_weight_share: "solved" false where the budget chose the reweighting;
        // "power_change" only where the power depends on the surface's shape; "landing_offset" in
        // receiver pixels, "target_offset" whether the solve's target was moved against it
        nlohmann::json& w = j["surface_weighted"];
        w = {{"landing_offset", s.landing_offset},
             {"target_offset", s.target_offset},
             {"first_error", s.plane_weighted_error},
             {"solved", s.surface_weighted_error >= 0}};
        if (s.lit_power_change >= 0) w["power_change"] = s.lit_power_change;
        if (s.surface_weighted_error >= 0)
            w["second_error"] = s.surface_weighted_error, w["kept"] = s.surface_weighted_error < s.plane_weighted_error;
    }
    if (s.reweighted_error >= 0)
        j["reweighted"] = {{"first_error", s.unreweighted_error},
                           {"second_error", s.reweighted_error},
                           {"kept", s.used == StartKind::transport && s.reweighted_error < s.unreweighted_error}};
    if (s.requested == StartKind::transport && s.transport.grid_x > 0) {
        const TransportReport& t = s.transport;
        j["transport"] = {{"grid", nlohmann::json::array({t.grid_x, t.grid_y})},
                          {"cell_size", t.cell_size},
                          {"ot_iterations", t.ot_iterations},
                          {"ot_residual", t.ot_residual},
                          {"ot_seconds", t.ot_seconds},
                          {"fit_iterations", t.fit_iterations},
                          {"fit_seconds", t.fit_seconds},
                          {"height_range", t.height_range},
                          {"height_excess", t.height_excess},
                          {"fits_height_bounds", t.height_excess <= 0},
                          {"unmapped_fraction", t.unmapped_fraction},
                          {"wall_strips", {{"margin", t.strip_margin}, {"wall_fraction", t.wall_fraction},
                                           {"strip_light", t.strip_light}}},
                          {"cells_per_pixel", t.cells_per_pixel}};
        if (t.other_error >= 0)
            j["transport"]["other_grid"] = {{"cells_per_pixel", t.other_cells_per_pixel}, {"error", t.other_error}};
    }
    return j;
}

inline nlohmann::json stage_reports_json(const std::vector<StageReport>& stages) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& s : stages) out.push_back(stage_report_json(s));
    return out;
}

// Shares of the emitted weight, by where it ended.
inline nlohmann::json totals_json(const TraceTotals& t) {
    const double n = double(t.emitted);
    nlohmann::json j;
    j["receiver"] = double(t.on_receiver()) / n;
    j["missed_receiver"] = double(t.weight_by_status[std::size_t(RayStatus::missed_receiver)]) / n;
    j["missed_surface"] = double(t.weight_by_status[std::size_t(RayStatus::missed_surface)]) / n;
    j["total_internal_reflection"] = double(t.lost_tir()) / n;
    j["max_depth"] = double(t.weight_by_status[std::size_t(RayStatus::lost_depth)]) / n;
    j["absorbed"] = double(t.weight_by_status[std::size_t(RayStatus::absorbed)]) / n;
    if (t.fresnel_reflected() != 0) j["fresnel_reflected"] = double(t.fresnel_reflected()) / n;
    return j;
}

inline nlohmann::json cell_means_json(const CellMeans& c, const std::string& traced) {
    nlohmann::json j;
    j["traced"] = traced;
    j["deposit"] = "nearest";
    j["rays_per_cell"] = c.rays_per_cell;
    j["rays"] = c.rays;
    j["batches"] = c.batches;
    j["change_on_doubling"] = c.change_on_doubling;
    j["converged"] = c.converged;
    return j;
}

// metrics.json's "fabrication" block (design/machining.hpp): what a machinist checks.
inline nlohmann::json fabrication_json(const MachiningReport& r, double tool_radius) {
    nlohmann::json f;
    f["cutter_side"] = "+normal of the surface frame: the light's side of a mirror, the air side of a lens's front face";
    f["min_concave_radius"] = r.min_concave_radius ? nlohmann::json(*r.min_concave_radius) : nlohmann::json(nullptr);
    f["min_concave_radius_at"] = {r.min_concave_u, r.min_concave_v};
    f["max_slope_degrees"] = r.max_slope_degrees;
    f["sag"] = {{"min", r.sag_min}, {"max", r.sag_max}, {"range", r.sag_range()}};
    f["bounding_box"] = {{"min", {r.box_min.x, r.box_min.y, r.box_min.z}},
                         {"max", {r.box_max.x, r.box_max.y, r.box_max.z}}};
    if (r.min_glass_thickness) f["min_glass_thickness"] = *r.min_glass_thickness;
    if (tool_radius > 0) f["tool_radius"] = tool_radius;
    f["units"] = "metres and degrees; curvatures from central differences of the heights (design/machining.hpp)";
    return f;
}

// The exported part's figures: error_exported, energy_exported, error_physical,
// energy_physical, cell_means, export and fabrication.
inline void add_export_json(nlohmann::json& m, const Scene& scene, const ExportChecks& c) {
    nlohmann::json exported;
    // k: whole, or fractional where it fills the triangle budget (design/fabrication.hpp).
    const double k = c.fabrication.subdivisions;
    exported["subdivisions"] = c.fabrication.whole() ? nlohmann::json(std::int64_t(k)) : nlohmann::json(k);
    exported["subdivisions_chosen"] =
        c.fabrication.automatic ? "auto (export_tolerance, export_max_triangles)" : "export_subdivisions";
    exported["facet_normal_error_mrad"] = c.fabrication.normal_error * 1e3;
    exported["facet_normal_tolerance_mrad"] = c.fabrication.normal_tolerance * 1e3;
    exported["tolerance_met"] = c.fabrication.tolerance_met;
    if (!c.fabrication.tolerance_met)
        exported["tolerance_missed"] =
            c.fabrication.automatic
                ? "the facets' normal error exceeds the tolerance at the finest k allowed (" +
                      what_stopped_k(c.fabrication) +
                      "); surface.step / surface.dat keep the designed surface (docs/export.md)"
                : "the facets' normal error exceeds the tolerance at the fixed optimise.export_subdivisions";
    exported["triangles"] = c.fabrication.mesh.triangles.size();
    if (c.cells) {
        m["error_exported"] = *c.error_exported;
        m["energy_exported"] = *c.energy_exported;
        exported["l1_to_design_irradiance"] = *c.l1_to_design;
        m["error_physical"] = c.cells->error;
        m["error_physical_form"] = "mesh";  // the CLI makes it the leading form's (io/forms.hpp)
        m["energy_physical"] = c.cells->totals.energy();
        m["cell_means"] = cell_means_json(*c.cells, "the exported surface.obj traced as flat triangles");
    } else {
        m["error_exported"] = nullptr;
        m["error_physical"] = nullptr;
        exported["not_traced"] = "built without Embree";
    }
    exported["spline_fit"] = {
        {"form", c.spline.hermite ? "C1 Hermite: the height map's vertices and vertex normals, double knots (the grid "
                                    "sag table's surface)"
                                  : "C2 least squares to the Phong surface, one knot per grid line"},
        {"samples_per_cell", c.spline.hermite ? nlohmann::json(nullptr) : nlohmann::json(c.spline_fit.samples_per_cell)},
        {"poles", {c.spline.nu, c.spline.nv}},
        {"max_height_error_m", c.spline_fit.max_height_error},
        {"rms_height_error_m", c.spline_fit.rms_height_error},
        {"max_normal_error_mrad", c.spline_fit.max_normal_error * 1e3},
        {"p90_normal_error_mrad", c.spline_fit.p90_normal_error * 1e3},
        {"against", "the designed (Phong) surface at two points per cell off the fit's samples"}};
    nlohmann::json forms = nlohmann::json::object();
    if (c.designed)
        forms["designed"] = {{"error_physical", c.designed->error},
                             {"energy", c.designed->totals.energy()},
                             {"rays_per_cell", c.designed->rays_per_cell},
                             {"traced", "heightmap.pfm as designed: its Phong patches (the reference)"}};
    if (c.cells)
        forms["mesh"] = {{"error_physical", c.cells->error},
                         {"energy", c.cells->totals.energy()},
                         {"rays_per_cell", c.cells->rays_per_cell},
                         {"triangles", c.fabrication.mesh.triangles.size()},
                         {"traced", "surface.obj/.stl as flat triangles"}};
    exported["forms"] = forms;
    m["export"] = exported;
    m["fabrication"] = fabrication_json(c.machining, scene.surface.tool_radius);
    // How far a lens's glass body reaches beyond its face (scene/scene.hpp lens_rim); the
    // exported solid rounds it up to whole cells (design/fabrication.hpp export_blank).
    if (is_lens(scene.surface.material)) m["fabrication"]["lens_rim"] = lens_rim(scene);
}

// metrics.json's export.forms entry of a smooth form written and read back (io/forms.hpp).
inline nlohmann::json form_json(const FormCheck& f) {
    nlohmann::json j;
    j["file"] = f.file.filename().string();
    j["bytes"] = f.bytes;
    j["write_seconds"] = f.write_seconds;
    j["check_seconds"] = f.check_seconds;
    j["valid"] = f.valid;
    if (f.cells) {
        j["error_physical"] = f.cells->error;
        j["energy"] = f.cells->totals.energy();
        j["rays_per_cell"] = f.cells->rays_per_cell;
        j["traced"] = "the file read back, tessellated with " + std::to_string(f.tessellation) +
                      " x " + std::to_string(f.tessellation) + " facet pairs per cell (" +
                      std::to_string(f.triangles) + " triangles) shaded with its own normals";
    } else {
        j["error_physical"] = nullptr;
    }
    return j;
}

// A finished design's metrics.json (docs/measures.md), but for what only its caller
// knows: the command, the scene's path, replicas.
inline nlohmann::json design_metrics_json(const CompletedDesign& d) {
    const DesignResult& r = d.result;
    const DesignOptions& options = d.options;
    nlohmann::json m;
    m["error"] = d.fitted.error;
    if (d.error_held_out) m["error_held_out"] = *d.error_held_out;
    m["energy"] = d.fitted.totals.energy();
    m["objective"] = r.value.total;
    if (r.held_out.total >= 0) m["objective_held_out"] = r.held_out.total;
    m["iterations"] = r.iterations;
    if (d.scene.surface.tool_radius > 0) m["tool_cut_max_added"] = r.tool_cut;  // metres the cutter left
    m["accepted"] = r.accepted;
    m["seconds"] = r.seconds;  // the design, its start included: what optimise.time_budget bounds
    m["finish_seconds"] = d.finish_seconds;  // then the final traces and the export checks
    m["iterations_per_second"] = r.seconds > 0 ? double(r.iterations) / r.seconds : 0.0;
    m["seed"] = options.seed;
    m["tracer"] = "heightfield";
    m["device"] = r.device;  // where the windows were judged: "cpu" or "cuda (<name>)"
    if (!r.device_failure.empty()) m["device_failure"] = r.device_failure;  // then the CPU took over
    m["interrupted"] = r.stopped_early;
    m["rays"] = d.fitted.rays.size();
    m["mesh"] = nlohmann::json::array({r.surface.nx(), r.surface.ny()});
    m["where_light_went"] = totals_json(d.fitted.totals);
    nlohmann::json bank = nlohmann::json::array();
    for (std::size_t k = 0; k < r.kernel_bank.size(); ++k) {
        const auto& s = r.kernel_bank[k];
        bank.push_back({{"sigma_x", s.sigma_x}, {"sigma_y", s.sigma_y}, {"rho", s.rho}, {"support", s.support},
                        {"weight", k < r.bandit_weights.size() ? r.bandit_weights[k] : 0.0}});
    }
    m["bandit"] = to_string(options.proposals.bandit);
    m["bandit_weights"] = r.bandit_weights;
    if (!r.preprocess_rates.empty()) m["bandit_preprocess_reward_per_move"] = r.preprocess_rates;
    m["kernels"] = bank;
    m["levels"] = stage_reports_json(r.stages);
    m["start"] = start_report_json(r.start);
    if (d.delivered)  // optimise.keep_better_start (design/pipeline.hpp, DeliveredSurface)
        m["delivered"] = {{"surface", d.delivered->start ? "start" : "annealed"},
                          {"annealed_error_physical", d.delivered->annealed_error},
                          {"start_error_physical", d.delivered->start_error},
                          {"traced", "both surfaces as designed (their Phong patches), finished alike"}};
    m["effective_scene"] = job_to_json(DesignJob{d.scene, d.options});
    add_export_json(m, d.scene, d.exported);
    return m;
}

// convergence.csv: one row per progress report of the annealing.
inline std::string convergence_csv(const DesignResult& r) {
    std::ostringstream csv;
    csv << "seconds,iteration,level,stage,error,energy,objective,temperature\n";
    for (const auto& c : r.convergence)
        csv << c.seconds << ',' << c.iteration << ',' << c.level << ',' << c.stage << ',' << c.error << ','
            << c.energy << ',' << c.objective << ',' << c.temperature << '\n';
    return csv.str();
}

}  // namespace freeform::io
