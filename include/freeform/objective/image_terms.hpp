#pragma once
// The image terms of the objective, kept exact under local updates.
//
// The state is the difference D = R - T between the received and the target irradiance,
// both in fixed point, so every image term is an integer sum:
//   L1     = sum |D|                                 (reference eq. 3.3, before / 2N)
//   Sobel  = sum |Gx(D)| + |Gy(D)|                   (reference eq. 4.5, before alpha / 2N)
// with Gx, Gy the 3 x 3 Sobel stencils and zero outside the receiver; Sobel(R) - Sobel(T)
// = Sobel(D) because the filter is linear. A move changes R on a few cells; the change of
// each sum is computed exactly from those cells (and their 3 x 3 neighbourhoods for
// Sobel), so a maintained sum always equals a full recompute, bit for bit.
#include <cstdint>
#include <cstdlib>
#include <vector>

#include "../core/fixed_point.hpp"
#include "../core/histogram.hpp"
#include "../core/sparse_delta.hpp"
#include "target.hpp"

namespace freeform {

struct ImageSums {
    std::int64_t l1 = 0;
    std::int64_t sobel = 0;
    Fixed on_receiver = 0;
    bool operator==(const ImageSums&) const = default;
};

// Per-evaluation working memory (one per concurrent evaluation).
struct ImageScratch {
    std::vector<std::uint8_t> mark;
    std::vector<std::int32_t> seen;
};

class ImageState {
public:
    ImageState() = default;
    explicit ImageState(Target target) : target_(std::move(target)) {
        d_.assign(target_.cells.size(), 0);
        mark_.assign(target_.cells.size(), 0);
    }

    const Target& target() const { return target_; }
    int width() const { return target_.width; }
    int height() const { return target_.height; }
    const ImageSums& sums() const { return sums_; }
    Fixed difference(std::size_t cell) const { return d_[cell]; }

    // Full recompute from a histogram.
    void reset(const Histogram& r) {
        sums_.on_receiver = 0;
        for (std::size_t k = 0; k < d_.size(); ++k) {
            d_[k] = r.cells[k] - target_.cells[k];
            sums_.on_receiver += r.cells[k];
        }
        sums_.l1 = 0;
        for (Fixed v : d_) sums_.l1 += std::llabs(v);
        sums_.sobel = 0;
        for (int y = 0; y < height(); ++y)
            for (int x = 0; x < width(); ++x) sums_.sobel += sobel_at(x, y, nullptr);
    }

    // The sums after adding `delta` to R, without changing the state.
    ImageSums evaluate(const SparseDelta& delta, ImageScratch& work) const {
        if (delta.touched.empty()) return sums_;
        // A move's rays land close together: when the box around the touched cells is
        // small, sweep it (no marks, no per-cell bookkeeping); else visit the cells.
        const int w = width(), h = height();
        int x0 = w, x1 = -1, y0 = h, y1 = -1;
        const double inv_w = 1.0 / w;
        for (auto c : delta.touched) {
            int y = int(double(c) * inv_w);  // c / w, corrected by one where rounding crossed a row
            y -= y * w > c ? 1 : 0;
            y += (y + 1) * w <= c ? 1 : 0;
            const int x = c - y * w;
            x0 = std::min(x0, x), x1 = std::max(x1, x), y0 = std::min(y0, y), y1 = std::max(y1, y);
        }
        const std::int64_t box = std::int64_t(x1 - x0 + 3) * (y1 - y0 + 3);
        if (box > 4 * std::int64_t(delta.touched.size()) + 64) return evaluate_cells(delta, work);
        ImageSums s = sums_;
        for (int y = y0; y <= y1; ++y)
            for (int x = x0; x <= x1; ++x) {
                const std::size_t n = std::size_t(y) * w + x;
                const Fixed dv = delta.value[n];
                s.l1 += std::llabs(d_[n] + dv) - std::llabs(d_[n]);
                s.on_receiver += dv;
            }
        // Sobel is linear: G(D + dR) = G(D) + G(dR); it changes only where G(dR) != 0,
        // within one cell of a touched cell.
        for (int y = std::max(y0 - 1, 0); y <= std::min(y1 + 1, h - 1); ++y)
            for (int x = std::max(x0 - 1, 0); x <= std::min(x1 + 1, w - 1); ++x) {
                const Gradient g = gradient(delta.value.data(), x, y);
                if (g.x == 0 && g.y == 0) continue;
                const Gradient f = gradient(d_.data(), x, y);
                s.sobel += std::llabs(f.x + g.x) + std::llabs(f.y + g.y) - std::llabs(f.x) - std::llabs(f.y);
            }
        return s;
    }

