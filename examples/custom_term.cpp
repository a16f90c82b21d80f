// A fabrication constraint of your own, added to the objective: keep the rim of a mirror
// flat, so that it can sit on a flat mounting frame.
//
//   build/release/bin/custom_term [ITERATIONS_PER_STAGE] [OUTPUT_DIR]   (4000, custom_term_out)
//
// Any type with name(), radius() and cost(heights, i, j) is a LocalHeightTerm
// (objective/penalty.hpp): the objective keeps the sum of its per-vertex costs exact
// under incremental moves, so a term needs no bookkeeping of its own.
//
// The designer (design/designer.hpp) builds its penalties from the scene's "optimise"
// block only, so this example drives one level of the design itself: a ReflectorProblem
// annealed by the generic annealer, one stage per kernel size, large to small. That is
// the layer below freeform::design(), shown here in full. The same level runs twice,
// without and with the term, and the program prints what the term changed.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdint>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include <freeform/anneal.hpp>
#include <freeform/design/problem.hpp>
#include <freeform/io.hpp>
#include <freeform/objective/target.hpp>
#include <freeform/scene/rays.hpp>
#include <freeform/scene/scene.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>

using namespace freeform;

namespace {

// Costs 1 for a rim vertex `tolerance` away from height 0 (the mounting plane), growing
// quadratically; interior vertices are free. It reads only its own vertex: radius 0.
struct FlatRimTerm {
    int width = 3;             // rim width in vertices
    double tolerance = 20e-6;  // metres
    std::string_view name() const { return "flat_rim"; }
    int radius() const { return 0; }
    double cost(const HeightsView& h, int i, int j) const {
        const bool rim = i < width || j < width || i >= h.nx() - width || j >= h.ny() - width;
        if (!rim) return 0.0;
        const double d = h(i, j) / tolerance;
        return d * d;
    }
};
static_assert(LocalHeightTerm<FlatRimTerm>, "FlatRimTerm must model LocalHeightTerm");

// Root-mean-square height of the rim, in micrometres: the term's job, measured directly.
double rim_rms_um(const Heightmap& hm, int width) {
    double sum = 0;
    int n = 0;
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i)
            if (i < width || j < width || i >= hm.nx() - width || j >= hm.ny() - width) {
                sum += double(hm(i, j)) * hm(i, j);
                ++n;
            }
    return 1e6 * std::sqrt(sum / n);
}

// The term's value on a surface (mean cost per vertex, weight 1), whatever run made it.
double term_value(const Heightmap& hm, const FlatRimTerm& term) {
    Penalties p;
    p.add(term, 1.0);
    return Penalties::value(p.full(hm), hm);
}

// An initial temperature at which a typical uphill move is accepted with probability
// `acceptance`, from a few trial moves that are evaluated but never applied (delta()
// changes nothing). design() does the same for each of its stages.
double calibrate(ReflectorProblem& problem, std::uint64_t seed, double acceptance) {
    ReflectorProblem::Move m;
    double sum = 0;
    int up = 0;
    for (int k = 0; k < 48; ++k) {
        CounterRng rng(seed, std::uint64_t(k));
        problem.propose(rng, 1.0, m);
        if (const double d = problem.delta(m); d > 0) sum += d, ++up;
    }
    return std::max(up > 0 ? sum / up : 1e-6, 1e-12) / -std::log(acceptance);
}

struct LevelResult {
    Heightmap surface;
    ObjectiveValue value;  // of the last stage, on the surface it ended with
    double seconds = 0;
};

// One level: every kernel size of the mesh, large to small, on one surface.
LevelResult design_level(const Scene& scene, const ImageD& target, const Penalties& penalties,
                         std::int64_t iterations_per_stage) {
    const SurfaceSpec& s = scene.surface;
    LevelResult out{Heightmap(s.nx, s.ny, s.size, s.h_min, s.h_max, s.frame, s.aperture), {}, 0};
    const RaySet rays = generate_rays(scene.light, out.surface, scene.receiver, scene.optimise.seed);
    const PathParams params = make_path_params(scene);
    const Receiver& rec = scene.receiver;
    // Height amplitude that tilts a kernel's steepest slope enough to move its reflected
    // light by one receiver cell: a mirror turns a slope change into twice the angle.
    const double cell = std::min(rec.size.x / rec.width, rec.size.y / rec.height);
    const double distance = length(rec.frame.origin - s.frame.origin);
    const double unit = cell * std::min(out.surface.du(), out.surface.dv()) / (2.0 * distance);

    const std::vector<int> supports = kernel_support_levels(std::max(s.nx, s.ny));
    for (std::size_t stage = 0; stage < supports.size(); ++stage) {
        ProposalSettings proposals;
        proposals.bank = default_kernel_bank(supports[stage]);
        const int arms = int(proposals.bank.size());
        // The problem anneals `out.surface` in place; its objective includes `penalties`.
        ReflectorProblem problem(out.surface, rays, params, make_target(target, rec.width, rec.height, rays.total),
                                 ObjectiveWeights{}, penalties, proposals, make_bandit("history", arms), unit, 1.0);
        const std::uint64_t seed = hash_combine(scene.optimise.seed, stage);
        const double t0 = calibrate(problem, seed, scene.optimise.initial_acceptance);
        problem.set_reference_temperature(t0);  // move amplitudes shrink as T falls below t0

        // The schedule design() would use, from the scene's optimise block.
        const OptimiseSpec& opt = scene.optimise;
        AnnealOptions o;
        o.seed = seed;
        o.initial_temperature = t0;
        o.cooling = opt.cooling;
        o.max_iterations = iterations_per_stage;  // an iteration cap: the same result on any machine
        o.iterations_per_temperature = std::max<std::int64_t>(1, iterations_per_stage / opt.temperature_steps);
        o.patience = std::max<std::int64_t>(100, std::int64_t(opt.patience_fraction * double(iterations_per_stage)));
        o.reheat_factor = opt.reheat_factor;
        o.speculative = 4;  // proposals judged at once: faster, and the same trajectory
        const AnnealResult r = anneal(problem, o);
        out.value = problem.value();
        out.seconds += r.seconds;
        std::printf("    kernel %2d: %6lld iterations, %5lld accepted, error %.4f, penalty %.4f\n", supports[stage],
                    static_cast<long long>(r.iterations), static_cast<long long>(r.accepted), out.value.error,
                    out.value.penalty);
    }
    return out;
}

