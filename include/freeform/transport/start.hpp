#pragma once
// The transport start (docs/architecture.md §4b): a surface that already puts the light roughly
// where the target wants it, for the annealer to refine under the exact model.
//
//  1. Source density μ: the scene's own rays (generate_rays: uniform for collimated
//     light, cos θ / r² and the intensity profile for a point, the disk's irradiance)
//     land where a *flat* surface would send them; μ is that footprint on the receiver
//     plane. Target density ν: the target image on the same grid. (The design's start
//     solves once more with each ray weighed by the power the fitted surface receives
//     above its plane point: TransportOptions::lit, design/start.hpp.)
//  2. The quadratic-cost optimal map T from μ to ν (transport/grid_ot.hpp).
//  3. Vertex (u, v) of the mesh, whose flat landing point is p, must send its light to
//     T(p): the vector law of reflection (or refraction at the lens's front face, with
//     the flat back face solved for) gives its normal, and a least-squares fit of
//     heights to those slopes (Eigen sparse CG) the surface. The fit is repeated a few
//     times with the new surface points, because the receiver is at a finite distance
//     and a point light's direction depends on the height.
//  4. Heights are shifted into surface.height_bounds; a surface that does not fit is
//     clamped, and the report says by how much it exceeded them.
// The result is judged by the exact tracer, never by the transport residual (the
// designer does that and writes both to metrics.json).
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <variant>
#include <vector>

#include <Eigen/Dense>

#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "../core/math.hpp"
#include "../scene/rays.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"
#include "grid_ot.hpp"
#include "morph.hpp"

namespace freeform {

// A lens's light leaves through its flat back face, and the body has side walls (trace/
// path.hpp), lens_rim beyond the face's edges: the "auto" rim puts them where no ray the
// map aims at the receiver meets them, and then nothing below applies (no strip is
// measured). With a narrower rim (a user's "rim": 0): a map that spreads the light wider
// than the lens tilts every ray outwards inside the glass, so the rays that enter within a
// few millimetres of an edge drift past it and meet the wall; total internal reflection
// there mirrors them back across the receiver. Left to the plain map, an edge strip's light lands on the
// centre row or column (a bright cross) and the receiver's edges go dark. No monotone map
// avoids the walls: the ray entering at the very edge would have to leave straight down.
// So the start uses them (docs/architecture.md §4b): the map carries the light of the
// interior (the face less a strip along each such wall) onto the target, the interior's
// edge reaching the receiver's edge; the strip's rays are aimed further out, up to the
// lens's width beyond the map's goal at the wall (transport_detail::aim), so that they meet the wall
// and are mirrored into a band across the receiver. Aimed that way the strip continues the
// interior's convex potential (a monotone map, no fold and no caustic), and where its
// mirrored light lands is known: the map is solved for the target less that light.
// Walls: 0 = −u, 1 = +u, 2 = −v, 3 = +v (surface frame); a zero margin is no strip.
struct WallStrips {
    std::array<double, 4> margin{};
    double half_u = 0, half_v = 0;  // the lens body's half extents
    double wall_fraction = 0;       // share of the active vertices the plain map sent into a wall
    // The map that places the strips' mirrored light when the start's map is solved (the
    // plain map they were measured on); unset: the strips' light is not subtracted.
    std::shared_ptr<const OtResult> placement;
    std::shared_ptr<const Heightmap> placement_surface;  // the surface fitted to it (glass thickness)

    bool any() const { return margin[0] > 0 || margin[1] > 0 || margin[2] > 0 || margin[3] > 0; }
    double widest() const { return std::max({margin[0], margin[1], margin[2], margin[3]}); }

    // How far into a strip the surface point s lies along each axis (−1 at the −u or −v
    // wall, 1 at the +u or +v wall, 0 outside the strips); true when it lies in one.
    bool depth(Vec3d s, double& tu, double& tv) const {
        const auto axis = [&](double x, double half, int lo, int hi) {
            const double mlo = margin[std::size_t(lo)], mhi = margin[std::size_t(hi)];
            if (mhi > 0 && x > half - mhi) return std::min(1.0, (x - (half - mhi)) / mhi);
            if (mlo > 0 && x < -half + mlo) return -std::min(1.0, (-half + mlo - x) / mlo);
            return 0.0;
        };
        tu = axis(s.x, half_u, 0, 1), tv = axis(s.y, half_v, 2, 3);
        return tu != 0 || tv != 0;
    }
};

// How the map is computed: the back-and-forth OT solver (the default), or Poisson mesh
// morphing (the alternative it is measured against in bench_transport).
enum class TransportMethod { back_and_forth, morphing };

struct TransportOptions {
    TransportMethod method = TransportMethod::back_and_forth;
    // The grid (transport_grid): `cells_per_pixel` cells per receiver pixel along each
    // axis, at most `max_grid` along the longer side. Finer than the pixel because the start's error is
    // set by the map at sub-pixel scale: the letter E (101² mesh, 200² px) starts at a
    // fitted error 0.045 / 0.038 / 0.036 / 0.036 with 1 / 2 / 3 / 4 cells per pixel, the
    // camera photograph (201² mesh) at 0.047 / 0.033 / 0.029 / 0.028 (docs/architecture.md
    // §4b). 600² cells cost about 0.15 s per iteration on 2 cores.
    int max_grid = 768;
    double cells_per_pixel = 3;
    double rays_per_grid_cell = 16;  // rays sampling the source footprint, per grid cell it covers
    int fit_iterations = 4;        // map → normals → heights rounds (near field)
    OtOptions ot{};
    WallStrips strips{};           // a lens's wall strips (measure_wall_strips); none: the plain map
    // The surface whose received power weighs μ (the start's second round, docs/
    // architecture.md §4b): each source point keeps its flat landing, and carries what the
    // ray aimed at this surface above it carries. None: the flat surface's power.
    std::shared_ptr<const Heightmap> lit;
};

// What the transport start did, for metrics.json.
struct TransportReport {
    bool used = false;            // false: the scene fell back to a flat start
    std::string fallback_reason;  // why, when not used
    int grid_x = 0, grid_y = 0;   // transport grid cells
    double cell_size = 0;         // metres
    int ot_iterations = 0;
    double ot_residual = 1;       // ½ Σ|ν − T#μ| on the transport grid (not the design error)
    double ot_seconds = 0, fit_seconds = 0;
    int fit_iterations = 0;
    double height_range = 0;      // max − min of the fitted heights (metres, active cells)
    double height_excess = 0;     // by how much the range exceeded height_bounds (0: it fits)
    double unmapped_fraction = 0; // vertices whose flat landing missed the receiver plane
    double cells_per_pixel = 0;   // TransportOptions::cells_per_pixel of the map used
    // The designer tries two grids and keeps the better start (design/start.hpp): the other
    // one's cells per pixel and its start's error under the exact tracer (−1: none tried).
    double other_cells_per_pixel = 0, other_error = -1;
    // A lens's wall strips (WallStrips): the widest strip (metres; 0: none), the share of
    // the vertices whose light the plain map sent into a side wall (WallStrips::
    // wall_fraction), and the share of the light the strips mirror onto the receiver (the
    // target less it is what the map carries).
    double strip_margin = 0, wall_fraction = 0, strip_light = 0;
};

// The transport map of a scene, reusable for several meshes.
struct TransportMap {
    OtResult ot;                 // in receiver-local metres (u right, v up)
    TransportReport report;      // grid and solver fields filled
    WallStrips strips;           // the lens's wall strips the map was solved with
};

namespace transport_detail {

// The scene's optics in the surface frame, double precision.
struct Optics {
    int light = 0;  // 0 collimated, 1 point, 2 disk (its centre stands for the source)
    Vec3d direction{}, position{};
    bool lens = false;
    double ior = 1.5, thickness = 0.01;
    Vec3d rc{}, ru{}, rv{}, rn{};  // receiver centre, axes, front normal
    double half_u = 0, half_v = 0;  // receiver half sizes

