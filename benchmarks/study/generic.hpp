#pragma once
// Thin adapters that let generic optimisers (pagmo2, NLopt) drive the height field
// through ControlObjective. They are what a user would write in an afternoon: the
// library's box bounds, a start at the scene's initial surface, step sizes in the
// physical unit of ControlObjective::shift_unit(), and the time budget as the only stop
// rule. Each adapter returns its settings as JSON so the report can state them.
//
// Settings (s = shift unit in normalised variables, d = dimension, x0 = start):
//   pagmo-sa     Corana's adaptive simulated annealing (pagmo::simulated_annealing):
//                Ts = 1 % of f(x0), Tf = Ts / 100, start_range = 2 s (a coordinate move of
//                up to ±4 s, ours' largest amplitude), bin_size 2, n_range_adj 1, n_T_adj
//                sized so one evolve() fits the budget (re-annealed if time is left).
//   pagmo-cmaes  CMA-ES (pagmo::cmaes), λ = 4 + ⌊3 ln d⌋, initial standard deviation 2 s
//                (pagmo scales sigma0 by the bound width 2, so sigma0 = s), tolerances off.
//   pagmo-xnes   exponential natural evolution strategies, same λ and width as CMA-ES.
//   pagmo-sade   self-adaptive differential evolution (variant 2, jDE adaptation),
//                20 individuals drawn around x0 with standard deviation 2 s.
//   nlopt-bobyqa Powell's BOBYQA (NLOPT_LN_BOBYQA): bound-constrained quadratic models,
//                initial trust radius 2 s, 2d + 1 interpolation points.
//   nlopt-crs2   controlled random search with local mutation (NLOPT_GN_CRS2_LM),
//                NLopt's default population 10 (d + 1) over the whole box.
// Population members other than x0 are drawn around x0 (never uniformly in the whole box,
// which would start from surfaces that throw the light everywhere).
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "control_grid.hpp"

#if defined(FREEFORM_HAVE_PAGMO)
#include <pagmo/algorithm.hpp>
#include <pagmo/algorithms/cmaes.hpp>
#include <pagmo/algorithms/sade.hpp>
#include <pagmo/algorithms/simulated_annealing.hpp>
#include <pagmo/algorithms/xnes.hpp>
#include <pagmo/population.hpp>
#include <pagmo/problem.hpp>
#include <pagmo/threading.hpp>
#include <pagmo/types.hpp>
#endif

#if defined(FREEFORM_HAVE_NLOPT)
#include <nlopt.hpp>
#endif

