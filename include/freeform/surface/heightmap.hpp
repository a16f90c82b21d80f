#pragma once
// The designed surface: a height field over a placed rectangle.
//
// Vertex (i, j) of an nx × ny grid sits at u = (i/(nx-1) - 1/2)·size.x,
// v = (j/(ny-1) - 1/2)·size.y of the surface frame, raised by h(i, j) along its normal.
// Heights are stored row-major (index j·nx + i) as float32, the precision of the PFM
// files they are exchanged in, and are always inside [h_min, h_max]. Cell (i, j) spans
// vertices i..i+1 × j..j+1 and is split into two triangles along the fixed diagonal
// (i, j)–(i+1, j+1). Vertex normals come from central differences with the physical
// grid spacing (second-order one-sided at the border), in the surface frame.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "../core/enum_names.hpp"
#include "../core/error.hpp"
#include "../core/math.hpp"
#include "../core/view.hpp"
#include "../core/frame.hpp"

namespace freeform {

enum class Aperture { rect, ellipse };
inline constexpr std::array<EnumName<Aperture>, 2> aperture_names{
    {{"rect", Aperture::rect}, {"ellipse", Aperture::ellipse}}};

// An inclusive rectangle of vertex indices.
struct Patch {
    int i0 = 0, j0 = 0, i1 = -1, j1 = -1;
    bool empty() const { return i1 < i0 || j1 < j0; }
    int width() const { return i1 - i0 + 1; }
    int height() const { return j1 - j0 + 1; }
    std::int64_t count() const { return empty() ? 0 : std::int64_t(width()) * height(); }
    Patch dilated(int r) const { return {i0 - r, j0 - r, i1 + r, j1 + r}; }
    Patch clipped(int nx, int ny) const {
        return {std::max(i0, 0), std::max(j0, 0), std::min(i1, nx - 1), std::min(j1, ny - 1)};
    }
};

// Heights saved from a patch, restored bit for bit.
struct HeightSnapshot {
    Patch patch;
    std::vector<float> heights;
};

// The height range of each tile of cells, for the walk's block skip (skip_tile in
// trace/heightfield_kernel.hpp; made by TileRanges, trace/heightfield.hpp): tile (ti, tj)
// holds the cells ci >> tile_shift == ti, cj >> tile_shift == tj, and lo/hi[tj * tiles_x +
// ti] bound the heights of their vertices. lo null: no tiles.
struct TileView {
    const float* lo = nullptr;
    const float* hi = nullptr;
    int tiles_x = 0;
};

// Everything a tracing kernel needs to know about a height field, as plain data.
struct HeightfieldView {
    const float* h = nullptr;          // nx*ny heights
    const Vec3* n = nullptr;           // nx*ny unit vertex normals (surface frame)
    const std::uint8_t* cell_on = nullptr;  // (nx-1)*(ny-1) aperture mask, nullptr: all on
    int nx = 0, ny = 0;
    float u0 = 0, v0 = 0;  // position of vertex (0, 0)
    float du = 0, dv = 0;  // grid spacing
    float h_min = 0, h_max = 0;
    TileView tiles{};  // a plain trace's tile ranges (HeightfieldTracer); none by default

    FREEFORM_HD float height(int i, int j) const { return h[j * nx + i]; }
    FREEFORM_HD Vec3 normal(int i, int j) const { return n[j * nx + i]; }
    FREEFORM_HD Vec3 vertex(int i, int j) const { return {u0 + i * du, v0 + j * dv, height(i, j)}; }
    FREEFORM_HD bool cell_active(int ci, int cj) const {
        return cell_on == nullptr || cell_on[cj * (nx - 1) + ci] != 0;
    }
};

// d/dt at point k of a line of values x(0..n-1) spaced h: the central difference, and at
// the ends the second-order one-sided difference (-3 x0 + 4 x1 - x2) / 2h, the derivative
// at the end point itself (the two-point difference x1 - x0 is the one half a step
// inwards); a line of two points has its one chord. The rule of the vertex normals, and of
// every derivative taken from them (io/sag.hpp's twist).
template <class At>
double line_derivative(const At& x, int k, int n, double h) {
    if (n < 3) return (x(1) - x(0)) / h;
    if (k == 0) return (-3 * x(0) + 4 * x(1) - x(2)) / (2 * h);
    if (k == n - 1) return (3 * x(n - 1) - 4 * x(n - 2) + x(n - 3)) / (2 * h);
    return (x(k + 1) - x(k - 1)) / (2 * h);
}

class Heightmap {
public:
    Heightmap() = default;

