// The objective terms against independent computations: the L1 error and the Sobel sum
// by brute force in double, the energy threshold, fixed-point targets, the exactness of
// incremental image updates and of incremental penalties.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <string_view>
#include <vector>

#include <freeform/core/rng.hpp>
#include <freeform/objective/image_terms.hpp>
#include <freeform/objective/objective.hpp>
#include <freeform/objective/penalty.hpp>
#include <freeform/objective/target.hpp>
#include <freeform/propose/kernel.hpp>

using namespace freeform;

namespace {

// A random non-negative image with some exact zeros (dark regions are the usual case).
ImageD random_image(int w, int h, std::uint64_t seed) {
    CounterRng rng(seed, 17);
    ImageD img(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) img(y, x) = rng.uniform() < 0.25 ? 0.0 : rng.uniform(0.0, 3.0);
    return img;
}

// A random histogram whose total is not N (part of the light missed the receiver).
Histogram random_histogram(int w, int h, Fixed mean_cell, std::uint64_t seed) {
    CounterRng rng(seed, 23);
    Histogram r(w, h);
    for (auto& c : r.cells) c = rng.uniform() < 0.2 ? 0 : Fixed(rng.uniform(0.0, 2.0) * double(mean_cell));
    return r;
}

// Zero-padded 3 x 3 correlation of a double image with a stencil s[row][col].
ImageD correlate3(const ImageD& d, const double (&s)[3][3]) {
    const int h = int(d.rows()), w = int(d.cols());
    ImageD out = ImageD::Zero(h, w);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            double acc = 0;
            for (int dy = -1; dy <= 1; ++dy)
                for (int dx = -1; dx <= 1; ++dx) {
                    const int yy = y + dy, xx = x + dx;
                    if (yy < 0 || xx < 0 || yy >= h || xx >= w) continue;
                    acc += s[dy + 1][dx + 1] * d(yy, xx);
                }
            out(y, x) = acc;
        }
    return out;
}

// sum |Gx(D)| + |Gy(D)| in double, D in fixed-point units (exact for these magnitudes).
double sobel_brute_force(const Histogram& r, const Target& t) {
    ImageD d(r.height, r.width);
    for (int y = 0; y < r.height; ++y)
        for (int x = 0; x < r.width; ++x) {
            const std::size_t k = std::size_t(y) * r.width + x;
            d(y, x) = double(r.cells[k]) - double(t.cells[k]);
        }
    static const double gx[3][3] = {{-1, 0, 1}, {-2, 0, 2}, {-1, 0, 1}};
    static const double gy[3][3] = {{-1, -2, -1}, {0, 0, 0}, {1, 2, 1}};
    return correlate3(d, gx).abs().sum() + correlate3(d, gy).abs().sum();
}

double l1_brute_force(const Histogram& r, const Target& t) {
    double s = 0;
    for (std::size_t k = 0; k < r.cells.size(); ++k) s += std::abs(double(r.cells[k]) - double(t.cells[k]));
    return s;
}

Fixed sum_of(const std::vector<Fixed>& v) {
    Fixed s = 0;
    for (Fixed x : v) s += x;
    return s;
}

}  // namespace

// ------------------------------------------------------------------------- image terms

TEST_CASE("L1 error and Sobel sum equal brute-force computations on random histograms") {
    const ObjectiveWeights plain{0.0, 0.0, 0.0};  // no Sobel, no threshold, no lost-light term
    for (std::uint64_t seed = 1; seed <= 6; ++seed) {
        const int w = 5 + int(seed * 7 % 23), h = 4 + int(seed * 5 % 19);
        CAPTURE(seed);
        CAPTURE(w);
        CAPTURE(h);
        const Fixed n = to_fixed(16.0 * w * h);
        const Target t = make_target(random_image(w, h, seed), w, h, n);
        const Histogram r = random_histogram(w, h, n / (w * h), seed + 100);
        ImageState state(t);
        state.reset(r);

        // The integer sums, against sums done independently in double (exact here: every
        // partial sum stays far below 2^53).
        CHECK(double(state.sums().l1) == l1_brute_force(r, t));
        CHECK(double(state.sums().sobel) == sobel_brute_force(r, t));
        CHECK(state.sums().on_receiver == r.total());
        for (std::size_t k = 0; k < r.cells.size(); ++k) REQUIRE(state.difference(k) == r.cells[k] - t.cells[k]);

        // The normalised values of the objective.
        const ObjectiveValue v = combine(state.sums(), n, 0.0, plain);
        CHECK(v.error == doctest::Approx(l1_brute_force(r, t) / (2.0 * double(n))).epsilon(1e-14));
        CHECK(v.sobel == doctest::Approx(sobel_brute_force(r, t) / (8.0 * 2.0 * double(n))).epsilon(1e-14));
        CHECK(v.energy == doctest::Approx(double(r.total()) / double(n)).epsilon(1e-15));
        CHECK(v.total == doctest::Approx(v.error).epsilon(1e-15));

        const ObjectiveValue with_sobel = combine(state.sums(), n, 0.0, ObjectiveWeights{0.3, 0.0, 0.0});
        CHECK(with_sobel.total == doctest::Approx(v.error + 0.3 * v.sobel).epsilon(1e-14));
        const ObjectiveValue with_lost = combine(state.sums(), n, 0.0, ObjectiveWeights{0.3, 0.0, 2.0});
        CHECK(with_lost.total ==
              doctest::Approx(v.error + 0.3 * v.sobel + 2.0 * 0.5 * (1.0 - v.energy)).epsilon(1e-14));
    }
}

