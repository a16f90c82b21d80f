#pragma once
// Targets: the irradiance the design should produce, as fixed-point cells summing to N.
//
// A target image holds relative irradiance (any scale; grey levels of a PNG, a PFM,
// rendered text). For a level with receiver resolution W × H and N emitted weight, the
// image is area-averaged to W × H (a box filter: coarse levels see the mean of the
// pixels they cover) and scaled so that its cells sum to exactly N (docs/architecture.md §1), with
// the rounding remainder given to the cells with the largest fractional parts. An image
// coarser than the scene's receiver has already been brought up to it smoothly
// (upsample_linear below, called by io::load_target_image), so no level sees its pixels
// as blocks.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/fixed_point.hpp"
#include "../core/histogram.hpp"
#include "../scene/scene.hpp"

namespace freeform {

struct Target {
    int width = 0, height = 0;
    std::vector<Fixed> cells;  // sums to `total`
    Fixed total = 0;
};

// The error of the reference's eq. 3.3 between two sets of cells of the same total:
// Σ|a − b| / (2·total). 0: identical; 1: disjoint.
inline double l1_error(std::span<const Fixed> a, std::span<const Fixed> b, Fixed total) {
    std::int64_t s = 0;
    for (std::size_t k = 0; k < a.size(); ++k) s += std::llabs(a[k] - b[k]);
    return total > 0 ? double(s) / (2.0 * double(total)) : 0.0;
}
inline double l1_error(const Histogram& h, const Target& t) { return l1_error(h.cells, t.cells, t.total); }

// Area-weighted resampling of an image to w × h (exact box filter for any ratio).
inline ImageD resample_area(const ImageD& img, int w, int h) {
    const int W = int(img.cols()), H = int(img.rows());
    ImageD out = ImageD::Zero(h, w);
    const double sx = double(W) / w, sy = double(H) / h;
    for (int y = 0; y < h; ++y) {
        const double y0 = y * sy, y1 = (y + 1) * sy;
        for (int x = 0; x < w; ++x) {
            const double x0 = x * sx, x1 = (x + 1) * sx;
            double sum = 0;
            for (int py = int(y0); py < std::min(H, int(std::ceil(y1))); ++py) {
                const double oy = std::min(y1, py + 1.0) - std::max(y0, double(py));
                if (oy <= 0) continue;
                for (int px = int(x0); px < std::min(W, int(std::ceil(x1))); ++px) {
                    const double ox = std::min(x1, px + 1.0) - std::max(x0, double(px));
                    if (ox > 0) sum += ox * oy * img(py, px);
                }
            }
            out(y, x) = sum / (sx * sy);
        }
    }
    return out;
}

namespace target_detail {

// One axis of the linear reconstruction of n pixels (their values at the pixel centres
// k + ½, joined by straight lines, held constant beyond the first and last centre),
// averaged over each of m equal cells spanning the same extent [0, n): for every cell the
// (pixel, weight) pairs, weights summing to 1. The reconstruction is linear between two
// centres, so its mean over a piece between them is its value at the piece's midpoint.
inline std::vector<std::vector<std::pair<int, double>>> linear_cell_weights(int n, int m) {
    std::vector<std::vector<std::pair<int, double>>> rows(static_cast<std::size_t>(m));
    const double s = double(n) / m;
    for (int i = 0; i < m; ++i) {
        const double a = i * s, b = (i + 1) * s;
        auto& row = rows[std::size_t(i)];
        // The pieces run left to right, so a pixel met again is the last one added.
        auto add = [&](int k, double w) {
            if (!row.empty() && row.back().first == k)
                row.back().second += w;
            else
                row.emplace_back(k, w);
        };
        for (double p = a; p < b;) {
            const double q = std::min(b, std::floor(p - 0.5) + 1.5);  // the next centre after p
            const double t = 0.5 * (p + q) - 0.5;                     // the midpoint, in centre units
            const double w = (q - p) / (b - a);
            if (t <= 0) {
                add(0, w);
            } else if (t >= n - 1) {
                add(n - 1, w);
            } else {
                const int k = int(std::floor(t));
                add(k, w * (1 - (t - k)));
                add(k + 1, w * (t - k));
            }
            p = q;
        }
    }
    return rows;
}

}  // namespace target_detail

// A target image brought up to w × h pixels along each axis where it has fewer: its
// pixels are samples of a smooth picture (a photograph's are), so the picture between
// them is the linear reconstruction through their centres, and each new pixel is that
// reconstruction's mean over its area (docs/scene.md, target.upsample). A piecewise-
// constant (box) enlargement would ask the optic for the old pixels' edges, steps a
// smooth surface cannot make and no one wants. An axis with at least as many pixels is
// kept as it is (make_target area-averages it down). Light is conserved up to the
// reconstruction's edge, which make_target's normalisation absorbs.
inline ImageD upsample_linear(const ImageD& img, int w, int h) {
    // Along the columns; the rows are the same step on the transpose.
    const auto widen = [](const ImageD& a, int m) -> ImageD {
        if (a.cols() == 0 || m <= a.cols()) return a;
        const auto cells = target_detail::linear_cell_weights(int(a.cols()), m);
        ImageD t = ImageD::Zero(a.rows(), m);
        for (int x = 0; x < m; ++x)
            for (const auto& [k, v] : cells[std::size_t(x)]) t.col(x) += v * a.col(k);
        return t;
    };
    return widen(widen(img, w).transpose(), h).transpose();
}

// How much a picture of w × h square pixels is stretched when it fills a receiver whose
// width / height (metres) is `aspect`: the larger ratio of the two aspect ratios (1: not at all).
inline double aspect_stretch(Eigen::Index w, Eigen::Index h, double aspect) {
    const double own = double(w) / double(h);
    return std::max(own / aspect, aspect / own);
}

namespace target_detail {
// How frame_to_aspect changes a w × h picture: along its rows (true) or its columns, by
// `side` pixels on each side (> 0 added, < 0 removed, 0 none).
struct Framing {
    bool rows = false;
    Eigen::Index side = 0;
};
inline Framing framing(Eigen::Index w, Eigen::Index h, double aspect, TargetFit fit) {
    if (fit == TargetFit::stretch || w == 0 || h == 0 || !(aspect > 0)) return {};
    const bool wider = double(w) / double(h) > aspect;
    // contain pads the short axis, cover trims the long one.
    const bool rows = (fit == TargetFit::contain) == wider;
    const Eigen::Index have = rows ? h : w;
    const double want = rows ? double(w) / aspect : double(h) * aspect;
    // At least one pixel is kept.
    return {rows, std::max<Eigen::Index>(std::llround((want - double(have)) / 2.0), -(have - 1) / 2)};
}
}  // namespace target_detail

// A picture laid on a receiver whose width / height (metres) is `aspect`, its pixels taken
// as square (docs/scene.md, target.fit). `stretch` leaves it as it is: make_target maps the
// whole picture onto the whole receiver, stretching it where the aspect ratios differ.
// `contain` adds dark rows (or columns) on two opposite sides, `cover` cuts them off, so
// that the picture keeps its shape. The same number go on (or come off) each side, whole
// pixels, so the picture stays exactly centred and its own pixels are not resampled; the
// framed aspect ratio is within one pixel pair of the receiver's.
inline ImageD frame_to_aspect(const ImageD& img, double aspect, TargetFit fit) {
    const Eigen::Index w = img.cols(), h = img.rows();
    const auto [rows, side] = target_detail::framing(w, h, aspect, fit);
    if (side == 0) return img;
    if (rows) {
        if (side < 0) return img.middleRows(-side, h + 2 * side);
        ImageD out = ImageD::Zero(h + 2 * side, w);
        out.middleRows(side, h) = img;
        return out;
    }
    if (side < 0) return img.middleCols(-side, w + 2 * side);
    ImageD out = ImageD::Zero(h, w + 2 * side);
    out.middleCols(side, w) = img;
    return out;
}

// The pixels (columns × rows) frame_to_aspect would give a w × h picture, without making it.
inline std::uint64_t framed_pixels(Eigen::Index w, Eigen::Index h, double aspect, TargetFit fit) {
    const auto [rows, side] = target_detail::framing(w, h, aspect, fit);
    return std::uint64_t(rows ? w * (h + 2 * side) : (w + 2 * side) * h);
}

// A picture (relative irradiance, any size) made the target of `scene`'s receiver: framed
// to its aspect ratio as target.fit says, then brought up to its pixel count along an axis
// where it has fewer (target.upsample). io::load_target_image and the Python module's
// arrays both come through here.
inline ImageD target_for_receiver(const ImageD& picture, const Scene& scene) {
    const TargetSpec spec = scene.target ? *scene.target : TargetSpec{};
    const Receiver& r = scene.receiver;
    ImageD framed = frame_to_aspect(picture, r.aspect(), spec.fit);
    if (spec.upsample == TargetUpsample::bilinear) return upsample_linear(framed, r.width, r.height);
    return framed;
}

// Builds the fixed-point target of one level from a relative-irradiance image.
inline Target make_target(const ImageD& image, int w, int h, Fixed total) {
    if (image.size() == 0) throw InputError("target: the image is empty");
    if (!image.isFinite().all()) throw InputError("target: the image has non-finite values");
    if ((image < 0).any()) throw InputError("target: the image has negative values");
    const ImageD img = (image.cols() == w && image.rows() == h) ? image : resample_area(image, w, h);
    const double sum = img.sum();
    if (!(sum > 0)) throw InputError("target: the image is entirely black");
    Target t;
    t.width = w;
    t.height = h;
    t.total = total;
    t.cells.resize(std::size_t(w) * h);
    std::vector<double> frac(t.cells.size());
    Fixed assigned = 0;
    const double scale = double(total) / sum;
    for (std::size_t k = 0; k < t.cells.size(); ++k) {
        const double v = img.data()[k] * scale;
        t.cells[k] = Fixed(std::floor(v));
        frac[k] = v - std::floor(v);
        assigned += t.cells[k];
    }
    // Hand out the remainder one unit at a time, largest fractions first (ties by index).
    std::vector<std::size_t> order(t.cells.size());
    std::iota(order.begin(), order.end(), std::size_t{0});
    Fixed rest = total - assigned;
    if (rest > 0) {
        std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return frac[a] > frac[b]; });
        for (std::size_t k = 0; rest > 0; k = (k + 1) % order.size(), --rest) ++t.cells[order[k]];
    }
    return t;
}

}  // namespace freeform
