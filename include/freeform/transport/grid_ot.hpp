#pragma once
// Optimal transport between two densities on one regular grid, quadratic cost, by the
// back-and-forth method (Jacobs & Léger, "A fast approach to optimal transport: the
// back-and-forth method", Numer. Math. 2020).
//
// Why this method: it keeps the two Kantorovich potentials on the grid and alternates
// gradient ascent steps on the dual problem in the H¹ metric, each step followed by an
// exact c-transform. A c-transform for the quadratic cost is two passes of the 1-D
// discrete Legendre transform (linear time), and the H¹ step is one Neumann Poisson
// solve, so an iteration costs a few passes over the grid. Zero densities need no
// special care: a region of the target with no mass simply never receives any, which a
// black background or the gaps of a letter ask for. Sinkhorn would blur the map by its
// entropic width unless the temperature is driven down at great cost, and semi-discrete
// solvers need power diagrams clipped to the aperture for every Newton step; the study
// (benchmarks/study) compares this solver's maps with Poisson mesh morphing.
//
// Conventions: an nx × ny grid of cells of size hx × hy whose cell (i, j) (column i,
// row j) has its centre at (x0 + (i + ½) hx, y0 + (j + ½) hy); arrays are ny rows × nx
// columns. Masses are per cell and must sum to the same total on both sides. Everything
// is deterministic: loops over rows and columns run on OpenMP threads (OtOptions::threads),
// each line by the same serial code, so the thread count never changes a result; no
// global state.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <complex>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Dense>
#include <unsupported/Eigen/FFT>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../core/math.hpp"

namespace freeform {

struct OtGrid {
    int nx = 0, ny = 0;
    double x0 = 0, y0 = 0;  // corner of cell (0, 0)
    double hx = 1, hy = 1;  // cell size
    // The source side's coordinates are the flat landings times this factor, about the
    // receiver's centre (transport_grid: a footprint wider than the grid may reach is
    // shrunk onto it, not cut). A similarity of the source leaves a quadratic-cost map
    // as it is: if T = ∇f is optimal from μ, then x ↦ T(x/s) = ∇(s·f(x/s)) is the
    // gradient of a convex function pushing the scaled μ onto the same ν (Brenier).
    double source_scale = 1;

    double x_of(int i) const { return x0 + (i + 0.5) * hx; }
    double y_of(int j) const { return y0 + (j + 0.5) * hy; }
};

struct OtOptions {
    int max_iterations = 120;  // back-and-forth iterations (each one step on either side)
    double tolerance = 2e-3;   // stop when the residual (see OtResult) falls below this
    int patience = 5;          // ... or when the best residual has not improved by 1 % in this many
    int samples = 4;           // samples per cell and axis in the exact pushforward
    int residual_block = 4;    // cells per side of the blocks the residual compares
    double time_limit = 0;     // seconds; 0: none (a limit makes the result time dependent)
    int threads = 0;           // OpenMP threads for the line passes and Poisson solves (0: default)
    // A target-side potential to start from (OtResult::phi of an earlier solve on the same
    // grid, for a target that differs a little); unset or of another size: zero.
    std::shared_ptr<const Eigen::ArrayXXd> warm_phi;
};

// The solution: T(x) = x − ∇ψ(x) moves the source mass μ onto ν.
struct OtResult {
    OtGrid grid;
    Eigen::ArrayXXd psi;             // source-side potential ψ (ny × nx), grid units
    Eigen::ArrayXXd phi;             // target-side potential φ = ψ^c
    Eigen::ArrayXXd target;          // ν as given
    Eigen::ArrayXXd map_x, map_y;    // T at the cell centres, physical coordinates
    Eigen::ArrayXXd pushed;          // T#μ (exact map, `samples`² per cell), in the target's units
    // ½ Σ |ν − T#μ| / Σ ν over blocks of residual_block² cells: the exact map's
    // pushforward is rasterised from samples² points per source cell, so a single cell
    // carries the sampling noise of a few points; blocks measure the map, not that noise.
    double residual = 1;
    int iterations = 0;
    double seconds = 0;
    std::vector<double> residual_history;