TEST_CASE("the error is 0 for R = T and 1 for disjoint R and T of equal weight") {
    const int w = 8, h = 6;
    const Fixed n = to_fixed(100.0);
    ImageD left = ImageD::Zero(h, w), right = ImageD::Zero(h, w);
    left.leftCols(3) = 1.0;
    right.rightCols(3) = 1.0;
    const Target t = make_target(left, w, h, n);
    ImageState state(t);

    Histogram same(w, h);
    same.cells = t.cells;
    state.reset(same);
    const ObjectiveValue zero = combine(state.sums(), n, 0.0, ObjectiveWeights{});
    CHECK(zero.error == 0.0);
    CHECK(zero.sobel == 0.0);
    CHECK(zero.energy == 1.0);
    CHECK(zero.total == 0.0);

    Histogram other(w, h);
    other.cells = make_target(right, w, h, n).cells;
    state.reset(other);
    const ObjectiveValue one = combine(state.sums(), n, 0.0, ObjectiveWeights{});
    CHECK(one.error == 1.0);
    CHECK(one.energy == 1.0);
}

TEST_CASE("the Sobel term sees the receiver border as zero (no wrap-around, no clamping)") {
    // D = a single unit in the top-left corner.
    const int w = 5, h = 4;
    const Fixed n = 1000;
    ImageD flat = ImageD::Ones(h, w);
    const Target t = make_target(flat, w, h, n);
    Histogram r(w, h);
    r.cells = t.cells;
    r.cells[0] += 1;  // top-left corner
    ImageState state(t);
    state.reset(r);
    CHECK(double(state.sums().sobel) == sobel_brute_force(r, t));
    // By hand: (0, 0) sees nothing of itself; (1, 0) has |Gx| = 2; (0, 1) has |Gy| = 2;
    // (1, 1) has |Gx| = |Gy| = 1. A wrap-around or a clamped border would add more.
    CHECK(state.sums().sobel == 6);
    CHECK(state.sums().l1 == 1);
}

TEST_CASE("energy threshold: error / energy below the threshold, unchanged at or above it") {
    const Fixed n = to_fixed(1000.0);
    ImageSums s;
    s.l1 = to_fixed(200.0);     // error 0.1
    s.sobel = to_fixed(1600.0);  // sobel 0.1 after / 8 / 2N
    const ObjectiveWeights w{0.5, 0.9, 0.0};  // the lost-light term is tested below
    const double image = 0.1 + 0.5 * 0.1;
    const double penalty = 0.02;

    s.on_receiver = to_fixed(950.0);  // energy 0.95 > threshold
    ObjectiveValue v = combine(s, n, penalty, w);
    CHECK(v.error == doctest::Approx(0.1).epsilon(1e-15));
    CHECK(v.sobel == doctest::Approx(0.1).epsilon(1e-15));
    CHECK(v.energy == doctest::Approx(0.95).epsilon(1e-15));
    CHECK(v.total == doctest::Approx(image + penalty).epsilon(1e-14));

    s.on_receiver = to_fixed(900.0);  // exactly at the threshold: unchanged
    v = combine(s, n, penalty, w);
    CHECK(v.energy == 0.9);
    CHECK(v.total == doctest::Approx(image + penalty).epsilon(1e-14));

    s.on_receiver = to_fixed(500.0);  // energy 0.5: the image part is doubled, not the penalty
    v = combine(s, n, penalty, w);
    CHECK(v.error == doctest::Approx(0.1).epsilon(1e-15));  // "error" stays the plain L1
    CHECK(v.total == doctest::Approx(image / 0.5 + penalty).epsilon(1e-14));

    s.on_receiver = to_fixed(100.0);
    v = combine(s, n, 0.0, w);
    CHECK(v.total == doctest::Approx(image / 0.1).epsilon(1e-14));

    // No light at all: a finite, large value rather than a division by zero.
    s.on_receiver = 0;
    v = combine(s, n, 0.0, w);
    CHECK(std::isfinite(v.total));
    CHECK(v.total > image / 0.1);

    // A threshold of 0 turns the term off.
    s.on_receiver = to_fixed(100.0);
    v = combine(s, n, 0.0, ObjectiveWeights{0.5, 0.0, 0.0});
    CHECK(v.total == doctest::Approx(image).epsilon(1e-14));
}