    explicit Optics(const Scene& s) {
        const Frame& f = s.surface.frame;
        if (const auto* c = std::get_if<CollimatedLight>(&s.light.shape)) {
            light = 0;
            direction = normalize(f.dir_to_local(c->direction));
        } else if (const auto* p = std::get_if<PointLight>(&s.light.shape)) {
            light = 1;
            position = f.to_local(p->position);
        } else {
            light = 2;
            position = f.to_local(std::get<DiskLight>(s.light.shape).center);
        }
        if (const auto* l = std::get_if<Lens>(&s.surface.material)) lens = true, ior = l->ior, thickness = l->thickness;
        rc = f.to_local(s.receiver.frame.origin);
        ru = f.dir_to_local(s.receiver.frame.u);
        rv = f.dir_to_local(s.receiver.frame.v);
        rn = f.dir_to_local(s.receiver.frame.w);
        half_u = 0.5 * s.receiver.size.x, half_v = 0.5 * s.receiver.size.y;
    }

    Vec3d incoming(Vec3d p) const { return light == 0 ? direction : normalize(p - position); }

    // Where light arriving along d at the point s of the flat surface (w = 0) lands on
    // the receiver plane, in receiver-local metres; nothing if it never meets its front.
    std::optional<Vec2d> flat_landing(Vec3d s, Vec3d d) const {
        Vec3d o = s, out = d;
        if (!lens) {
            out.z = -out.z;
        } else {
            // Through a flat slab the direction is unchanged; the exit point moves.
            const double ct = std::sqrt(std::max(0.0, 1.0 - (1.0 - d.z * d.z) / (ior * ior)));
            const Vec3d g{d.x / ior, d.y / ior, -ct};
            o = s + g * (thickness / std::max(ct, 1e-9));
        }
        const double dn = dot(out, rn);
        if (!(dn < 0)) return std::nullopt;
        const double t = dot(rc - o, rn) / dn;
        if (!(t > 0)) return std::nullopt;
        const Vec3d q = o + t * out - rc;
        return Vec2d{dot(q, ru), dot(q, rv)};
    }

    // Inside a lens, the ray from surface point s that the flat back face refracts
    // towards q: its direction g in the glass and its exit point e on the back face.
    // Solved for e by fixed point.
    void glass_path(Vec3d s, Vec3d q, Vec3d& g, Vec3d& e) const {
        e = {s.x, s.y, -thickness}, g = {0, 0, -1};
        for (int k = 0; k < 6; ++k) {
            const Vec3d out = normalize(q - e);
            const Vec3d t{out.x / ior, out.y / ior, 0};
            const double tz = std::sqrt(std::max(1e-12, 1.0 - t.x * t.x - t.y * t.y));
            g = {t.x, t.y, -tz};
            e = s + g * ((s.z + thickness) / tz);
        }
    }