    // True when the target has mass in the cell containing (x, y).
    bool lit(double x, double y) const {
        const int i = std::clamp(int(std::floor((x - grid.x0) / grid.hx)), 0, grid.nx - 1);
        const int j = std::clamp(int(std::floor((y - grid.y0) / grid.hy)), 0, grid.ny - 1);
        return target(j, i) > 0;
    }

    // The exact transport of the point (x, y): the centre of the lit target cell y that
    // minimises |x − y|²/2 − φ(y), the first such cell in row-major order on a tie. With
    // the rows' envelopes (index_exact, made by solve_grid_ot) a row is asked only for the
    // cells its envelope holds at x, about 2 log n operations a row instead of n; without
    // them (or when φ or the target has another size) every lit cell is scanned. Both
    // give the same cell: the envelope's cell and its two neighbours on the envelope are
    // compared by the scan's own expression.
    Vec2d exact(double x, double y) const {
        double best = std::numeric_limits<double>::infinity();
        Vec2d out{x, y};
        const auto consider = [&](int i, int j) {
            const double dx = x - grid.x_of(i), dy = y - grid.y_of(j);
            const double c = 0.5 * (dx * dx + dy * dy) - phi(j, i);
            if (c < best) best = c, out = {grid.x_of(i), grid.y_of(j)};
        };
        if (!exact_index_current()) {
            for (int j = 0; j < grid.ny; ++j)
                for (int i = 0; i < grid.nx; ++i)
                    if (target(j, i) > 0) consider(i, j);
            return out;
        }
        for (int j = 0; j < grid.ny; ++j) {
            const std::size_t b = envelope_start_[std::size_t(j)], e = envelope_start_[std::size_t(j) + 1];
            if (b == e) continue;  // no lit cell in this row
            // The envelope's piece holding x: the last whose lower end is at or below it.
            const auto from = envelope_from_.begin();
            std::size_t k = std::size_t(std::upper_bound(from + std::ptrdiff_t(b) + 1, from + std::ptrdiff_t(e), x) - from) - 1;
            for (std::size_t c = k > b ? k - 1 : k; c <= std::min(k + 1, e - 1); ++c) consider(envelope_cell_[c], j);
        }
        return out;
    }

    // Makes the rows' envelopes that speed up exact(): in each row, the lower envelope of
    // the lit cells' parabolas |x − x_i|²/2 − φ_i along the row (all of one curvature, so
    // each is on it over one interval; Felzenszwalb & Huttenlocher's distance-transform
    // construction), as cells in order and the x where each one's interval begins. Linear
    // in the cells. Call it again after changing `phi` or `target`.
    void index_exact() {
        envelope_cell_.clear(), envelope_from_.clear();
        envelope_start_.assign(std::size_t(grid.ny) + 1, 0);
        if (!arrays_on_grid()) return;
        const double inf = std::numeric_limits<double>::infinity();
        for (int j = 0; j < grid.ny; ++j) {
            const std::size_t b = envelope_cell_.size();
            for (int i = 0; i < grid.nx; ++i) {
                if (!(target(j, i) > 0)) continue;
                double from = -inf;
                while (envelope_cell_.size() > b) {
                    const int a = envelope_cell_.back();
                    // Where cell i's parabola meets cell a's (a < i): below it a's is lower.
                    from = 0.5 * (grid.x_of(a) + grid.x_of(i)) + (phi(j, a) - phi(j, i)) / (grid.x_of(i) - grid.x_of(a));
                    if (from > envelope_from_.back()) break;
                    envelope_cell_.pop_back(), envelope_from_.pop_back();  // a is nowhere lowest
                    from = -inf;
                }
                envelope_cell_.push_back(i), envelope_from_.push_back(from);
            }
            envelope_start_[std::size_t(j) + 1] = envelope_cell_.size();
        }
    }

