#pragma once
// The designed surface as one smooth B-spline: what the STEP part (io/step.hpp) carries
// and a mill reads (docs/export.md). The grid sag table (io/sag.hpp) no longer carries
// it: it holds the height map's own vertices and vertex normals.
//
// The tracers simulate the Phong-tessellated height field (surface/phong.hpp): curved
// quadratic patches, continuous in position, with small kinks of the normal across cell
// edges. An exported triangle mesh replaces each patch by flat facets and loses accuracy
// where the surface is curved (design/fabrication.hpp). A bicubic B-spline has no facets:
// it is fitted here to the Phong surface by least squares, heights sampled at
// `samples_per_cell`² points of every cell, with one knot per grid line (clamped ends:
// (nx − 1) spans, nx + 2 poles per direction).
//
// Height field form: the poles stand at the Greville abscissae of the knots, which makes
// the surface's (x, y) exactly the parameter (u, v) (a cubic B-spline reproduces linear
// functions), so the spline is z(u, v) over the surface's rectangle, in the surface
// frame, in metres. The Phong correction also moves points sideways by nanometres (its
// offset along tilted vertex normals); the fit takes each sample's height at its nominal
// (u, v), an error of slope × that shift (about 10⁻⁹ m on the example designs).
//
// Because the knots lie on the grid lines the spline is one bicubic polynomial per grid
// cell, which a bicubic Hermite interpolation of z, z_u, z_v and z_uv at the cell's four
// corners reproduces exactly (a grid sag of the spline would be the STEP part; we write
// the design's vertices there instead, which the spline's least squares miss by a
// fraction of a micrometre).
//
// The fit is separable (samples on a tensor grid): with B_u, B_v the basis matrices of
// the sample positions, the poles C solve (B_vᵀB_v) C (B_uᵀB_u) = B_vᵀ Z B_u, two small
// symmetric solves of nx + 2 and ny + 2 unknowns. Cells outside an elliptical aperture
// are fitted too (the surface covers the rectangle).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Dense>

#include "../core/error.hpp"
#include "../core/frame.hpp"
#include "../core/math.hpp"
#include "export.hpp"
#include "heightmap.hpp"

