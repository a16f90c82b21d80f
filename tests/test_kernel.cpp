// Gaussian kernel moves: shape of the weights, application to a height map as an
// overlay, exact round trips through commit and restore, and the multi-level sizes.
#include <doctest/doctest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <vector>

#include <freeform/propose.hpp>

using namespace freeform;

namespace {

struct Moments {
    double xx = 0, yy = 0, xy = 0, mass = 0;
};

Moments moments(const Kernel& k) {
    Moments m;
    const int r = k.radius();
    for (int dj = -r; dj <= r; ++dj)
        for (int di = -r; di <= r; ++di) {
            const double w = k.at(di, dj);
            m.mass += w;
            m.xx += w * di * di;
            m.yy += w * dj * dj;
            m.xy += w * di * dj;
        }
    m.xx /= m.mass, m.yy /= m.mass, m.xy /= m.mass;
    return m;
}

// A non-flat surface, so that moves and normals are exercised on real slopes.
Heightmap wavy(int n = 41, Aperture ap = Aperture::rect) {
    Heightmap hm(n, n, {0.1, 0.1}, -0.004, 0.004, Frame{}, ap);
    std::vector<float> h(std::size_t(n) * n);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
            h[std::size_t(j) * n + i] = float(0.002 * std::sin(0.37 * i + 0.1) * std::cos(0.23 * j - 0.4));
    hm.set_heights(h);
    return hm;
}

bool same_bits(float a, float b) { return std::bit_cast<std::uint32_t>(a) == std::bit_cast<std::uint32_t>(b); }
bool same_bits(Vec3 a, Vec3 b) { return same_bits(a.x, b.x) && same_bits(a.y, b.y) && same_bits(a.z, b.z); }

bool same_surface(const Heightmap& a, const Heightmap& b) {
    for (std::size_t k = 0; k < a.heights().size(); ++k)
        if (!same_bits(a.heights()[k], b.heights()[k]) || !same_bits(a.normals()[k], b.normals()[k])) return false;
    return true;
}

}  // namespace

TEST_CASE("an isotropic kernel peaks at 1 in the centre and is symmetric") {
    for (KernelEdge edge : {KernelEdge::taper, KernelEdge::truncate}) {
        const Kernel k({2.5, 2.5, 0.0, 13}, edge);
        CHECK(k.radius() == 6);
        CHECK(k.support() == 13);
        CHECK(k.weights().size() == 13u * 13u);
        CHECK(k.at(0, 0) == 1.0f);
        for (int dj = -6; dj <= 6; ++dj)
            for (int di = -6; di <= 6; ++di) {
                const float w = k.at(di, dj);
                CHECK(w >= 0.0f);
                CHECK(w <= 1.0f);
                CHECK(w == k.at(-di, dj));
                CHECK(w == k.at(di, -dj));
                CHECK(w == k.at(dj, di));
                if (di != 0 || dj != 0) CHECK(w < 1.0f);
                if (w != 0.0f) CHECK(w >= Kernel::cutoff);
            }
        // Weights fall off with distance along an axis.
        for (int d = 1; d <= 6; ++d) CHECK(k.at(d, 0) < k.at(d - 1, 0));
    }
}

TEST_CASE("a truncated kernel on a wide support has the requested covariance") {
    // Sampled at unit spacing, a Gaussian with σ >= 1.5 keeps its moments to well under 1 %.
    for (double rho : {-0.5, 0.0, 0.3}) {
        const KernelShape s{3.0, 1.5, rho, 41};
        const Moments m = moments(Kernel(s, KernelEdge::truncate));
        CHECK(m.xx == doctest::Approx(s.sigma_x * s.sigma_x).epsilon(0.01));
        CHECK(m.yy == doctest::Approx(s.sigma_y * s.sigma_y).epsilon(0.01));
        CHECK(m.xy == doctest::Approx(rho * s.sigma_x * s.sigma_y).epsilon(0.01).scale(1.0));
    }
}

TEST_CASE("kernel shapes: elongated along x for sigma_x > sigma_y, rotated with rho") {
    const Moments along_x = moments(Kernel({4.0, 2.0, 0.0, 15}));
    CHECK(along_x.xx > 1.5 * along_x.yy);
    CHECK(std::abs(along_x.xy) < 1e-9);
    const Moments along_y = moments(Kernel({2.0, 4.0, 0.0, 15}));
    CHECK(along_y.yy > 1.5 * along_y.xx);
    const Moments plus = moments(Kernel({3.0, 3.0, 0.6, 15}));
    const Moments minus = moments(Kernel({3.0, 3.0, -0.6, 15}));
    CHECK(plus.xy > 0.1 * plus.xx);
    CHECK(minus.xy < -0.1 * minus.xx);
    CHECK(plus.xy == doctest::Approx(-minus.xy));
    // ρ > 0 stretches along the i = j diagonal: more weight there than on the other one.
    const Kernel k({3.0, 3.0, 0.6, 15});
    CHECK(k.at(3, 3) > k.at(3, -3));
    CHECK(k.at(-3, -3) > k.at(-3, 3));
}