    // Where the map sends the point (x, y): the smooth map, interpolated between cell
    // centres, except where that lands on an unlit cell. There the point sits on a crack
    // of the map (it jumps, and interpolation across the jump lands in the gap between
    // two parts of the target), and gets its exact transport, always a lit cell.
    // (A map without potentials, such as mesh morphing's, is taken as it is.)
    Vec2d transport(double x, double y) const {
        const Vec2d q = (*this)(x, y);
        return phi.size() == 0 || lit(q.x, q.y) ? q : exact(x, y);
    }

    // T at any point, bilinear between cell centres (clamped to the grid's centres).
    Vec2d operator()(double x, double y) const {
        const double fx = std::clamp((x - grid.x0) / grid.hx - 0.5, 0.0, double(grid.nx - 1));
        const double fy = std::clamp((y - grid.y0) / grid.hy - 0.5, 0.0, double(grid.ny - 1));
        const int i = std::min(int(fx), std::max(0, grid.nx - 2)), j = std::min(int(fy), std::max(0, grid.ny - 2));
        const int i1 = std::min(i + 1, grid.nx - 1), j1 = std::min(j + 1, grid.ny - 1);
        const double a = fx - i, b = fy - j;
        const auto lerp = [&](const Eigen::ArrayXXd& m) {
            return (1 - b) * ((1 - a) * m(j, i) + a * m(j, i1)) + b * ((1 - a) * m(j1, i) + a * m(j1, i1));
        };
        return {lerp(map_x), lerp(map_y)};
    }

private:
    // Whether envelopes of this grid's size are there (a copy of the result carries its
    // envelopes with its equal arrays).
    bool exact_index_current() const { return envelope_start_.size() == std::size_t(grid.ny) + 1 && arrays_on_grid(); }
    bool arrays_on_grid() const {
        return phi.rows() == grid.ny && phi.cols() == grid.nx && target.rows() == grid.ny && target.cols() == grid.nx;
    }
    std::vector<int> envelope_cell_;       // each row's envelope cells, rows one after another
    std::vector<double> envelope_from_;    // where each envelope cell's interval begins
    std::vector<std::size_t> envelope_start_;  // row j's envelope: [start[j], start[j + 1])
};

// Solves (−Δ)u = f on an nx × ny grid with spacing hx × hy and Neumann boundaries,
// where −Δ is the 5-point graph Laplacian (row p: Σ over grid neighbours q of
// (u_p − u_q)/h²), by its eigenbasis: the cosines cos(πk(i + ½)/n) of each axis, i.e. an
// orthonormal DCT-II along each axis, a division by the eigenvalues, and the inverse
// DCT (DCT-III). Each 1-D transform is one complex FFT of twice the length (Eigen's FFT
// module, kissfft underneath) of the even extension: O(n² log n) per solve where the
// dense eigenbasis products it replaced cost O(n³) (half of a 600² transport solve's time).
// The solution has zero mean (the constant is the null space). Rows and columns are
// transformed in parallel, each by the same serial FFT whatever the thread count, so the
// result does not depend on it (tested).
class NeumannPoisson {
public:
    NeumannPoisson(int nx, int ny, double hx, double hy, int threads = 0)
        : x_(nx, hx), y_(ny, hy), threads_(threads) {}

    // f and the result are ny rows × nx columns.
    Eigen::ArrayXXd solve(const Eigen::ArrayXXd& f) const {
        const int nx = x_.n, ny = y_.n;
        Eigen::ArrayXXd a = f;
        // Forward: along y (columns, contiguous), then along x (rows).
        along(a, y_, false, true);
        along(a, x_, false, false);
        for (int i = 0; i < nx; ++i)
            for (int j = 0; j < ny; ++j) {
                const double l = y_.lambda[std::size_t(j)] + x_.lambda[std::size_t(i)];
                a(j, i) = l > 0 ? a(j, i) / l : 0.0;
            }
        along(a, x_, true, false);
        along(a, y_, true, true);
        return a;
    }

private:
    struct Axis {
        int n = 0;
        std::vector<double> lambda;               // eigenvalues of the 1-D Neumann Laplacian
        std::vector<std::complex<double>> shift;  // norm_k · e^{iπk/(2n)}
        Axis(int n_, double h) : n(n_), lambda(std::size_t(n_)), shift(std::size_t(n_)) {
            for (int k = 0; k < n; ++k) {
                const double norm = k == 0 ? std::sqrt(1.0 / n) : std::sqrt(2.0 / n);
                lambda[std::size_t(k)] = (2.0 - 2.0 * std::cos(pi * k / n)) / (h * h);
                shift[std::size_t(k)] = norm * std::polar(1.0, pi * k / (2.0 * n));
            }
        }
    };