namespace freeform {

// A point of a height-field spline: the height and its partial derivatives.
struct SplineSample {
    double z = 0, z_u = 0, z_v = 0, z_uv = 0;
    // The unit normal of the graph z(u, v), facing +w.
    Vec3d normal() const { return normalize(Vec3d{-z_u, -z_v, 1.0}); }
};

namespace bspline_detail {

inline constexpr int degree = 3;

// The clamped knot vector of `spans` equal spans over [lo, hi]: four equal knots at each
// end, `interior` equal knots (1: C², 2: C¹) at each interior grid line.
inline std::vector<double> clamped_knots(double lo, double hi, int spans, int interior = 1) {
    std::vector<double> k;
    k.reserve(std::size_t(spans) * std::size_t(interior) + 8);
    for (int m = 0; m < degree; ++m) k.push_back(lo);
    for (int s = 0; s <= spans; ++s)
        k.insert(k.end(), s == 0 || s == spans ? 1 : interior, s == spans ? hi : lo + (hi - lo) * double(s) / spans);
    for (int m = 0; m < degree; ++m) k.push_back(hi);
    return k;
}

// The span index s with knots[s] <= t < knots[s + 1] (the last span for t = hi), for a
// clamped vector; t is clamped to the parameter range.
inline int find_span(const std::vector<double>& knots, double& t) {
    const int n = int(knots.size()) - degree - 1;  // poles
    t = std::clamp(t, knots[degree], knots[std::size_t(n)]);
    if (t >= knots[std::size_t(n)]) return n - 1;
    const auto it = std::upper_bound(knots.begin() + degree, knots.begin() + n + 1, t);
    return int(it - knots.begin()) - 1;
}

// Values and first derivatives of the four basis functions that are non-zero on span s
// at t (poles s − 3 … s): the Cox–de Boor recursion, derivatives from the degree-2
// functions.
struct Basis {
    std::array<double, 4> value{}, slope{};
};
inline Basis basis(const std::vector<double>& U, int s, double t) {
    // N[d][m]: degree-d functions non-zero on span s, for poles s − d … s.
    double N[4][4] = {};
    N[0][0] = 1.0;
    for (int d = 1; d <= degree; ++d)
        for (int m = 0; m <= d; ++m) {
            const int i = s - d + m;  // pole index
            double v = 0;
            if (m > 0) {  // N_{i,d-1} is N[d-1][m-1]
                const double den = U[std::size_t(i + d)] - U[std::size_t(i)];
                if (den > 0) v += (t - U[std::size_t(i)]) / den * N[d - 1][m - 1];
            }
            if (m < d) {  // N_{i+1,d-1} is N[d-1][m]
                const double den = U[std::size_t(i + d + 1)] - U[std::size_t(i + 1)];
                if (den > 0) v += (U[std::size_t(i + d + 1)] - t) / den * N[d - 1][m];
            }
            N[d][m] = v;
        }
    Basis b;
    for (int m = 0; m <= degree; ++m) {
        const int i = s - degree + m;
        b.value[std::size_t(m)] = N[degree][m];
        double d = 0;
        if (m > 0) {
            const double den = U[std::size_t(i + degree)] - U[std::size_t(i)];
            if (den > 0) d += degree / den * N[degree - 1][m - 1];
        }
        if (m < degree) {
            const double den = U[std::size_t(i + degree + 1)] - U[std::size_t(i + 1)];
            if (den > 0) d -= degree / den * N[degree - 1][m];
        }
        b.slope[std::size_t(m)] = d;
    }
    return b;
}

// Greville abscissae: the mean of each pole's three interior knots.
inline std::vector<double> greville(const std::vector<double>& U) {
    const int n = int(U.size()) - degree - 1;
    std::vector<double> g(static_cast<std::size_t>(n));
    for (int i = 0; i < n; ++i)
        g[std::size_t(i)] = (U[std::size_t(i + 1)] + U[std::size_t(i + 2)] + U[std::size_t(i + 3)]) / 3.0;
    return g;
}

}  // namespace bspline_detail

// A bicubic, clamped, non-rational B-spline height field z(u, v) over the rectangle
// [knots_u.front(), knots_u.back()] × [knots_v.front(), knots_v.back()] of the surface
// frame (metres). Pole (i, j) is (pole_u[i], pole_v[j], z[j·nu + i]).
struct BSplineSurface {
    static constexpr int degree = bspline_detail::degree;
    std::vector<double> knots_u, knots_v;  // full knot vectors: nu + 4 and nv + 4 values
    std::vector<double> pole_u, pole_v;    // Greville abscissae: the poles' u and v
    std::vector<double> z;                 // pole heights, row-major
    int nu = 0, nv = 0;                    // poles per direction
    Frame frame;                           // surface frame → world
    Aperture aperture = Aperture::rect;    // the design's aperture (the spline covers the rectangle)
    bool hermite = false;                  // made by hermite_bspline (else fit_bspline)

    double u_min() const { return knots_u.front(); }
    double u_max() const { return knots_u.back(); }
    double v_min() const { return knots_v.front(); }
    double v_max() const { return knots_v.back(); }
    double pole(int i, int j) const { return z[std::size_t(j) * std::size_t(nu) + std::size_t(i)]; }