TEST_CASE("the taper takes the kernel smoothly to zero at the border of its support") {
    const KernelShape s{4.0, 4.0, 0.0, 15};  // σ = support/4: the truncated edge keeps a step
    const Kernel cut(s, KernelEdge::truncate), tapered(s, KernelEdge::taper);
    const int r = 7;
    CHECK(cut.at(r, 0) > 0.1f);
    CHECK(tapered.at(r, 0) < 0.02f);
    // The window is cos²(π d / (2(r+1))): at the border it is sin²(π / (2(r+1))).
    const double window = std::pow(std::sin(3.14159265358979 / (2 * (r + 1))), 2);
    CHECK(tapered.at(r, 0) == doctest::Approx(cut.at(r, 0) * window).epsilon(1e-5));
    CHECK(tapered.at(0, 0) == 1.0f);
}

TEST_CASE("zero rows trim the footprint of a narrow kernel") {
    const Kernel narrow({1.0, 1.0, 0.0, 21});
    CHECK(narrow.extent_i() < narrow.radius());
    CHECK(narrow.extent_j() == narrow.extent_i());
    CHECK(narrow.at(narrow.extent_i(), 0) > 0.0f);
    for (int d = narrow.extent_i() + 1; d <= narrow.radius(); ++d)
        for (int e = -narrow.radius(); e <= narrow.radius(); ++e) {
            CHECK(narrow.at(d, e) == 0.0f);
            CHECK(narrow.at(e, d) == 0.0f);
        }
    const Patch p = narrow.footprint(20, 30);
    CHECK(p.i0 == 20 - narrow.extent_i());
    CHECK(p.j1 == 30 + narrow.extent_j());
    // A wide, tapered kernel keeps its whole support.
    const Kernel wide({5.0, 5.0, 0.0, 21});
    CHECK(wide.extent_i() == wide.radius());
}

TEST_CASE("invalid kernel shapes throw InputError naming the field") {
    CHECK_THROWS_WITH_AS(Kernel({0.0, 1.0, 0.0, 5}), doctest::Contains("kernel.sigma_x"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({-1.0, 1.0, 0.0, 5}), doctest::Contains("kernel.sigma_x"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, std::nan(""), 0.0, 5}), doctest::Contains("kernel.sigma_y"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, HUGE_VAL, 0.0, 5}), doctest::Contains("kernel.sigma_y"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, 1.0, 5}), doctest::Contains("kernel.rho"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, -1.5, 5}), doctest::Contains("kernel.rho"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, std::nan(""), 5}), doctest::Contains("kernel.rho"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, 0.0, 4}), doctest::Contains("kernel.support"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, 0.0, 0}), doctest::Contains("kernel.support"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, 0.0, -3}), doctest::Contains("kernel.support"), InputError);
    CHECK_THROWS_WITH_AS(Kernel({1.0, 1.0, 0.0, 100001}), doctest::Contains("kernel.support"), InputError);
    CHECK_NOTHROW(Kernel({1.0, 1.0, 0.0, 1}));
}

TEST_CASE("the default kernel bank: valid, distinct shapes of one support") {
    for (int support : {3, 7, 13, 21}) {
        const auto bank = default_kernel_bank(support);
        CHECK(bank.size() == 7);
        int isotropic = 0, along_x = 0, along_y = 0, pos = 0, neg = 0;
        for (std::size_t a = 0; a < bank.size(); ++a) {
            const KernelShape& s = bank[a];
            CHECK(s.support == support);
            CHECK_NOTHROW(validate(s));
            isotropic += s.sigma_x == s.sigma_y && s.rho == 0;
            along_x += s.sigma_x > s.sigma_y;
            along_y += s.sigma_x < s.sigma_y;
            pos += s.rho > 0;
            neg += s.rho < 0;
            for (std::size_t b = 0; b < a; ++b)
                CHECK_FALSE((s.sigma_x == bank[b].sigma_x && s.sigma_y == bank[b].sigma_y && s.rho == bank[b].rho));
        }
        CHECK(isotropic == 3);
        CHECK(along_x == 1);
        CHECK(along_y == 1);
        CHECK(pos == 1);
        CHECK(neg == 1);
    }
    CHECK_THROWS_WITH_AS(default_kernel_bank(8), doctest::Contains("kernel.support"), InputError);
    CHECK_THROWS_WITH_AS(default_kernel_bank(1), doctest::Contains("kernel.support"), InputError);
}