    // Transforms every column (`columns`) or every row of `a` along `ax`: the orthonormal
    // DCT-II (inverse = false) or its inverse, the DCT-III.
    void along(Eigen::ArrayXXd& a, const Axis& ax, bool inverse, bool columns) const {
        const int n = ax.n, lines = columns ? int(a.cols()) : int(a.rows());
        for_each_worker_range(exec::omp_t{threads_}, lines, [&](std::int64_t begin, std::int64_t end) {
            Eigen::FFT<double> fft;
            std::vector<std::complex<double>> in(std::size_t(2 * n)), out(std::size_t(2 * n));
            for (std::int64_t l = begin; l < end; ++l) {
                const auto at = [&](int m) -> double& { return columns ? a(m, l) : a(l, m); };
                if (!inverse) {
                    // Even extension y = (x, reversed x): Y_k = 2 e^{iπk/2n} Σ x_m cos(πk(m + ½)/n).
                    for (int m = 0; m < n; ++m) in[std::size_t(m)] = in[std::size_t(2 * n - 1 - m)] = at(m);
                    fft.fwd(out, in);
                    for (int k = 0; k < n; ++k)  // X_k = norm_k Σ x_m cos(πk(m + ½)/n)
                        at(k) = 0.5 * (std::conj(ax.shift[std::size_t(k)]) * out[std::size_t(k)]).real();
                } else {
                    // x_m = Σ_k norm_k X_k cos(πk(m + ½)/n) = Re Σ_k (norm_k X_k e^{iπk/2n}) e^{2πikm/2n}.
                    for (int k = 0; k < n; ++k) in[std::size_t(k)] = ax.shift[std::size_t(k)] * at(k);
                    for (int k = n; k < 2 * n; ++k) in[std::size_t(k)] = 0.0;
                    fft.inv(out, in);  // scaled by 1/(2n)
                    for (int m = 0; m < n; ++m) at(m) = 2.0 * n * out[std::size_t(m)].real();
                }
            }
        });
    }

    Axis x_, y_;
    int threads_ = 0;
};

namespace ot_detail {

// out[j] = max_k x_j y_k − f_k for m sorted queries x over n sorted abscissae y: the
// discrete Legendre transform, linear time by the lower convex hull of (y_k, f_k).
// `arg` (optional) receives the maximising k of each query. Abscissae where f is +∞
// take no part (out is −∞ and arg −1 when none is left).
inline void legendre_1d(const double* f, std::ptrdiff_t stride, int n, const double* y, const double* x, int m,
                        double* out, std::ptrdiff_t out_stride, int* arg, std::vector<int>& hull) {
    hull.clear();
    for (int k = 0; k < n; ++k) {
        if (!(f[k * stride] < std::numeric_limits<double>::infinity())) continue;
        while (hull.size() >= 2) {
            const int a = hull[hull.size() - 2], b = hull.back();
            // b is not on the lower hull if the slope a→k is at most the slope a→b.
            const double lhs = (f[b * stride] - f[a * stride]) * (y[k] - y[a]);
            const double rhs = (f[k * stride] - f[a * stride]) * (y[b] - y[a]);
            if (lhs >= rhs)
                hull.pop_back();
            else
                break;
        }
        hull.push_back(k);
    }
    if (hull.empty()) {
        for (int j = 0; j < m; ++j) {
            out[j * out_stride] = -std::numeric_limits<double>::infinity();
            if (arg) arg[j] = -1;
        }
        return;
    }
    std::size_t p = 0;
    for (int j = 0; j < m; ++j) {
        const double q = x[j];
        while (p + 1 < hull.size()) {
            const int a = hull[p], b = hull[p + 1];
            const double slope = (f[b * stride] - f[a * stride]) / (y[b] - y[a]);
            if (slope <= q)
                ++p;
            else
                break;
        }
        const int k = hull[p];
        out[j * out_stride] = q * y[k] - f[k * stride];
        if (arg) arg[j] = k;
    }
}

// The solver's workspace: coordinates, Poisson bases, scratch.
class Workspace {
public:
    explicit Workspace(const OtGrid& g, int threads = 0)
        : g_(g), xs_(std::size_t(g.nx)), ys_(std::size_t(g.ny)), poisson_(g.nx, g.ny, g.hx, g.hy, threads), threads_(threads) {
        for (int i = 0; i < g.nx; ++i) xs_[std::size_t(i)] = g.x_of(i);
        for (int j = 0; j < g.ny; ++j) ys_[std::size_t(j)] = g.y_of(j);
        sq_ = Eigen::ArrayXXd(g.ny, g.nx);
        for (int j = 0; j < g.ny; ++j)
            for (int i = 0; i < g.nx; ++i) sq_(j, i) = 0.5 * (xs_[std::size_t(i)] * xs_[std::size_t(i)] + ys_[std::size_t(j)] * ys_[std::size_t(j)]);
    }