    // Height and derivatives at (u, v), clamped to the rectangle.
    SplineSample eval(double u, double v) const {
        const int su = bspline_detail::find_span(knots_u, u), sv = bspline_detail::find_span(knots_v, v);
        const bspline_detail::Basis bu = bspline_detail::basis(knots_u, su, u);
        const bspline_detail::Basis bv = bspline_detail::basis(knots_v, sv, v);
        SplineSample s;
        for (int b = 0; b <= degree; ++b) {
            double row = 0, row_u = 0;
            for (int a = 0; a <= degree; ++a) {
                const double c = pole(su - degree + a, sv - degree + b);
                row += bu.value[std::size_t(a)] * c;
                row_u += bu.slope[std::size_t(a)] * c;
            }
            s.z += bv.value[std::size_t(b)] * row;
            s.z_u += bv.value[std::size_t(b)] * row_u;
            s.z_v += bv.slope[std::size_t(b)] * row;
            s.z_uv += bv.slope[std::size_t(b)] * row_u;
        }
        return s;
    }
};

// The corner data of the C¹ bicubic Hermite surface through a height map's vertices: per
// vertex (row-major, j·nx + i) its height, the slopes of its vertex normal
// (Heightmap::normals(), the normals the Phong patches are built from; slope = −n_u/n_w,
// −n_v/n_w) and the twist ∂²z/∂u∂v. What the grid sag table holds (io/sag.hpp) and, for
// grids small enough, what the STEP part carries (hermite_bspline).
//
// The twist is the mean of ∂(z_u)/∂v and ∂(z_v)/∂u, each a central difference of the
// vertex slopes (second-order one-sided at the border: line_derivative,
// surface/heightmap.hpp, the rule of the vertex normals themselves). In the interior both
// are the same four-point cross difference of the heights, (h(i+1,j+1) − h(i−1,j+1) −
// h(i+1,j−1) + h(i−1,j−1)) / (4 du dv), exact for a quadratic; at the border the two
// stencils differ and the mean favours neither axis. A zero twist (Ferguson's patches)
// would flatten every cell's cross term: wrong on a saddle-like or tilted-paraboloid design.
struct HermiteCorners {
    std::vector<double> z, z_u, z_v, z_uv;
};
inline HermiteCorners hermite_corners(const Heightmap& hm) {
    const int nx = hm.nx(), ny = hm.ny();
    HermiteCorners c;
    const std::size_t n = std::size_t(nx) * std::size_t(ny);
    c.z.resize(n), c.z_u.resize(n), c.z_v.resize(n), c.z_uv.resize(n);
    for (std::size_t k = 0; k < n; ++k) {
        const Vec3d nv = Vec3d(hm.normals()[k]);
        c.z[k] = double(hm.heights()[k]);
        c.z_u[k] = -nv.x / nv.z, c.z_v[k] = -nv.y / nv.z;
    }
    const auto at = [nx](int i, int j) { return std::size_t(j) * std::size_t(nx) + std::size_t(i); };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const double suv = line_derivative([&](int jj) { return c.z_u[at(i, jj)]; }, j, ny, hm.dv());
            const double svu = line_derivative([&](int ii) { return c.z_v[at(ii, j)]; }, i, nx, hm.du());
            c.z_uv[at(i, j)] = 0.5 * (suv + svu);
        }
    return c;
}

// The C¹ bicubic Hermite surface of hermite_corners as a B-spline, exactly: double knots
// at the interior grid lines (so each cell is one bicubic Bézier patch, 2·nx poles along u),
// the poles the patches' Bézier nets. Along one direction, a cell from vertex a to a + 1
// of spacing h has the Bézier points z_a, z_a + h z'_a / 3, z_{a+1} − h z'_{a+1} / 3,
// z_{a+1}; neighbouring cells share their end points, which are then the midpoints of
// the poles either side (C¹ with equal spans), so the poles are each cell's two inner
// points plus the two ends: pole p stands for vertex 0 (p = 0), vertex nx − 1
// (p = 2nx − 1), or vertex (p − 1) / 2 with +h/3 (p odd) and vertex p / 2 with −h/3
// (p even). A pole of the tensor net adds the two directions' offsets and their product
// times the twist. The poles' (u, v) are again the Greville abscissae.
inline BSplineSurface hermite_bspline(const Heightmap& hm) {
    if (hm.nx() < 2 || hm.ny() < 2) throw InputError("cannot make a spline of an empty height map");
    const HermiteCorners c = hermite_corners(hm);
    // Pole p of a direction of `vertices` vertices: (vertex, offset in spacings).
    const auto stands_for = [](int p, int vertices) -> std::pair<int, double> {
        if (p == 0) return {0, 0.0};
        if (p == 2 * vertices - 1) return {vertices - 1, 0.0};
        return p % 2 == 1 ? std::pair{(p - 1) / 2, 1.0 / 3.0} : std::pair{p / 2, -1.0 / 3.0};
    };
    BSplineSurface s;
    s.frame = hm.frame();
    s.aperture = hm.aperture();
    s.knots_u = bspline_detail::clamped_knots(hm.u_of(0), hm.u_of(hm.nx() - 1), hm.nx() - 1, 2);
    s.knots_v = bspline_detail::clamped_knots(hm.v_of(0), hm.v_of(hm.ny() - 1), hm.ny() - 1, 2);
    s.nu = 2 * hm.nx(), s.nv = 2 * hm.ny();
    s.hermite = true;
    s.pole_u = bspline_detail::greville(s.knots_u);
    s.pole_v = bspline_detail::greville(s.knots_v);
    s.z.resize(std::size_t(s.nu) * std::size_t(s.nv));
    for (int q = 0; q < s.nv; ++q)
        for (int p = 0; p < s.nu; ++p) {
            const auto [i, a] = stands_for(p, hm.nx());
            const auto [j, b] = stands_for(q, hm.ny());
            const std::size_t k = std::size_t(j) * std::size_t(hm.nx()) + std::size_t(i);
            const double du = a * hm.du(), dv = b * hm.dv();
            s.z[std::size_t(q) * std::size_t(s.nu) + std::size_t(p)] =
                c.z[k] + du * c.z_u[k] + dv * c.z_v[k] + du * dv * c.z_uv[k];
        }
    return s;
}