TEST_CASE("kernel support levels decrease, stay odd and never go below 3") {
    CHECK(kernel_support_levels(101) == std::vector<int>{21, 13, 7});
    CHECK(kernel_support_levels(13) == std::vector<int>{5, 3});
    CHECK(kernel_support_levels(25) == std::vector<int>{5, 3});
    CHECK(kernel_support_levels(51) == std::vector<int>{11, 7, 5});
    CHECK(kernel_support_levels(5) == std::vector<int>{3});
    for (int n = 2; n <= 1200; ++n) {
        const auto levels = kernel_support_levels(n);
        REQUIRE(!levels.empty());
        for (std::size_t k = 0; k < levels.size(); ++k) {
            CHECK(levels[k] % 2 == 1);
            CHECK(levels[k] >= 3);
            if (k > 0) CHECK(levels[k] < levels[k - 1]);
        }
    }
    CHECK_THROWS_AS(kernel_support_levels(1), InputError);
}

TEST_CASE("apply_kernel: base + amplitude * weight over the footprint, surface untouched") {
    const Heightmap hm = wavy();
    const Heightmap before = hm;
    const Kernel k({2.0, 1.5, 0.3, 9});
    HeightOverlay o;
    const float a = 0.0007f;
    apply_kernel(hm, k, 20, 17, a, o);
    CHECK(o.patch.i0 == 16);
    CHECK(o.patch.i1 == 24);
    CHECK(o.patch.j0 == 13);
    CHECK(o.patch.j1 == 21);
    CHECK(o.heights.size() == 81u);
    CHECK(o.normal_patch.i0 == 15);
    CHECK(o.normal_patch.j1 == 22);
    std::size_t n = 0;
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i) {
            const float expect = std::clamp(hm(i, j) + a * k.at(i - 20, j - 17), hm.h_min(), hm.h_max());
            CHECK(same_bits(o.heights[n], expect));
            CHECK(same_bits(o.height(hm, i, j), expect));
            ++n;
        }
    CHECK(o.height(hm, 0, 0) == hm(0, 0));
    CHECK(max_abs_change(o, hm) == doctest::Approx(a).epsilon(1e-3));
    CHECK(same_surface(hm, before));
    // The same move twice gives the same overlay, bit for bit.
    HeightOverlay o2;
    apply_kernel(hm, k, 20, 17, a, o2);
    CHECK(o2.heights == o.heights);
    for (std::size_t m = 0; m < o.normals.size(); ++m) CHECK(same_bits(o.normals[m], o2.normals[m]));
}

TEST_CASE("apply_kernel keeps every height inside the bounds for huge amplitudes") {
    const Heightmap hm = wavy();
    HeightOverlay o;
    for (float a : {1.0f, -1.0f, 1e6f, -1e6f}) {
        apply_kernel(hm, Kernel({3.0, 3.0, 0.0, 11}), 10, 30, a, o);
        for (float h : o.heights) {
            CHECK(h >= hm.h_min());
            CHECK(h <= hm.h_max());
        }
        CHECK(o.heights[o.heights.size() / 2] == (a > 0 ? hm.h_max() : hm.h_min()));
        for (const Vec3& nrm : o.normals) {
            CHECK(std::isfinite(nrm.x));
            CHECK(std::abs(nrm.x * nrm.x + nrm.y * nrm.y + nrm.z * nrm.z - 1.0f) < 1e-5f);
        }
    }
}

TEST_CASE("a kernel at the border is clipped to the grid") {
    const Heightmap hm = wavy(21);
    const Kernel k({2.0, 2.0, 0.0, 9});
    HeightOverlay o;
    apply_kernel(hm, k, 0, 0, 0.001f, o);
    CHECK(o.patch.i0 == 0);
    CHECK(o.patch.j0 == 0);
    CHECK(o.patch.i1 == 4);
    CHECK(o.patch.j1 == 4);
    CHECK(o.heights.size() == 25u);
    CHECK(o.normal_patch.i1 == 5);
    CHECK(o.normals.size() == 36u);
    apply_kernel(hm, k, 20, 18, 0.001f, o);
    CHECK(o.patch.i0 == 16);
    CHECK(o.patch.i1 == 20);
    CHECK(o.patch.j0 == 14);
    CHECK(o.patch.j1 == 20);
    CHECK(o.heights.size() == 35u);
    // Weights still line up with the centre, not with the clipped patch.
    CHECK(o.height(hm, 20, 18) == hm.clamp_height(hm(20, 18) + 0.001f));
}

