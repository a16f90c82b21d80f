#pragma once
// The fabrication surface: the Phong-tessellated height field the tracers simulate,
// as a fine triangle mesh (an open sheet) or as a closed lens solid, plus a topology and
// volume check for meshes.
//
// Every grid cell (ci, cj) is split into k × k sub-cells; sub-vertex (a, b) of the cell
// (cell-local coordinates in [0, 1]) lies in flat triangle 0 (v00, v10, v11) when a >= b,
// with barycentric weights (1-a, a-b, b), and in triangle 1 (v00, v11, v01) otherwise,
// with weights (1-b, a, b-a): the layout and the weights of find_heightfield_hit. The
// sub-vertex is placed by the Phong formula of phong_point (surface/phong.hpp) and gets the
// normal of the curved patch there (patch_normal). Sub-cells use the
// same diagonal direction as the cells, so each sub-triangle lies over one flat triangle.
// The stored vertex normal is the patch's true normal (patch_normal) for viewers; the
// geometry alone is what the tracers simulate: the tessellation's flat facets approach
// the patches as k grows, and subdivisions_for_tolerance picks k from a bound on the
// angle between the facets and the patches' normals.
//
// The formula is evaluated in double with the nominal grid positions (Heightmap::u_of,
// v_of), not in the float arithmetic of the kernels: the outline of the mesh is then the
// exact rectangle and volumes come out to double precision, while the difference to the
// float kernel (phong_point on HeightfieldView positions) is float rounding, nanometres
// on a decimetre part. A point on a shared edge (the cell diagonal, or the side between
// two cells) depends only on the edge's two end vertices, and the two triangles sum the
// same non-zero terms, so both give the same position bit for bit: one vertex per grid
// point, no cracks.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/math.hpp"
#include "../core/frame.hpp"
#include "../core/material.hpp"
#include "phong.hpp"
#include "heightmap.hpp"
#include "triangle_mesh.hpp"

