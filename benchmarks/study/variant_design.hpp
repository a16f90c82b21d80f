#pragma once
// Variants of our designer that the library does not expose as options:
//   - full evaluation: every proposal is judged by retracing every ray
//     (HeightfieldTracer::trace_all) instead of the incremental retrace of the rays its
//     patch can affect. The objective values are the same bit for bit (DESIGN.md §4), so
//     the trajectory is the same move for move; only the speed differs. Each accepted
//     move's full-retrace delta is compared with the incremental one and mismatches are
//     counted (0 expected).
//   - one kernel: the bank holds only the isotropic Gaussian (σ = support/4) instead of
//     the seven shapes, to re-measure the reference's kernel-shape randomisation claim.
//
// design_variant() is the library's freeform::design() loop (design/designer.hpp) written
// out again with those two switches: same plan, same seeds, same calibration, same stage
// budgets. With both switches off it must reproduce freeform::design() exactly; study_run
// --selftest checks that (a fixed iteration budget makes both deterministic).
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <freeform/surface/refine.hpp>

#include "common.hpp"

namespace study {

enum class EvaluationMode { incremental, full };
enum class BankChoice { standard, one_isotropic };

struct VariantSettings {
    EvaluationMode evaluation = EvaluationMode::incremental;
    BankChoice bank = BankChoice::standard;
};

struct FullEvaluationStats {
    std::int64_t full_deltas = 0;       // proposals judged by a full retrace
    std::int64_t checked = 0;           // accepted moves whose incremental delta was compared
    std::int64_t mismatches = 0;        // ... and differed (the invariant says never)
    double seconds_in_full_deltas = 0;
};

// Judges proposals of a ReflectorProblem by full retraces. The surface copy `scratch_`
// follows the real surface: a proposal is written into it, every ray is traced, the
// objective is computed from scratch, and the patch is restored bit for bit.
// Not safe for concurrent delta() calls: run it with speculative = 1 (the trace itself
// uses all threads).
class FullEvaluationProblem {
public:
    using Move = ReflectorProblem::Move;

    FullEvaluationProblem(ReflectorProblem& inner, const RaySet& rays, const PathParams& params, const Target& target,
                          ObjectiveWeights weights, const Penalties& penalties, int threads, FullEvaluationStats& stats)
        : inner_(&inner), scratch_(inner.surface()), rays_(&rays), params_(params), image_(target), weights_(weights),
          penalties_(&penalties), threads_(threads), stats_(&stats) {}

    double energy() const { return inner_->energy(); }
    void propose(CounterRng& rng, double temperature, Move& m) { inner_->propose(rng, temperature, m); }

    double delta(Move& m) const {
        if (m.noop) return m.delta_value = 0.0;
        const auto start = Clock::now();
        const HeightSnapshot saved = scratch_.snapshot(m.overlay.patch);
        m.overlay.commit(scratch_);
        Histogram h(params_.receiver.width, params_.receiver.height);
        TraceTotals totals;
        HeightfieldTracer(scratch_, *rays_, params_).trace_all(exec::omp_t{threads_}, h, totals);
        const std::int64_t penalty_sum = penalties_->full(scratch_);
        const double penalty = Penalties::value(penalty_sum, scratch_);
        scratch_.restore(saved);
        image_.reset(h);
        const ObjectiveValue after = combine(image_.sums(), rays_->total, penalty, weights_);
        ++stats_->full_deltas;
        stats_->seconds_in_full_deltas += seconds_since(start);
        return m.delta_value = after.total - inner_->energy();
    }

    void accept(Move& m) {
        const double full = m.delta_value;
        // The incremental bookkeeping the commit needs (records, sums) comes from the
        // inner problem's own delta; it must agree with the full retrace exactly.
        const double incremental = inner_->delta(m);
        ++stats_->checked;
        if (incremental != full) ++stats_->mismatches;
        inner_->accept(m);
        if (!m.noop) m.overlay.commit(scratch_);
    }
    void reject(Move& m) { inner_->reject(m); }