namespace study {

constexpr bool have_pagmo =
#if defined(FREEFORM_HAVE_PAGMO)
    true;
#else
    false;
#endif

constexpr bool have_nlopt =
#if defined(FREEFORM_HAVE_NLOPT)
    true;
#else
    false;
#endif

// Points around x0 with standard deviation `sd`, clamped to the box (x0 itself first).
inline std::vector<std::vector<double>> points_around(const std::vector<double>& x0, int count, double sd,
                                                      std::uint64_t seed) {
    std::vector<std::vector<double>> pts{x0};
    for (int k = 1; k < count; ++k) {
        CounterRng rng(hash_combine(seed, 0x90b5ULL), std::uint64_t(k));
        std::vector<double> x = x0;
        for (double& v : x) v = std::clamp(v + sd * rng.normal(), -1.0, 1.0);
        pts.push_back(std::move(x));
    }
    return pts;
}

#if defined(FREEFORM_HAVE_PAGMO)

// The pagmo user-defined problem: one objective, box [-1, 1]^d, not thread-safe (the
// evaluator traces with all threads itself).
struct PagmoHeightfield {
    ControlObjective* objective = nullptr;
    pagmo::vector_double fitness(const pagmo::vector_double& z) const { return {objective->evaluate(z)}; }
    std::pair<pagmo::vector_double, pagmo::vector_double> get_bounds() const {
        const auto d = std::size_t(objective->dimension());
        return {pagmo::vector_double(d, -1.0), pagmo::vector_double(d, 1.0)};
    }
    std::string get_name() const { return "freeform height field (control grid)"; }
    pagmo::thread_safety get_thread_safety() const { return pagmo::thread_safety::none; }
};

inline json run_pagmo(const std::string& which, ControlObjective& f, std::uint64_t seed) {
    const int d = f.dimension();
    const double s = f.shift_unit();
    const unsigned pseed = unsigned(hash_combine(seed, 0x9a90ULL) & 0x7fffffffU);
    const pagmo::problem prob{PagmoHeightfield{&f}};
    json settings;
    std::int64_t generations_or_passes = 0;
    try {
        pagmo::population pop{prob, 0u, pseed};
        if (which == "pagmo-sa") {
            const auto t0 = Clock::now();
            pop.push_back(f.initial_point());
            const double t_eval = std::max(seconds_since(t0), 1e-6);
            const double f0 = pop.get_f()[0][0];
            const double ts = 0.01 * f0, tf = ts / 100;
            const unsigned bin = 2, range_adj = 1;
            const double expected = std::max(1.0, (f.budget() - f.elapsed()) / t_eval);
            const unsigned t_adj = unsigned(std::max(1.0, std::floor(expected / double(bin * range_adj * d))));
            const double start_range = std::clamp(2 * s, 1e-6, 1.0);
            settings = {{"Ts", ts}, {"Tf", tf}, {"n_T_adj", t_adj}, {"n_range_adj", range_adj}, {"bin_size", bin},
                        {"start_range", start_range}};
            const pagmo::algorithm algo{pagmo::simulated_annealing(ts, tf, t_adj, range_adj, bin, start_range, pseed)};
            while (!f.exhausted()) {
                pop = algo.evolve(pop);
                ++generations_or_passes;
            }
        } else if (which == "pagmo-cmaes" || which == "pagmo-xnes") {
            const int lambda = 4 + int(std::floor(3 * std::log(double(d))));
            for (const auto& x : points_around(f.initial_point(), lambda, 2 * s, seed)) pop.push_back(x);
            const double sigma0 = std::clamp(s, 1e-9, 1.0);
            settings = {{"lambda", lambda}, {"sigma0", sigma0}, {"initial_sd", 2 * s}, {"ftol", 0}, {"xtol", 0}};
            const unsigned gens = 1000000u;
            // Debian's libpagmo is built for plain x86-64, where Eigen takes memory from malloc;
            // this program is built with -march=x86-64-v3 (AVX), where Eigen frees its blocks as
            // 32-byte aligned ones. CMA-ES and xNES keep Eigen state that libpagmo allocates and
            // whose destructor is compiled here: destroying the algorithm crashes (free() of a
            // bad pointer). So it is never destroyed: a few kB per run, returned at exit.
            const pagmo::algorithm& algo = *new pagmo::algorithm{
                which == "pagmo-cmaes"
                    ? pagmo::algorithm{pagmo::cmaes(gens, -1, -1, -1, -1, sigma0, 1e-300, 1e-300, false, false, pseed)}
                    : pagmo::algorithm{pagmo::xnes(gens, -1, -1, -1, sigma0, 1e-300, 1e-300, false, false, pseed)}};
            while (!f.exhausted()) {
                pop = algo.evolve(pop);
                ++generations_or_passes;
            }
        } else if (which == "pagmo-sade") {
            const int np = 20;
            for (const auto& x : points_around(f.initial_point(), np, 2 * s, seed)) pop.push_back(x);
            settings = {{"population", np}, {"variant", 2}, {"variant_adptv", 1}, {"initial_sd", 2 * s}};
            const pagmo::algorithm algo{pagmo::sade(1000000u, 2u, 1u, 1e-300, 1e-300, false, pseed)};
            while (!f.exhausted()) {
                pop = algo.evolve(pop);
                ++generations_or_passes;
            }
        } else {
            throw InputError("--method: unknown pagmo method '" + which + "'");
        }
    } catch (const BudgetExhausted&) {
    }
    settings["evolve_calls_completed"] = generations_or_passes;
    return settings;
}

#endif

#if defined(FREEFORM_HAVE_NLOPT)

inline double nlopt_objective(const std::vector<double>& x, std::vector<double>& /*grad*/, void* data) {
    try {
        return static_cast<ControlObjective*>(data)->evaluate(x);
    } catch (const BudgetExhausted&) {
        throw nlopt::forced_stop();
    }
}

inline json run_nlopt(const std::string& which, ControlObjective& f) {
    const unsigned d = unsigned(f.dimension());
    const double s = f.shift_unit();
    const nlopt::algorithm alg = which == "nlopt-bobyqa" ? nlopt::LN_BOBYQA
                                 : which == "nlopt-crs2" ? nlopt::GN_CRS2_LM
                                                         : throw InputError("--method: unknown NLopt method '" + which + "'");
    nlopt::opt opt(alg, d);
    opt.set_lower_bounds(-1.0);
    opt.set_upper_bounds(1.0);
    opt.set_min_objective(nlopt_objective, &f);
    json settings;
    if (alg == nlopt::LN_BOBYQA) {
        opt.set_initial_step(2 * s);
        settings["initial_trust_radius"] = 2 * s;
        settings["interpolation_points"] = 2 * d + 1;
    } else {
        settings["population"] = "NLopt default, 10 (d + 1)";
    }
    std::vector<double> x = f.initial_point();
    double value = 0;
    std::string outcome;
    // NLopt passes extra evaluations past the budget only if one is running when it ends;
    // maxtime makes it stop by itself, forced_stop covers the rest.
    opt.set_maxtime(std::max(1e-3, f.budget() - f.elapsed()));
    try {
        const nlopt::result r = opt.optimize(x, value);
        outcome = "nlopt result " + std::to_string(int(r));
    } catch (const nlopt::forced_stop&) {
        outcome = "time budget (forced stop)";
    } catch (const std::exception& e) {
        outcome = std::string("stopped: ") + e.what();
    }
    settings["outcome"] = outcome;
    return settings;
}

#endif

}  // namespace study
