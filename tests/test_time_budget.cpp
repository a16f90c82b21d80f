// The time budget's guard (design/designer.hpp, Designer::trace_affordable): a level is
// annealed only when the budget left affords building its trace. A budget the start has
// already used up must therefore leave every level out, and the result must still
// describe the surface it returns, at the final mesh, exactly as a fresh trace does.
// (How long designs take is measured in benchmarks/, never asserted here.)
#include <doctest/doctest.h>

#include <cmath>
#include <string>

#include <freeform/design/designer.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

TEST_CASE("a budget the start used up: no level is annealed, and the result describes the start at the final mesh") {
    Scene scene = basic_scene(32, 4);
    ImageD target = two_blocks(32, 32);
    DesignOptions o;
    o.time_budget = 1e-9;  // gone before the first level begins
    o.seed = 5;
    o.threads = 1;
    LevelPlan coarse, fine;
    coarse.mesh_x = coarse.mesh_y = 9;
    coarse.resolution_x = coarse.resolution_y = 16;
    coarse.kernel_supports = {5};
    coarse.iterations = 500;
    fine.mesh_x = fine.mesh_y = 17;
    fine.resolution_x = fine.resolution_y = 32;
    fine.kernel_supports = {5, 3};
    fine.iterations = 500;
    o.levels = {coarse, fine};
    Heightmap start = surface_for(scene, 17);
    shape(start, [](double u, double v) { return 0.05 * u * u - 0.03 * u * v; });
    const DesignResult r = design(scene, start, target, o, [](const DesignProgress&) { return false; });

    CHECK(r.iterations == 0);
    CHECK(r.stages.empty());
    CHECK(r.start.levels_planned == 2);
    CHECK(r.start.levels_used == 0);
    CHECK(r.start.plan.find("the 9 x 9 level and the 1 after it not annealed") != std::string::npos);
    CHECK(r.start.left_out.rfind("the 9 x 9 level and the 1 after it not annealed", 0) == 0);
    REQUIRE(r.surface.nx() == 17);
    REQUIRE(r.surface.ny() == 17);

    // The surface returned is the start (refined to the coarse level's mesh and back):
    // its irradiance and objective are those a fresh trace and a fresh problem give.
    const RaySet rays = generate_rays(scene.light, r.surface, scene.receiver, o.seed);
    CHECK(r.rays == rays.size());
    CHECK(r.irradiance == trace_scene(scene, r.surface, rays).histogram);
    Heightmap copy = r.surface;
    const Penalties penalties = default_penalties(o.penalties);
    const PathParams pp = make_path_params(scene);
    ProposalSettings ps;
    ps.bank = default_kernel_bank(5);
    SurfaceProblem fresh(copy, rays, pp, make_target(target, 32, 32, target_total(rays, pp)),
                         o.objective, penalties, ps,
                         make_bandit(BanditKind::uniform, int(ps.bank.size())), 1.0, 1.0);
    CHECK(r.value.total == fresh.value().total);
    CHECK(r.value.error == fresh.value().error);
    CHECK(r.held_out.total >= 0);  // judged on the final level's held-out rays as well
}

TEST_CASE("a stage that stops paying hands on its time: StageGainWatch") {
    using design_detail::StageGainWatch;
    // Off by default: never stalls, whatever it is fed.
    StageGainWatch off;
    for (int k = 0; k < 100; ++k) CHECK_FALSE(off.stalled(0.1 * k, 1.0));

    // A window of 1 s and a floor of 1 %, from t = 2 s.
    StageGainWatch w(1.0, 0.01, 2.0);
    double error = 0.05;
    double t = 2.0;
    // 2 % a second (0.2 % every 0.1 s): never stalls, also not within the first window.
    for (; t < 6.0; t += 0.1) {
        CHECK_FALSE(w.stalled(t, error));
        error *= 0.998;
    }
    // Then no gain but noise (a rise is not a loss: the best is kept): the watch stalls
    // once the last window's gain falls under 1 % (from t = 6.5: five steps of 0.2 %),
    // and at the latest a window after the gain stopped.
    const double flat = error;
    bool stalled = false;
    double stalled_at = 0;
    for (int k = 0; !stalled && k < 40; ++k, t += 0.1) {
        const double e = k % 2 ? flat * 1.02 : flat * (1 - 0.0005 * (k / 2 % 10 == 0));
        stalled = w.stalled(t, e);
        stalled_at = t;
    }
    CHECK(stalled);
    CHECK(w.gave_up);
    CHECK(stalled_at > 6.45);
    CHECK(stalled_at < 7.05);

    // A slow but sufficient gain (1.5 % a window) does not stall.
    StageGainWatch slow(1.0, 0.01, 0.0);
    for (int k = 0; k < 100; ++k) CHECK_FALSE(slow.stalled(0.1 * k, 0.05 * std::pow(0.985, 0.1 * k)));
}
