#pragma once
// Gaussian kernel moves: the neighbour step of the annealer.
//
// Moving one vertex at a time makes spikes and changes the light too little to judge
// (reference §3.3, §4.2). A move instead adds amplitude · K to the heights around a
// vertex, where K is a discrete, peak-normalised Gaussian of covariance
//     Σ = [[σx², ρ σx σy], [ρ σx σy, σy²]]
// sampled on support × support vertices (reference §4.3.1). Σ and the support are
// independent: the support bounds the footprint (and so the work of a move), Σ sets its
// shape inside it. Both are in grid units (vertex spacings), so a bank of shapes means
// the same thing on every level of the multi-level schedule.
//
// Beyond the reference, the Gaussian is multiplied by a smooth window that falls to zero
// just outside the support (KernelEdge::taper, the default). A Gaussian cut off by the
// square support leaves a step at the footprint border (13 % of the amplitude for
// σ = support/4): every move would then draw a small crease into the surface, which is
// what kernels are meant to avoid. KernelEdge::truncate reproduces the reference's plain
// truncated Gaussian for comparisons.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <sstream>
#include <string>
#include <vector>

#include "../core/error.hpp"
#include "../core/hd.hpp"
#include "../core/math.hpp"
#include "../surface/heightmap.hpp"
#include "../surface/overlay.hpp"

namespace freeform {

// The shape of a kernel in grid units. `support` is odd: the kernel covers
// support × support vertices centred on the moved vertex.
struct KernelShape {
    double sigma_x = 2.0;
    double sigma_y = 2.0;
    double rho = 0.0;  // correlation, |rho| < 1; rho > 0 stretches along the i = j diagonal
    int support = 9;
};

// Largest accepted support: a 2001² kernel already weighs 16 MB, and nothing larger is
// a sensible move on any mesh we can trace.
inline constexpr int max_kernel_support = 2001;

// Throws InputError naming the first bad field.
inline void validate(const KernelShape& s) {
    const auto bad = [](const char* field, const std::string& rule, double value) {
        std::ostringstream m;
        m << "kernel." << field << " must be " << rule << ", got " << value;
        throw InputError(m.str());
    };
    if (!(s.sigma_x > 0) || !std::isfinite(s.sigma_x)) bad("sigma_x", "positive and finite", s.sigma_x);
    if (!(s.sigma_y > 0) || !std::isfinite(s.sigma_y)) bad("sigma_y", "positive and finite", s.sigma_y);
    if (!(std::abs(s.rho) < 1)) bad("rho", "in (-1, 1)", s.rho);
    if (s.support < 1 || s.support > max_kernel_support || s.support % 2 == 0)
        bad("support", "an odd integer in [1, " + std::to_string(max_kernel_support) + "]", s.support);
}

inline std::string to_string(const KernelShape& s) {
    std::ostringstream m;
    m << "sigma=(" << s.sigma_x << ", " << s.sigma_y << ") rho=" << s.rho << " support=" << s.support;
    return m.str();
}

enum class KernelEdge {
    taper,     // Gaussian × a cos² window that reaches 0 one vertex outside the support
    truncate,  // the plain Gaussian, cut at the support (the reference's kernel)
};

// Plain-data view of a kernel's weights for FREEFORM_HD code.
struct KernelView {
    const float* w = nullptr;  // (2r+1)² weights, row-major, index (dj + r)(2r+1) + (di + r)
    int r = 0;

    FREEFORM_HD float at(int di, int dj) const { return w[(dj + r) * (2 * r + 1) + (di + r)]; }
};

// The height a vertex gets when a kernel of weight `w` and amplitude `a` passes over it,
// before clamping. Written once so that every back end rounds alike: one float product,
// one float sum, never fused into an FMA (nvcc fuses by default; the explicit rounding
// intrinsics forbid it on the device, and x86-64 hosts without -mfma have no FMA).
FREEFORM_HD inline float kernel_height(float h, float a, float w) {
#if defined(__CUDA_ARCH__)
    return __fadd_rn(h, __fmul_rn(a, w));
#else
    return h + a * w;
#endif
}

class Kernel {
public:
    // Weights below this fraction of the peak are set to exactly 0 (they move a vertex by
    // less than a float ulp of typical heights, and zero rows shrink the footprint).
    static constexpr double cutoff = 1e-4;