// The spline's point and normal at cell-local (a, b) of the grid cell (ci, cj) of `hm`
// (the grid the spline was fitted on): the `point` of detail::tessellate_local and
// lens_solid_of (surface/export.hpp) for tessellating the smooth form.
inline PhongVertex spline_vertex(const BSplineSurface& s, const Heightmap& hm, int ci, int cj, double a, double b) {
    const double u = hm.u_of(ci) + a * hm.du(), v = hm.v_of(cj) + b * hm.dv();
    const SplineSample q = s.eval(u, v);
    return {{u, v, q.z}, q.normal()};
}

// How closely a fitted spline follows the Phong surface, at check points that are not
// sample points (cell-local (1/3, 2/3) and (2/3, 1/3), one on each flat triangle, and
// every grid vertex).
struct SplineFitReport {
    int samples_per_cell = 0;
    double max_height_error = 0;  // metres
    double rms_height_error = 0;
    double max_normal_error = 0;  // radians
    double p90_normal_error = 0;  // 90th percentile over the check points
};

// Least-squares bicubic B-spline through `samples_per_cell`² heights of each cell of the
// Phong surface of `hm` (alpha: scene.surface.phong_alpha). Throws InputError for a grid
// under 2 × 2 or samples_per_cell outside [2, 16].
inline BSplineSurface fit_bspline(const Heightmap& hm, double alpha, int samples_per_cell = 4) {
    if (hm.nx() < 2 || hm.ny() < 2) throw InputError("cannot fit a spline to an empty height map");
    // One sample per cell and direction gives fewer equations than poles (cells + 2 against
    // cells + 3): at least two.
    if (samples_per_cell < 2 || samples_per_cell > 16)
        throw InputError("spline fit: samples_per_cell must be in [2, 16], got " + std::to_string(samples_per_cell));
    namespace bd = bspline_detail;
    const int nx = hm.nx(), ny = hm.ny(), m = samples_per_cell;
    BSplineSurface s;
    s.frame = hm.frame();
    s.aperture = hm.aperture();
    s.knots_u = bd::clamped_knots(hm.u_of(0), hm.u_of(nx - 1), nx - 1);
    s.knots_v = bd::clamped_knots(hm.v_of(0), hm.v_of(ny - 1), ny - 1);
    s.nu = nx + 2, s.nv = ny + 2;
    s.pole_u = bd::greville(s.knots_u);
    s.pole_v = bd::greville(s.knots_v);
    // Sample positions: m per cell, at cell-local (q + ½)/m, plus both ends so the rim is
    // pinned; parameters in cell units.
    const auto positions = [m](int cells) {
        std::vector<double> x{0.0};
        for (int c = 0; c < cells; ++c)
            for (int q = 0; q < m; ++q) x.push_back(c + (q + 0.5) / m);
        x.push_back(double(cells));
        return x;
    };
    const std::vector<double> xs = positions(nx - 1), ys = positions(ny - 1);
    const auto basis_matrix = [](const std::vector<double>& knots, const std::vector<double>& cells, double lo,
                                 double step, int poles) {
        Eigen::MatrixXd B = Eigen::MatrixXd::Zero(Eigen::Index(cells.size()), poles);
        for (std::size_t r = 0; r < cells.size(); ++r) {
            double t = lo + cells[r] * step;
            const int span = bd::find_span(knots, t);
            const bd::Basis b = bd::basis(knots, span, t);
            for (int a = 0; a <= bd::degree; ++a) B(Eigen::Index(r), span - bd::degree + a) = b.value[std::size_t(a)];
        }
        return B;
    };
    const Eigen::MatrixXd Bu = basis_matrix(s.knots_u, xs, hm.u_of(0), hm.du(), s.nu);
    const Eigen::MatrixXd Bv = basis_matrix(s.knots_v, ys, hm.v_of(0), hm.dv(), s.nv);
    // Z: rows are v samples, columns u samples.
    Eigen::MatrixXd Z(Eigen::Index(ys.size()), Eigen::Index(xs.size()));
    for (std::size_t r = 0; r < ys.size(); ++r)
        for (std::size_t c = 0; c < xs.size(); ++c) {
            const int ci = std::min(int(xs[c]), nx - 2), cj = std::min(int(ys[r]), ny - 2);
            Z(Eigen::Index(r), Eigen::Index(c)) =
                phong_vertex_in_cell(hm, ci, cj, xs[c] - ci, ys[r] - cj, alpha).position.z;
        }
    // C = (BvᵀBv)⁻¹ BvᵀZ Bu (BuᵀBu)⁻¹; both normal matrices are symmetric positive definite.
    const Eigen::MatrixXd right = (Bv.transpose() * Z) * Bu;  // nv × nu
    const Eigen::LDLT<Eigen::MatrixXd> Au(Bu.transpose() * Bu), Av(Bv.transpose() * Bv);
    const Eigen::MatrixXd half = Av.solve(right);                            // nv × nu
    const Eigen::MatrixXd C = Au.solve(half.transpose()).transpose();       // nv × nu
    s.z.resize(std::size_t(s.nu) * std::size_t(s.nv));
    for (int j = 0; j < s.nv; ++j)
        for (int i = 0; i < s.nu; ++i) s.z[std::size_t(j) * std::size_t(s.nu) + std::size_t(i)] = C(j, i);
    return s;
}

