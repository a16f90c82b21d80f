// Incremental evaluation must agree with a full retrace bit for bit, whatever the moves.
#include <doctest/doctest.h>

#include <cmath>
#include <vector>

#include <freeform/trace/incremental.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

// A random smooth bump (or single-vertex spike) written into an overlay.
void random_bump(const Heightmap& hm, CounterRng& rng, HeightOverlay& o) {
    const int r = int(rng.below(4));  // radius 0..3 (0: one vertex)
    const int ci = int(rng.below(std::uint64_t(hm.nx()))), cj = int(rng.below(std::uint64_t(hm.ny())));
    const double amp = rng.uniform(-1, 1) * 0.4 * (hm.h_max() - hm.h_min());
    o.patch = Patch{ci - r, cj - r, ci + r, cj + r}.clipped(hm.nx(), hm.ny());
    o.heights.clear();
    for (int j = o.patch.j0; j <= o.patch.j1; ++j)
        for (int i = o.patch.i0; i <= o.patch.i1; ++i) {
            const double d2 = double((i - ci) * (i - ci) + (j - cj) * (j - cj));
            const double w = r == 0 ? 1.0 : std::exp(-d2 / (0.5 * r * r));
            o.heights.push_back(hm.clamp_height(float(hm(i, j) + amp * w)));
        }
    o.finish(hm);
}

struct Case {
    const char* name;
    Scene scene;
    int mesh;
};

std::vector<Case> cases() {
    std::vector<Case> out;
    {
        Scene s = basic_scene(40, 8);
        out.push_back({"collimated mirror, Phong", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.surface.phong_alpha = 0;
        s.receiver.deposit = Deposit::bilinear;
        out.push_back({"collimated mirror, flat hits, bilinear", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.light.shape = PointLight{{0.01, -0.02, 0.3}, {}, {}};
        s.receiver.deposit = Deposit::bilinear;
        out.push_back({"point light mirror", s, 25});
    }
    {
        Scene s = basic_scene(40, 8);
        s.surface.material = Lens{1.49, 0.01};
        s.receiver.frame = make_frame({0, 0, -0.4}, {0, 0, 1}, {0, 1, 0}, "receiver");
        out.push_back({"collimated lens", s, 25});
    }
    {
        // Grazing light (75 degrees): rays cross many cells inside the slab and
        // interreflect on the bumps.
        Scene s = basic_scene(40, 8);
        const double a = degrees_to_radians(75.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.1, -std::cos(a)}};
        s.receiver.frame = make_frame({0.3, 0, 0.3}, {-1, 0, -1}, {0, 1, 0}, "receiver");
        s.receiver.size = {0.4, 0.4};
        s.receiver.deposit = Deposit::bilinear;
        out.push_back({"grazing light", s, 31});
    }
    return out;
}

}  // namespace

TEST_CASE("incremental histogram equals a full retrace after thousands of mixed moves") {
    for (const Case& c : cases()) {
        CAPTURE(c.name);
        Heightmap hm = surface_for(c.scene, c.mesh);
        shape(hm, [](double u, double v) { return 0.001 * std::sin(80 * u) * std::cos(70 * v); });
        const RaySet rays = generate_rays(c.scene.light, hm, c.scene.receiver, 5);
        const PathParams pp = make_path_params(c.scene);
        IncrementalTrace inc(hm, rays, pp);
        Histogram hist = inc.rebuild(exec::seq);
        HeightOverlay o;
        TraceChange change;
        CounterRng rng(99, 0);
        int accepted = 0;
        std::int64_t moved = 0;
        for (int it = 0; it < 2500; ++it) {
            random_bump(hm, rng, o);
            inc.evaluate(o, change);
            if (rng.uniform() < 0.4) {
                o.commit(hm);
                inc.commit(change);
                for (auto cell : change.histogram.touched) (void)cell;
                // Apply the sparse delta (cells may be listed twice: add each once).
                std::vector<char> done(hist.cells.size(), 0);
                for (auto cell : change.histogram.touched)
                    if (!done[std::size_t(cell)]) {
                        done[std::size_t(cell)] = 1;
                        hist.cells[std::size_t(cell)] += change.histogram.value[std::size_t(cell)];
                    }
                ++accepted;
                moved += change.rays_moved;
            }
        }
        CHECK(accepted > 800);
        CHECK(moved > 1000);  // the moves really moved light
        const Traced full = trace_scene(c.scene, hm, rays);
        CHECK(hist == full.histogram);
        CHECK(inc.histogram() == full.histogram);
        // A rebuilt index and records agree with the maintained ones.
        IncrementalTrace fresh(hm, rays, pp);
        fresh.rebuild(exec::seq);
        CHECK(fresh.records() == inc.records());
        CHECK(fresh.weight_by_status() == inc.weight_by_status());
    }
}