TEST_CASE("lost-light term: weight x (1 - energy) / 2, added after the energy threshold") {
    const Fixed n = to_fixed(1000.0);
    ImageSums s;
    s.l1 = to_fixed(200.0);  // error 0.1
    s.sobel = 0;
    s.on_receiver = to_fixed(800.0);  // energy 0.8
    const ObjectiveValue v = combine(s, n, 0.01, ObjectiveWeights{0.0, 0.9, 1.5});
    CHECK(v.total == doctest::Approx(0.1 / 0.8 + 1.5 * 0.5 * 0.2 + 0.01).epsilon(1e-14));
    // Nothing lost, nothing added; the defaults charge it with weight 1.
    s.on_receiver = n;
    CHECK(combine(s, n, 0.0, ObjectiveWeights{0.0, 0.9, 1.5}).total == doctest::Approx(0.1).epsilon(1e-14));
    s.on_receiver = to_fixed(960.0);
    CHECK(combine(s, n, 0.0, ObjectiveWeights{}).total ==
          doctest::Approx(0.1 + 0.5 * 0.04).epsilon(1e-14));
}

TEST_CASE("with the lost-light weight 1, discarding light costs as much as misplacing it") {
    // R = T, then one unit of light either moved to another cell or thrown away.
    const int w = 6, h = 5;
    const Fixed n = to_fixed(300.0);
    const Target t = make_target(random_image(w, h, 21), w, h, n);
    std::size_t from = 0;
    while (t.cells[from] < to_fixed(2.0)) ++from;
    const Fixed unit = to_fixed(1.0);
    const ObjectiveWeights weights{0.0, 0.0, 1.0};

    Histogram misplaced(w, h);
    misplaced.cells = t.cells;
    misplaced.cells[from] -= unit;
    misplaced.cells[(from + 7) % misplaced.cells.size()] += unit;
    Histogram discarded(w, h);
    discarded.cells = t.cells;
    discarded.cells[from] -= unit;

    ImageState a(t), b(t);
    a.reset(misplaced);
    b.reset(discarded);
    const ObjectiveValue va = combine(a.sums(), n, 0.0, weights), vb = combine(b.sums(), n, 0.0, weights);
    CHECK(va.error == doctest::Approx(1.0 / 300.0).epsilon(1e-12));
    CHECK(vb.error == doctest::Approx(0.5 / 300.0).epsilon(1e-12));
    CHECK(vb.total == doctest::Approx(va.total).epsilon(1e-12));
    // Without the term (the reference's objective) discarding is half the price.
    const ObjectiveWeights reference{0.0, 0.0, 0.0};
    CHECK(combine(b.sums(), n, 0.0, reference).total ==
          doctest::Approx(0.5 * combine(a.sums(), n, 0.0, reference).total).epsilon(1e-12));
}

// ------------------------------------------------------------------------- targets

TEST_CASE("make_target sums to exactly N and is proportional to the image within one unit") {
    const Fixed totals[] = {1, 7, 1000, 999983, to_fixed(12345.678), to_fixed(640000.0)};
    for (std::uint64_t seed = 1; seed <= 4; ++seed)
        for (Fixed n : totals) {
            const int w = 3 + int(seed * 11 % 29), h = 2 + int(seed * 13 % 17);
            CAPTURE(seed);
            CAPTURE(n);
            const ImageD img = random_image(w, h, seed);
            const Target t = make_target(img, w, h, n);
            REQUIRE(t.width == w);
            REQUIRE(t.height == h);
            REQUIRE(t.cells.size() == std::size_t(w) * h);
            CHECK(t.total == n);
            CHECK(sum_of(t.cells) == n);
            const long double sum = img.sum();
            double worst = 0, largest = 0;
            bool negative = false;
            for (int y = 0; y < h; ++y)
                for (int x = 0; x < w; ++x) {
                    const Fixed c = t.cells[std::size_t(y) * w + x];
                    negative |= c < 0;
                    const long double exact = (long double)img(y, x) * (long double)n / sum;
                    worst = std::max(worst, double(std::fabs((long double)c - exact)));
                    largest = std::max(largest, double(exact));
                }
            CHECK_FALSE(negative);
            // One unit of rounding, plus what double arithmetic loses on huge cells.
            CHECK(worst < 1.0 + 1e-15 * largest);
        }
}