TEST_CASE("commit gives the overlay's heights and normals; restore gives back the surface bit for bit") {
    for (Aperture ap : {Aperture::rect, Aperture::ellipse}) {
        Heightmap hm = wavy(41, ap);
        const Heightmap original = hm;
        HeightOverlay o;
        apply_kernel(hm, Kernel({2.5, 1.5, -0.4, 11}), 3, 37, 0.003f, o);  // partly clipped, partly clamped
        const HeightSnapshot saved = hm.snapshot(o.patch);
        o.commit(hm);
        // The overlay predicted the committed surface exactly, normals included.
        for (int j = 0; j < hm.ny(); ++j)
            for (int i = 0; i < hm.nx(); ++i) CHECK(same_bits(hm(i, j), o.height(original, i, j)));
        std::size_t n = 0;
        for (int j = o.normal_patch.j0; j <= o.normal_patch.j1; ++j)
            for (int i = o.normal_patch.i0; i <= o.normal_patch.i1; ++i)
                CHECK(same_bits(o.normals[n++], hm.normals()[std::size_t(j) * hm.nx() + i]));
        // Nothing outside the normal patch moved.
        for (int j = 0; j < hm.ny(); ++j)
            for (int i = 0; i < hm.nx(); ++i) {
                const bool inside = i >= o.normal_patch.i0 && i <= o.normal_patch.i1 && j >= o.normal_patch.j0 &&
                                    j <= o.normal_patch.j1;
                if (!inside) CHECK(same_bits(hm.normals()[std::size_t(j) * hm.nx() + i],
                                             original.normals()[std::size_t(j) * hm.nx() + i]));
            }
        CHECK_FALSE(same_surface(hm, original));
        hm.restore(saved);
        CHECK(same_surface(hm, original));
    }
}

TEST_CASE("a sequence of committed moves matches the overlays, and restores unwind it") {
    Heightmap hm = wavy(31);
    const Heightmap original = hm;
    const auto bank = default_kernel_bank(7);
    std::vector<HeightSnapshot> undo;
    HeightOverlay o;
    CounterRng rng(7, 1);
    for (int step = 0; step < 40; ++step) {
        const Kernel k(bank[rng.below(bank.size())]);
        const int ci = int(rng.below(31)), cj = int(rng.below(31));
        apply_kernel(hm, k, ci, cj, float(rng.uniform(-0.003, 0.003)), o);
        undo.push_back(hm.snapshot(o.patch));
        Heightmap expect = hm;
        o.commit(hm);
        // Same normals as recomputing the whole surface from its heights.
        expect.set_heights(hm.heights());
        CHECK(same_surface(hm, expect));
    }
    while (!undo.empty()) {
        hm.restore(undo.back());
        undo.pop_back();
    }
    CHECK(same_surface(hm, original));
}

TEST_CASE("a warmed-up overlay is reused without reallocating") {
    const Heightmap hm = wavy();
    HeightOverlay o;
    const Kernel big({3.0, 3.0, 0.0, 13}), small({1.0, 1.0, 0.0, 5});
    apply_kernel(hm, big, 20, 20, 0.001f, o);
    const float* h = o.heights.data();
    const Vec3* nrm = o.normals.data();
    apply_kernel(hm, small, 5, 7, 0.001f, o);
    apply_kernel(hm, big, 0, 40, -0.001f, o);
    apply_kernel(hm, big, 22, 21, 0.002f, o);
    CHECK(o.heights.data() == h);
    CHECK(o.normals.data() == nrm);
}

TEST_CASE("single-vertex move: a 1 x 1 patch, clamped, same result as a delta kernel") {
    const Heightmap hm = wavy();
    HeightOverlay o;
    apply_single_vertex(hm, 12, 9, 0.0005f, o);
    CHECK(o.patch.i0 == 12);
    CHECK(o.patch.i1 == 12);
    CHECK(o.patch.j0 == 9);
    CHECK(o.patch.j1 == 9);
    CHECK(o.heights.size() == 1u);
    CHECK(o.normals.size() == 9u);
    CHECK(same_bits(o.heights[0], hm.clamp_height(hm(12, 9) + 0.0005f)));
    HeightOverlay delta;
    apply_kernel(hm, Kernel({1.0, 1.0, 0.0, 1}), 12, 9, 0.0005f, delta);
    CHECK(same_bits(delta.heights[0], o.heights[0]));
    apply_single_vertex(hm, 0, 40, 10.0f, o);
    CHECK(o.heights[0] == hm.h_max());
    CHECK(o.normals.size() == 4u);
    Heightmap moved = hm;
    o.commit(moved);
    CHECK(moved(0, 40) == hm.h_max());
    CHECK(same_bits(moved.normals()[std::size_t(39) * 41 + 1], o.normals[std::size_t(0) * 2 + 1]));
}
