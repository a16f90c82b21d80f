#pragma once
// The height field as a black-box function of a few variables, for the baselines.
//
// Generic optimisers (SPSA, pagmo2, NLopt) cannot work on 10^4 heights when every
// evaluation is a full retrace, so they get what a user would give them: a coarse
// control grid of heights (13 x 13 by default, the shape of the surface), bilinearly
// refined to the case's final mesh, traced with the same tracer (HeightfieldTracer, the
// same Phong correction) against the same objective our method minimises (L1 error +
// Sobel term, divided by the energy below the threshold, plus the lost-light term). The
// refinement is bilinear, as a user would first write it (the library's designer refines
// its levels with refine_preserving_normals instead). With a control grid as fine
// as the final mesh (the headlight's 13 x 13) nothing is refined.
//
// Variables are normalised: z in [-1, 1] maps to [h_min, h_max]; z = 0 is the middle of
// the bounds (the flat start of every public case). Step sizes of the baselines are given
// in the physical unit our method uses for its move amplitudes: the height change that
// moves reflected light by one receiver cell across one control-grid spacing
// (shift_unit()).
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "common.hpp"

namespace study {

// Thrown by ControlObjective::evaluate once the time budget is spent; optimisers that
// cannot be stopped from outside (pagmo's evolve) are unwound by it.
struct BudgetExhausted {};

class ControlObjective {
public:
    // `start`: when the method's clock started (setup such as ray generation counts).
    ControlObjective(const DesignJob& run_job, const ImageD& target_image, int control_x, int control_y, int final_x,
                     int final_y, std::uint64_t seed, int threads, double budget_seconds, Clock::time_point start)
        : scene_(run_job.scene), threads_(threads), budget_(budget_seconds), start_(start),
          initial_(io::make_initial_heightmap(run_job.scene, final_x, final_y)), surface_(initial_),
          rays_(generate_rays(run_job.scene.light, initial_, run_job.scene.receiver, seed)),
          params_(make_path_params(run_job.scene)),
          target_(make_target(target_image, run_job.scene.receiver.width, run_job.scene.receiver.height,
                              rays_.total)),
          image_(target_), weights_(run_job.options.objective),
          cx_(control_x), cy_(control_y) {
        if (cx_ < 2 || cy_ < 2) throw InputError("--control: the control grid needs at least 2 x 2 vertices");
        control_ = Heightmap(cx_, cy_, initial_.size(), initial_.h_min(), initial_.h_max(), initial_.frame(),
                             initial_.aperture());
        mid_ = 0.5 * (double(initial_.h_min()) + initial_.h_max());
        half_ = 0.5 * (double(initial_.h_max()) - initial_.h_min());
        if (!(half_ > 0)) throw InputError("surface.height_bounds: the baselines need h_min < h_max");
        const Heightmap start_control = initial_.resampled(cx_, cy_);
        x0_.resize(std::size_t(cx_) * cy_);
        for (std::size_t k = 0; k < x0_.size(); ++k)
            x0_[k] = std::clamp((double(start_control.heights()[k]) - mid_) / half_, -1.0, 1.0);
    }

    int dimension() const { return cx_ * cy_; }
    int control_x() const { return cx_; }
    int control_y() const { return cy_; }
    const std::vector<double>& initial_point() const { return x0_; }
    std::int64_t rays() const { return rays_.size(); }

    // Normalised height change that moves the light by one receiver cell across one
    // control-grid spacing (design_detail::amplitude_unit on the control grid).
    double shift_unit() const {
        Receiver rec = scene_.receiver;
        return design_detail::amplitude_unit(scene_, rec, control_) / half_;
    }

    double elapsed() const { return seconds_since(start_); }
    double budget() const { return budget_; }
    bool exhausted() const { return elapsed() >= budget_; }

    // The final-mesh surface of a point z (clamped to [-1, 1]).
    Heightmap surface_of(std::span<const double> z) const {
        std::vector<float> h(z.size());
        for (std::size_t k = 0; k < z.size(); ++k) h[k] = float(mid_ + std::clamp(z[k], -1.0, 1.0) * half_);
        Heightmap c = control_;
        c.set_heights(h);
        if (c.nx() == initial_.nx() && c.ny() == initial_.ny()) return c;
        return c.resampled(initial_.nx(), initial_.ny());
    }

    // The objective at z: one full trace. Throws BudgetExhausted when called after the
    // budget is spent (the best point so far is kept).
    double evaluate(std::span<const double> z) {
        if (exhausted()) throw BudgetExhausted{};
        if (z.size() != x0_.size())
            throw InputError("control objective: expected " + std::to_string(x0_.size()) + " variables, got " +
                             std::to_string(z.size()));
        for (double v : z)
            if (!std::isfinite(v)) return record(z, nullptr);  // an optimiser diverged: worst value, no trace
        surface_ = surface_of(z);
        HeightfieldTracer tracer(surface_, rays_, params_);
        Histogram h(params_.receiver.width, params_.receiver.height);
        TraceTotals totals;
        tracer.trace_all(exec::omp_t{threads_}, h, totals);
        image_.reset(h);
        const ObjectiveValue v = combine(image_.sums(), rays_.total, 0.0, weights_);
        return record(z, &v);
    }

    std::int64_t evaluations() const { return evaluations_; }
    const std::vector<double>& best_point() const { return best_.empty() ? x0_ : best_; }
    double best_value() const { return best_value_; }
    const std::vector<TracePoint>& trace() const { return trace_; }

    // Adds a final trace point at the current time (the curve holds its last value).
    void close_trace() {
        if (trace_.empty()) return;
        TracePoint p = trace_.back();
        p.seconds = elapsed();
        p.iterations = evaluations_;
        trace_.push_back(p);
    }

private:
    double record(std::span<const double> z, const ObjectiveValue* v) {
        ++evaluations_;
        const double value = v ? v->total : std::numeric_limits<double>::max();
        if (v && value < best_value_) {
            best_value_ = value;
            best_.assign(z.begin(), z.end());
            for (double& b : best_) b = std::clamp(b, -1.0, 1.0);
            trace_.push_back({elapsed(), evaluations_, 0, v->error, v->energy, v->total});
        }
        return value;
    }

    Scene scene_;
    int threads_;
    double budget_;
    Clock::time_point start_;
    Heightmap initial_, surface_, control_;
    RaySet rays_;
    PathParams params_;
    Target target_;
    ImageState image_;
    ObjectiveWeights weights_;
    int cx_, cy_;
    double mid_ = 0, half_ = 1;
    std::vector<double> x0_, best_;
    double best_value_ = std::numeric_limits<double>::max();
    std::int64_t evaluations_ = 0;
    std::vector<TracePoint> trace_;
};

// A control grid with about `n` vertices along the longer side of the surface and the
// surface's aspect ratio, never finer than the final mesh.
inline std::pair<int, int> control_grid_for(int n, int final_x, int final_y) {
    if (n <= 0) return {final_x, final_y};
    const int longer = std::max(final_x, final_y);
    if (n >= longer) return {final_x, final_y};
    const double ratio = double(std::min(final_x, final_y) - 1) / double(longer - 1);
    const int shorter = std::max(2, int(std::lround((n - 1) * ratio)) + 1);
    return final_x >= final_y ? std::pair{n, shorter} : std::pair{shorter, n};
}

}  // namespace study
