// JSON for what the designer reports: one object per annealing stage (level, model,
// work done, temperatures, errors, why it stopped, the bandit's weights). Used by the
// command line's metrics.json and by the study's result files, so both read alike.
#pragma once

#include <vector>

#include <nlohmann/json.hpp>

#include <freeform/design/designer.hpp>

namespace freeform {

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
            {"stop", s.stop_reason},
            {"bandit_weights", s.bandit_weights}};
    if (s.held_out_start >= 0)
        j["held_out"] = {{"error_start", s.held_out_start},
                         {"error_end", s.held_out_end},
                         {"checks", s.held_out_checks},
                         {"kept_iteration", s.held_out_kept}};
    if (s.merges > 0) j["merges"] = s.merges;
    return j;
}

// Where the design started (metrics.json "start"): the shape asked for and used, the
// transport solve and fit, the start's error under the exact tracer, and the schedule's
// decision.
inline nlohmann::json start_report_json(const StartReport& s) {
    nlohmann::json j{{"requested", s.requested},
                     {"used", s.used},
                     {"seconds", s.seconds},
                     {"levels_planned", s.levels_planned},
                     {"levels_used", s.levels_used},
                     {"plan", s.plan}};
    if (!s.fallback_reason.empty()) j["fallback_reason"] = s.fallback_reason;
    if (s.error >= 0) j["error"] = s.error, j["energy"] = s.energy;
    if (s.flat_error >= 0) j["flat_error"] = s.flat_error;
    if (s.requested == "transport" && s.transport.grid_x > 0) {
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
                          {"unmapped_fraction", t.unmapped_fraction}};
    }
    return j;
}

inline nlohmann::json stage_reports_json(const std::vector<StageReport>& stages) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& s : stages) out.push_back(stage_report_json(s));
    return out;
}

}  // namespace freeform
