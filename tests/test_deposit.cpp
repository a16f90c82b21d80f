// Receiver deposits (core/deposit.hpp) and the cell-mean measure (design/cell_means.hpp):
// what each deposit can see, checked against independent computations.
#include <doctest/doctest.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include <freeform/design/cell_means.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

ReceiverView receiver_view(int w, int h, Deposit d) {
    ReceiverView v;
    v.width = w;
    v.height = h;
    v.deposit = d;
    return v;
}

std::vector<Fixed> deposit_points(const ReceiverView& rv, const std::vector<std::pair<float, float>>& points, Fixed w) {
    std::vector<Fixed> cells(std::size_t(rv.width) * rv.height, 0);
    for (const auto& [x, y] : points)
        deposit(rv, x, y, w, [&](std::int64_t c, Fixed a) { cells[std::size_t(c)] += a; });
    return cells;
}

// Points on a fine regular grid with twice the density in even receiver columns: an
// irradiance that alternates from cell to cell along x (and is uniform along y).
std::vector<std::pair<float, float>> alternating_columns(int w, int h, int per_cell) {
    std::vector<std::pair<float, float>> pts;
    for (int x = 0; x < w; ++x) {
        const int n = x % 2 == 0 ? 2 * per_cell : per_cell;
        for (int y = 0; y < h; ++y)
            for (int i = 0; i < n; ++i)
                for (int j = 0; j < per_cell; ++j)
                    pts.emplace_back(float(x + (i + 0.5) / n), float(y + (j + 0.5) / per_cell));
    }
    return pts;
}

double l1_to_uniform_interior(const std::vector<Fixed>& cells, int w, int h) {
    // Cells away from the receiver's edges, against their own mean.
    double sum = 0, mean = 0;
    int n = 0;
    for (int y = 2; y < h - 2; ++y)
        for (int x = 2; x < w - 2; ++x) mean += double(cells[std::size_t(y) * w + x]), ++n;
    mean /= n;
    for (int y = 2; y < h - 2; ++y)
        for (int x = 2; x < w - 2; ++x) sum += std::abs(double(cells[std::size_t(y) * w + x]) - mean);
    return sum / (2.0 * mean * n);
}

}  // namespace

TEST_CASE("every deposit keeps a ray's weight exactly, at the edges too") {
    const Fixed w = to_fixed(1.2345);
    for (const Deposit d : {Deposit::nearest, Deposit::bilinear, Deposit::fine_bilinear}) {
        const ReceiverView rv = receiver_view(7, 5, d);
        for (float x : {0.0f, 0.1f, 0.24f, 0.26f, 0.39f, 0.41f, 0.5f, 0.6f, 0.74f, 0.76f, 3.0f, 3.999f, 6.9f, 6.999f})
            for (float y : {0.0f, 0.2f, 2.5f, 2.8f, 4.99f}) {
                Fixed sum = 0;
                deposit(rv, x, y, w, [&](std::int64_t c, Fixed a) {
                    CHECK(c >= 0);
                    CHECK(c < 35);
                    sum += a;
                });
                CHECK(sum == w);
            }
    }
}

TEST_CASE("fine_bilinear is bilinear on a grid k times finer, summed into cells") {
    // The independent computation: a receiver k times the resolution with the plain
    // bilinear deposit, each k x k block of its cells added up. Landing points on a grid of
    // 1/1024 cell keep k·x exact in float, so both sides see the same point.
    for (const int k : {fine_deposit_factor, fine_deposit_factor_blurred}) {
        CAPTURE(k);
        const int w = 6, h = 4;
        ReceiverView coarse = receiver_view(w, h, Deposit::fine_bilinear);
        coarse.fine_factor = float(k);
        const ReceiverView fine = receiver_view(k * w, k * h, Deposit::bilinear);
        const Fixed weight = to_fixed(1.0);
        CounterRng rng(7, 0);
        for (int n = 0; n < 2000; ++n) {
            const float x = float(std::floor(rng.uniform() * w * 1024) / 1024);
            const float y = float(std::floor(rng.uniform() * h * 1024) / 1024);
            const std::vector<Fixed> a = deposit_points(coarse, {{x, y}}, weight);
            const std::vector<Fixed> fine_cells = deposit_points(fine, {{float(k) * x, float(k) * y}}, weight);
            for (int cy = 0; cy < h; ++cy)
                for (int cx = 0; cx < w; ++cx) {
                    Fixed b = 0;
                    for (int dy = 0; dy < k; ++dy)
                        for (int dx = 0; dx < k; ++dx) b += fine_cells[std::size_t(k * cy + dy) * k * w + k * cx + dx];
                    // Both round shares to fixed point; they agree to a few units of 2^-32.
                    CHECK(std::abs(a[std::size_t(cy) * w + cx] - b) <= 4);
                }
        }
    }
}