    // a^c(x) = min_y |x − y|²/2 − a(y) on the grid: |x|²/2 − (|y|²/2 − a)*(x), the
    // Legendre transform taken along rows, then along columns.
    // Only cells where `support` > 0 take part (the minimum runs over the support of
    // the side's mass: a cell without mass never receives any).
    Eigen::ArrayXXd c_transform(const Eigen::ArrayXXd& a, const Eigen::ArrayXXd& support) const {
        const int nx = g_.nx, ny = g_.ny;
        const Eigen::ArrayXXd gfun = restrict(sq_ - a, support);
        Eigen::ArrayXXd h(ny, nx);
        lines(ny, [&](std::int64_t j, LineScratch& scratch) {  // along x: h(j, i) = max_k x_i x_k − g(j, k)
            legendre_1d(&gfun(j, 0), ny, nx, xs_.data(), xs_.data(), nx, &h(j, 0), ny, nullptr, scratch.hull);
        });
        // along y: g*(j, i) = max_k y_j y_k + h(k, i) = Legendre of −h.
        const Eigen::ArrayXXd neg = -h;
        Eigen::ArrayXXd star(ny, nx);
        lines(nx, [&](std::int64_t i, LineScratch& scratch) {
            legendre_1d(&neg(0, i), 1, ny, ys_.data(), ys_.data(), ny, &star(0, i), 1, nullptr, scratch.hull);
        });
        return sq_ - star;
    }