TEST_CASE("make_target of integer-proportional images is exact and keeps black cells black") {
    ImageD img(3, 4);
    img << 0, 1, 2, 3,  //
        4, 0, 0, 1,     //
        1, 1, 1, 2;
    const Target t = make_target(img, 4, 3, 16 * 1000);
    for (int k = 0; k < 12; ++k) CHECK(t.cells[std::size_t(k)] == Fixed(img.data()[k] * 1000));

    // Scaled by an awkward factor and with a total that leaves a remainder.
    const Target u = make_target(img * 0.1, 4, 3, 17);
    CHECK(sum_of(u.cells) == 17);
    for (int k = 0; k < 12; ++k)
        if (img.data()[k] == 0) CHECK(u.cells[std::size_t(k)] == 0);
}

TEST_CASE("make_target sums to N even when the image sum rounds badly in double") {
    // Values whose double sum is off by an ulp or so, with totals that make many cells
    // land on (or a hair off) integers: the floor-and-distribute rounding must still
    // hand out exactly N.
    const double values[] = {0.1, 0.2, 0.3, 0.7, 1.0 / 3.0, 1e-17, 0.6, 0.9};
    for (int w = 1; w <= 8; ++w)
        for (int h = 1; h <= 5; ++h)
            for (Fixed n : {Fixed(10), Fixed(30), Fixed(3), Fixed(1000000007), to_fixed(3.0)}) {
                ImageD img(h, w);
                for (int k = 0; k < w * h; ++k) img.data()[k] = values[std::size_t(k * 3 + w + h) % 8];
                const Target t = make_target(img, w, h, n);
                CAPTURE(w);
                CAPTURE(h);
                CAPTURE(n);
                REQUIRE(sum_of(t.cells) == n);
                for (Fixed c : t.cells) REQUIRE(c >= 0);
            }
}

TEST_CASE("make_target rejects empty, black, negative and non-finite images naming the target") {
    const auto message = [](const ImageD& img) {
        try {
            (void)make_target(img, 4, 4, 100);
        } catch (const InputError& e) {
            return std::string(e.what());
        }
        return std::string("no exception");
    };
    CHECK(message(ImageD()).find("target") != std::string::npos);
    CHECK(message(ImageD::Zero(4, 4)).find("black") != std::string::npos);
    ImageD neg = ImageD::Ones(4, 4);
    neg(1, 2) = -0.5;
    CHECK(message(neg).find("negative") != std::string::npos);
    ImageD nan = ImageD::Ones(4, 4);
    nan(0, 3) = std::numeric_limits<double>::quiet_NaN();
    CHECK(message(nan).find("non-finite") != std::string::npos);
    ImageD inf = ImageD::Ones(4, 4);
    inf(3, 3) = std::numeric_limits<double>::infinity();
    CHECK(message(inf).find("non-finite") != std::string::npos);
}

TEST_CASE("area resampling preserves the mean and constants, for any ratio") {
    struct Size {
        int w, h;
    };
    const Size from[] = {{37, 23}, {5, 3}, {64, 64}, {200, 200}, {7, 41}};
    const Size to[] = {{10, 7}, {13, 11}, {32, 32}, {50, 50}, {3, 100}, {1, 1}, {64, 64}};
    for (const Size& a : from)
        for (const Size& b : to) {
            CAPTURE(a.w);
            CAPTURE(a.h);
            CAPTURE(b.w);
            CAPTURE(b.h);
            const ImageD img = random_image(a.w, a.h, std::uint64_t(a.w * 1000 + a.h));
            const ImageD r = resample_area(img, b.w, b.h);
            REQUIRE(r.cols() == b.w);
            REQUIRE(r.rows() == b.h);
            CHECK(r.mean() == doctest::Approx(img.mean()).epsilon(1e-12));
            CHECK(r.minCoeff() >= img.minCoeff() - 1e-12);
            CHECK(r.maxCoeff() <= img.maxCoeff() + 1e-12);
            const ImageD c = resample_area(ImageD::Constant(a.h, a.w, 2.5), b.w, b.h);
            CHECK((c - 2.5).abs().maxCoeff() < 1e-12);
        }
    // An exact 2 x 2 box average when halving.
    ImageD img(2, 4);
    img << 1, 3, 0, 8,  //
        5, 7, 4, 4;
    const ImageD half = resample_area(img, 2, 1);
    CHECK(half(0, 0) == doctest::Approx(4.0));
    CHECK(half(0, 1) == doctest::Approx(4.0));
}