// Checks a fitted spline against the Phong surface it came from (see SplineFitReport).
inline SplineFitReport check_spline_fit(const BSplineSurface& s, const Heightmap& hm, double alpha,
                                        int samples_per_cell) {
    SplineFitReport r;
    r.samples_per_cell = samples_per_cell;
    std::vector<float> angles;
    double sum2 = 0;
    std::size_t count = 0;
    const auto check = [&](int ci, int cj, double a, double b) {
        const PhongVertex p = phong_vertex_in_cell(hm, ci, cj, a, b, alpha);
        const SplineSample q = s.eval(hm.u_of(ci) + a * hm.du(), hm.v_of(cj) + b * hm.dv());
        const double dz = std::abs(q.z - p.position.z);
        r.max_height_error = std::max(r.max_height_error, dz);
        sum2 += dz * dz, ++count;
        const Vec3d n = q.normal();
        const double angle = std::atan2(length(cross(n, p.normal)), dot(n, p.normal));
        angles.push_back(float(angle));
        r.max_normal_error = std::max(r.max_normal_error, angle);
    };
    for (int cj = 0; cj + 1 < hm.ny(); ++cj)
        for (int ci = 0; ci + 1 < hm.nx(); ++ci) {
            check(ci, cj, 1.0 / 3.0, 2.0 / 3.0);
            check(ci, cj, 2.0 / 3.0, 1.0 / 3.0);
        }
    if (count > 0) r.rms_height_error = std::sqrt(sum2 / double(count));
    if (!angles.empty()) {
        const auto q = std::size_t(0.9 * double(angles.size() - 1) + 0.5);
        std::nth_element(angles.begin(), angles.begin() + std::ptrdiff_t(q), angles.end());
        r.p90_normal_error = double(angles[q]);
    }
    return r;
}

}  // namespace freeform