    // A flat surface at height clamp(0) with the given placement.
    Heightmap(int nx, int ny, Vec2d size, double h_min, double h_max, Frame frame = {},
              Aperture aperture = Aperture::rect)
        : frame_(frame), size_(size), nx_(nx), ny_(ny), h_min_(float(h_min)), h_max_(float(h_max)),
          aperture_(aperture) {
        if (nx < 2 || ny < 2)
            throw InputError("surface.mesh must be at least 2 x 2 vertices, got " + std::to_string(nx) +
                             " x " + std::to_string(ny));
        if (!(size.x > 0) || !(size.y > 0) || !std::isfinite(size.x) || !std::isfinite(size.y))
            throw InputError("surface.size must be two positive finite numbers");
        if (!(h_min <= h_max) || !std::isfinite(h_min) || !std::isfinite(h_max))
            throw InputError("surface.height_bounds must be finite with min <= max");
        heights_.assign(std::size_t(nx) * ny, std::clamp(0.0f, h_min_, h_max_));
        normals_.assign(std::size_t(nx) * ny, Vec3{0, 0, 1});
        build_mask();
    }

    int nx() const { return nx_; }
    int ny() const { return ny_; }
    Vec2d size() const { return size_; }
    const Frame& frame() const { return frame_; }
    float h_min() const { return h_min_; }
    float h_max() const { return h_max_; }
    Aperture aperture() const { return aperture_; }
    double du() const { return size_.x / (nx_ - 1); }
    double dv() const { return size_.y / (ny_ - 1); }
    double u_of(int i) const { return (double(i) / (nx_ - 1) - 0.5) * size_.x; }
    double v_of(int j) const { return (double(j) / (ny_ - 1) - 0.5) * size_.y; }

    float operator()(int i, int j) const { return heights_[std::size_t(j) * nx_ + i]; }
    const std::vector<float>& heights() const { return heights_; }
    const std::vector<Vec3>& normals() const { return normals_; }
    const std::vector<std::uint8_t>& cell_mask() const { return cell_on_; }
    bool cell_active(int ci, int cj) const { return cell_on_[std::size_t(cj) * (nx_ - 1) + ci] != 0; }

    // Sets all heights (clamped to the bounds) and recomputes every normal.
    void set_heights(const std::vector<float>& h) {
        if (h.size() != heights_.size())
            throw InputError("heightmap has " + std::to_string(h.size()) + " values, expected " +
                             std::to_string(heights_.size()));
        for (std::size_t k = 0; k < h.size(); ++k) heights_[k] = clamp_height(h[k]);
        update_normals(full_patch());
    }
    // Sets one height (clamped); normals are not updated: call update_normals.
    void set(int i, int j, float h) { heights_[std::size_t(j) * nx_ + i] = clamp_height(h); }
    float clamp_height(float h) const { return std::clamp(h, h_min_, h_max_); }

    Patch full_patch() const { return {0, 0, nx_ - 1, ny_ - 1}; }

    // Vertices whose normals depend on heights in `p`: the central-difference stencil, and
    // at the border the one-sided stencil, which reaches two vertices inwards.
    Patch normal_support(const Patch& p) const {
        Patch s = p.dilated(1).clipped(nx_, ny_);
        if (p.i0 <= 2) s.i0 = 0;
        if (p.i1 >= nx_ - 3) s.i1 = nx_ - 1;
        if (p.j0 <= 2) s.j0 = 0;
        if (p.j1 >= ny_ - 3) s.j1 = ny_ - 1;
        return s;
    }

    // Recomputes the normals of the vertices in `p` (already including the stencil).
    void update_normals(const Patch& p) {
        const Patch q = p.clipped(nx_, ny_);
        const auto h = [this](int i, int j) { return (*this)(i, j); };
        for (int j = q.j0; j <= q.j1; ++j)
            for (int i = q.i0; i <= q.i1; ++i) normals_[std::size_t(j) * nx_ + i] = vertex_normal(h, i, j);
    }

