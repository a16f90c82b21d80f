#pragma once
// Where a fitted transport start lands its light, against where its map sends it, and the
// target that corrects for it (docs/architecture.md §4b, step 4).
//
// The least-squares fit (surface_from_transport) keeps the part of the map's slopes that
// a height field can have. Where the map asks for slopes no surface has, the fitted
// surface lands each vertex's light some way from its goal. With light along the normal
// and the receiver parallel to the surface that part is small (the letter E's vertices
// land 0.06 mm from their goals on 1 mm pixels); where the lever arm from surface to
// receiver changes across the surface (oblique light, a tilted receiver) it is not: lit at
// 70°, the letter E's vertices land 2.7 px from their goals on average, everything inside
// the E moved 3.5 px towards its top. The offset field is smooth and changes little when
// the map changes a little, so solving the map once more for the target moved against
// it lands the light where the target wants it: the target at t becomes
// ν(t + Δ(t)) · det(I + ∇Δ(t)), the density whose image under t ↦ t + Δ(t) is ν.
#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include "../core/histogram.hpp"
#include "start.hpp"

namespace freeform {

// Each receiver pixel's mean offset of landing from goal (receiver-local metres, row 0 =
// the top, as images), filled and smoothed, and the mean offset's length over the active
// vertices in pixels.
struct LandingOffsets {
    ImageD du, dv;
    double mean_pixels = 0;
};

// The Gaussian (σ, receiver pixels) that smooths the offsets: the offsets that matter
// are the fit's smooth distortion, and per-pixel noise in Δ would become noise in the
// det(I + ∇Δ) of the moved target (on the point-light example, whose vertices land 0.07 px
// from their goals, σ = 1 px made the start worse by 0.0045, σ = 3 by 0.003). Below a
// mean offset of `landing_offset_threshold` pixels the target is left alone: the side lamp
// (0.5 px) gained 0.002 from the moved target and the point-light example (0.07 px) lost.
inline constexpr double landing_offset_smoothing = 3.0, landing_offset_threshold = 0.25;

namespace transport_detail {

// Where light arriving along d at surface point s with unit normal n lands on the
// receiver plane (receiver-local metres): reflected, or refracted into the lens and out
// of its flat back face. Nothing where it never meets the receiver's front (or is
// totally reflected inside the glass).
inline std::optional<Vec2d> surface_landing(const Optics& o, Vec3d s, Vec3d d, Vec3d n) {
    Vec3d p = s, out;
    if (!o.lens) {
        out = d - 2 * dot(d, n) * n;
    } else {
        const auto refract = [](Vec3d in, Vec3d nn, double eta) -> std::optional<Vec3d> {
            const double ci = -dot(in, nn), k = 1 - eta * eta * (1 - ci * ci);
            if (k < 0) return std::nullopt;
            return eta * in + (eta * ci - std::sqrt(k)) * nn;
        };
        const auto g = refract(d, n, 1 / o.ior);
        if (!g || !(g->z < 0)) return std::nullopt;
        p = s + *g * ((s.z + o.thickness) / -g->z);
        const auto e = refract(*g, Vec3d{0, 0, 1}, o.ior);
        if (!e) return std::nullopt;
        out = *e;
    }
    const double dn = dot(out, o.rn);
    if (!(dn < 0)) return std::nullopt;
    const double t = dot(o.rc - p, o.rn) / dn;
    if (!(t > 0)) return std::nullopt;
    const Vec3d q = p + t * out - o.rc;
    return Vec2d{dot(q, o.ru), dot(q, o.rv)};
}

// A normalised Gaussian blur of σ pixels, the image taken as zero outside.
inline ImageD gaussian_blur(const ImageD& a, double sigma) {
    const int r = int(std::ceil(3 * sigma));
    std::vector<double> k(std::size_t(2 * r + 1));
    double sum = 0;
    for (int i = -r; i <= r; ++i) sum += k[std::size_t(i + r)] = std::exp(-0.5 * i * i / (sigma * sigma));
    for (double& x : k) x /= sum;
    const Eigen::Index h = a.rows(), w = a.cols();
    ImageD t = ImageD::Zero(h, w), out = ImageD::Zero(h, w);
    for (Eigen::Index y = 0; y < h; ++y)
        for (Eigen::Index x = 0; x < w; ++x)
            for (int i = std::max<int>(-r, int(-x)); i <= std::min<int>(r, int(w - 1 - x)); ++i)
                t(y, x) += k[std::size_t(i + r)] * a(y, x + i);
    for (Eigen::Index y = 0; y < h; ++y)
        for (int i = std::max<int>(-r, int(-y)); i <= std::min<int>(r, int(h - 1 - y)); ++i)
            out.row(y) += k[std::size_t(i + r)] * t.row(y + i);
    return out;
}

// f at (x, y) in pixel units of f (pixel centres at half-integers), bilinear, clamped
// to the centres.
inline double bilinear(const ImageD& f, double x, double y) {
    const Eigen::Index w = f.cols(), h = f.rows();
    const double fx = std::clamp(x - 0.5, 0.0, double(w - 1)), fy = std::clamp(y - 0.5, 0.0, double(h - 1));
    const Eigen::Index i = std::min<Eigen::Index>(Eigen::Index(fx), std::max<Eigen::Index>(0, w - 2));
    const Eigen::Index j = std::min<Eigen::Index>(Eigen::Index(fy), std::max<Eigen::Index>(0, h - 2));
    const Eigen::Index i1 = std::min(i + 1, w - 1), j1 = std::min(j + 1, h - 1);
    const double a = fx - double(i), b = fy - double(j);
    return (1 - b) * ((1 - a) * f(j, i) + a * f(j, i1)) + b * ((1 - a) * f(j1, i) + a * f(j1, i1));
}

}  // namespace transport_detail

// The offsets of `surface` (fitted to `map`): each active vertex's light, arriving along
// the light's direction at the vertex and leaving by its vertex normal, against the
// map's goal for it (vertex_goals), binned by goal pixel, averaged, smoothed by
// landing_offset_smoothing and carried into pixels without goals by wider Gaussians
// (4σ, 16σ, then the mean of all).
inline LandingOffsets landing_offsets(const Scene& scene, const TransportMap& map, const Heightmap& surface) {
    const transport_detail::Optics optics(scene);
    const int w = scene.receiver.width, h = scene.receiver.height;
    const double px_u = 2 * optics.half_u / w, px_v = 2 * optics.half_v / h;
    ImageD su = ImageD::Zero(h, w), sv = su, count = su;
    const std::vector<std::uint8_t> active = transport_detail::active_vertices(surface);
    double length = 0;
    std::int64_t landed = 0;
    for (int j = 0; j < surface.ny(); ++j)
        for (int i = 0; i < surface.nx(); ++i) {
            const std::size_t p = std::size_t(j) * std::size_t(surface.nx()) + std::size_t(i);
            if (!active[p]) continue;
            const auto goal = transport_detail::aim(optics, map.strips, map.ot, Vec3d{surface.u_of(i), surface.v_of(j), 0});
            if (!goal) continue;
            const Vec3d s{surface.u_of(i), surface.v_of(j), double(surface(i, j))};
            const auto land = transport_detail::surface_landing(optics, s, optics.incoming(s), Vec3d(surface.normals()[p]));
            if (!land) continue;
            const Vec3d g = *goal - optics.rc;
            const double gu = dot(g, optics.ru), gv = dot(g, optics.rv);
            const int x = int(std::floor((gu + optics.half_u) / px_u)), y = int(std::floor((optics.half_v - gv) / px_v));
            if (x < 0 || x >= w || y < 0 || y >= h) continue;
            su(y, x) += land->x - gu, sv(y, x) += land->y - gv, count(y, x) += 1;
            length += std::hypot((land->x - gu) / px_u, (land->y - gv) / px_v), ++landed;
        }
    LandingOffsets out{ImageD::Zero(h, w), ImageD::Zero(h, w), landed > 0 ? length / double(landed) : 0};
    if (landed == 0) return out;
    const double mean_u = su.sum() / count.sum(), mean_v = sv.sum() / count.sum();
    Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic> filled = Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic>::Zero(h, w);
    for (const double scale : {1.0, 4.0, 16.0}) {
        const double sigma = scale * landing_offset_smoothing;
        const ImageD c = transport_detail::gaussian_blur(count, sigma);
        const ImageD bu = transport_detail::gaussian_blur(su, sigma), bv = transport_detail::gaussian_blur(sv, sigma);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                if (!filled(y, x) && c(y, x) >= 0.05) out.du(y, x) = bu(y, x) / c(y, x), out.dv(y, x) = bv(y, x) / c(y, x), filled(y, x) = true;
    }
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            if (!filled(y, x)) out.du(y, x) = mean_u, out.dv(y, x) = mean_v;
    return out;
}

// `target` (any resolution, spanning the receiver) moved against the offsets: the value
// at receiver point t is ν(t + Δ(t)) · det(I + ∇Δ(t)) (the determinant clamped to
// [1/20, 20]), so that light sent to t and landing at t + Δ(t) lands as ν asks.
inline ImageD offset_target(const ImageD& target, const LandingOffsets& offsets, const Receiver& receiver) {
    const int w = receiver.width, h = receiver.height;
    const double px_u = receiver.size.x / w, px_v = receiver.size.y / h;
    const Eigen::Index tw = target.cols(), th = target.rows();
    // Δ in receiver pixels (x right, y down) at (x, y) in receiver pixels.
    const auto delta = [&](double x, double y) {
        return Vec2d{transport_detail::bilinear(offsets.du, x, y) / px_u, -transport_detail::bilinear(offsets.dv, x, y) / px_v};
    };
    ImageD out(th, tw);
    for (Eigen::Index py = 0; py < th; ++py)
        for (Eigen::Index px = 0; px < tw; ++px) {
            const double x = (double(px) + 0.5) * w / double(tw), y = (double(py) + 0.5) * h / double(th);
            const Vec2d d = delta(x, y);
            const Vec2d xp = delta(x + 1, y), xm = delta(x - 1, y), yp = delta(x, y + 1), ym = delta(x, y - 1);
            const double a = 1 + 0.5 * (xp.x - xm.x), b = 0.5 * (yp.x - ym.x), c = 0.5 * (xp.y - xm.y), e = 1 + 0.5 * (yp.y - ym.y);
            const double det = std::clamp(a * e - b * c, 0.05, 20.0);
            out(py, px) = det * transport_detail::bilinear(target, (x + d.x) * double(tw) / w, (y + d.y) * double(th) / h);
        }
    return out;
}

}  // namespace freeform