namespace freeform {

// A point of the Phong-tessellated surface, in the surface frame.
struct PhongVertex {
    Vec3d position;
    Vec3d normal;  // unit: the patch's own normal there (patch_normal of surface/phong.hpp)
};

// The Phong-tessellated point of flat triangle `tri` (ids as in triangle_vertices of
// trace/heightfield_kernel.hpp) at barycentric weights (b0, b1, b2); alpha = 0 is flat.
inline PhongVertex phong_vertex(const Heightmap& hm, std::int32_t tri, double b0, double b1, double b2, double alpha) {
    const int nx = hm.nx();
    const std::int32_t c = tri >> 1;
    const int ci = int(c % (nx - 1)), cj = int(c / (nx - 1));
    int vi[3], vj[3];
    if ((tri & 1) == 0) {
        vi[0] = ci, vj[0] = cj, vi[1] = ci + 1, vj[1] = cj, vi[2] = ci + 1, vj[2] = cj + 1;
    } else {
        vi[0] = ci, vj[0] = cj, vi[1] = ci + 1, vj[1] = cj + 1, vi[2] = ci, vj[2] = cj + 1;
    }
    const double b[3] = {b0, b1, b2};
    Vec3d p[3], n[3];
    for (int k = 0; k < 3; ++k) {
        p[k] = {hm.u_of(vi[k]), hm.v_of(vj[k]), double(hm(vi[k], vj[k]))};
        n[k] = Vec3d(hm.normals()[std::size_t(vj[k]) * nx + vi[k]]);
    }
    const Vec3d flat = b[0] * p[0] + b[1] * p[1] + b[2] * p[2];
    PhongVertex out;
    out.position = phong_point<double>(p, n, b, flat, alpha);
    out.normal = normalize(patch_normal<double>(p, n, b, flat, alpha));
    return out;
}

// The Phong-tessellated point at cell-local coordinates (a, b) ∈ [0, 1]² of cell
// (ci, cj), picking the flat triangle that contains it as the tracer does.
inline PhongVertex phong_vertex_in_cell(const Heightmap& hm, int ci, int cj, double a, double b, double alpha) {
    const std::int32_t base = 2 * (cj * (hm.nx() - 1) + ci);
    if (a >= b) return phong_vertex(hm, base, 1.0 - a, a - b, b, alpha);
    return phong_vertex(hm, base + 1, 1.0 - b, a, b - a, alpha);
}

namespace detail {

// The fine grid of a tessellation with s ≥ 1 facet pairs a cell side: cell c of the
// height map spans fine lines x[c] .. x[c + 1] along u (y likewise along v), with
// x[c] = round(c·s). An integer s = k splits every cell k × k (x[c] = c·k); between
// integers the cells get ⌊s⌋ or ⌈s⌉ sub-cells a side, spread evenly, so a triangle budget
// is filled rather than left at the integer below it (docs/export.md, "The facets").
// The grid stays one tensor-product grid: neighbouring cells share their fine lines, and
// no stitching is needed.
struct FineGrid {
    std::vector<int> x, y;            // the fine line where each cell starts; nx and ny entries
    std::vector<int> cell_x, cell_y;  // per fine line: the cell from it up (the last cell at the far end)
    int fx() const { return x.back() + 1; }
    int fy() const { return y.back() + 1; }
    int kx(int ci) const { return x[std::size_t(ci) + 1] - x[std::size_t(ci)]; }
    int ky(int cj) const { return y[std::size_t(cj) + 1] - y[std::size_t(cj)]; }
};

// The border actually kept along an axis of n vertices: none where it would leave no
// cell inside it.
inline int border_cells(int n, int border) { return border < 0 || 2 * border >= n - 1 ? 0 : border; }

inline void fine_lines(int n, double s, std::vector<int>& start, std::vector<int>& cell, int border = 0) {
    start.resize(std::size_t(n));
    // The first and last `border` cells get one sub-cell each (CoarseBorder).
    border = border_cells(n, border);
    const int last = n - 1 - border;  // the line where the far border starts
    for (int c = 0; c < n; ++c)
        start[std::size_t(c)] = c <= border ? c
                                : c <= last ? border + int(std::llround(double(c - border) * s))
                                            : start[std::size_t(last)] + (c - last);
    cell.resize(std::size_t(start.back()) + 1);
    for (int c = 0; c + 1 < n; ++c)
        for (int f = start[std::size_t(c)]; f < start[std::size_t(c) + 1]; ++f) cell[std::size_t(f)] = c;
    cell.back() = n - 2;
}

}  // namespace detail

// The cells along the edges of a height map that are tessellated with one facet pair a
// side whatever the level: `u` columns at each end along u, `v` rows at each end along v.
// A lens blank's rim (design/fabrication.hpp, export_blank) is such a border: light falls
// on the face only and rays inside the glass only go down, so no traced ray meets the
// rim's top, and finer facets there would only spend the triangle budget (on a lens that
// spreads its light the rim can be a third of the top's cells). The grid stays one tensor
// product: a rim cell beside the face shares the face's fine lines along their common
// edge, so the front has no cracks.
struct CoarseBorder {
    int u = 0;
    int v = 0;
};

namespace detail {

// The active cells that `border` leaves at whatever level the tessellation has.
inline std::int64_t cells_inside_border(const Heightmap& hm, CoarseBorder border) {
    const int bu = border_cells(hm.nx(), border.u), bv = border_cells(hm.ny(), border.v);
    std::int64_t cells = 0;
    for (int j = bv; j + 1 + bv < hm.ny(); ++j)
        for (int i = bu; i + 1 + bu < hm.nx(); ++i) cells += hm.cell_active(i, j) ? 1 : 0;
    return cells;
}

// Whether cell (ci, cj) exists and is active: outside the grid counts as missing (the
// outline of a lens solid, LensClosure).
inline bool cell_present(const Heightmap& hm, int ci, int cj) {
    return ci >= 0 && cj >= 0 && ci < hm.nx() - 1 && cj < hm.ny() - 1 && hm.cell_active(ci, cj);
}

inline FineGrid fine_grid(const Heightmap& hm, double s, CoarseBorder border = {}) {
    FineGrid g;
    fine_lines(hm.nx(), s, g.x, g.cell_x, border.u);
    fine_lines(hm.ny(), s, g.y, g.cell_y, border.v);
    return g;
}

}  // namespace detail

// How far the flat facets of a tessellation with s facet pairs a cell side (detail::
// fine_grid; an integer s is the k-fold one) are from the curved patches they stand for:
// per sub-triangle, the largest angle (radians) between its facet normal and the patch
// normal at its three corners and its centroid. `quantile` in [0, 1] picks which
// sub-triangle's angle is reported (1: the worst).
inline double tessellation_normal_error(const Heightmap& hm, double alpha, double s, double quantile = 1.0) {
    const int nx = hm.nx(), ny = hm.ny();
    const detail::FineGrid g = detail::fine_grid(hm, s);
    std::vector<float> angles;
    angles.reserve(std::size_t(g.fx() - 1) * std::size_t(g.fy() - 1) * 2);
    for (int cj = 0; cj + 1 < ny; ++cj)
        for (int ci = 0; ci + 1 < nx; ++ci) {
            if (!hm.cell_active(ci, cj)) continue;
            const std::int32_t base = 2 * (cj * (nx - 1) + ci);
            const int kx = g.kx(ci), ky = g.ky(cj);
            for (int r = 0; r < ky; ++r)
                for (int q = 0; q < kx; ++q)
                    for (int half = 0; half < 2; ++half) {
                        // Cell-local corners of sub-triangle `half` of sub-cell (q, r). With
                        // kx = ky the sub-cell's diagonal runs as the cell's, so each
                        // sub-triangle lies on one flat triangle (its centroid's), and its
                        // corners are points of that triangle's patch; otherwise a corner
                        // across the cell's diagonal is taken from its own triangle.
                        const double a0 = double(q) / kx, b0 = double(r) / ky, a1 = double(q + 1) / kx,
                                     b1 = double(r + 1) / ky;
                        const double ca[3] = {a0, a1, half == 0 ? a1 : a0};
                        const double cb[3] = {b0, half == 0 ? b0 : b1, b1};
                        const double ac = (ca[0] + ca[1] + ca[2]) / 3.0, bc = (cb[0] + cb[1] + cb[2]) / 3.0;
                        const int parent = ac >= bc ? 0 : 1;
                        const auto at = [&](double a, double b) {
                            if (a != b && (a > b ? 0 : 1) != parent)
                                return phong_vertex_in_cell(hm, ci, cj, a, b, alpha);
                            return parent == 0 ? phong_vertex(hm, base, 1.0 - a, a - b, b, alpha)
                                               : phong_vertex(hm, base + 1, 1.0 - b, a, b - a, alpha);
                        };
                        PhongVertex v[4];
                        for (int m = 0; m < 3; ++m) v[m] = at(ca[m], cb[m]);
                        v[3] = at(ac, bc);
                        const Vec3d f = normalize(cross(v[1].position - v[0].position, v[2].position - v[0].position));
                        double worst = 0;
                        for (const PhongVertex& pv : v)
                            worst = std::max(worst, std::atan2(length(cross(f, pv.normal)), dot(f, pv.normal)));
                        angles.push_back(float(worst));
                    }
        }
    if (angles.empty()) return 0.0;
    const auto qi = std::size_t(std::clamp(quantile, 0.0, 1.0) * double(angles.size() - 1) + 0.5);
    std::nth_element(angles.begin(), angles.begin() + std::ptrdiff_t(qi), angles.end());
    return double(angles[qi]);
}

// The subdivision level the exported facets need: the smallest k in [1, max_k] whose
// tessellation_normal_error (at `quantile`) is at most `max_angle` radians, or max_k when
// none is. The error falls about as 1/k (the patches are quadratic), which gives the
// first guess; the guess is then checked and raised until it holds.
struct SubdivisionChoice {
    int k = 1;
    double normal_error = 0;  // tessellation_normal_error at k (radians)
};
inline SubdivisionChoice subdivisions_for_tolerance(const Heightmap& hm, double alpha, double max_angle,
                                                    int max_k = 16, double quantile = 0.9) {
    if (!(max_angle > 0)) throw InputError("export: the facet tolerance must be positive");
    SubdivisionChoice c;
    c.normal_error = tessellation_normal_error(hm, alpha, 1, quantile);
    if (c.normal_error <= max_angle || max_k <= 1) return c;
    int k = std::clamp(int(std::ceil(c.normal_error / max_angle)), 2, max_k);
    while (true) {
        c.k = k;
        c.normal_error = tessellation_normal_error(hm, alpha, k, quantile);
        if (c.normal_error <= max_angle || k >= max_k) return c;
        k = std::min(max_k, std::max(k + 1, int(std::ceil(k * c.normal_error / max_angle))));
    }
}

// The cells inside the aperture: the ones an exported mesh covers.
inline std::int64_t active_cell_count(const Heightmap& hm) {
    std::int64_t cells = 0;
    for (int j = 0; j + 1 < hm.ny(); ++j)
        for (int i = 0; i + 1 < hm.nx(); ++i) cells += hm.cell_active(i, j) ? 1 : 0;
    return cells;
}

namespace detail {

inline void check_export_args(const Heightmap& hm, double phong_alpha, double subdivisions) {
    if (hm.nx() < 2 || hm.ny() < 2) throw InputError("cannot export an empty height map");
    if (!std::isfinite(phong_alpha))
        throw InputError("export: phong_alpha must be a finite number, got " + std::to_string(phong_alpha));
    if (!(subdivisions >= 1) || !std::isfinite(subdivisions))
        throw InputError("export: subdivisions must be at least 1, got " + std::to_string(subdivisions));
    const double fine = (double(hm.nx() - 1) * subdivisions + 1) * (double(hm.ny() - 1) * subdivisions + 1);
    // Two triangles per sub-cell, plus the lens solid's back face and walls: stay well
    // inside the int32 indices of TriangleMesh.
    if (fine > double(std::numeric_limits<std::int32_t>::max()) / 4)
        throw InputError("export: subdivisions = " + std::to_string(subdivisions) + " on a " + std::to_string(hm.nx()) +
                         " x " + std::to_string(hm.ny()) + " grid gives too many vertices for one mesh");
}

// The tessellated sheet in the surface frame, on fine grid `g` (fine_grid). `fine_index`
// receives, per fine-grid vertex (row-major, g.fx() columns), its index in the mesh or -1
// when no active cell uses it. `point(ci, cj, a, b)` gives the surface point (a PhongVertex) at
// cell-local (a, b) of cell (ci, cj): the Phong patches for the milled mesh, another
// smooth form of the design (a fitted spline) for judging it. Each fine vertex is
// computed once, from one of the cells that share it.
template <class PointFn>
TriangleMesh tessellate_local(const Heightmap& hm, const FineGrid& g, std::vector<std::int32_t>& fine_index,
                              PointFn&& point) {
    const int nx = hm.nx(), ny = hm.ny();
    const int fx = g.fx(), fy = g.fy();
    fine_index.assign(std::size_t(fx) * std::size_t(fy), -1);
    // A fine vertex is kept when one of the (up to four) cells around it is active.
    for (int cj = 0; cj + 1 < ny; ++cj)
        for (int ci = 0; ci + 1 < nx; ++ci) {
            if (!hm.cell_active(ci, cj)) continue;
            for (int J = g.y[std::size_t(cj)]; J <= g.y[std::size_t(cj) + 1]; ++J)
                for (int I = g.x[std::size_t(ci)]; I <= g.x[std::size_t(ci) + 1]; ++I)
                    fine_index[std::size_t(J) * std::size_t(fx) + std::size_t(I)] = 0;
        }
    TriangleMesh mesh;
    std::int32_t next = 0;
    for (int J = 0; J < fy; ++J)
        for (int I = 0; I < fx; ++I) {
            std::int32_t& idx = fine_index[std::size_t(J) * fx + I];
            if (idx < 0) continue;
            idx = next++;
            // Any cell containing the point gives the same position (see the header); take
            // the one to its upper right, the last one at the far borders.
            const int ci = g.cell_x[std::size_t(I)], cj = g.cell_y[std::size_t(J)];
            const double a = double(I - g.x[std::size_t(ci)]) / g.kx(ci);
            const double b = double(J - g.y[std::size_t(cj)]) / g.ky(cj);
            const PhongVertex pv = point(ci, cj, a, b);
            mesh.vertices.push_back(pv.position);
            mesh.normals.push_back(pv.normal);
        }
    // Sub-cells in fine-grid row order: with k = 1 on a rectangular aperture, triangle t
    // of the mesh is triangle t of the tracer.
    for (int J = 0; J + 1 < fy; ++J)
        for (int I = 0; I + 1 < fx; ++I) {
            if (!hm.cell_active(g.cell_x[std::size_t(I)], g.cell_y[std::size_t(J)])) continue;
            const auto at = [&](int i, int j) { return fine_index[std::size_t(j) * fx + i]; };
            const std::int32_t v00 = at(I, J), v10 = at(I + 1, J), v11 = at(I + 1, J + 1), v01 = at(I, J + 1);
            mesh.triangles.push_back({v00, v10, v11});
            mesh.triangles.push_back({v00, v11, v01});
        }
    return mesh;
}

// The same with s facet pairs a cell side.
template <class PointFn>
TriangleMesh tessellate_local(const Heightmap& hm, double s, std::vector<std::int32_t>& fine_index, PointFn&& point) {
    return tessellate_local(hm, fine_grid(hm, s), fine_index, point);
}

inline void to_world(const Frame& f, TriangleMesh& mesh) {
    for (Vec3d& p : mesh.vertices) p = f.to_world(p);
    for (Vec3d& n : mesh.normals) n = f.dir_to_world(n);
}

// Throws InputError unless the back face at w = -t (t the lens thickness) lies below the
// first `front_count` vertices of the mesh (the front).
inline void check_lens_clearance(double t, const TriangleMesh& mesh, std::size_t front_count) {
    for (std::size_t v = 0; v < front_count; ++v)
        if (!(mesh.vertices[v].z > -t))
            throw InputError(
                "lens thickness " + std::to_string(t) + " does not clear the front surface, which reaches w = " +
                std::to_string(mesh.vertices[v].z) + ": the back face must lie below every point of the front");
}

// Adds the side walls and the back face of lens_solid_of to its front, one cell at a
// time. `fine_index` maps the front's fine grid `g` to its vertices, as tessellate_local
// left it.
class LensClosure {
public:
    LensClosure(TriangleMesh& mesh, const std::vector<std::int32_t>& fine_index, const FineGrid& g, double t,
                bool front_normals)
        : mesh_(mesh), fine_index_(fine_index), g_(g), t_(t), front_normals_(front_normals),
          back_of_(mesh.vertices.size(), -1) {}

