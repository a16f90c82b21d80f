#pragma once
// SPSA (Spall's simultaneous perturbation stochastic approximation) on the height field:
// the gradient-based method the reference compares against (its Fig. 6.10 / 6.11).
//
// Each iteration perturbs every variable at once by ±c_k (Rademacher signs Δ), evaluates
// the objective at θ + c_k Δ and θ − c_k Δ, and steps along the estimated gradient
//     ĝ_i = (y+ − y−) / (2 c_k Δ_i),   θ ← clamp(θ − a_k ĝ, −1, 1),
// with Spall's standard gain sequences
//     a_k = a / (k + 1 + A)^α,  α = 0.602;   c_k = c / (k + 1)^γ,  γ = 0.101.
// The constants are set as Spall recommends (Spall 1998, "Implementation of the
// simultaneous perturbation algorithm for stochastic optimization"):
//   c: the perturbation, `c_cells` (default 2) shift units, i.e. each control vertex
//      moves the light by about two receiver cells;
//   A: 10 % of the iterations the budget allows, from the time of the first evaluation;
//   a: chosen so that the first step moves a variable by `step_cells` (default 2) shift
//      units on average: a = step · (A + 1)^α / mean|ĝ_0|, with mean|ĝ_0| averaged over
//      `calibration_samples` gradient estimates at the start (their evaluations count).
// c = 2 and step = 2 were the best of c in {0.5, 1, 2, 4} x step in {0.1, 0.5, 2, 4, 8}
// on the headlight case (8 s); study_run --spsa-c/--spsa-step override them.
// The current iterate θ_k is itself evaluated every `eval_every` iterations; the result is
// the best point evaluated (perturbed points included), so the method is never judged
// on a diverged iterate.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "control_grid.hpp"

namespace study {

struct SpsaSettings {
    double alpha = 0.602, gamma = 0.101;
    double c_cells = 2.0;
    double step_cells = 2.0;
    double a_fraction = 0.1;  // A as a fraction of the expected iterations
    int calibration_samples = 2;
    int eval_every = 10;
};

struct SpsaReport {
    double a = 0, c = 0, A = 0, g0 = 0;
    std::int64_t iterations = 0, expected_iterations = 0;
};

inline SpsaReport run_spsa(ControlObjective& f, const SpsaSettings& s, std::uint64_t seed) {
    SpsaReport r;
    const std::size_t d = std::size_t(f.dimension());
    const double unit = f.shift_unit();
    std::vector<double> theta = f.initial_point(), plus(d), minus(d), delta(d);
    r.c = s.c_cells * unit;
    const auto rademacher = [&](std::uint64_t k) {
        CounterRng rng(hash_combine(seed, 0x5b5aULL), k);
        for (auto& v : delta) v = rng.uniform() < 0.5 ? -1.0 : 1.0;
    };
    // y(θ ± c Δ), with the perturbed points clamped to the bounds.
    const auto difference = [&](double ck) {
        for (std::size_t i = 0; i < d; ++i) {
            plus[i] = std::clamp(theta[i] + ck * delta[i], -1.0, 1.0);
            minus[i] = std::clamp(theta[i] - ck * delta[i], -1.0, 1.0);
        }
        return f.evaluate(plus) - f.evaluate(minus);
    };
    try {
        const auto t0 = Clock::now();
        f.evaluate(theta);
        const double t_eval = std::max(seconds_since(t0), 1e-6);
        const double left = std::max(0.0, f.budget() - f.elapsed());
        r.expected_iterations =
            std::max<std::int64_t>(10, std::int64_t(left / (t_eval * (2.0 + 1.0 / s.eval_every))));
        r.A = s.a_fraction * double(r.expected_iterations);
        double g_sum = 0;
        for (int k = 0; k < s.calibration_samples; ++k) {
            rademacher(~std::uint64_t(k));
            const double dy = difference(r.c);
            g_sum += std::abs(dy) / (2 * r.c);  // |ĝ_i| is the same for every i
        }
        r.g0 = g_sum / std::max(1, s.calibration_samples);
        // A flat start (every perturbation gives the same value) has no gradient to scale
        // by; take |ĝ_0| = 1 then, which makes the first step `step` units per unit slope.
        const double g0 = r.g0 > 0 ? r.g0 : 1.0;
        r.a = s.step_cells * unit * std::pow(r.A + 1, s.alpha) / g0;
        for (std::int64_t k = 0;; ++k) {
            const double ak = r.a / std::pow(double(k) + 1 + r.A, s.alpha);
            const double ck = r.c / std::pow(double(k) + 1, s.gamma);
            rademacher(std::uint64_t(k));
            const double dy = difference(ck);
            for (std::size_t i = 0; i < d; ++i) theta[i] = std::clamp(theta[i] - ak * dy / (2 * ck * delta[i]), -1.0, 1.0);
            r.iterations = k + 1;
            if ((k + 1) % s.eval_every == 0) f.evaluate(theta);
        }
    } catch (const BudgetExhausted&) {
    }
    return r;
}

}  // namespace study