    int sync_interval() const { return inner_->sync_interval(); }
    void sync() { inner_->sync(); }
    void on_new_best() { inner_->on_new_best(); }
    void restore_best() {
        inner_->restore_best();
        scratch_.set_heights(inner_->surface().heights());
    }

private:
    ReflectorProblem* inner_;
    mutable Heightmap scratch_;
    const RaySet* rays_;
    PathParams params_;
    mutable ImageState image_;
    ObjectiveWeights weights_;
    const Penalties* penalties_;
    int threads_;
    FullEvaluationStats* stats_;
};

namespace variant_detail {

inline ProposalSettings proposals(const DesignOptions& o, int support, BankChoice bank, const std::vector<int>& kept) {
    if (bank == BankChoice::one_isotropic) {
        ProposalSettings p = design_detail::proposals_for(o, support);
        if (!o.single_vertex) p.bank.resize(1);  // shape 0 of default_kernel_bank: isotropic, σ = support/4
        return p;
    }
    return design_detail::proposals_for(o, support, kept);
}

// Progress hook of one stage: the same convergence record as the library's designer,
// one point every `record_every` iterations. It also ends the stage at its deadline: the
// annealer reads the clock only every few dozen iterations at first, which is nothing for
// incremental moves but seconds for full retraces, so the full variant calls this hook
// after every iteration.
struct StageHooks {
    ReflectorProblem* problem;
    std::vector<ConvergencePoint>* convergence;  // nullptr: record nothing (the pre-process)
    std::int64_t base;
    int level, stage;
    Clock::time_point t_start;
    std::int64_t record_every;
    double deadline;  // seconds since t_start; 0: none
    std::int64_t last_recorded = -1;
    double last_time = -1;
    bool progress(const AnnealState& s) {
        const double now = seconds_since(t_start);
        // Every record_every iterations, and at least every half second when moves are slow.
        if (convergence && (last_recorded < 0 || s.iteration - last_recorded >= record_every || now - last_time >= 0.5)) {
            const ObjectiveValue& v = problem->value();
            convergence->push_back({now, base + s.iteration, level, stage, v.error, v.energy, v.total, s.temperature});
            last_recorded = s.iteration;
            last_time = now;
        }
        return deadline > 0 && now >= deadline;
    }
};

}  // namespace variant_detail

// freeform::design() with the switches of VariantSettings (see the top of this file).
inline DesignResult design_variant(const Scene& scene, Heightmap initial, const ImageD& target_image,
                                   const DesignOptions& options, const VariantSettings& variant,
                                   FullEvaluationStats& stats) {
    const auto t_start = Clock::now();
    const auto elapsed = [&] { return seconds_since(t_start); };
    Scene planned = scene;
    planned.optimise = options;
    std::vector<LevelPlan> levels = options.levels.empty() ? plan_levels(planned, &target_image) : options.levels;
    for (std::size_t k = 0; k < levels.size(); ++k)
        if (levels[k].kernel_supports.empty()) levels[k].kernel_supports = level_kernel_supports(levels, k);
    const Penalties penalties = design_detail::make_penalties(options);
    const int threads = thread_count(exec::omp_t{options.threads});
    const bool full = variant.evaluation == EvaluationMode::full;
    DesignResult result;
    std::int64_t total_iterations = 0;
    double share_used = 0;
    Heightmap surface = std::move(initial);
    std::vector<int> kept_arms;  // after the history bandit's pre-process

    for (std::size_t li = 0; li < levels.size(); ++li) {
        const LevelPlan& level = levels[li];
        surface = refine_preserving_normals(surface, level.mesh_x, level.mesh_y);
        Receiver receiver = scene.receiver;
        receiver.width = level.resolution_x;
        receiver.height = level.resolution_y;
        Light light = scene.light;
        if (li + 1 < levels.size() && options.coarse_rays_per_cell > 0 && light.rays == 0)
            light.rays_per_cell = std::min(light.rays_per_cell, options.coarse_rays_per_cell);
        const RaySet rays = generate_rays(light, surface, receiver, options.seed);
        Scene level_scene = scene;
        level_scene.receiver = receiver;
        const PathParams pp = make_path_params(level_scene);
        const double unit = design_detail::amplitude_unit(scene, receiver, surface);
        const std::size_t stages = level.kernel_supports.empty() ? 1 : level.kernel_supports.size();
        for (std::size_t si = 0; si < stages; ++si) {
            const int support = level.kernel_supports.empty() ? 3 : level.kernel_supports[si];
            const std::uint64_t stage_seed = hash_combine(options.seed, li * 16 + si);
            const Target target = make_target(target_image, receiver.width, receiver.height, rays.total);
            const ObjectiveWeights weights{options.sobel_weight, options.energy_threshold, options.lost_light_weight};
            // The history bandit's pre-process, as in the library (reference §4.3.2); with one
            // kernel shape there is nothing to choose from. The full variant judges its trial
            // moves by full retraces too.
            if (li == 0 && si == 0 && options.bandit == "history" && !options.single_vertex &&
                options.preprocess_iterations > 0 && options.preprocess_keep > 0 &&
                variant.bank == BankChoice::standard) {
                ProposalSettings all = design_detail::proposals_for(options, support);
                const int arms = int(all.bank.size());
                ReflectorProblem pre(surface, rays, pp, target, weights, penalties, all,
                                     make_bandit("uniform", arms, options.bandit_sync), unit, 1.0);
                const auto cal = design_detail::calibrate(pre, hash_combine(stage_seed, 1), options.initial_acceptance);
                pre.set_reference_temperature(cal.temperature);
                AnnealOptions po;
                po.seed = hash_combine(stage_seed, 2);
                po.initial_temperature = cal.temperature;
                po.cooling = 1.0;
                po.max_iterations = options.preprocess_iterations;
                po.time_budget = options.time_budget > 0 ? 0.05 * options.time_budget : 0;
                po.threads = 1;
                AnnealResult pr;
                if (full) {
                    FullEvaluationProblem full_pre(pre, rays, pp, target, weights, penalties, threads, stats);
                    po.progress_every = 1;
                    variant_detail::StageHooks stop_hook{&pre, nullptr, 0, 0, 0, t_start, 1,
                                                         po.time_budget > 0 ? elapsed() + po.time_budget : 0.0};
                    pr = anneal(full_pre, po, stop_hook);
                } else {
                    pr = anneal(pre, po);
                }
                total_iterations += pr.iterations;
                result.accepted += pr.accepted;
                std::vector<double> rate(std::size_t(arms), 0.0);
                for (int a = 0; a < arms; ++a) {
                    const auto pulls = pre.bandit().pulls()[std::size_t(a)];
                    rate[std::size_t(a)] = pulls > 0 ? pre.bandit().total_rewards()[std::size_t(a)] / double(pulls) : 0.0;
                }
                kept_arms = HistoryBandit::preselect(rate, std::min(options.preprocess_keep, arms));
                std::sort(kept_arms.begin(), kept_arms.end());
                result.preprocess_rates = rate;
            }
            const ProposalSettings ps = variant_detail::proposals(options, support, variant.bank, kept_arms);
            const int arms = std::max<int>(1, int(ps.bank.size()));
            ReflectorProblem problem(surface, rays, pp, target, weights, penalties, ps,
                                     make_bandit(options.bandit, arms, options.bandit_sync, "optimise.bandit"), unit,
                                     1.0);
            design_detail::Calibration cal = design_detail::calibrate(problem, stage_seed, options.initial_acceptance);
            problem.set_reference_temperature(cal.temperature);
            std::optional<FullEvaluationProblem> full_problem;
            if (full) {
                full_problem.emplace(problem, rays, pp, target, weights, penalties, threads, stats);
                // Same temperature (the deltas are identical); the speed is that of full retraces.
                ReflectorProblem::Move m;
                const auto t0 = Clock::now();
                constexpr int trials = 3;
                for (int k = 0; k < trials; ++k) {
                    CounterRng rng(hash_combine(stage_seed, 0xca11b7a7eULL), std::uint64_t(k));
                    full_problem->propose(rng, 1.0, m);
                    full_problem->delta(m);
                }
                cal.moves_per_second = trials / std::max(seconds_since(t0), 1e-9);
            }

            StageReport report;
            report.level = int(li);
            report.mesh_x = level.mesh_x;
            report.mesh_y = level.mesh_y;
            report.resolution_x = receiver.width;
            report.resolution_y = receiver.height;
            report.kernel_support = options.single_vertex ? 1 : support;
            report.initial_temperature = cal.temperature;
            report.error_start = problem.value().error;
            report.rays = rays.size();

            AnnealOptions ao;
            ao.seed = stage_seed;
            ao.initial_temperature = cal.temperature;
            ao.cooling = options.cooling;
            const double level_end = options.time_budget * (share_used + level.time_share);
            const double stage_time = std::max(0.05, (level_end - elapsed()) / double(stages - si));
            const int speculative = full ? 1 : (options.speculative > 0 ? options.speculative : threads);
            std::int64_t budget = std::max<std::int64_t>(1000, level.iterations / std::int64_t(stages));
            if (options.time_budget > 0 && options.max_iterations == 0) {
                const double parallel = 1.0 + 0.6 * (std::min(speculative, threads) - 1);
                budget = std::max<std::int64_t>(500, std::int64_t(0.9 * cal.moves_per_second * parallel * stage_time));
            }
            if (options.max_iterations > 0) {
                const std::int64_t left = options.max_iterations - total_iterations;
                if (left <= 0) break;
                budget = std::min(budget, std::max<std::int64_t>(1, left / std::int64_t(stages - si)));
            }
            ao.max_iterations = budget;
            ao.iterations_per_temperature = std::max<std::int64_t>(1, budget / std::max(1, options.temperature_steps));
            ao.patience = std::max<std::int64_t>(100, std::int64_t(options.patience_fraction * double(budget)));
            ao.reheat_factor = options.reheat_factor;
            ao.time_budget = options.time_budget > 0 ? stage_time : 0;
            if (options.target_error > 0) ao.target_energy = options.target_error;
            ao.speculative = speculative;
            ao.threads = full ? 1 : threads;
            const std::int64_t record_every = std::max<std::int64_t>(1, options.progress_every);
            ao.progress_every = full ? 1 : record_every;

            const double stage_start = elapsed();
            variant_detail::StageHooks hooks{&problem, &result.convergence, total_iterations, int(li), int(si), t_start,
                                             record_every, ao.time_budget > 0 ? stage_start + stage_time : 0.0};
            const AnnealResult ar = full ? anneal(*full_problem, ao, hooks) : anneal(problem, ao, hooks);
            total_iterations += ar.iterations;
            result.accepted += ar.accepted;
            report.iterations = ar.iterations;
            report.accepted = ar.accepted;
            report.proposals_evaluated = ar.proposals_evaluated;
            report.seconds = elapsed() - stage_start;
            report.error_end = problem.value().error;
            report.energy_end = problem.value().energy;
            report.objective_end = problem.value().total;
            report.bandit_weights = options.single_vertex ? std::vector<double>{} : problem.bandit().weights();
            report.stop_reason = to_string(ar.reason);
            result.stages.push_back(report);
            if (li + 1 == levels.size() && si + 1 == stages) {
                result.irradiance = problem.histogram();
                result.target = problem.image().target();
                result.value = problem.value();
                result.kernel_bank = ps.bank;
                result.bandit_weights = report.bandit_weights;
                result.rays = rays.size();
            }
        }
        share_used += level.time_share;
    }
    result.surface = std::move(surface);
    result.iterations = total_iterations;
    result.seconds = elapsed();
    return result;
}

}  // namespace study