    // Closes cell (ci, cj); open_side[s] tells whether side s (bottom, right, top,
    // left) is on the outline, the cell across it missing.
    void close_cell(int ci, int cj, const bool (&open_side)[4]) {
        const int I0 = g_.x[std::size_t(ci)], J0 = g_.y[std::size_t(cj)];
        const int I1 = g_.x[std::size_t(ci) + 1], J1 = g_.y[std::size_t(cj) + 1];
        // Corner start points, unit steps and sub-cell counts of the four sides: bottom,
        // right, top, left.
        const int start[4][2] = {{I0, J0}, {I1, J0}, {I1, J1}, {I0, J1}};
        const int step[4][2] = {{1, 0}, {0, 1}, {-1, 0}, {0, -1}};
        const int count[4] = {I1 - I0, J1 - J0, I1 - I0, J1 - J0};
        ring_.clear();
        bool any_open = false;
        for (int s = 0; s < 4; ++s) {
            if (!open_side[s]) {
                ring_.push_back(fine(start[s][0], start[s][1]));
                continue;
            }
            any_open = true;
            for (int m = 0; m < count[s]; ++m) {
                const std::int32_t a = fine(start[s][0] + m * step[s][0], start[s][1] + m * step[s][1]);
                const std::int32_t b = fine(start[s][0] + (m + 1) * step[s][0], start[s][1] + (m + 1) * step[s][1]);
                ring_.push_back(a);
                // Front edge a→b; the wall uses b→a on top and a'→b' at the bottom.
                const std::int32_t ab = back(a), bb = back(b);
                mesh_.triangles.push_back({b, a, ab});
                mesh_.triangles.push_back({b, ab, bb});
            }
        }
        for (std::int32_t& v : ring_) v = back(v);
        // The back face looks along -w: its triangles run clockwise seen from +w.
        if (!any_open) {
            mesh_.triangles.push_back({ring_[0], ring_[2], ring_[1]});
            mesh_.triangles.push_back({ring_[0], ring_[3], ring_[2]});
            return;
        }
        Vec3d centre{0, 0, 0};
        for (int s = 0; s < 4; ++s) centre = centre + mesh_.vertices[std::size_t(back(fine(start[s][0], start[s][1])))];
        const auto c = std::int32_t(mesh_.vertices.size());
        mesh_.vertices.push_back(0.25 * centre);
        if (front_normals_) mesh_.normals.push_back({0, 0, -1});
        for (std::size_t m = 0; m < ring_.size(); ++m)
            mesh_.triangles.push_back({c, ring_[(m + 1) % ring_.size()], ring_[m]});
    }

private:
    std::int32_t fine(int I, int J) const {
        return fine_index_[std::size_t(J) * std::size_t(g_.fx()) + std::size_t(I)];
    }