TEST_CASE("fine_bilinear keeps a ray whole in its cell unless it lands within 1/(2k) of an edge") {
    const double r = 0.5 / fine_deposit_factor;
    const ReceiverView rv = receiver_view(8, 8, Deposit::fine_bilinear);
    CHECK(rv.fine_factor == float(fine_deposit_factor));
    const Fixed weight = to_fixed(1.0);
    const auto right_share = [&](float x) {  // the share of cell (4, 4) for a point in row 4
        return double(deposit_points(rv, {{x, 4.5f}}, weight)[4 * 8 + 4]) / double(weight);
    };
    CHECK(right_share(float(3.5)) == 0.0);
    CHECK(right_share(float(4.0 - 1.01 * r)) == 0.0);
    CHECK(right_share(4.0f) == doctest::Approx(0.5).epsilon(1e-6));
    CHECK(right_share(float(4.0 - 0.5 * r)) == doctest::Approx(0.25).epsilon(1e-5));
    CHECK(right_share(float(4.0 + 1.01 * r)) == 1.0);
}

TEST_CASE("the wide ramp only where the light source blurs an image point over a cell") {
    // basic_scene: the receiver 0.5 m from the surface; its cells, and the blur each
    // source makes there, computed here from the geometry.
    Scene s = basic_scene(100);
    const double cell = s.receiver.size.x / s.receiver.width;
    const auto factor = [&](const LightShape& shape) {
        s.light.shape = shape;
        const PathParams pp = make_path_params(s);
        CHECK(pp.receiver.fine_factor == float(fine_deposit_factor_for(s, s.receiver)));
        return fine_deposit_factor_for(s, s.receiver);
    };
    CHECK(factor(CollimatedLight{}) == fine_deposit_factor);
    CHECK(factor(PointLight{}) == fine_deposit_factor);
    // A distant source whose disc smears a point over 0.9 and 1.1 cells at 0.5 m.
    const auto sun = [&](double cells) {
        CollimatedLight c;
        c.angular_radius = std::atan(cells * cell / 0.5) * 180.0 / pi;
        return c;
    };
    CHECK(factor(sun(0.9)) == fine_deposit_factor);
    CHECK(factor(sun(1.1)) == fine_deposit_factor_blurred);
    CHECK(source_blur_cells(s, s.receiver) == doctest::Approx(1.1));
    // A disc 0.3 m from the surface: radius R smears over R · 0.5 / 0.3.
    DiskLight disk;
    disk.center = {0, 0, 0.3};
    disk.radius = 0.5 * cell * 0.3 / 0.5;
    CHECK(factor(disk) == fine_deposit_factor);
    disk.radius = 2 * cell * 0.3 / 0.5;
    CHECK(factor(disk) == fine_deposit_factor_blurred);
    // A coarser receiver (a design's first level) sees the same blur in fewer cells.
    s.light.shape = sun(1.5);
    Receiver coarse = s.receiver;
    coarse.width = coarse.height = 50;
    CHECK(source_blur_cells(s, coarse) == doctest::Approx(0.75));
    CHECK(fine_deposit_factor_for(s, coarse) == fine_deposit_factor);
}