TEST_CASE("frame_to_aspect pads (contain) or trims (cover) whole pixel pairs, centred, and stretch keeps all") {
    const ImageD img = random_image(24, 18, 3) + 0.5;  // 24 wide, 18 tall: aspect 4:3, no zero pixel
    SUBCASE("a wide picture on a square receiver") {
        const ImageD contain = frame_to_aspect(img, 1.0, TargetFit::contain);
        REQUIRE(contain.cols() == 24);
        REQUIRE(contain.rows() == 24);  // 3 dark rows above, 3 below
        CHECK(contain.topRows(3).abs().maxCoeff() == 0.0);
        CHECK(contain.bottomRows(3).abs().maxCoeff() == 0.0);
        CHECK((contain.middleRows(3, 18) - img).abs().maxCoeff() == 0.0);
        const ImageD cover = frame_to_aspect(img, 1.0, TargetFit::cover);
        REQUIRE(cover.rows() == 18);
        REQUIRE(cover.cols() == 18);  // 3 columns off each side
        CHECK((cover - img.middleCols(3, 18)).abs().maxCoeff() == 0.0);
        CHECK((frame_to_aspect(img, 1.0, TargetFit::stretch) - img).abs().maxCoeff() == 0.0);
        CHECK(aspect_stretch(24, 18, 1.0) == doctest::Approx(4.0 / 3.0));
    }
    SUBCASE("a wide picture on a wider receiver: columns added, rows cut") {
        const ImageD contain = frame_to_aspect(img, 2.0, TargetFit::contain);  // wants 36 x 18
        REQUIRE(contain.rows() == 18);
        REQUIRE(contain.cols() == 36);
        CHECK((contain.middleCols(6, 24) - img).abs().maxCoeff() == 0.0);
        CHECK(contain.leftCols(6).abs().maxCoeff() == 0.0);
        const ImageD cover = frame_to_aspect(img, 2.0, TargetFit::cover);  // wants 24 x 12
        REQUIRE(cover.cols() == 24);
        REQUIRE(cover.rows() == 12);
        CHECK((cover - img.middleRows(3, 12)).abs().maxCoeff() == 0.0);
        CHECK(aspect_stretch(24, 18, 2.0) == doctest::Approx(1.5));
    }
    SUBCASE("the same aspect ratio, an odd difference, an extreme receiver") {
        CHECK((frame_to_aspect(img, 24.0 / 18.0, TargetFit::contain) - img).abs().maxCoeff() == 0.0);
        CHECK((frame_to_aspect(img, 24.0 / 18.0, TargetFit::cover) - img).abs().maxCoeff() == 0.0);
        // 5 x 3 on a square: one row a side (5 x 5), or one column a side (3 x 3): the
        // same on both sides, whatever the rounding, so the picture stays centred.
        const ImageD small = random_image(5, 3, 4) + 0.5;
        CHECK(frame_to_aspect(small, 1.0, TargetFit::contain).rows() == 5);
        CHECK(frame_to_aspect(small, 1.0, TargetFit::cover).cols() == 3);
        // A receiver a thousand times taller than wide: cover keeps at least a pixel.
        const ImageD thin = frame_to_aspect(img, 1e-3, TargetFit::cover);
        CHECK(thin.rows() == 18);
        CHECK(thin.cols() == 2);
        CHECK((thin - img.middleCols(11, 2)).abs().maxCoeff() == 0.0);
    }
}

TEST_CASE("upsampling reproduces a linear picture exactly and keeps axes that have enough pixels") {
    // Pixel k of a ramp holds the picture's value at its centre, k + ½ (in pixel units).
    // The linear reconstruction of a ramp is the ramp itself between the first and last
    // centres, and constant beyond them; the new pixel is its mean over the pixel's area.
    const int W = 5, H = 4, w = 23, h = 9;
    ImageD ramp(H, W);
    for (int y = 0; y < H; ++y)
        for (int x = 0; x < W; ++x) ramp(y, x) = 2.0 * (x + 0.5) - 3.0 * (y + 0.5);
    const ImageD up = upsample_linear(ramp, w, h);
    REQUIRE(up.cols() == w);
    REQUIRE(up.rows() == h);
    // The mean over [a, b] of t clamped to [½, n − ½], integrated piecewise by hand.
    auto clamped_mean = [](double a, double b, int n) {
        const double lo = 0.5, hi = n - 0.5;
        auto integral = [&](double t) {  // ∫_0^t clamp(s) ds
            if (t <= lo) return lo * t;
            if (t <= hi) return lo * lo + 0.5 * (t * t - lo * lo);
            return lo * lo + 0.5 * (hi * hi - lo * lo) + hi * (t - hi);
        };
        return (integral(b) - integral(a)) / (b - a);
    };
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) {
            const double sx = double(W) / w, sy = double(H) / h;
            const double want = 2.0 * clamped_mean(x * sx, (x + 1) * sx, W) - 3.0 * clamped_mean(y * sy, (y + 1) * sy, H);
            CHECK(up(y, x) == doctest::Approx(want).epsilon(1e-12));
        }
    // Constants stay constant; an axis with at least as many pixels as asked is kept.
    const ImageD c = upsample_linear(ImageD::Constant(3, 7, 1.5), 20, 11);
    CHECK((c - 1.5).abs().maxCoeff() < 1e-12);
    const ImageD img = random_image(8, 3, 5);
    const ImageD tall = upsample_linear(img, 4, 6);
    REQUIRE(tall.cols() == 8);
    REQUIRE(tall.rows() == 6);
    CHECK((upsample_linear(img, 8, 3) - img).abs().maxCoeff() == 0.0);
    // Between two pixels the new ones step through the values in between, no blocks:
    // two pixels 0 and 1 brought up to 8 give a rising ramp from the first centre on.
    ImageD two(1, 2);
    two << 0.0, 1.0;
    const ImageD eight = upsample_linear(two, 8, 1);
    for (int x = 1; x < 8; ++x) CHECK(eight(0, x) >= eight(0, x - 1));
    CHECK(eight(0, 0) == 0.0);
    CHECK(eight(0, 7) == 1.0);
    CHECK(eight(0, 3) == doctest::Approx(0.375));  // cell [0.75, 1]: the line t − ½ has mean 0.375 there
}