    // Back vertices are created on demand, one per front vertex that needs one.
    std::int32_t back(std::int32_t front) {
        std::int32_t& b = back_of_[std::size_t(front)];
        if (b < 0) {
            const Vec3d p = mesh_.vertices[std::size_t(front)];
            b = std::int32_t(mesh_.vertices.size());
            mesh_.vertices.push_back({p.x, p.y, -t_});
            if (front_normals_) mesh_.normals.push_back({0, 0, -1});
        }
        return b;
    }

    TriangleMesh& mesh_;
    const std::vector<std::int32_t>& fine_index_;
    const FineGrid& g_;
    double t_;
    bool front_normals_;
    std::vector<std::int32_t> back_of_;  // per front vertex; -1 until it has one
    std::vector<std::int32_t> ring_;     // one cell's outline, counter-clockwise seen from +w
};

}  // namespace detail

// The Phong-tessellated fabrication surface (an open sheet): ((nx-1)k+1) × ((ny-1)k+1)
// shared vertices, 2k² triangles per active cell (k = subdivisions; a fractional one
// mixes ⌊k⌋ and ⌈k⌉ sub-cells a side, detail::fine_grid), counter-clockwise seen from +w
// (face normals on the light side), per-vertex shading normals. Cells outside an elliptical
// aperture are left out, and so are the vertices only they use. Coordinates are in the
// world frame (Heightmap::frame()) unless world_frame is false.
// Throws InputError for subdivisions < 1, a non-finite alpha or an oversized mesh.
inline TriangleMesh tessellate_surface(const Heightmap& hm, float phong_alpha, double subdivisions,
                                       bool world_frame = true) {
    detail::check_export_args(hm, phong_alpha, subdivisions);
    std::vector<std::int32_t> fine_index;
    const double alpha = double(phong_alpha);
    TriangleMesh mesh = detail::tessellate_local(hm, subdivisions, fine_index, [&](int ci, int cj, double a, double b) {
        return phong_vertex_in_cell(hm, ci, cj, a, b, alpha);
    });
    if (world_frame) detail::to_world(hm.frame(), mesh);
    return mesh;
}

// A closed, outward-oriented lens solid for machining or printing:
//  - front: the tessellated surface of tessellate_surface over the active cells;
//  - side walls: parallel to the surface normal, one quad (two triangles) under every
//    boundary edge of the front, down to w = -thickness;
//  - back: the plane w = -thickness, one or two triangles per cell (a fan around the
//    cell centre where the cell has sub-vertices on the outline, so every boundary edge
//    matches a wall edge exactly).
// The solid covers the active cells: the full rectangle for a rectangular aperture, the
// staircase of cells whose centres lie inside the ellipse for an elliptical one (the only
// part of the front the tracer models). Phong correction moves boundary points a little
// within the plane, as in the simulation; the walls follow them, so the outline is the
// nominal one up to that displacement (about 1 µm for a steep dome on a 101 × 101 grid,
// growing with slope and cell size). The solid is the union of vertical prisms under the
// front triangles: its volume is ∫(h + thickness) dA over the tessellated front. Vertex
// normals are not set (they are undefined along the sharp rims;
// TriangleMesh::compute_normals() gives area-weighted ones).
// Throws InputError for a thickness that is not positive and finite or that does not
// clear the lowest point of the front, and for the arguments tessellate_surface rejects.
//
// lens_solid_of builds the same solid over another form of the front (`point` as in
// detail::tessellate_local); lens_solid below is it over the Phong patches. With
// `front_normals` the front keeps its vertex normals (the other vertices get the back
// face's, −w), for tracing the front as a smooth surface (design/exported.hpp); the
// front's triangles (2k² per active cell for a whole k) come first in the mesh either
// way.
//
// `border` keeps the cells along the edges at one facet pair (CoarseBorder: a lens blank's
// rim).
template <class PointFn>
TriangleMesh lens_solid_of(const Heightmap& hm, const Lens& lens, double subdivisions, PointFn&& point,
                           bool front_normals, bool world_frame, CoarseBorder border = {}) {
    detail::check_export_args(hm, 0.0, subdivisions);
    const double t = lens.thickness;
    if (!(t > 0) || !std::isfinite(t))
        throw InputError("lens thickness must be a positive finite number, got " + std::to_string(t));
    const int nx = hm.nx(), ny = hm.ny();
    const detail::FineGrid g = detail::fine_grid(hm, subdivisions, border);
    std::vector<std::int32_t> fine_index;
    TriangleMesh mesh = detail::tessellate_local(hm, g, fine_index, point);
    if (!front_normals) mesh.normals.clear();
    detail::check_lens_clearance(t, mesh, mesh.vertices.size());

    const auto active = [&](int ci, int cj) { return detail::cell_present(hm, ci, cj); };
    detail::LensClosure closure(mesh, fine_index, g, t, front_normals);
    for (int cj = 0; cj + 1 < ny; ++cj)
        for (int ci = 0; ci + 1 < nx; ++ci) {
            if (!active(ci, cj)) continue;
            // A side is on the outline when the cell across it is missing; there the front
            // has that side's sub-cell count of boundary edges, each getting a wall quad,
            // and the back face takes all their points. The front runs counter-clockwise
            // around the region, so its boundary edges follow the ring's direction.
            const bool open_side[4] = {!active(ci, cj - 1), !active(ci + 1, cj), !active(ci, cj + 1),
                                       !active(ci - 1, cj)};
            closure.close_cell(ci, cj, open_side);
        }
    if (world_frame) detail::to_world(hm.frame(), mesh);
    return mesh;
}

// The solid over the Phong patches: what is milled or printed (see lens_solid_of above).
inline TriangleMesh lens_solid(const Heightmap& hm, const Lens& lens, float phong_alpha, double subdivisions,
                               bool world_frame = true, CoarseBorder border = {}) {
    detail::check_export_args(hm, phong_alpha, subdivisions);
    const double alpha = double(phong_alpha);
    return lens_solid_of(
        hm, lens, subdivisions,
        [&](int ci, int cj, double a, double b) { return phong_vertex_in_cell(hm, ci, cj, a, b, alpha); }, false,
        world_frame, border);
}

// The triangles of the mesh tessellate_surface (solid = false) or lens_solid (solid =
// true) makes on fine grid `g` (detail::fine_grid), counted without building it: two per
// sub-cell of an active cell; for the solid also two per wall quad under each sub-edge of
// the outline, and the back face, two a cell or a fan of one per ring point where a side
// of the cell is on the outline (detail::LensClosure).
inline std::int64_t export_triangle_count(const Heightmap& hm, const detail::FineGrid& g, bool solid) {
    const int nx = hm.nx(), ny = hm.ny();
    const auto active = [&](int ci, int cj) { return detail::cell_present(hm, ci, cj); };
    std::int64_t t = 0;
    for (int cj = 0; cj + 1 < ny; ++cj)
        for (int ci = 0; ci + 1 < nx; ++ci) {
            if (!active(ci, cj)) continue;
            const int kx = g.kx(ci), ky = g.ky(cj);
            t += 2 * std::int64_t(kx) * ky;
            if (!solid) continue;
            const bool open[4] = {!active(ci, cj - 1), !active(ci + 1, cj), !active(ci, cj + 1), !active(ci - 1, cj)};
            const int count[4] = {kx, ky, kx, ky};
            std::int64_t ring = 0, walls = 0;
            for (int side = 0; side < 4; ++side) {
                ring += open[side] ? count[side] : 1;
                walls += open[side] ? 2 * count[side] : 0;
            }
            t += walls + (walls > 0 ? ring : 2);
        }
    return t;
}

// Topology and size of a triangle mesh.
struct MeshCheck {
    bool closed = false;           // every edge is shared by exactly two triangles
    bool manifold = false;         // no edge is shared by more than two triangles (a boundary is allowed)
    bool oriented = false;         // no directed edge is used twice: neighbours agree on orientation
    double volume = 0;             // signed volume enclosed (divergence theorem); positive for an
                                   // outward-oriented closed mesh, meaningless for an open one
    double area = 0;               // total surface area
    int boundary_edges = 0;        // edges used by one triangle
    int non_manifold_edges = 0;    // edges used by three or more triangles
    int degenerate_triangles = 0;  // triangles repeating a vertex index