    // The normal at vertex (i, j) of a height field read through `h(i, j)`: central
    // differences with the physical spacing; at the border the second-order one-sided
    // difference (-3 h0 + 4 h1 - h2) / 2d, the slope at the border vertex itself. (The
    // two-point difference h1 - h0 is the slope half a cell inwards; with it the Phong
    // patch of a border cell bends its light through half the range its heights ask for,
    // and no choice of heights can restore it: a converging lens lost a third of its
    // outermost receiver row that way, docs/architecture.md §1.) Shared by the height map
    // and by overlays that preview a move, so both agree to the last bit.
    template <class Heights>
    Vec3 vertex_normal(const Heights& h, int i, int j) const {
        const double dhdu = line_derivative([&](int k) { return double(h(k, j)); }, i, nx_, du());
        const double dhdv = line_derivative([&](int k) { return double(h(i, k)); }, j, ny_, dv());
        return static_cast<Vec3>(normalize(Vec3d{-dhdu, -dhdv, 1.0}));
    }

    HeightSnapshot snapshot(const Patch& p) const {
        HeightSnapshot s{p.clipped(nx_, ny_), {}};
        s.heights.reserve(std::size_t(s.patch.count()));
        for (int j = s.patch.j0; j <= s.patch.j1; ++j)
            for (int i = s.patch.i0; i <= s.patch.i1; ++i) s.heights.push_back((*this)(i, j));
        return s;
    }
    // Puts back saved heights exactly and recomputes the affected normals.
    void restore(const HeightSnapshot& s) {
        std::size_t k = 0;
        for (int j = s.patch.j0; j <= s.patch.j1; ++j)
            for (int i = s.patch.i0; i <= s.patch.i1; ++i) heights_[std::size_t(j) * nx_ + i] = s.heights[k++];
        update_normals(normal_support(s.patch));
    }

    // Bilinear resampling onto another grid over the same rectangle (multi-level refinement).
    Heightmap resampled(int nx, int ny) const {
        Heightmap r(nx, ny, size_, h_min_, h_max_, frame_, aperture_);
        for (int j = 0; j < ny; ++j) {
            const double y = double(j) * (ny_ - 1) / (ny - 1);
            const int j0 = std::min(int(y), ny_ - 2);
            const double fy = y - j0;
            for (int i = 0; i < nx; ++i) {
                const double x = double(i) * (nx_ - 1) / (nx - 1);
                const int i0 = std::min(int(x), nx_ - 2);
                const double fx = x - i0;
                const double h = (1 - fy) * ((1 - fx) * (*this)(i0, j0) + fx * (*this)(i0 + 1, j0)) +
                                 fy * ((1 - fx) * (*this)(i0, j0 + 1) + fx * (*this)(i0 + 1, j0 + 1));
                r.heights_[std::size_t(j) * nx + i] = r.clamp_height(float(h));
            }
        }
        r.update_normals(r.full_patch());
        return r;
    }

    HeightfieldView view() const {
        HeightfieldView v;
        v.h = heights_.data();
        v.n = normals_.data();
        v.cell_on = aperture_ == Aperture::rect ? nullptr : cell_on_.data();
        v.nx = nx_;
        v.ny = ny_;
        v.u0 = float(-0.5 * size_.x);
        v.v0 = float(-0.5 * size_.y);
        v.du = float(du());
        v.dv = float(dv());
        v.h_min = h_min_;
        v.h_max = h_max_;
        return v;
    }

    // True when the surface point (u, v) of the plane lies inside the aperture.
    bool in_aperture(double u, double v) const {
        if (std::abs(u) > 0.5 * size_.x || std::abs(v) > 0.5 * size_.y) return false;
        if (aperture_ == Aperture::rect) return true;
        const double a = u / (0.5 * size_.x), b = v / (0.5 * size_.y);
        return a * a + b * b <= 1.0;
    }

private:
    void build_mask() {
        cell_on_.assign(std::size_t(nx_ - 1) * (ny_ - 1), 1);
        if (aperture_ == Aperture::rect) return;
        // A cell belongs to an elliptical aperture when its centre lies inside the ellipse.
        for (int j = 0; j + 1 < ny_; ++j)
            for (int i = 0; i + 1 < nx_; ++i)
                cell_on_[std::size_t(j) * (nx_ - 1) + i] =
                    in_aperture(0.5 * (u_of(i) + u_of(i + 1)), 0.5 * (v_of(j) + v_of(j + 1))) ? 1 : 0;
    }

    Frame frame_{};
    Vec2d size_{0.1, 0.1};
    int nx_ = 0, ny_ = 0;
    float h_min_ = 0, h_max_ = 0;
    Aperture aperture_ = Aperture::rect;
    std::vector<float> heights_;
    std::vector<Vec3> normals_;
    std::vector<std::uint8_t> cell_on_;
};

}  // namespace freeform