    // The unit normal at surface point s that sends light arriving along d_in to the
    // point q (surface frame): reflection, or refraction into the lens whose flat back
    // face then bends the ray towards q.
    Vec3d normal_towards(Vec3d s, Vec3d d_in, Vec3d q) const {
        Vec3d n;
        if (!lens) {
            n = normalize(q - s) - d_in;
        } else {
            Vec3d g, e;
            glass_path(s, q, g, e);
            n = d_in - ior * g;  // n1 d_in − n2 d_out, n1 = 1 outside
        }
        if (n.z < 0) n = -n;
        return normalize(n);
    }
};

// Area-weighted overlap of the cells of two regular 1-D grids: rows = cells of the
// first (origin a0, step ha, na cells), columns = cells of the second.
inline Eigen::MatrixXd overlap_1d(double a0, double ha, int na, double b0, double hb, int nb) {
    Eigen::MatrixXd m = Eigen::MatrixXd::Zero(na, nb);
    for (int i = 0; i < na; ++i) {
        const double lo = a0 + i * ha, hi = lo + ha;
        const int k0 = std::max(0, int(std::floor((lo - b0) / hb))), k1 = std::min(nb - 1, int(std::floor((hi - b0) / hb)));
        for (int k = k0; k <= k1; ++k) {
            const double o = std::min(hi, b0 + (k + 1) * hb) - std::max(lo, b0 + k * hb);
            if (o > 0) m(i, k) = o / hb;
        }
    }
    return m;
}

// The smallest count ≥ n whose only prime factors are 2, 3 and 5: FFTs of such lengths
// (and of twice them) take the fast radix paths.
inline int fft_friendly(int n) {
    for (int m = std::max(1, n);; ++m) {
        int r = m;
        for (const int p : {2, 3, 5})
            while (r % p == 0) r /= p;
        if (r == 1) return m;
    }
}

inline void splat(Eigen::ArrayXXd& m, const OtGrid& g, double x, double y, double w) {
    const double fx = std::clamp((x - g.x0) / g.hx - 0.5, 0.0, double(g.nx - 1));
    const double fy = std::clamp((y - g.y0) / g.hy - 0.5, 0.0, double(g.ny - 1));
    const int i = std::min(int(fx), g.nx - 2), j = std::min(int(fy), g.ny - 2);
    const double a = fx - i, b = fy - j;
    m(j, i) += w * (1 - a) * (1 - b);
    m(j, i + 1) += w * a * (1 - b);
    m(j + 1, i) += w * (1 - a) * b;
    m(j + 1, i + 1) += w * a * b;
}

// The right-hand side of the least-squares height fit: minus the divergence of the edge
// slopes, each edge's slope the mean of its ends' (su, sv: vertex slopes along u and v).
inline Eigen::ArrayXXd edge_slope_divergence(const Eigen::ArrayXXd& su, const Eigen::ArrayXXd& sv, double du, double dv) {
    const Eigen::Index ny = su.rows(), nx = su.cols();
    Eigen::ArrayXXd rhs = Eigen::ArrayXXd::Zero(ny, nx);
    for (Eigen::Index j = 0; j < ny; ++j)
        for (Eigen::Index i = 0; i < nx; ++i) {
            if (i + 1 < nx) {
                const double e = 0.5 * (su(j, i) + su(j, i + 1)) / du;
                rhs(j, i) -= e, rhs(j, i + 1) += e;
            }
            if (j + 1 < ny) {
                const double e = 0.5 * (sv(j, i) + sv(j + 1, i)) / dv;
                rhs(j, i) -= e, rhs(j + 1, i) += e;
            }
        }
    return rhs;
}

// The height of `hm` at (u, v) (surface frame), bilinear between its vertices, clamped to
// the grid.
inline double height_at(const Heightmap& hm, double u, double v) {
    const double fx = std::clamp((u - hm.u_of(0)) / hm.du(), 0.0, double(hm.nx() - 1));
    const double fy = std::clamp((v - hm.v_of(0)) / hm.dv(), 0.0, double(hm.ny() - 1));
    const int i = std::min(int(fx), hm.nx() - 2), j = std::min(int(fy), hm.ny() - 2);
    const double a = fx - i, b = fy - j;
    const auto h = [&](int x, int y) { return double(hm.heights()[std::size_t(y * hm.nx() + x)]); };
    return (1 - b) * ((1 - a) * h(i, j) + a * h(i + 1, j)) + b * ((1 - a) * h(i, j + 1) + a * h(i + 1, j + 1));
}

// The vertices of `hm`'s active cells (1: a corner of an active cell).
inline std::vector<std::uint8_t> active_vertices(const Heightmap& hm) {
    const int nx = hm.nx(), ny = hm.ny();
    std::vector<std::uint8_t> active(std::size_t(nx * ny), 0);
    for (int j = 0; j + 1 < ny; ++j)
        for (int i = 0; i + 1 < nx; ++i)
            if (hm.cell_active(i, j))
                for (int b = 0; b < 2; ++b)
                    for (int a = 0; a < 2; ++a) active[std::size_t((j + b) * nx + i + a)] = 1;
    return active;
}

// Where the light entering the flat surface at s is sent (surface frame, a point of the
// receiver plane): the map's goal for its flat landing. In a wall strip (WallStrips) the
// goal moves outwards along the receiver plane by the lens's width along that axis times
// the square of how far into the strip s lies: the square keeps the aim's slope
// continuous at the strip's inner edge (a kink there bends the central-difference normals
// of the interior's last cells and starves the receiver's edge), and the map, which
// extends smoothly past the interior, carries it on. Nothing when the flat landing misses
// the receiver plane.
inline std::optional<Vec3d> aim(const Optics& optics, const WallStrips& strips, const OtResult& map, Vec3d s) {
    const auto land = optics.flat_landing(s, optics.incoming(s));
    if (!land) return std::nullopt;
    const Vec2d q = map.transport(map.grid.source_scale * land->x, map.grid.source_scale * land->y);
    Vec3d goal = optics.rc + q.x * optics.ru + q.y * optics.rv;
    double tu = 0, tv = 0;
    if (strips.depth(s, tu, tv)) {
        const auto along = [&](Vec3d axis) { return normalize(axis - dot(axis, optics.rn) * optics.rn); };
        goal = goal + (2 * strips.half_u * tu * std::abs(tu)) * along(Vec3d{1, 0, 0}) +
               (2 * strips.half_v * tv * std::abs(tv)) * along(Vec3d{0, 1, 0});
    }
    return goal;
}

// Where the light of a strip ray entering at s (flat surface) lands, in receiver-local
// metres: its path through the glass to the strip goal under `map`, mirrored by each wall
// its exit lies beyond. Nothing when it misses the receiver plane.
inline std::optional<Vec2d> strip_landing(const Optics& optics, const WallStrips& strips, const OtResult& map, Vec3d s) {
    const auto goal = aim(optics, strips, map, s);
    if (!goal) return std::nullopt;
    Vec3d g, e;
    optics.glass_path(Vec3d{s.x, s.y, strips.placement_surface ? height_at(*strips.placement_surface, s.x, s.y) : 0.0},
                      *goal, g, e);
    Vec3d out = normalize(*goal - e);
    if (std::abs(e.x) > strips.half_u) e.x = std::copysign(2 * strips.half_u, e.x) - e.x, out.x = -out.x;
    if (std::abs(e.y) > strips.half_v) e.y = std::copysign(2 * strips.half_v, e.y) - e.y, out.y = -out.y;
    const double dn = dot(out, optics.rn);
    if (!(dn < 0)) return std::nullopt;
    const double t = dot(optics.rc - e, optics.rn) / dn;
    if (!(t > 0)) return std::nullopt;
    const Vec3d q = e + t * out - optics.rc;
    return Vec2d{dot(q, optics.ru), dot(q, optics.rv)};
}

// Adds the light of the strip ray entering at s to `placed` (the light the strips
// mirror onto the receiver, on the transport grid). The ray stands for the strip's light
// over about `spacing` around s, which the strip's aim stretches by its reach over its
// margin along the wall's normal: it is spread over that stretch in as many pieces, about
// one per grid cell (a single sample per ray would leave most grid lines empty and stripe
// the map that is solved for the target less this light).
inline void place_strip_ray(Eigen::ArrayXXd& placed, const OtGrid& g, const Optics& optics, const WallStrips& strips,
                            Vec3d s, double spacing, double w) {
    double tu = 0, tv = 0;
    strips.depth(s, tu, tv);
    const auto pieces = [&](double t, double half, int lo, int hi) {
        if (t == 0) return 1;
        const double m = strips.margin[std::size_t(t > 0 ? hi : lo)];
        return std::clamp(int(std::ceil(spacing * 2 * half / m / std::min(g.hx, g.hy))), 1, 256);
    };
    const int nu = pieces(tu, strips.half_u, 0, 1), nv = pieces(tv, strips.half_v, 2, 3);
    const double wp = w / double(nu * nv);
    for (int b = 0; b < nv; ++b)
        for (int a = 0; a < nu; ++a) {
            const Vec3d sp{s.x + spacing * ((a + 0.5) / nu - 0.5) * (nu > 1), s.y + spacing * ((b + 0.5) / nv - 0.5) * (nv > 1), s.z};
            const auto p = strip_landing(optics, strips, *strips.placement, sp);
            if (p && p->x >= g.x0 && p->x < g.x0 + g.nx * g.hx && p->y >= g.y0 && p->y < g.y0 + g.ny * g.hy)
                splat(placed, g, p->x, p->y, wp);
        }
}

// Where the target is lit all the way from `from` out to the receiver's edge along the
// unit direction e (receiver plane, surface frame), the distance to that edge; nothing
// when the edge lies beyond `reach` or a dark cell comes first.
inline std::optional<double> lit_run_to_receiver_edge(const Optics& optics, const OtResult& ot, Vec3d from, Vec3d e,
                                                      double reach) {
    const double x = dot(from - optics.rc, optics.ru), y = dot(from - optics.rc, optics.rv);
    const double ex = dot(e, optics.ru), ey = dot(e, optics.rv);
    double edge = std::numeric_limits<double>::infinity();
    if (std::abs(ex) > 1e-12) edge = std::min(edge, (std::copysign(optics.half_u, ex) - x) / ex);
    if (std::abs(ey) > 1e-12) edge = std::min(edge, (std::copysign(optics.half_v, ey) - y) / ey);
    if (!(edge >= 0 && edge <= reach)) return std::nullopt;
    const double h = 0.125 * std::min(ot.grid.hx, ot.grid.hy);
    for (double t = 0.5 * h; t < edge; t += h)
        if (!ot.lit(x + t * ex, y + t * ey)) return std::nullopt;
    return edge;
}

// The border vertices' goals, which the map gets wrong by a little: it is bilinear
// between the transport grid's cell centres, and the flat footprint's light is splatted
// onto those centres, which blurs the footprint's edge by up to a cell, so at the face's
// very edge the map points short of where the edge's light belongs. One vertex in, the
// map is right. Along the line from the next vertex's goal outwards:
//  - Where the map is straight to within `straight` of its step (the second difference
//    of the three inner goals against their first), the goal is continued straight, if it
//    lands on lit target (never into a dark margin or a crack). The example lens's
//    uniform target: its outermost column got 10 % too little light before this rule.
//  - Where it bends, a line would overshoot, as at a headlight pattern's soft edge, and
//    the goal stays, unless the target is lit all the way from the next vertex's goal to
//    the receiver's edge within three of the map's steps (a picture that fills the
//    receiver): then the border vertex is aimed at the receiver's edge, as optimal
//    transport maps the source's boundary onto the boundary of the target's support. A
//    photograph's map bends with its texture, and the short goal costs most where it is
//    dark at the edge: the edge row's light comes from a sliver of the source narrower
//    than the blur (a 512² photograph's bottom row, a fifth of the mean brightness, got
//    19 % of its light from the start; aimed at the edge, 64 %; at 200², 36 % and 92 %).
// Both need all four vertices mapped. The corners take the rows' extrapolation of the
// columns' extrapolated goals.
inline void extrapolate_border_aims(std::vector<Vec3d>& goal, const std::vector<std::uint8_t>& mapped, int nx, int ny,
                                    const Optics& optics, const OtResult& ot) {
    constexpr double straight = 0.05, reach_steps = 3;
    const auto lit = [&](Vec3d g) {
        return ot.target.size() == 0 || ot.lit(dot(g - optics.rc, optics.ru), dot(g - optics.rc, optics.rv));
    };
    const auto extend = [&](std::size_t edge, std::size_t in1, std::size_t in2, std::size_t in3) {
        if (!mapped[edge] || !mapped[in1] || !mapped[in2] || !mapped[in3]) return;
        const Vec3d step = goal[in1] - goal[in2];
        const double len = length(step);
        if (length(step - (goal[in2] - goal[in3])) <= straight * len) {
            const Vec3d g = goal[in1] + step;
            if (lit(g)) goal[edge] = g;
            return;
        }
        if (ot.target.size() == 0 || !(len > 0)) return;
        const auto to_edge = lit_run_to_receiver_edge(optics, ot, goal[in1], step / len, reach_steps * len);
        if (!to_edge) return;
        goal[edge] = goal[in1] + (*to_edge / len) * step;
    };
    const auto at = [nx](int i, int j) { return std::size_t(j) * std::size_t(nx) + std::size_t(i); };
    if (nx >= 4)
        for (int j = 0; j < ny; ++j) {
            extend(at(0, j), at(1, j), at(2, j), at(3, j));
            extend(at(nx - 1, j), at(nx - 2, j), at(nx - 3, j), at(nx - 4, j));
        }
    if (ny >= 4)
        for (int i = 0; i < nx; ++i) {
            extend(at(i, 0), at(i, 1), at(i, 2), at(i, 3));
            extend(at(i, ny - 1), at(i, ny - 2), at(i, ny - 3), at(i, ny - 4));
        }
}

}  // namespace transport_detail

// Why a scene cannot start from a transport map (empty: it can).
inline std::string transport_unsupported_reason(const Scene& scene) {
    if (!scene.target) return "the scene has no target";
    if (!scene.meshes.empty()) return "extra meshes can reflect or block light: the transport model has none";
    return {};
}

// Where a flat surface sends the light on the receiver plane (receiver-local metres),
// from a 33 × 33 sampling of the aperture. Throws InputError when none of it meets the
// receiver's front: a transport start cannot be made (checked up front by the CLI).
struct FlatFootprint {
    double lo_u = 0, hi_u = 0, lo_v = 0, hi_v = 0;
};

inline FlatFootprint flat_footprint(const Scene& scene, const Heightmap& surface) {
    const transport_detail::Optics optics(scene);
    FlatFootprint fp{1e300, -1e300, 1e300, -1e300};
    int landed = 0;
    for (int b = 0; b <= 32; ++b)
        for (int a = 0; a <= 32; ++a) {
            const double u = (a / 32.0 - 0.5) * surface.size().x, v = (b / 32.0 - 0.5) * surface.size().y;
            if (!surface.in_aperture(u, v)) continue;
            const Vec3d s{u, v, 0};
            const auto p = optics.flat_landing(s, optics.incoming(s));
            if (!p) continue;
            ++landed;
            fp.lo_u = std::min(fp.lo_u, p->x), fp.hi_u = std::max(fp.hi_u, p->x);
            fp.lo_v = std::min(fp.lo_v, p->y), fp.hi_v = std::max(fp.hi_v, p->y);
        }
    if (landed == 0)
        throw InputError("surface.initial: \"transport\": light reflected (or refracted) by a flat surface never meets "
                         "the receiver's front; use \"flat\" or check receiver.center and receiver.normal");
    return fp;
}

// How far the transport grid reaches from the receiver's centre, in receiver widths
// (heights): a flat footprint reaching farther is shrunk about that centre until it fits
// (OtGrid::source_scale: the map is the same, docs/architecture.md §4b). A quarter of the
// receiver's width beyond each edge: the map must run on past the receiver's edges for
// the aims that continue it there (a raised rim's edge vertex, the border goals). Onto
// the receiver itself (0.5) a raised rim's worst edge got 42 % of its light and the
// reweighted second solve stopped gaining (tests/test_transport.cpp), 84 % at 0.6, 99 %
// at 0.75; the focusing scenes below did as well at 0.75 as at 0.5. Until 2026-11-30 the
// grid reached 1.5 widths and cut the footprint there.
inline constexpr double footprint_reach = 0.75;

// The transport grid of a scene whose flat surface lands the light on `fp`: it covers the
// receiver and the footprint, the latter shrunk to footprint_reach. Cut there instead (its
// light beyond piled onto the grid's edge), a 10 cm mirror focusing a checkerboard onto a
// 3 cm receiver 0.5 m away started at a cell-mean error of 0.129, the receiver's outer
// three pixels dark; shrunk onto 1.5 widths, 0.027 (1.5 cells a pixel on a 960² grid);
// onto 0.75 widths, 0.017 (3 cells a pixel). The grid is fine enough to resolve the
// receiver's pixels by `cells_per_pixel` cells and the (shrunk) footprint by about 100
// cells along its longer side, with at most `max_grid` cells a side; the sides are
// rounded up to FFT-friendly counts (the Poisson solves' transforms), the extra cells
// padding it evenly. Only the pixels are refined: where the
// footprint sets the cell (a 50² receiver of 4 mm pixels, a footprint of 1 mm cells), a
// finer grid gave worse starts (the headlight: 0.015 / 0.021 / 0.024 at 1 / 2 / 3 times).
inline OtGrid transport_grid(const Scene& scene, const FlatFootprint& fp, const TransportOptions& options) {
    const Receiver& rec = scene.receiver;
    const double pu = rec.size.x / rec.width, pv = rec.size.y / rec.height;
    double lo_u = -0.5 * rec.size.x, hi_u = 0.5 * rec.size.x, lo_v = -0.5 * rec.size.y, hi_v = 0.5 * rec.size.y;
    const double limit_u = footprint_reach * rec.size.x, limit_v = footprint_reach * rec.size.y;
    const double reach_u = std::max(-fp.lo_u, fp.hi_u), reach_v = std::max(-fp.lo_v, fp.hi_v);
    const double scale = std::min(limit_u / std::max(reach_u, limit_u), limit_v / std::max(reach_v, limit_v));
    lo_u = std::min(lo_u, scale * fp.lo_u), hi_u = std::max(hi_u, scale * fp.hi_u);
    lo_v = std::min(lo_v, scale * fp.lo_v), hi_v = std::max(hi_v, scale * fp.hi_v);
    const double fp_extent = scale * std::max(fp.hi_u - fp.lo_u, fp.hi_v - fp.lo_v);
    const double refine = std::max(1.0, options.cells_per_pixel);
    double cell = std::min({pu / refine, pv / refine, fp_extent > 0 ? fp_extent / 100.0 : pu});
    cell = std::max(cell, std::max(hi_u - lo_u, hi_v - lo_v) / options.max_grid);
    OtGrid g;
    g.nx = transport_detail::fft_friendly(std::max(2, int(std::ceil((hi_u - lo_u) / cell - 1e-9))));
    g.ny = transport_detail::fft_friendly(std::max(2, int(std::ceil((hi_v - lo_v) / cell - 1e-9))));
    g.hx = g.hy = cell;
    g.source_scale = scale;
    g.x0 = 0.5 * (lo_u + hi_u) - 0.5 * g.nx * cell;
    g.y0 = 0.5 * (lo_v + hi_v) - 0.5 * g.ny * cell;
    return g;
}

namespace transport_detail {

// ν: the target image, area-averaged onto the grid g (image row 0 is the top, largest v).
inline Eigen::ArrayXXd target_density(const Receiver& rec, const ImageD& target_image, const OtGrid& g) {
    const ImageD flipped = target_image.colwise().reverse();
    const double tu = rec.size.x / double(target_image.cols()), tv = rec.size.y / double(target_image.rows());
    const Eigen::MatrixXd ox = overlap_1d(g.x0, g.hx, g.nx, -0.5 * rec.size.x, tu, int(target_image.cols()));
    const Eigen::MatrixXd oy = overlap_1d(g.y0, g.hy, g.ny, -0.5 * rec.size.y, tv, int(target_image.rows()));
    return (oy * flipped.matrix() * ox.transpose()).array().max(0.0);
}

// μ: the rays' weights splatted at their flat landings on grid g (scaled by its
// source_scale), a lens's wall-strip rays placed where the walls mirror them (`placed`),
// and the weight whose flat landing misses the receiver plane (`lost`) of the `total`.
struct SourceDensity {
    Eigen::ArrayXXd mu, placed;
    double lost = 0, total = 0;
};

// Each ray is labelled by its flat landing: that of its own line through the plane w = 0,
// or, with `aims` (rays aimed at a lit surface: TransportOptions::lit), that of the line
// from its source through the plane point it is aimed above (collimated light keeps its
// direction). `spacing`: the rays' spacing on the face (place_strip_ray).
inline SourceDensity source_density(const Optics& optics, const OtGrid& g, const RaySet& rays,
                                    const std::vector<Vec2d>* aims, const WallStrips& strips, double spacing) {
    SourceDensity out{Eigen::ArrayXXd::Zero(g.ny, g.nx), Eigen::ArrayXXd::Zero(g.ny, g.nx)};
    const double scale = g.source_scale;
    for (std::int64_t k = 0; k < rays.size(); ++k) {
        const Vec3d o(rays.origin[std::size_t(k)]);
        const double w = double(rays.weight[std::size_t(k)]);
        out.total += w;
        Vec3d d(rays.direction[std::size_t(k)]), s = o + d * (-o.z / d.z);
        if (aims) {
            s = {(*aims)[std::size_t(k)].x, (*aims)[std::size_t(k)].y, 0.0};
            if (optics.light != 0) d = normalize(s - o);
        }
        double depth_u = 0, depth_v = 0;
        if (strips.any() && strips.depth(s, depth_u, depth_v)) {
            // A strip ray: its mirrored light is placed, not transported.
            place_strip_ray(out.placed, g, optics, strips, s, spacing, w);
            continue;
        }
        const auto p = optics.flat_landing(s, d);
        if (!p) {
            out.lost += w;
            continue;
        }
        splat(out.mu, g, scale * p->x, scale * p->y, w);
    }
    return out;
}

}  // namespace transport_detail

// Solves the transport from the light's flat-surface footprint to the target image
// (relative irradiance, any resolution). `surface` gives the aperture (its mask).
inline TransportMap solve_transport(const Scene& scene, const Heightmap& surface, const ImageD& target_image,
                                    std::uint64_t seed, const TransportOptions& options = {}) {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    if (target_image.size() == 0 || !(target_image.maxCoeff() > 0))
        throw InputError("target: the image is entirely black: there is nothing to send light to");
    const transport_detail::Optics optics(scene);
    const Receiver& rec = scene.receiver;
    const FlatFootprint fp = flat_footprint(scene, surface);
    const double fp_lo_u = fp.lo_u, fp_hi_u = fp.hi_u, fp_lo_v = fp.lo_v, fp_hi_v = fp.hi_v;
    const OtGrid g = transport_grid(scene, fp, options);
    const double cell = g.hx;

    const Eigen::ArrayXXd nu = transport_detail::target_density(rec, target_image, g);

    // μ: the light's rays, landed by the flat surface.
    const double scale = g.source_scale, fp_cells = std::max(1.0, scale * scale * (fp_hi_u - fp_lo_u) * (fp_hi_v - fp_lo_v) / (cell * cell));
    Light light = scene.light;
    light.rays = std::clamp<std::int64_t>(std::int64_t(options.rays_per_grid_cell * fp_cells), 4096, 4'000'000);
    std::vector<Vec2d> aims;  // only on a lit surface: the plain solve labels rays by their own lines
    const RaySet rays = generate_rays(light, options.lit ? *options.lit : surface, rec,
                                      hash_combine(seed, 0x7a2a5b0e1ULL), options.lit ? &aims : nullptr);
    // A lens's wall strips: their light is placed with the plain map (WallStrips).
    WallStrips strips = options.strips;
    if (!strips.placement) strips.margin = {};
    const double spacing = std::sqrt(surface.size().x * surface.size().y / double(std::max<std::int64_t>(1, rays.size())));
    const transport_detail::SourceDensity source =
        transport_detail::source_density(optics, g, rays, options.lit ? &aims : nullptr, strips, spacing);
    const Eigen::ArrayXXd& mu = source.mu;
    const Eigen::ArrayXXd& placed = source.placed;
    if (!(mu.sum() > 0))
        throw InputError("surface.initial: \"transport\": no light from the aperture reaches the receiver plane");

    // The target less the strips' light: ν scaled to all the light, then what is placed taken off.
    const double placed_sum = placed.sum();
    const Eigen::ArrayXXd nu_rest =
        placed_sum > 0 ? Eigen::ArrayXXd((nu * ((mu.sum() + placed_sum) / nu.sum()) - placed).max(0.0)) : nu;
    if (!(nu_rest.sum() > 0)) throw InputError("target: the image is entirely black: there is nothing to send light to");

    TransportMap m;
    m.ot = options.method == TransportMethod::morphing ? solve_morphing(g, mu, nu_rest)
                                                       : solve_grid_ot(g, mu, nu_rest, options.ot);
    m.strips = strips;
    m.report.strip_margin = strips.widest();
    m.report.wall_fraction = options.strips.wall_fraction;
    m.report.strip_light = placed_sum > 0 ? placed_sum / (mu.sum() + placed_sum) : 0;
    m.report.cells_per_pixel = options.cells_per_pixel;
    m.report.grid_x = g.nx;
    m.report.grid_y = g.ny;
    m.report.cell_size = cell;
    m.report.ot_iterations = m.ot.iterations;
    m.report.ot_residual = m.ot.residual;
    m.report.ot_seconds = std::chrono::duration<double>(clock::now() - t0).count();
    m.report.unmapped_fraction = source.total > 0 ? source.lost / source.total : 0;
    m.report.used = true;
    return m;
}

// Whether the power a surface receives at each source point depends on its shape: not
// under collimated light along the normal, where every slope receives the same.
inline bool power_depends_on_shape(const Scene& scene) {
    const transport_detail::Optics optics(scene);
    return !(optics.light == 0 && optics.direction.x == 0 && optics.direction.y == 0);
}

// How much of the light the surface `lit` receives sits elsewhere than the light that the
// flat aperture of `surface` receives, both labelled by their flat landings: half the sum
// of the absolute differences of the two μ (TransportOptions::lit against the plain μ),
// each normalised to one, on a grid of the receiver's pixels, the light that lands off
// the receiver plane one more cell. It is the share of the light a solve weighed by
// `lit` moves, in the units of the error (docs/measures.md: Σ|R − T| / 2N), so it bounds
// what that solve can gain; 0 where power_depends_on_shape is false. The same strata and
// jitter for both (`seed`), `rays_per_cell` rays per grid cell: no sampling noise in the
// difference.
inline double lit_power_change(const Scene& scene, const Heightmap& surface, const Heightmap& lit, std::uint64_t seed,
                               double rays_per_cell = 16) {
    if (!power_depends_on_shape(scene)) return 0;
    const transport_detail::Optics optics(scene);
    TransportOptions options;
    options.cells_per_pixel = 1;
    options.max_grid = std::max(scene.receiver.width, scene.receiver.height);
    const OtGrid g = transport_grid(scene, flat_footprint(scene, surface), options);
    Light light = scene.light;
    light.rays = std::clamp<std::int64_t>(std::int64_t(rays_per_cell * double(g.nx) * double(g.ny)), 4096, 4'000'000);
    std::vector<Vec2d> aims;
    const RaySet flat_rays = generate_rays(light, surface, scene.receiver, seed);
    const RaySet lit_rays = generate_rays(light, lit, scene.receiver, seed, &aims);
    const auto flat = transport_detail::source_density(optics, g, flat_rays, nullptr, WallStrips{}, 0);
    const auto weighed = transport_detail::source_density(optics, g, lit_rays, &aims, WallStrips{}, 0);
    const double a = flat.mu.sum() + flat.lost, b = weighed.mu.sum() + weighed.lost;
    if (!(a > 0 && b > 0)) return 0;
    return 0.5 * ((flat.mu / a - weighed.mu / b).abs().sum() + std::abs(flat.lost / a - weighed.lost / b));
}

namespace transport_detail {

// Each vertex's goal (surface frame): the goal of the plane point below it, and whether
// the map reaches it; returns the fraction of active vertices it does not. The rays are
// aimed at the surface itself (scene/rays.hpp, surface_aim), so the ray that meets a
// vertex at any height is the one aimed above it. Until 2026-12-07 they were aimed at
// the plane w = 0, a raised or lowered vertex was lit by the ray through another plane
// point, and the goals followed that point, with a stretch of each line's (or a round
// face's radial) lit interval over the aperture and a continuation of the map for a raised
// rim's unlit vertices; none of it is needed now.
inline double vertex_goals(const Optics& optics, const TransportMap& map, const Heightmap& hm,
                           const std::vector<std::uint8_t>& active, std::vector<Vec3d>& goal,
                           std::vector<std::uint8_t>& mapped) {
    const int nx = hm.nx(), ny = hm.ny();
    int unmapped = 0, active_count = 0;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const std::size_t p = std::size_t(j * nx + i);
            active_count += active[p];
            const auto g = aim(optics, map.strips, map.ot, Vec3d{hm.u_of(i), hm.v_of(j), 0});
            mapped[p] = g ? 1 : 0;
            if (g) goal[p] = *g;
            else unmapped += active[p];
        }
    extrapolate_border_aims(goal, mapped, nx, ny, optics, map.ot);
    return active_count > 0 ? double(unmapped) / active_count : 0;
}

}  // namespace transport_detail

