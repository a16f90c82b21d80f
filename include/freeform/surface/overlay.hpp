#pragma once
// A proposed change of a height field, held beside it instead of written into it.
//
// A move (a kernel added to a patch) is evaluated by tracing against the height map as it
// would be after the move, without touching the height map itself: several proposals can
// be evaluated at once against the same state, and a rejected one leaves nothing to undo.
// OverlayView reads heights and normals from the overlay inside its patches and from the
// base everywhere else; the tracing kernels are templated on the view type, so the plain
// HeightfieldView pays nothing for this.
#include <algorithm>
#include <cstdint>
#include <vector>

#include "heightmap.hpp"

namespace freeform {

// Per-vertex height limits narrower than the height bounds (row-major over the grid), or
// none (null): the reach envelope of an incremental trace (trace/incremental.hpp), which
// stays exact only while every vertex stays inside them. Proposals clamp to them after
// the height bounds.
struct VertexBounds {
    const float* lo = nullptr;
    const float* hi = nullptr;

    explicit operator bool() const { return lo != nullptr; }
    // Height h of vertex k (row-major) clamped to its limits; h itself without limits.
    float clamp(std::size_t k, float h) const { return lo != nullptr ? std::clamp(h, lo[k], hi[k]) : h; }
};

struct HeightOverlay {
    Patch patch;         // vertices whose heights change (inside the grid)
    Patch normal_patch;  // vertices whose normals change: patch dilated by 1, clipped
    std::vector<float> heights;  // row-major over patch
    std::vector<Vec3> normals;   // row-major over normal_patch

    bool empty() const { return patch.empty(); }

    // Heights of the patch after the move must already be in `heights`; this computes
    // the normals of normal_patch exactly as Heightmap::update_normals would.
    void finish(const Heightmap& base) {
        normal_patch = base.normal_support(patch);
        normals.resize(std::size_t(normal_patch.count()));
        const auto h = [&](int i, int j) { return height(base, i, j); };
        std::size_t k = 0;
        for (int j = normal_patch.j0; j <= normal_patch.j1; ++j)
            for (int i = normal_patch.i0; i <= normal_patch.i1; ++i) normals[k++] = base.vertex_normal(h, i, j);
    }

    // Shrinks the patch to the bounding box of the heights that really change (a kernel's
    // faint rim, or heights pinned at a bound, change nothing), so a move retraces no
    // more rays than it must. An overlay that changes nothing becomes empty.
    void trim(const Heightmap& base) {
        int i0 = patch.i1 + 1, i1 = patch.i0 - 1, j0 = patch.j1 + 1, j1 = patch.j0 - 1;
        std::size_t k = 0;
        for (int j = patch.j0; j <= patch.j1; ++j)
            for (int i = patch.i0; i <= patch.i1; ++i, ++k)
                if (heights[k] != base(i, j)) i0 = std::min(i0, i), i1 = std::max(i1, i), j0 = std::min(j0, j), j1 = std::max(j1, j);
        if (i0 > i1) {
            patch = Patch{};
            normal_patch = Patch{};
            heights.clear();
            normals.clear();
            return;
        }
        if (i0 == patch.i0 && i1 == patch.i1 && j0 == patch.j0 && j1 == patch.j1) return;
        const Patch old = patch;
        patch = Patch{i0, j0, i1, j1};
        std::size_t out = 0;
        for (int j = j0; j <= j1; ++j)
            for (int i = i0; i <= i1; ++i)
                heights[out++] = heights[std::size_t(j - old.j0) * old.width() + (i - old.i0)];
        heights.resize(out);
        finish(base);
    }

    float height(const Heightmap& base, int i, int j) const {
        if (i >= patch.i0 && i <= patch.i1 && j >= patch.j0 && j <= patch.j1)
            return heights[std::size_t(j - patch.j0) * patch.width() + (i - patch.i0)];
        return base(i, j);
    }

    // Writes the overlay into the height map (the move is accepted).
    void commit(Heightmap& base) const {
        std::size_t k = 0;
        for (int j = patch.j0; j <= patch.j1; ++j)
            for (int i = patch.i0; i <= patch.i1; ++i) base.set(i, j, heights[k++]);
        base.update_normals(normal_patch);
    }
};

// Kernel-side view of "base + overlay"; same interface as HeightfieldView.
struct OverlayView : HeightfieldView {
    const float* oh = nullptr;  // overlay heights over [pi0, pi0+pw) x [pj0, pj0+ph)
    const Vec3* on = nullptr;   // overlay normals over [ni0, ni0+nw) x [nj0, nj0+nh)
    int pi0 = 0, pj0 = 0, pw = 0, ph = 0;
    int ni0 = 0, nj0 = 0, nw = 0, nh = 0;

    FREEFORM_HD FREEFORM_FORCE_INLINE float height(int i, int j) const {
        const unsigned a = unsigned(i - pi0), b = unsigned(j - pj0);
        return a < unsigned(pw) && b < unsigned(ph) ? oh[b * pw + a] : HeightfieldView::height(i, j);
    }
    FREEFORM_HD FREEFORM_FORCE_INLINE Vec3 normal(int i, int j) const {
        const unsigned a = unsigned(i - ni0), b = unsigned(j - nj0);
        return a < unsigned(nw) && b < unsigned(nh) ? on[b * nw + a] : HeightfieldView::normal(i, j);
    }
    FREEFORM_HD Vec3 vertex(int i, int j) const { return {u0 + i * du, v0 + j * dv, height(i, j)}; }
};

inline OverlayView overlay_view(const Heightmap& base, const HeightOverlay& o) {
    OverlayView v;
    static_cast<HeightfieldView&>(v) = base.view();
    v.oh = o.heights.data();
    v.on = o.normals.data();
    v.pi0 = o.patch.i0, v.pj0 = o.patch.j0, v.pw = o.patch.width(), v.ph = o.patch.height();
    v.ni0 = o.normal_patch.i0, v.nj0 = o.normal_patch.j0, v.nw = o.normal_patch.width(), v.nh = o.normal_patch.height();
    if (o.empty()) v.pw = v.ph = v.nw = v.nh = 0;
    return v;
}

}  // namespace freeform