    // evaluate() by visiting the touched cells and their neighbours (deltas spread wide).
    ImageSums evaluate_cells(const SparseDelta& delta, ImageScratch& work) const {
        ImageSums s = sums_;
        const int w = width(), h = height();
        std::vector<std::uint8_t>& scratch = work.mark;
        if (scratch.size() != d_.size()) scratch.assign(d_.size(), 0);
        std::vector<std::int32_t>& seen = work.seen;
        seen.clear();
        for (auto c : delta.touched) {
            if (scratch[std::size_t(c)] & 1) continue;
            scratch[std::size_t(c)] |= 1;
            seen.push_back(c);
            const Fixed dv = delta.value[std::size_t(c)];
            s.l1 += std::llabs(d_[std::size_t(c)] + dv) - std::llabs(d_[std::size_t(c)]);
            s.on_receiver += dv;
        }
        // Sobel: every cell within one of a touched cell.
        const std::size_t first_sobel = seen.size();
        for (std::size_t k = 0; k < first_sobel; ++k) {
            const int c = seen[k], cx = c % w, cy = c / w;
            for (int y = cy - 1; y <= cy + 1; ++y) {
                if (y < 0 || y >= h) continue;
                for (int x = cx - 1; x <= cx + 1; ++x) {
                    if (x < 0 || x >= w) continue;
                    const std::size_t n = std::size_t(y) * w + x;
                    if (scratch[n] & 2) continue;
                    scratch[n] |= 2;
                    seen.push_back(std::int32_t(n));
                    s.sobel += sobel_at(x, y, &delta) - sobel_at(x, y, nullptr);
                }
            }
        }
        for (auto c : seen) scratch[std::size_t(c)] = 0;
        seen.clear();
        return s;
    }

    // Applies a delta whose sums were computed by evaluate().
    void apply(const SparseDelta& delta, const ImageSums& new_sums) {
        for (auto c : delta.touched) {
            // A cell may be listed twice; add its value once.
            if (mark_[std::size_t(c)]) continue;
            mark_[std::size_t(c)] = 1;
            d_[std::size_t(c)] += delta.value[std::size_t(c)];
        }
        for (auto c : delta.touched) mark_[std::size_t(c)] = 0;
        sums_ = new_sums;
    }

    // |Gx| + |Gy| of D (+ delta) at (x, y), zero padding outside.
    std::int64_t sobel_at(int x, int y, const SparseDelta* delta) const {
        Gradient g = gradient(d_.data(), x, y);
        if (delta) {
            const Gradient e = gradient(delta->value.data(), x, y);
            g.x += e.x, g.y += e.y;
        }
        return std::llabs(g.x) + std::llabs(g.y);
    }

private:
    struct Gradient {
        Fixed x, y;
    };
    // The Sobel gradient of the width() x height() image `a` at (x, y), zero padding outside.
    Gradient gradient(const Fixed* a, int x, int y) const {
        const int w = width(), h = height();
        if (x > 0 && y > 0 && x + 1 < w && y + 1 < h) {  // interior: no padding
            const Fixed* up = a + std::size_t(y - 1) * w + x;
            const Fixed* mid = up + w;
            const Fixed* down = mid + w;
            return {(up[1] + 2 * mid[1] + down[1]) - (up[-1] + 2 * mid[-1] + down[-1]),
                    (down[-1] + 2 * down[0] + down[1]) - (up[-1] + 2 * up[0] + up[1])};
        }
        auto at = [&](int i, int j) -> Fixed {
            return i < 0 || j < 0 || i >= w || j >= h ? 0 : a[std::size_t(j) * w + i];
        };
        return {(at(x + 1, y - 1) + 2 * at(x + 1, y) + at(x + 1, y + 1)) - (at(x - 1, y - 1) + 2 * at(x - 1, y) + at(x - 1, y + 1)),
                (at(x - 1, y + 1) + 2 * at(x, y + 1) + at(x + 1, y + 1)) - (at(x - 1, y - 1) + 2 * at(x, y - 1) + at(x + 1, y - 1))};
    }

    Target target_;
    std::vector<Fixed> d_;
    std::vector<std::uint8_t> mark_;
    ImageSums sums_;
};

}  // namespace freeform