    Kernel() : Kernel(KernelShape{}) {}

    explicit Kernel(const KernelShape& shape, KernelEdge edge = KernelEdge::taper) : shape_(shape), edge_(edge) {
        validate(shape);
        r_ = (shape.support - 1) / 2;
        const int s = shape.support;
        weights_.assign(std::size_t(s) * s, 0.0f);
        // Inverse covariance, written out: q = xᵀ Σ⁻¹ x.
        const double sx = shape.sigma_x, sy = shape.sigma_y, rho = shape.rho;
        const double k = 1.0 / (1.0 - rho * rho);
        const double a = k / (sx * sx), b = -k * rho / (sx * sy), c = k / (sy * sy);
        const auto window = [&](int d) {
            if (edge_ == KernelEdge::truncate) return 1.0;
            const double t = std::cos(pi * d / (2.0 * (r_ + 1)));
            return t * t;
        };
        ri_ = rj_ = 0;
        for (int dj = -r_; dj <= r_; ++dj)
            for (int di = -r_; di <= r_; ++di) {
                const double q = a * di * di + 2 * b * di * dj + c * dj * dj;
                double w = std::exp(-0.5 * q) * window(di) * window(dj);
                if (w < cutoff) w = 0;
                weights_[std::size_t(dj + r_) * s + (di + r_)] = float(w);
                if (w > 0) {
                    ri_ = std::max(ri_, std::abs(di));
                    rj_ = std::max(rj_, std::abs(dj));
                }
            }
        // exp(0) · cos²(0) is exactly 1; stated so the peak-normalisation is explicit.
        weights_[std::size_t(r_) * s + r_] = 1.0f;
    }

    const KernelShape& shape() const { return shape_; }
    KernelEdge edge() const { return edge_; }
    int support() const { return shape_.support; }
    int radius() const { return r_; }
    // Row-major support × support weights, peak 1 at the centre.
    const std::vector<float>& weights() const { return weights_; }
    float at(int di, int dj) const { return weights_[std::size_t(dj + r_) * shape_.support + (di + r_)]; }
    KernelView view() const { return {weights_.data(), r_}; }