TEST_CASE("make_target at another resolution is the area-resampled image scaled to N") {
    const ImageD img = random_image(40, 30, 9);
    const Fixed n = to_fixed(4321.0);
    const Target t = make_target(img, 17, 13, n);
    CHECK(sum_of(t.cells) == n);
    const ImageD r = resample_area(img, 17, 13);
    const double scale = double(n) / r.sum();
    for (int y = 0; y < 13; ++y)
        for (int x = 0; x < 17; ++x) CHECK(std::abs(double(t.cells[std::size_t(y) * 17 + x]) - r(y, x) * scale) < 1.0 + 1e-3);
}

// ------------------------------------------------------------------------- incremental image state

TEST_CASE("ImageState evaluate + apply equals reset on the modified histogram, bit for bit") {
    const int w = 23, h = 17;
    const Fixed n = to_fixed(8.0 * w * h);
    const Target t = make_target(random_image(w, h, 3), w, h, n);
    Histogram r = random_histogram(w, h, n / (w * h), 4);
    ImageState state(t);
    state.reset(r);

    SparseDelta delta;
    delta.resize(std::size_t(w) * h);
    ImageScratch scratch;
    CounterRng rng(77, 0);
    int twice = 0, applied = 0;
    for (int it = 0; it < 3000; ++it) {
        delta.clear();
        // A ray moving: take weight from some cells, give it to others, sometimes to a cell
        // that was just emptied (which lists it twice), sometimes back to where it was.
        const int moves = 1 + int(rng.below(6));
        for (int m = 0; m < moves; ++m) {
            const auto from = std::int64_t(rng.below(std::uint64_t(w * h)));
            const auto to = rng.uniform() < 0.3 ? from : std::int64_t(rng.below(std::uint64_t(w * h)));
            const Fixed amount = Fixed(rng.uniform(0.0, 3.0) * double(n / (w * h)));
            delta.add(from, -amount);
            delta.add(to, amount);
            if (rng.uniform() < 0.3) delta.add(from, Fixed(rng.below(1000)) - 500);
        }
        std::vector<int> count(std::size_t(w) * h, 0);
        for (auto c : delta.touched) ++count[std::size_t(c)];
        twice += int(std::count_if(count.begin(), count.end(), [](int c) { return c > 1; }));

        const ImageSums before = state.sums();
        const ImageSums after = state.evaluate(delta, scratch);
        REQUIRE(state.sums() == before);  // evaluate changes nothing

        Histogram modified = r;
        for (std::size_t k = 0; k < modified.cells.size(); ++k) modified.cells[k] += delta.value[k];
        ImageState fresh(t);
        fresh.reset(modified);
        REQUIRE(after == fresh.sums());

        if (rng.uniform() < 0.5) {
            state.apply(delta, after);
            r = modified;
            ++applied;
            REQUIRE(state.sums() == fresh.sums());
        }
    }
    CHECK(twice > 100);  // the duplicate-listing path was exercised
    CHECK(applied > 1000);
    ImageState fresh(t);
    fresh.reset(r);
    CHECK(state.sums() == fresh.sums());
    for (std::size_t k = 0; k < r.cells.size(); ++k) REQUIRE(state.difference(k) == fresh.difference(k));
}

TEST_CASE("a cell listed twice in SparseDelta::touched is counted once") {
    const int w = 4, h = 4;
    const Target t = make_target(ImageD::Ones(h, w), w, h, 1600);
    Histogram r(w, h);
    r.cells = t.cells;
    ImageState state(t);
    state.reset(r);

    SparseDelta d;
    d.resize(std::size_t(w) * h);
    d.add(5, 30);
    d.add(5, -30);  // back to zero
    d.add(5, 7);    // listed again
    d.add(10, -7);
    REQUIRE(std::count(d.touched.begin(), d.touched.end(), 5) == 2);
    ImageScratch scratch;
    const ImageSums s = state.evaluate(d, scratch);
    CHECK(s.l1 == 14);
    CHECK(s.on_receiver == 1600);
    state.apply(d, s);
    CHECK(state.difference(5) == 7);
    CHECK(state.difference(10) == -7);

    // Hand-built duplicates (touched written directly) behave the same.
    SparseDelta e;
    e.resize(std::size_t(w) * h);
    e.value[0] = 3;
    e.touched = {0, 0, 0};
    const ImageSums s2 = state.evaluate(e, scratch);
    CHECK(s2.l1 == 14 + 3);
    CHECK(s2.on_receiver == 1603);
    state.apply(e, s2);
    CHECK(state.difference(0) == 3);
}

