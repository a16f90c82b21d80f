#pragma once
// Held-out checks: judging a design with rays it was not fitted to.
//
// The annealer minimises the objective of one fixed set of jittered rays. With few rays
// per receiver cell and a fine mesh, it can lower that objective by arranging where
// those particular rays land (fitting their sampling noise) while the light the surface
// really throws gets no better, or worse. Measured on the headlight case (53² mesh,
// 16 rays per cell, 64,000 iterations; git show fc8ce6e:benchmarks/results/stability_fixed_speed11/REPORT.md, with
// the old, too hot initial temperature): the objective's error fell from 0.016 to
// 0.010 while the same surfaces traced with other rays went from 0.0164 to 0.0170. With
// today's calibration both fall (0.0163 -> 0.0063 fitted, -> 0.0096 on other rays;
// git show ce210ae:benchmarks/results/calibration/REPORT.md), and a third of the gain is
// still noise. On the letter E and the point-light case the two agree within 1 %.
//
// A HeldOutCheck traces a surface with a second, independent jitter of the same light
// (same count, same weights; the seed is derived from the design's) and returns the
// objective of that render. The designer calls it at the start of every stage, every
// `interval()` iterations during it and at its end, keeps a copy of the heights that
// did best, and ends the stage with them when they beat its end state: a stage never
// ends worse on rays it has not seen than the best state it passed through (its start
// included). The error of the final design on the held-out rays is reported next to
// the fitted one (metrics.json final.error_held_out), which tells a user how much of
// the fitted error is real.
#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "../core/exec.hpp"
#include "../core/rng.hpp"
#include "../objective/objective.hpp"
#include "../objective/trace_setup.hpp"
#include "../scene/rays.hpp"
#include "../trace/heightfield.hpp"

namespace freeform {

class HeldOutCheck {
public:
    // The held-out rays of a design with seed `design_seed` on `level` (the same light,
    // aperture and receiver as the fitted rays, another jitter).
    static std::uint64_t seed_for(std::uint64_t design_seed, std::size_t level) {
        return hash_combine(hash_combine(design_seed, 0x4e1d0075ULL), std::uint64_t(level));
    }

    // `setup`: the rays (of seed_for's seed), path parameters and target (make_trace_setup).
    HeldOutCheck(TraceSetup setup, ObjectiveWeights weights, const Penalties& penalties, int threads)
        : seed_(setup.seed), rays_(std::move(setup.rays)), params_(setup.params), image_(std::move(setup.target)),
          weights_(weights), penalties_(&penalties), threads_(threads) {}

    std::int64_t rays() const { return rays_.size(); }
    std::uint64_t seed() const { return seed_; }

    // Iterations between checks: a check is one full trace of the held-out rays, which
    // costs about as much as (rays / 32) incremental moves on the cases measured, so a
    // check every rays / 32 iterations keeps their cost near a few per cent of a stage.
    std::int64_t interval() const { return std::max<std::int64_t>(500, rays_.size() / 32); }

    // The objective of `surface` traced with the held-out rays (its penalties are the
    // surface's own: they do not depend on rays).
    ObjectiveValue operator()(const Heightmap& surface) {
        const HeightfieldTracer tracer(surface, rays_, params_);
        histogram_ = Histogram(image_.width(), image_.height());
        TraceTotals totals;
        tracer.trace_all(exec::omp_t{threads_}, histogram_, totals);
        image_.reset(histogram_);
        return combine(image_.sums(), image_.target().total, Penalties::value(penalties_->full(surface), surface), weights_);
    }
    // What the last call traced, and the target it was judged against.
    const Histogram& histogram() const { return histogram_; }
    const Target& target() const { return image_.target(); }

private:
    std::uint64_t seed_;
    RaySet rays_;
    PathParams params_;
    ImageState image_;
    ObjectiveWeights weights_;
    const Penalties* penalties_;
    int threads_;
    Histogram histogram_;
};

// The best state seen by held-out checks during one stage.
struct HeldOutBest {
    ObjectiveValue value;          // held-out objective of `heights`
    std::vector<float> heights;    // empty until the first check
    std::int64_t iteration = -1;   // stage iteration of the check (0 = the stage's start)
    std::int64_t checks = 0;       // states offered
    // Keeps `surface` when its held-out objective beats the best so far.
    bool offer(const Heightmap& surface, const ObjectiveValue& v, std::int64_t it) {
        ++checks;
        if (!heights.empty() && !(v.total < value.total)) return false;
        value = v;
        heights = surface.heights();
        iteration = it;
        return true;
    }
};

}  // namespace freeform
