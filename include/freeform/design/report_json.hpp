// JSON for what the designer reports: one object per annealing stage (level, model,
// work done, temperatures, errors, why it stopped, the bandit's weights). Used by the
// command line's metrics.json and by the study's result files, so both read alike.
#pragma once

#include <vector>

#include <nlohmann/json.hpp>

#include <freeform/design/designer.hpp>

namespace freeform {

inline nlohmann::json stage_report_json(const StageReport& s) {
    return {{"level", s.level},
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
}

inline nlohmann::json stage_reports_json(const std::vector<StageReport>& stages) {
    nlohmann::json out = nlohmann::json::array();
    for (const auto& s : stages) out.push_back(stage_report_json(s));
    return out;
}

}  // namespace freeform