// ------------------------------------------------------------------------- penalties

namespace {

// A term of the caller's own with a wider reach than the built-in ones: the squared
// height difference to the vertex two steps to the right, relative to the range.
struct ReachTwoTerm {
    std::string_view name() const { return "reach_two"; }
    int radius() const { return 2; }
    double cost(const HeightsView& h, int i, int j) const {
        if (i + 2 >= h.nx()) return 0.0;
        const double d = (double(h(i + 2, j)) - h(i, j)) / (double(h.h_max()) - h.h_min());
        return 3.0 * d * d;
    }
};

// A bumpy surface that touches both bounds, so every built-in term is non-zero.
Heightmap bumpy(int n) {
    Heightmap hm(n, n, {0.1, 0.1}, -0.002, 0.002);
    std::vector<float> h(std::size_t(n) * n);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
            h[std::size_t(j) * n + i] = float(0.0025 * std::sin(0.9 * i + 0.3) * std::cos(0.7 * j - 0.2));
    hm.set_heights(h);
    return hm;
}

// A random move: a kernel of random support anywhere (border included), or one vertex.
void random_move(const Heightmap& hm, CounterRng& rng, HeightOverlay& o) {
    const int ci = int(rng.below(std::uint64_t(hm.nx()))), cj = int(rng.below(std::uint64_t(hm.ny())));
    const float amp = float(rng.uniform(-1.0, 1.0) * 0.003);
    const int support = 1 + 2 * int(rng.below(4));
    const Kernel k(KernelShape{0.3 + support / 3.0, 0.3 + support / 4.0, rng.uniform(-0.5, 0.5), support});
    apply_kernel(hm, k, ci, cj, amp, o);
}

template <class Term>
void check_incremental_penalty(Term term, double weight) {
    Penalties p;
    p.add(term, weight);
    REQUIRE_FALSE(p.empty());
    Heightmap hm = bumpy(19);
    HeightOverlay o;
    CounterRng rng(5, 6);
    std::int64_t maintained = p.full(hm);
    int nonzero = 0;
    for (int it = 0; it < 400; ++it) {
        random_move(hm, rng, o);
        const std::int64_t before = p.full(hm);
        const std::int64_t d = p.delta(hm, o);
        REQUIRE(p.full(hm) == before);  // delta changes nothing
        nonzero += d != 0;
        if (rng.uniform() < 0.6) {
            o.commit(hm);
            REQUIRE(p.full(hm) == before + d);
            maintained += d;
        }
    }
    CHECK(maintained == p.full(hm));
    CHECK(nonzero > 100);  // the term really responds to the moves
}

}  // namespace

TEST_CASE("Penalties: full() after a committed overlay equals full() before + delta(), exactly") {
    SUBCASE("height bound") { check_incremental_penalty(HeightBoundTerm{0.2}, 1.5); }
    SUBCASE("concave valley") { check_incremental_penalty(ValleyTerm{175.0}, 40.0); }
    SUBCASE("smoothness") { check_incremental_penalty(SmoothnessTerm{}, 0.7); }
    SUBCASE("custom term of radius 2") { check_incremental_penalty(ReachTwoTerm{}, 2.0); }
    SUBCASE("all together") {
        Penalties p;
        p.add(HeightBoundTerm{}, 1.0);
        p.add(ValleyTerm{}, 3.0);
        p.add(SmoothnessTerm{}, 0.25);
        p.add(ReachTwoTerm{}, 1.0);
        CHECK(p.radius() == 2);
        CHECK(p.names() == std::vector<std::string>{"height_bound", "concave_valley", "smoothness", "reach_two"});
        Heightmap hm = bumpy(23);
        HeightOverlay o;
        CounterRng rng(8, 1);
        for (int it = 0; it < 300; ++it) {
            random_move(hm, rng, o);
            const std::int64_t before = p.full(hm), d = p.delta(hm, o);
            o.commit(hm);
            REQUIRE(p.full(hm) == before + d);
        }
    }
}