// The surface of `nx × ny` vertices (placed like `like`) that realises the map.
inline Heightmap surface_from_transport(const Scene& scene, const TransportMap& map, int nx, int ny,
                                        TransportReport& report, const TransportOptions& options = {}) {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    const SurfaceSpec& spec = scene.surface;
    Heightmap hm(nx, ny, spec.size, spec.h_min, spec.h_max, spec.frame, spec.aperture);
    const transport_detail::Optics optics(scene);
    const int n = nx * ny;
    // Where each vertex must send its light (surface frame), from its flat landing point.
    std::vector<Vec3d> goal(static_cast<std::size_t>(n));
    std::vector<std::uint8_t> mapped(std::size_t(n), 0);
    const std::vector<std::uint8_t> active = transport_detail::active_vertices(hm);
    report.unmapped_fraction = transport_detail::vertex_goals(optics, map, hm, active, goal, mapped);

    // Heights whose edge difference quotients best match the mean slope of each edge's
    // ends, in least squares: the normal equations are a Neumann Poisson problem on the
    // vertex grid (every edge weighs the same, so one fast solver serves every aperture:
    // vertices outside an elliptical aperture follow the map's extension and keep the
    // field smooth; they do not meet light).
    const double du = hm.du(), dv = hm.dv();
    const NeumannPoisson poisson(nx, ny, du, dv, options.ot.threads);
    Eigen::ArrayXXd h = Eigen::ArrayXXd::Zero(ny, nx);
    Eigen::ArrayXXd su = Eigen::ArrayXXd::Zero(ny, nx), sv = Eigen::ArrayXXd::Zero(ny, nx);
    const double bound_mid = 0.5 * (double(spec.h_min) + double(spec.h_max));
    const double bound_range = double(spec.h_max) - double(spec.h_min);
    for (int round = 0; round < std::max(1, options.fit_iterations); ++round) {
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const std::size_t p = std::size_t(j * nx + i);
                if (!mapped[p]) {
                    su(j, i) = sv(j, i) = 0;
                    continue;
                }
                const Vec3d s{hm.u_of(i), hm.v_of(j), h(j, i)};
                const Vec3d nn = optics.normal_towards(s, optics.incoming(s), goal[p]);
                const double nz = std::max(nn.z, 1e-3);
                su(j, i) = -nn.x / nz;
                sv(j, i) = -nn.y / nz;
            }
        Eigen::ArrayXXd sol = poisson.solve(transport_detail::edge_slope_divergence(su, sv, du, dv));
        if (!sol.allFinite()) sol.setZero();
        // Into the bounds: centre the active range in them.
        double lo = 1e300, hi = -1e300;
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i)
                if (active[std::size_t(j * nx + i)]) lo = std::min(lo, sol(j, i)), hi = std::max(hi, sol(j, i));
        if (!(hi >= lo)) lo = hi = 0;
        sol += bound_mid - 0.5 * (lo + hi);
        const double change = (sol - h).abs().maxCoeff();
        h = sol;
        report.height_range = hi - lo;
        report.height_excess = std::max(0.0, (hi - lo) - bound_range);
        report.fit_iterations = round + 1;
        // The surface points moved too little to change the normals: done.
        if (round > 0 && change < 1e-4 * std::max(hi - lo, 1e-9)) break;
    }
    std::vector<float> heights(static_cast<std::size_t>(n));
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) heights[std::size_t(j * nx + i)] = float(h(j, i));
    hm.set_heights(heights);  // clamps to the bounds, computes the normals
    report.fit_seconds = std::chrono::duration<double>(clock::now() - t0).count();
    return hm;
}