    // Closed, manifold and consistently oriented: a valid solid for slicers and CAM.
    bool watertight() const { return closed && manifold && oriented && degenerate_triangles == 0; }
};

// Builds the edge map of the mesh (edges by vertex index, so coincident but distinct
// vertices count as different) and sums area and signed volume. Throws InputError for a
// triangle index outside the vertex list.
inline MeshCheck check_mesh(const TriangleMesh& mesh) {
    MeshCheck r;
    const auto nv = std::int64_t(mesh.vertices.size());
    // Volume relative to the bounding-box centre: the same for a closed mesh, with far
    // less cancellation for a part that sits far from the origin.
    Vec3d lo{INFINITY, INFINITY, INFINITY}, hi{-INFINITY, -INFINITY, -INFINITY};
    for (const Vec3d& p : mesh.vertices) {
        lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
        hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
    }
    const Vec3d ref = mesh.vertices.empty() ? Vec3d{0, 0, 0} : 0.5 * (lo + hi);

    // (undirected key, 1 when stored low → high) for every triangle edge.
    std::vector<std::pair<std::uint64_t, std::uint8_t>> edges;
    edges.reserve(mesh.triangles.size() * 3);
    double six_volume = 0;
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
        const auto& tri = mesh.triangles[t];
        for (std::int32_t v : tri)
            if (v < 0 || v >= nv)
                throw InputError("check_mesh: triangle " + std::to_string(t) + " refers to vertex " +
                                 std::to_string(v) + " of " + std::to_string(nv));
        if (tri[0] == tri[1] || tri[1] == tri[2] || tri[2] == tri[0]) {
            ++r.degenerate_triangles;
            continue;
        }
        const Vec3d a = mesh.vertices[std::size_t(tri[0])] - ref, b = mesh.vertices[std::size_t(tri[1])] - ref,
                    c = mesh.vertices[std::size_t(tri[2])] - ref;
        r.area += 0.5 * length(cross(b - a, c - a));
        six_volume += dot(a, cross(b, c));
        for (int e = 0; e < 3; ++e) {
            const auto from = std::uint32_t(tri[e]), to = std::uint32_t(tri[(e + 1) % 3]);
            const std::uint64_t key = from < to ? (std::uint64_t(from) << 32 | to) : (std::uint64_t(to) << 32 | from);
            edges.emplace_back(key, std::uint8_t(from < to ? 1 : 0));
        }
    }
    r.volume = six_volume / 6.0;
    std::sort(edges.begin(), edges.end());
    r.oriented = true;
    for (std::size_t e = 0; e < edges.size();) {
        std::size_t f = e;
        int forward = 0;
        while (f < edges.size() && edges[f].first == edges[e].first) forward += edges[f++].second;
        const int uses = int(f - e);
        if (uses == 1) ++r.boundary_edges;
        if (uses > 2) ++r.non_manifold_edges;
        if (forward > 1 || uses - forward > 1) r.oriented = false;
        e = f;
    }
    r.manifold = r.non_manifold_edges == 0;
    r.closed = r.manifold && r.boundary_edges == 0 && !mesh.triangles.empty();
    return r;
}