    // The mass `m` carried to the cells of the other side by the exact transport map of
    // the potential `a` there: each cell of m is split into k × k samples, and sample z
    // goes whole to the cell y that minimises |z − y|²/2 − a(y) (the argmax of the
    // Legendre transform, found with it). This is the mass of each cell's Laguerre cell,
    // rasterised: regions that the map skips (the gaps of a letter) stay exactly empty,
    // where interpolating a map between cell centres smears mass across every jump.
    // `value` receives Σ over samples of their mass times a^c at the sample, the second
    // half of the dual objective with the same samples (so that the objective and the
    // mass it is steered by agree).
    // The transforms run line by line in parallel; where each sample goes is recorded and
    // the masses are then added in one fixed order, so the sums never depend on threads.
    Eigen::ArrayXXd push_exact(const Eigen::ArrayXXd& a, const Eigen::ArrayXXd& support, const Eigen::ArrayXXd& m, int k,
                               double& value) {
        const int nx = g_.nx, ny = g_.ny, fx = nx * k, fy = ny * k;
        std::vector<double> qx(static_cast<std::size_t>(fx)), qy(static_cast<std::size_t>(fy));
        for (int i = 0; i < fx; ++i) qx[std::size_t(i)] = g_.x0 + (i + 0.5) * g_.hx / k;
        for (int j = 0; j < fy; ++j) qy[std::size_t(j)] = g_.y0 + (j + 0.5) * g_.hy / k;
        const Eigen::ArrayXXd gfun = restrict(sq_ - a, support);
        // Along x, for every row of a: h(row, q) and its maximiser.
        Eigen::ArrayXXd& h = push_h_;  // reused: allocating it per call costs page faults
        h.resize(ny, fx);
        std::vector<int>& arg_x = push_arg_;
        arg_x.resize(std::size_t(ny) * fx);
        lines(ny, [&](std::int64_t j, LineScratch& scratch) {
            legendre_1d(&gfun(j, 0), ny, nx, xs_.data(), qx.data(), fx, &h(j, 0), ny, &arg_x[std::size_t(j) * fx], scratch.hull);
        });
        // Along y, for every fine column that carries mass: the maximising row of each
        // sample, its target cell (−1: no mass) and the column's share of `value`.
        h = -h;  // the column pass transforms −h
        const Eigen::ArrayXXd& neg = h;
        std::vector<std::uint8_t> carries(static_cast<std::size_t>(nx), 0);
        for (int i = 0; i < nx; ++i) carries[std::size_t(i)] = (m.col(i) > 0).any();
        std::vector<int>& dest = push_dest_;  // written for every sample of a column that carries mass
        dest.resize(std::size_t(fx) * fy);
        std::vector<double> column_value(static_cast<std::size_t>(fx), 0.0);
        const double share = 1.0 / (k * k);
        lines(fx, [&](std::int64_t q, LineScratch& scratch) {
            const int i_src = int(q) / k;
            if (!carries[std::size_t(i_src)]) return;
            std::vector<double>& col_out = scratch.values;
            std::vector<int>& arg_y = scratch.args;
            col_out.resize(std::size_t(fy));
            arg_y.resize(std::size_t(fy));
            legendre_1d(&neg(0, q), 1, ny, ys_.data(), qy.data(), fy, col_out.data(), 1, arg_y.data(), scratch.hull);
            double v = 0;
            for (int r = 0; r < fy; ++r) {
                const double w = m(r / k, i_src);
                dest[std::size_t(q) * fy + std::size_t(r)] = -1;
                if (!(w > 0)) continue;
                const int jt = arg_y[std::size_t(r)];
                const int it = arg_x[std::size_t(jt) * fx + std::size_t(q)];
                dest[std::size_t(q) * fy + std::size_t(r)] = it * ny + jt;
                // a^c(z) = |z|²/2 − g*(z), g* = −(the column transform of −h).
                v += w * share * (0.5 * (qx[std::size_t(q)] * qx[std::size_t(q)] + qy[std::size_t(r)] * qy[std::size_t(r)]) -
                                  col_out[std::size_t(r)]);
            }
            column_value[std::size_t(q)] = v;
        });
        Eigen::ArrayXXd out = Eigen::ArrayXXd::Zero(ny, nx);
        value = 0;
        for (int q = 0; q < fx; ++q) {
            if (!carries[std::size_t(q / k)]) continue;
            value += column_value[std::size_t(q)];
            for (int r = 0; r < fy; ++r) {
                const int d = dest[std::size_t(q) * fy + std::size_t(r)];
                if (d >= 0) out.data()[d] += m(r / k, q / k) * share;
            }
        }
        return out;
    }

    // T(z) = z − ∇b(z) at the cell centres (central differences, one-sided at the border).
    void map_of(const Eigen::ArrayXXd& b, Eigen::ArrayXXd& tx, Eigen::ArrayXXd& ty) const {
        const int nx = g_.nx, ny = g_.ny;
        tx.resize(ny, nx);
        ty.resize(ny, nx);
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const int il = std::max(i - 1, 0), ir = std::min(i + 1, nx - 1);
                const int jl = std::max(j - 1, 0), jr = std::min(j + 1, ny - 1);
                const double gx = ir > il ? (b(j, ir) - b(j, il)) / ((ir - il) * g_.hx) : 0.0;
                const double gy = jr > jl ? (b(jr, i) - b(jl, i)) / ((jr - jl) * g_.hy) : 0.0;
                tx(j, i) = xs_[std::size_t(i)] - gx;
                ty(j, i) = ys_[std::size_t(j)] - gy;
            }
    }