TEST_CASE("light that alternates from cell to cell: how much of its contrast each deposit keeps") {
    // Light spread evenly inside each cell, twice as much in even columns. A ray's share
    // of its neighbour, averaged over its cell, is what the deposit blurs: bilinear gives
    // 1/8 to each neighbour (a cell keeps 3/4), so it keeps half the alternation
    // (3/4 − 2 · 1/8); fine_bilinear's ramp of 1/(2k) either side of an edge gives
    // 1/(8k) (keeps 1 − 1/(4k)), so 1 − 1/(2k) of the alternation: 9/10 at k = 5, 3/4 at
    // k = 2; nearest all. (At finer scales bilinear's tent loses more: its response is
    // sinc²(f) against the cell mean's sinc(f), fine_bilinear's sinc(f) · sinc(f/k).)
    // Points spaced 1/(4k) of a cell (or half that) sample each ramp at its midpoints, so
    // the sums are exact.
    for (const int k : {fine_deposit_factor, fine_deposit_factor_blurred}) {
        CAPTURE(k);
        const int w = 24, h = 6;
        const auto pts = alternating_columns(w, h, 4 * k);
        const Fixed weight = to_fixed(1.0);
        const auto error = [&](Deposit d) {
            ReceiverView rv = receiver_view(w, h, d);
            rv.fine_factor = float(k);
            return l1_to_uniform_interior(deposit_points(rv, pts, weight), w, h);
        };
        // Cell means: columns of 2 and 1 parts, mean 1.5: |0.5| / (2 · 1.5) = 1/6.
        CHECK(error(Deposit::nearest) == doctest::Approx(1.0 / 6.0).epsilon(1e-6));
        CHECK(error(Deposit::bilinear) == doctest::Approx(0.5 / 6.0).epsilon(1e-4));
        CHECK(error(Deposit::fine_bilinear) == doctest::Approx((1.0 - 0.5 / k) / 6.0).epsilon(1e-4));
    }
}

TEST_CASE("cell means: the error converges as rays double, and is the nearest-deposit error") {
    // A flat mirror under collimated light throws a uniform square on the receiver; the
    // target is that square, so the cell-mean error is only what finite rays leave.
    Scene s = basic_scene(40, 16);
    const Heightmap hm = surface_for(s, 21);
    ImageD target = ImageD::Zero(40, 40);
    target.block(10, 10, 20, 20).setConstant(1.0);
    CellMeanOptions o;
    o.rays_per_cell = 16;
    o.tolerance = 0.002;
    int calls = 0;
    const auto trace = [&](const Scene& sc, const TraceSetup& batch, Histogram& h, TraceTotals& t) {
        const RaySet& rays = batch.rays;
        CHECK(sc.receiver.deposit == Deposit::nearest);
        CHECK(batch.params.receiver.deposit == Deposit::nearest);
        CHECK(rays.size() == ray_budget(sc.light, sc.receiver));
        ++calls;
        const Traced tr = trace_scene(sc, hm, rays);
        h = tr.histogram;
        t = tr.totals;
    };
    const CellMeans c = converged_cell_means(s, hm, &target, o, trace);
    CHECK(c.converged);
    CHECK(c.change_on_doubling < 0.002);
    CHECK(c.batches == calls);
    CHECK((c.batches & (c.batches - 1)) == 0);  // judged at 1, 2, 4, ... batches
    CHECK(c.rays_per_cell == doctest::Approx(16.0 * c.batches));
    CHECK(c.totals.energy() == doctest::Approx(1.0));
    CHECK(c.error < 0.02);
    // The same rays in one histogram give the same error (batches add exactly).
    Histogram all(40, 40);
    Fixed total = 0;
    Scene near = s;
    near.receiver.deposit = Deposit::nearest;
    near.light.rays_per_cell = 16;
    for (int b = 0; b < c.batches; ++b) {
        const RaySet rays = generate_rays(near.light, hm, near.receiver, hash_combine(o.seed, std::uint64_t(b) + 1));
        const Traced tr = trace_scene(near, hm, rays);
        for (std::size_t k = 0; k < all.cells.size(); ++k) all.cells[k] += tr.histogram.cells[k];
        total += rays.total;
    }
    CHECK(all == c.histogram);
    CHECK(l1_error(all, make_target(target, 40, 40, total)) == doctest::Approx(c.error));
}