// A refractive mesh must bound a solid, or the tracer cannot tell inside from outside:
// closed (so manifold) and consistently oriented, with outward-facing triangles
// (counter-clockwise seen from outside: a positive signed volume). Degenerate triangles
// are harmless and allowed. Throws InputError naming `what` (a file name, say) and the
// first failed condition.
inline MeshCheck check_refractive_solid(const TriangleMesh& mesh, const std::string& what) {
    const MeshCheck c = check_mesh(mesh);
    const std::string prefix = what + ": a refractive mesh must be a closed solid, but ";
    if (mesh.triangles.empty()) throw InputError(prefix + "it has no triangles");
    if (!c.manifold)
        throw InputError(prefix + std::to_string(c.non_manifold_edges) +
                         " edge(s) are shared by three or more triangles (not manifold)");
    if (!c.closed)
        throw InputError(prefix + "it is not closed: " + std::to_string(c.boundary_edges) +
                         " edge(s) belong to one triangle only (edges are matched by vertex index: shared "
                         "corners must be one vertex)");
    if (!c.oriented)
        throw InputError(prefix + "its triangles are not consistently oriented (neighbours wind in opposite "
                         "directions)");
    if (!(c.volume > 0)) {
        char volume[32];
        std::snprintf(volume, sizeof volume, "%.3g", c.volume);
        throw InputError(prefix + "it is inside out (signed volume " + volume +
                         " m^3): its triangles must wind counter-clockwise seen from outside");
    }
    return c;
}

}  // namespace freeform