    // Half-extents of the non-zero weights along i and j (<= radius()).
    int extent_i() const { return ri_; }
    int extent_j() const { return rj_; }
    // The vertices a move centred at (ci, cj) can change, not clipped to the grid.
    Patch footprint(int ci, int cj) const { return {ci - ri_, cj - rj_, ci + ri_, cj + rj_}; }

private:
    KernelShape shape_;
    KernelEdge edge_ = KernelEdge::taper;
    int r_ = 0, ri_ = 0, rj_ = 0;
    std::vector<float> weights_;
};

// A bank of shapes for one support size (odd, >= 3). With r = (support - 1) / 2:
//   0 isotropic     σ = support/4        the workhorse: a round bump (the reference's default)
//   1 narrow        σ = support/8        sharp local detail (edges of a pattern) at the same reach
//   2 wide          σ = support/2        a near-flat-topped bump: shifts or tilts a whole region
//   3 long along i  σ = (support/3, support/6)   stripes and edges running along u ...
//   4 long along j  σ = (support/6, support/3)   ... and along v (reference fig. 4.10)
//   5 diagonal +    σ = support/4, ρ = +0.6      features along the u = v diagonal
//   6 diagonal −    σ = support/4, ρ = −0.6      ... and along u = −v
// The anisotropic ones all have a 2 : 1 ratio of principal standard deviations
// (for ρ = ±0.6 the principal variances are σ²(1 ± ρ)), so no direction is favoured.
// Which of them pays off depends on the target; a Bandit learns that at run time.
inline std::vector<KernelShape> default_kernel_bank(int support) {
    if (support < 3 || support > max_kernel_support || support % 2 == 0)
        throw InputError("kernel.support must be an odd integer in [3, " + std::to_string(max_kernel_support) +
                         "] for a kernel bank, got " + std::to_string(support));
    const double s = support;
    return {
        {s / 4, s / 4, 0.0, support},  {s / 8, s / 8, 0.0, support},  {s / 2, s / 2, 0.0, support},
        {s / 3, s / 6, 0.0, support},  {s / 6, s / 3, 0.0, support},  {s / 4, s / 4, 0.6, support},
        {s / 4, s / 4, -0.6, support},
    };
}

// The kernel supports of the multi-level schedule for a mesh of n vertices per side
// (reference §4.4: coarse shape with big kernels first, then detail with smaller ones).
//   - the first level is the odd number nearest n/5, at least 5 once n >= 9: a kernel a
//     fifth of the surface wide shapes the coarse light distribution;
//   - each next level is about 0.6 of the previous (odd, rounded to nearest), so each
//     level works at roughly the scale the previous one could not resolve;
//   - levels stop at max(3, n/15): smaller kernels are close to single-vertex moves,
//     and finer detail is the job of the next, finer mesh level.
// Examples: 101 → {21, 13, 7}; 51 → {11, 7, 5}; 25 → {5, 3}; 13 → {5, 3}; n < 9 → {3}.
inline std::vector<int> kernel_support_levels(int mesh_vertices_per_side) {
    const int n = mesh_vertices_per_side;
    if (n < 2) throw InputError("mesh size must be at least 2 vertices per side, got " + std::to_string(n));
    const auto odd_nearest = [](double x) {
        const int lo = 2 * int(std::floor((x - 1) / 2)) + 1;  // largest odd <= x
        return x - lo <= (lo + 2) - x ? lo : lo + 2;
    };
    int s = std::max(odd_nearest(n / 5.0), n >= 9 ? 5 : 3);
    s = std::min(s, max_kernel_support);
    const double smallest = std::max(3.0, n / 15.0);
    std::vector<int> levels{s};
    for (;;) {
        const int next = odd_nearest(0.6 * levels.back());
        if (next >= levels.back() || next < smallest) break;
        levels.push_back(next);
    }
    return levels;
}

// Fills `out` with the surface as it would be after adding amplitude · K centred at
// vertex (ci, cj), which must lie on the grid: heights over the kernel's footprint
// clipped to the grid, clamped to the height bounds (and to `limits` where given: an
// incremental trace's reach envelope), and the normals that change.
// `out`'s buffers are reused, so a warmed-up overlay does not allocate.
inline void apply_kernel(const Heightmap& base, const Kernel& k, int ci, int cj, float amplitude,
                         HeightOverlay& out, VertexBounds limits = {}) {
    FREEFORM_KERNEL_ASSERT(ci >= 0 && ci < base.nx() && cj >= 0 && cj < base.ny());
    out.patch = k.footprint(ci, cj).clipped(base.nx(), base.ny());
    out.heights.resize(std::size_t(out.patch.count()));
    std::size_t n = 0;
    for (int j = out.patch.j0; j <= out.patch.j1; ++j)
        for (int i = out.patch.i0; i <= out.patch.i1; ++i) {
            const float h = base.clamp_height(kernel_height(base(i, j), amplitude, k.at(i - ci, j - cj)));
            out.heights[n++] = limits.clamp(std::size_t(j) * std::size_t(base.nx()) + std::size_t(i), h);
        }
    out.finish(base);
}

// Largest |new - old| height over the overlay's patch (0 for an empty overlay).
inline float max_abs_change(const HeightOverlay& o, const Heightmap& base) {
    float m = 0;
    std::size_t n = 0;
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i) m = std::max(m, std::abs(o.heights[n++] - base(i, j)));
    return m;
}

}  // namespace freeform