TEST_CASE("penalty values: hand-computed costs of the built-in terms") {
    const int n = 9;
    SUBCASE("height bound: 0 inside, 1 at the bounds, quadratic in the margin band") {
        Heightmap hm(n, n, {0.1, 0.1}, -0.01, 0.01);
        const HeightsView v(hm);
        const HeightBoundTerm t{0.1};  // band 0.002 at each end
        CHECK(t.cost(v, 3, 3) == 0.0);
        hm.set(3, 3, 0.01f);
        CHECK(t.cost(v, 3, 3) == doctest::Approx(1.0).epsilon(1e-5));
        hm.set(3, 3, -0.01f);
        CHECK(t.cost(v, 3, 3) == doctest::Approx(1.0).epsilon(1e-5));
        hm.set(3, 3, 0.009f);  // half-way into the top band
        CHECK(t.cost(v, 3, 3) == doctest::Approx(0.25).epsilon(1e-4));
        hm.set(3, 3, 0.0079f);  // just inside the free range
        CHECK(t.cost(v, 3, 3) == 0.0);

        // Mean weighted cost per vertex: one vertex at the bound out of n^2, weight 2.
        Penalties p;
        p.add(HeightBoundTerm{0.1}, 2.0);
        Heightmap one(n, n, {0.1, 0.1}, -0.01, 0.01);
        one.set(4, 4, 0.01f);
        CHECK(Penalties::value(p.full(one), one) == doctest::Approx(2.0 / (n * n)).epsilon(1e-6));
    }
    SUBCASE("valley: zero on planes and ridges, squared angle shortfall in a V") {
        Heightmap hm(n, n, {0.08, 0.08}, -0.03, 0.03);  // spacing 0.01
        const ValleyTerm t{170.0};
        // A tilted plane: no valley anywhere.
        std::vector<float> h(std::size_t(n) * n);
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) h[std::size_t(j) * n + i] = float(0.0005 * i - 0.0003 * j);
        hm.set_heights(h);
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) CHECK(t.cost(HeightsView(hm), i, j) == 0.0);
        // A V along u with slopes -s and +s (s = 0.5): the angle is pi - 2 atan(s).
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) h[std::size_t(j) * n + i] = float(0.005 * std::abs(i - 4));
        hm.set_heights(h);
        const double angle = pi - 2 * std::atan(0.5);
        const double short_by = degrees_to_radians(170.0) - angle;
        CHECK(t.cost(HeightsView(hm), 4, 4) == doctest::Approx(short_by * short_by).epsilon(1e-5));
        CHECK(t.cost(HeightsView(hm), 2, 4) == 0.0);  // straight flank
        // The same shape upside down is a ridge: no cost.
        for (auto& x : h) x = -x;
        hm.set_heights(h);
        CHECK(t.cost(HeightsView(hm), 4, 4) == 0.0);
    }
    SUBCASE("smoothness: zero on a plane, (Laplacian / range)^2 on a bump, zero at the border") {
        Heightmap hm(n, n, {0.1, 0.1}, -0.01, 0.01);
        std::vector<float> h(std::size_t(n) * n);
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) h[std::size_t(j) * n + i] = float(0.0004 * i + 0.0002 * j - 0.001);
        hm.set_heights(h);
        for (int j = 0; j < n; ++j)
            for (int i = 0; i < n; ++i) CHECK(SmoothnessTerm{}.cost(HeightsView(hm), i, j) == doctest::Approx(0.0).epsilon(1e-10));
        Heightmap bump(n, n, {0.1, 0.1}, -0.01, 0.01);
        bump.set(4, 4, 0.002f);
        const double lap = -4 * 0.002 / 0.02;
        CHECK(SmoothnessTerm{}.cost(HeightsView(bump), 4, 4) == doctest::Approx(lap * lap).epsilon(1e-6));
        CHECK(SmoothnessTerm{}.cost(HeightsView(bump), 3, 4) == doctest::Approx(0.01).epsilon(1e-6));
        bump.set(0, 4, 0.002f);
        CHECK(SmoothnessTerm{}.cost(HeightsView(bump), 0, 4) == 0.0);
    }
}

TEST_CASE("an invalid penalty weight throws InputError naming the term") {
    const double bad[] = {-1.0, -1e-300, std::numeric_limits<double>::quiet_NaN(),
                          std::numeric_limits<double>::infinity()};
    for (double w : bad) {
        CAPTURE(w);
        Penalties p;
        CHECK_THROWS_WITH_AS(p.add(HeightBoundTerm{}, w), doctest::Contains("height_bound"), InputError);
        CHECK_THROWS_WITH_AS(p.add(ValleyTerm{}, w), doctest::Contains("concave_valley"), InputError);
        CHECK_THROWS_WITH_AS(p.add(SmoothnessTerm{}, w), doctest::Contains("smoothness"), InputError);
        CHECK_THROWS_WITH_AS(p.add(ReachTwoTerm{}, w), doctest::Contains("reach_two"), InputError);
        CHECK(p.empty());
    }
    // A zero weight is valid and adds nothing.
    Penalties p;
    p.add(SmoothnessTerm{}, 0.0);
    CHECK(p.empty());
    CHECK(p.full(bumpy(7)) == 0);
}