    // u = (−Δ)⁻¹ f with Neumann boundaries (zero-mean solution).
    Eigen::ArrayXXd inverse_laplacian(const Eigen::ArrayXXd& f) const { return poisson_.solve(f); }

    const OtGrid& grid() const { return g_; }

private:
    static Eigen::ArrayXXd restrict(Eigen::ArrayXXd g, const Eigen::ArrayXXd& support) {
        g = (support > 0).select(g, std::numeric_limits<double>::infinity());
        return g;
    }

    // One worker's scratch for legendre_1d.
    struct LineScratch {
        std::vector<int> hull, args;
        std::vector<double> values;
    };

    // Calls f(line, scratch) for lines 0 … n − 1 on the workspace's threads, a contiguous
    // range of lines per worker.
    template <class F>
    void lines(int n, F&& f) const {
        for_each_worker_range(exec::omp_t{threads_}, n, [&](std::int64_t begin, std::int64_t end) {
            LineScratch scratch;
            for (std::int64_t l = begin; l < end; ++l) f(l, scratch);
        });
    }

    OtGrid g_;
    std::vector<double> xs_, ys_;
    Eigen::ArrayXXd sq_;
    NeumannPoisson poisson_;
    int threads_ = 0;
    Eigen::ArrayXXd push_h_;            // push_exact's scratch, kept between calls
    std::vector<int> push_arg_, push_dest_;
};

// ½ Σ |a − b| over blocks of k × k cells (partial blocks at the far edges).
inline double block_residual(const Eigen::ArrayXXd& a, const Eigen::ArrayXXd& b, int k) {
    k = std::max(1, k);
    double sum = 0;
    for (int j0 = 0; j0 < a.rows(); j0 += k)
        for (int i0 = 0; i0 < a.cols(); i0 += k) {
            const int h = std::min<int>(k, int(a.rows()) - j0), w = std::min<int>(k, int(a.cols()) - i0);
            sum += std::abs(a.block(j0, i0, h, w).sum() - b.block(j0, i0, h, w).sum());
        }
    return 0.5 * sum;
}

// Throws InputError unless the grid has at least 2 × 2 cells of positive size and the
// source and target are finite, non-negative masses of its size.
inline void check_ot_input(const OtGrid& grid, const Eigen::ArrayXXd& source, const Eigen::ArrayXXd& target) {
    if (grid.nx < 2 || grid.ny < 2 || !(grid.hx > 0) || !(grid.hy > 0))
        throw InputError("transport: the grid must be at least 2 x 2 cells with a positive cell size");
    if (source.rows() != grid.ny || source.cols() != grid.nx || target.rows() != grid.ny || target.cols() != grid.nx)
        throw InputError("transport: source and target must match the grid's size");
    if (!source.isFinite().all() || (source < 0).any())
        throw InputError("transport: the source has negative or non-finite mass");
    if (!target.isFinite().all() || (target < 0).any())
        throw InputError("transport: the target has negative or non-finite mass");
}

// One ascent step on the potential `a` of side A (mass mA), whose c-transform `b`
// lives on side B (mass mB): J(a) = <a, mA> + <a^c, mB>, whose gradient is
// mA − T#mB, T the map of a (push_exact). The step is that gradient in the H¹ metric
// (one Poisson solve, `cell` the cell area); `sigma` adapts to how much of the
// predicted gain a step achieves, and a step that loses is halved. Returns the residual
// ½Σ|mA − T#mB| before the step.
inline double half_step(Workspace& ws, Eigen::ArrayXXd& a, Eigen::ArrayXXd& b, const Eigen::ArrayXXd& mA,
                        const Eigen::ArrayXXd& mB, double& sigma, double cell, const OtOptions& options) {
    double value = 0;
    const Eigen::ArrayXXd rho = ws.push_exact(a, mA, mB, options.samples, value);
    const double residual = block_residual(mA, rho, options.residual_block);
    const Eigen::ArrayXXd grad = ws.inverse_laplacian((mA - rho) / cell);
    const double slope = (grad * (mA - rho)).sum();  // H¹ norm² of the gradient
    const double j0 = (a * mA).sum() + value;
    for (int attempt = 0; attempt < 8; ++attempt) {
        Eigen::ArrayXXd a_new = a + sigma * grad;
        double value_new = 0;
        ws.push_exact(a_new, mA, mB, options.samples, value_new);
        const double gain = (a_new * mA).sum() + value_new - j0;
        if (gain < 0) {  // overshoot: a smaller step
            sigma *= 0.5;
            continue;
        }
        const double ratio = slope > 0 ? gain / (sigma * slope) : 1.0;
        a = std::move(a_new);
        if (ratio > 0.75) sigma *= 1.5;
        else if (ratio < 0.25) sigma *= 0.75;
        break;
    }
    b = ws.c_transform(a, mA);
    return residual;
}

}  // namespace ot_detail