void save(const std::filesystem::path& dir, const std::string& name, const LevelResult& r, const Scene& scene) {
    const Heightmap& hm = r.surface;
    ImageF heights(hm.ny(), hm.nx());  // h_min black, h_max white; image row 0 = +v edge
    for (int j = 0; j < hm.ny(); ++j)
        for (int i = 0; i < hm.nx(); ++i)
            heights(hm.ny() - 1 - j, i) = (hm(i, j) - hm.h_min()) / (hm.h_max() - hm.h_min());
    io::write_png(dir / (name + "-heights.png"), heights);
    // Trace the final surface once more for a picture of its light.
    const RaySet rays = generate_rays(scene.light, hm, scene.receiver, scene.optimise.seed);
    Histogram irradiance(scene.receiver.width, scene.receiver.height);
    TraceTotals totals;
    HeightfieldTracer(hm, rays, make_path_params(scene)).trace_all(exec::omp, irradiance, totals);
    io::write_png(dir / (name + "-irradiance.png"), io::tone_map(irradiance.to_image()));
}

}  // namespace

int main(int argc, char** argv) try {
    const std::int64_t iterations = argc > 1 ? std::atoll(argv[1]) : 4000;
    const std::filesystem::path out = argc > 2 ? argv[2] : "custom_term_out";
    if (iterations < 1) throw InputError("ITERATIONS_PER_STAGE: must be a positive integer");
    std::filesystem::create_directories(out);  // before the runs: fail early on a bad path

    // A 10 cm mirror, collimated light, a 20 cm screen 0.5 m away, letter T. The letter
    // fills the middle half of the screen, where a flat mirror sends the light, so that
    // one level from a flat start can draw it.
    Scene scene;
    scene.light.rays_per_cell = 4;
    scene.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    scene.surface.nx = scene.surface.ny = 51;
    scene.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    scene.receiver.width = scene.receiver.height = 100;
    const ImageD target = io::render_text("T", io::find_font("DejaVuSans-Bold"), 400, 400, 0.25).cast<double>();

    const FlatRimTerm rim;
    const double rim_weight = 0.05;  // how much image error a unit of the term's mean cost is worth
    Penalties none;
    Penalties with_rim;
    with_rim.add(rim, rim_weight);  // a weight of 0 would leave the term out

    const SurfaceSpec& s = scene.surface;
    const Heightmap flat(s.nx, s.ny, s.size, s.h_min, s.h_max, s.frame, s.aperture);
    std::printf("flat start: rim RMS %.1f um, term %.4f\n", rim_rms_um(flat, rim.width), term_value(flat, rim));
    std::printf("without the term:\n");
    const LevelResult a = design_level(scene, target, none, iterations);
    std::printf("with %s (weight %g):\n", std::string(rim.name()).c_str(), rim_weight);
    const LevelResult b = design_level(scene, target, with_rim, iterations);

    std::printf("\n%-18s %8s %8s %12s %10s %8s\n", "run", "error", "energy", "rim RMS um", "term", "seconds");
    for (const auto& [label, r] : {std::pair{"without the term", &a}, std::pair{"with the term", &b}})
        std::printf("%-18s %8.4f %8.4f %12.1f %10.4f %8.1f\n", label, r->value.error, r->value.energy,
                    rim_rms_um(r->surface, rim.width), term_value(r->surface, rim), r->seconds);

    save(out, "without", a, scene);
    save(out, "with", b, scene);
    std::printf("height and irradiance images in %s/\n", out.string().c_str());
    return 0;
} catch (const InputError& e) {
    std::fprintf(stderr, "custom_term: %s\n", e.what());
    return 2;
} catch (const std::exception& e) {  // e.g. the output directory cannot be created
    std::fprintf(stderr, "custom_term: %s\n", e.what());
    return 1;
}