// The wall strips a lens needs (WallStrips), measured on `plain`, a surface fitted to the
// plain map `map` (solved without strips) on the mesh the design uses: for each wall, in
// each line of vertices along it, the strip whose rays leave the glass beyond the wall
// (exit point past it, interpolated between the last vertex that does and the first that
// does not). The margin is the widest such strip, rounded up to whole mesh cells. A
// mirror, or a lens whose light stays inside its walls, needs none.
inline WallStrips measure_wall_strips(const Scene& scene, const TransportMap& map, const Heightmap& plain) {
    WallStrips strips;
    const transport_detail::Optics optics(scene);
    if (!optics.lens) return strips;
    // The body's walls stand lens_rim beyond the face's edges.
    const double rim = lens_rim(scene);
    const double hu = 0.5 * scene.surface.size.x + rim, hv = 0.5 * scene.surface.size.y + rim;
    strips.half_u = hu, strips.half_v = hv;
    const int nx = plain.nx(), ny = plain.ny();
    // Each active vertex's exit point (NaN: inactive or unmapped).
    const double nan = std::numeric_limits<double>::quiet_NaN();
    std::vector<Vec3d> exit(std::size_t(nx * ny), Vec3d{nan, nan, nan});
    const std::vector<std::uint8_t> active = transport_detail::active_vertices(plain);
    int counted = 0, beyond = 0;
    for (int j = 0; j < ny; ++j)
        for (int i = 0; i < nx; ++i) {
            const std::size_t p = std::size_t(j * nx + i);
            const auto goal = active[p] ? transport_detail::aim(optics, map.strips, map.ot, Vec3d{plain.u_of(i), plain.v_of(j), 0})
                                        : std::nullopt;
            if (!goal) continue;
            Vec3d g;
            optics.glass_path(Vec3d{plain.u_of(i), plain.v_of(j), double(plain.heights()[p])}, *goal, g, exit[p]);
            ++counted;
            beyond += std::abs(exit[p].x) > hu || std::abs(exit[p].y) > hv;
        }
    strips.wall_fraction = counted > 0 ? double(beyond) / counted : 0;
    // One wall: `at(line, k)` is the k-th vertex of a line walked from the wall inwards,
    // `x(k)` its distance from the wall, `over(e)` how far an exit point lies beyond it.
    const auto measure = [&](int wall, int lines, int depth, auto at, auto x, auto over) {
        double margin = 0;
        int crossing = 0;  // lines with a vertex whose light meets the wall
        for (int l = 0; l < lines; ++l) {
            double prev_over = 0, prev_x = 0;
            bool seen = false;
            for (int k = 0; k < depth; ++k) {
                const Vec3d e = exit[at(l, k)];
                if (std::isnan(e.x)) {
                    if (seen) break;
                    continue;
                }
                const double o = over(e), xk = x(k);
                if (o <= 0) {
                    if (seen) margin = std::max(margin, prev_x + (xk - prev_x) * prev_over / (prev_over - o)), ++crossing;
                    break;
                }
                seen = true, prev_over = o, prev_x = xk;
            }
        }
        // Whole mesh cells, so that the strip's inner edge is a vertex: the interior's
        // cells aim at the interior's map, the strip's at the walls.
        // A wall that a few lines' corner vertices graze (under 2 % of the lines) keeps its
        // plain map: their light is a speck, and a strip along the whole wall would stretch
        // its few cells' light into lines across the receiver (a receiver the lens's size).
        const double cell = wall < 2 ? plain.du() : plain.dv();
        if (margin > 0 && 50 * crossing >= lines) strips.margin[std::size_t(wall)] = cell * std::ceil(margin / cell - 1e-6);
    };
    const auto idx = [nx](int i, int j) { return std::size_t(j * nx + i); };
    measure(1, ny, nx, [&](int l, int k) { return idx(nx - 1 - k, l); }, [&](int k) { return hu - plain.u_of(nx - 1 - k); },
            [&](Vec3d e) { return e.x - hu; });
    measure(0, ny, nx, [&](int l, int k) { return idx(k, l); }, [&](int k) { return plain.u_of(k) + hu; },
            [&](Vec3d e) { return -hu - e.x; });
    measure(3, nx, ny, [&](int l, int k) { return idx(l, ny - 1 - k); }, [&](int k) { return hv - plain.v_of(ny - 1 - k); },
            [&](Vec3d e) { return e.y - hv; });
    measure(2, nx, ny, [&](int l, int k) { return idx(l, k); }, [&](int k) { return plain.v_of(k) + hv; },
            [&](Vec3d e) { return -hv - e.y; });
    if (strips.any()) {
        strips.placement = std::make_shared<const OtResult>(map.ot);
        strips.placement_surface = std::make_shared<const Heightmap>(plain);
    }
    return strips;
}

}  // namespace freeform
