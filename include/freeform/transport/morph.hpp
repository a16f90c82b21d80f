#pragma once
// The alternative the back-and-forth solver is measured against (bench_transport):
// Poisson mesh morphing, the iteration many caustic tools use. The source cells are
// points that carry their mass; each round splats them onto the grid (bilinear), solves
// (−Δ)Φ = ρ − ν with Neumann boundaries, and moves every point by −τ∇Φ/ρ, the step of
// the continuity equation that drives ρ towards ν. It needs no potentials and no
// c-transforms, but its map is not optimal (it accumulates curl) and it cannot empty a
// region of the target completely: points are only ever pushed, never assigned.
#include <algorithm>
#include <chrono>
#include <cmath>

#include "grid_ot.hpp"

namespace freeform {

struct MorphOptions {
    int iterations = 60;
    double step = 0.5;  // τ, fraction of the continuity step per round
};

// The morphing map from `source` to `target` on `grid`, in an OtResult (map_x, map_y,
// pushed, residual; the potentials are left empty and `transport()` is not meaningful:
// use operator()).
inline OtResult solve_morphing(const OtGrid& grid, const Eigen::ArrayXXd& source, const Eigen::ArrayXXd& target,
                               const MorphOptions& options = {}) {
    const auto t0 = std::chrono::steady_clock::now();
    const double ms = source.sum(), mt = target.sum();
    if (!(ms > 0)) throw InputError("transport: the source carries no light");
    if (!(mt > 0)) throw InputError("transport: the target is entirely black");
    const int nx = grid.nx, ny = grid.ny;
    const double cell = grid.hx * grid.hy;
    const Eigen::ArrayXXd mu = source / ms, nu = target / mt;
    const NeumannPoisson poisson(nx, ny, grid.hx, grid.hy);
    OtResult r;
    r.grid = grid;
    r.target = target;
    r.map_x.resize(ny, nx);
    r.map_y.resize(ny, nx);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) r.map_x(j, i) = grid.x_of(i), r.map_y(j, i) = grid.y_of(j);
    const auto splat = [&](Eigen::ArrayXXd& out) {
        out.setZero(ny, nx);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const double w = mu(j, i);
                if (!(w > 0)) continue;
                const double fx = std::clamp((r.map_x(j, i) - grid.x0) / grid.hx - 0.5, 0.0, double(nx - 1));
                const double fy = std::clamp((r.map_y(j, i) - grid.y0) / grid.hy - 0.5, 0.0, double(ny - 1));
                const int a = std::min(int(fx), nx - 2), b = std::min(int(fy), ny - 2);
                const double p = fx - a, q = fy - b;
                out(b, a) += w * (1 - p) * (1 - q);
                out(b, a + 1) += w * p * (1 - q);
                out(b + 1, a) += w * (1 - p) * q;
                out(b + 1, a + 1) += w * p * q;
            }
    };
    const auto at = [&](const Eigen::ArrayXXd& f, double x, double y) {
        const double fx = std::clamp((x - grid.x0) / grid.hx - 0.5, 0.0, double(nx - 1));
        const double fy = std::clamp((y - grid.y0) / grid.hy - 0.5, 0.0, double(ny - 1));
        const int a = std::min(int(fx), nx - 2), b = std::min(int(fy), ny - 2);
        const double p = fx - a, q = fy - b;
        return (1 - q) * ((1 - p) * f(b, a) + p * f(b, a + 1)) + q * ((1 - p) * f(b + 1, a) + p * f(b + 1, a + 1));
    };
    Eigen::ArrayXXd rho;
    const double floor = 0.05 * nu.maxCoeff() / cell;
    for (int it = 0; it < options.iterations; ++it) {
        splat(rho);
        r.residual_history.push_back(ot_detail::block_residual(nu, rho, 4));
        const Eigen::ArrayXXd phi = poisson.solve((rho - nu) / cell);
        Eigen::ArrayXXd gx(ny, nx), gy(ny, nx);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const int il = std::max(i - 1, 0), ir = std::min(i + 1, nx - 1);
                const int jl = std::max(j - 1, 0), jr = std::min(j + 1, ny - 1);
                const double dens = std::max(rho(j, i) / cell, floor);
                gx(j, i) = (phi(j, ir) - phi(j, il)) / ((ir - il) * grid.hx) / dens;
                gy(j, i) = (phi(jr, i) - phi(jl, i)) / ((jr - jl) * grid.hy) / dens;
            }
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                if (!(mu(j, i) > 0)) continue;
                const double x = r.map_x(j, i), y = r.map_y(j, i);
                r.map_x(j, i) = x - options.step * at(gx, x, y);
                r.map_y(j, i) = y - options.step * at(gy, x, y);
            }
        r.iterations = it + 1;
    }
    splat(rho);
    r.pushed = rho * mt;
    r.residual = ot_detail::block_residual(target, r.pushed, 4) / mt;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return r;
}

}  // namespace freeform
