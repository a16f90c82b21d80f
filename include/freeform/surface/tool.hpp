#pragma once
// What a ball-end mill can cut: the surface's curvature, and the surface a ball of a given
// radius leaves when it cuts from the front (+w, where the light comes from).
//
// A ball of radius r can follow a surface only where every concave region, seen from the
// side the cutter comes from, has a radius of curvature of at least r. cut_with_ball()
// returns what the mill leaves of any surface: each valley narrower than the ball is
// filled with the ball's own round, everything the ball can reach is left as it was. It
// is the morphological closing of the height field by the ball (a dilation, then an
// erosion), computed exactly at the vertices.
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "heightmap.hpp"

namespace freeform {

// The largest principal curvature seen from +w (positive where the surface is concave
// from the front) and the slope (radians) at interior vertex (i, j) of any height field
// `h` (h(i, j) in metres, vertices du by dv apart), from central differences.
struct VertexCurvature {
    double kappa_max;
    double slope;
};

template <class Heights>
inline VertexCurvature vertex_curvature(const Heights& h, int i, int j, double du, double dv) {
    const double c = h(i, j);
    const double hu = (double(h(i + 1, j)) - double(h(i - 1, j))) / (2 * du);
    const double hv = (double(h(i, j + 1)) - double(h(i, j - 1))) / (2 * dv);
    const double huu = (double(h(i + 1, j)) - 2 * c + double(h(i - 1, j))) / (du * du);
    const double hvv = (double(h(i, j + 1)) - 2 * c + double(h(i, j - 1))) / (dv * dv);
    const double huv = (double(h(i + 1, j + 1)) - double(h(i + 1, j - 1)) - double(h(i - 1, j + 1)) +
                        double(h(i - 1, j - 1))) / (4 * du * dv);
    // Shape operator I^-1 II of the graph w = h(u, v): its eigenvalues are the principal
    // curvatures; k_max = H + sqrt(H^2 - K).
    const double E = 1 + hu * hu, F = hu * hv, G = 1 + hv * hv;
    const double W = std::sqrt(1 + hu * hu + hv * hv);
    const double L = huu / W, M = huv / W, N = hvv / W;
    const double det_i = E * G - F * F;
    const double H = (E * N - 2 * F * M + G * L) / (2 * det_i);
    const double K = (L * N - M * M) / det_i;
    return {H + std::sqrt(std::max(0.0, H * H - K)), std::atan(std::sqrt(hu * hu + hv * hv))};
}

// The surface a ball-end mill of radius `radius` (metres) leaves of `surface`, cutting from
// +w with its centre over the grid's vertices: the ball's centre over vertex x rests at
//     z(x) = max over vertices y within radius of  h(y) + sqrt(r^2 - |x - y|^2),
// and what is left at y is the lowest point of the balls over it,
//     g(y) = min over vertices x within radius of  z(x) - sqrt(r^2 - |x - y|^2).
// g >= h everywhere, and every concave radius of g is at least r. Balls centred on
// vertices only touch a curved surface at their own contact points, so between them g
// stands a scallop above h (micrometres at millimetre spacing) even where the ball fits:
// g replaces h only within r of a vertex whose concave curvature the ball cannot follow
// (k_max > 1/r, central differences), and h is kept everywhere else, untouched. Cutting
// the result again changes nothing. Heights stay within the surface's bounds (g never
// rises above the highest height within r). The tool is not taken past the grid's edge.
// Returns the largest height added (metres).
inline double cut_with_ball(Heightmap& surface, double radius) {
    if (!(radius > 0)) return 0;
    const int nx = surface.nx(), ny = surface.ny();
    const double du = surface.size().x / (nx - 1), dv = surface.size().y / (ny - 1);
    const int ri = int(std::floor(radius / du)), rj = int(std::floor(radius / dv));
    // The ball's lower cap over each offset (a, b) within reach.
    struct Offset {
        int a, b;
        double rise;  // sqrt(r^2 - d^2)
    };
    std::vector<Offset> ball;
    for (int b = -rj; b <= rj; ++b)
        for (int a = -ri; a <= ri; ++a) {
            const double d2 = (a * du) * (a * du) + (b * dv) * (b * dv);
            if (d2 <= radius * radius) ball.push_back({a, b, std::sqrt(radius * radius - d2)});
        }
    const auto at = [&](const std::vector<double>& v, int i, int j) { return v[std::size_t(j) * nx + i]; };
    // Where the ball cannot follow the surface, and everything within its reach of there.
    std::vector<char> tight(std::size_t(nx) * ny, 0), reach(tight.size(), 0);
    bool any = false;
    for (int j = 1; j + 1 < ny; ++j)
        for (int i = 1; i + 1 < nx; ++i)
            if (vertex_curvature(surface, i, j, du, dv).kappa_max * radius > 1.0) tight[std::size_t(j) * nx + i] = 1, any = true;
    if (!any) return 0;
    // Calls visit(i2, j2) for every vertex of the grid within the ball's reach of (i, j).
    const auto around = [&](int i, int j, auto&& visit) {
        for (const Offset& o : ball) {
            const int i2 = i + o.a, j2 = j + o.b;
            if (i2 >= 0 && i2 < nx && j2 >= 0 && j2 < ny) visit(i2, j2, o.rise);
        }
    };
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i)
            if (tight[std::size_t(j) * nx + i]) around(i, j, [&](int i2, int j2, double) { reach[std::size_t(j2) * nx + i2] = 1; });
    std::vector<double> h(std::size_t(nx) * ny), z(h.size());
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) h[std::size_t(j) * nx + i] = surface(i, j);
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            double top = -std::numeric_limits<double>::infinity();
            around(i, j, [&](int i2, int j2, double rise) { top = std::max(top, at(h, i2, j2) + rise); });
            z[std::size_t(j) * nx + i] = top;
        }
    double added = 0;
    std::vector<float> out(h.size());
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const std::size_t k = std::size_t(j) * nx + i;
            out[k] = float(h[k]);
            if (!reach[k]) continue;  // out of the ball's reach of any tight vertex: untouched
            double low = std::numeric_limits<double>::infinity();
            around(i, j, [&](int i2, int j2, double rise) { low = std::min(low, at(z, i2, j2) - rise); });
            // Rounding may leave low a hair under h where the ball touches: keep h there.
            out[k] = float(std::max(low, h[k]));
            added = std::max(added, double(out[k]) - h[k]);
        }
    surface.set_heights(out);
    return added;
}

}  // namespace freeform