// Solves the quadratic-cost transport from `source` to `target` (masses per cell on
// `grid`, ny × nx, non-negative, same total up to rounding: the target is rescaled).
inline OtResult solve_grid_ot(const OtGrid& grid, const Eigen::ArrayXXd& source, const Eigen::ArrayXXd& target,
                              const OtOptions& options = {}) {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    ot_detail::check_ot_input(grid, source, target);
    const double ms = source.sum(), mt = target.sum();
    if (!(ms > 0)) throw InputError("transport: the source carries no light");
    if (!(mt > 0)) throw InputError("transport: the target is entirely black");

    ot_detail::Workspace ws(grid, options.threads);
    const double cell = grid.hx * grid.hy;
    // Masses normalised to 1; densities (per unit area) drive the H¹ steps.
    const Eigen::ArrayXXd mu = source / ms, nu = target / mt;
    const double max_density = std::max(mu.maxCoeff(), nu.maxCoeff()) / cell;

    OtResult r;
    r.grid = grid;
    const bool warm = options.warm_phi && options.warm_phi->rows() == grid.ny && options.warm_phi->cols() == grid.nx;
    Eigen::ArrayXXd phi = warm ? *options.warm_phi : Eigen::ArrayXXd::Zero(grid.ny, grid.nx);  // target side
    Eigen::ArrayXXd psi = ws.c_transform(phi, nu);                   // source side
    double sigma_phi = 1.0 / max_density, sigma_psi = 1.0 / max_density;
    double best = 2;
    int best_at = 0;
    Eigen::ArrayXXd best_psi = psi;
    for (int it = 0; it < options.max_iterations; ++it) {
        // φ step: the source pushed by x − ∇ψ must match ν; `res` is the residual of
        // the ψ it started from.
        const Eigen::ArrayXXd psi_before = psi;
        const double res = ot_detail::half_step(ws, phi, psi, nu, mu, sigma_phi, cell, options);
        r.residual_history.push_back(res);
        if (res < 0.99 * best) best_at = it;
        if (res < best) best = res, best_psi = psi_before;
        r.iterations = it + 1;
        if (res <= options.tolerance || it - best_at >= options.patience) break;
        if (options.time_limit > 0 && std::chrono::duration<double>(clock::now() - t0).count() > options.time_limit)
            break;
        // ψ step: the target pushed back by y − ∇φ must match μ.
        ot_detail::half_step(ws, psi, phi, mu, nu, sigma_psi, cell, options);
    }
    // The returned map is the best one measured; recompute it from its potential.
    r.psi = best_psi;
    r.phi = ws.c_transform(r.psi, mu);
    r.target = target;
    r.index_exact();
    ws.map_of(r.psi, r.map_x, r.map_y);
    double value = 0;
    r.pushed = ws.push_exact(r.phi, nu, mu, options.samples, value) * mt;
    r.residual = ot_detail::block_residual(target, r.pushed, options.residual_block) / mt;
    r.seconds = std::chrono::duration<double>(clock::now() - t0).count();
    return r;
}

}  // namespace freeform
