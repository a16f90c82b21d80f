// A fabrication constraint of your own, added to the objective: keep the rim of a mirror
// flat, so that it can sit on a flat mounting frame.
//
//   build/release/bin/custom_term [MAX_ITERATIONS] [OUTPUT_DIR]   (30000, custom_term_out)
//
// Any type with name(), radius() and cost(heights, i, j) is a LocalHeightTerm
// (objective/penalty.hpp): the objective keeps the sum of its per-vertex costs exact
// under incremental moves, so a term needs no bookkeeping of its own. Add it to the
// penalties the options ask for and give them to freeform::design() in its DesignSetup.
// The same design runs twice, without and with the term, and the program prints what
// the term changed.
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <string>
#include <string_view>

#include <freeform/design/pipeline.hpp>
#include <freeform/io.hpp>

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
    return std::sqrt(sum / n) * 1e6;
}

}  // namespace

int main(int argc, char** argv) {
    try {
        const long iterations = argc > 1 ? std::atol(argv[1]) : 30000;
        const std::filesystem::path out = argc > 2 ? argv[2] : "custom_term_out";
        // The docs/architecture.md §2 scene at 100 x 100 pixels, with a "T" to throw.
        Scene scene;
        scene.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
        scene.receiver.width = scene.receiver.height = 100;
        scene.surface.nx = scene.surface.ny = 51;
        // A flat start, so that the rim begins on the mounting plane (the transport start,
        // the default, is centred in the height bounds: its rim stands a millimetre off).
        scene.surface.initial_shape = InitialShape::flat;
        TargetSpec t;
        t.text = "T";
        t.margin = 0.15;
        scene.target = t;
        const ImageD target = io::load_target_image(scene);
        DesignOptions options;
        options.max_iterations = iterations;  // a fixed budget: the same result on any machine
        options.time_budget = 600;

        const FlatRimTerm rim;
        for (const bool with_term : {false, true}) {
            // The terms the options ask for, and the rim's added to them.
            Penalties penalties = default_penalties(options.penalties, scene.surface.tool_radius);
            if (with_term) penalties.add(rim, 0.05);
            DesignSetup setup;
            setup.penalties = penalties;
            const CompletedDesign d = design(DesignJob{scene, options}, target, setup);
            std::printf("%-17s error %.3f, energy %.3f, rim RMS height %6.1f um\n",
                        with_term ? "with flat_rim:" : "without the term:", d.fitted.error, d.fitted.totals.energy(),
                        rim_rms_um(d.result.surface, rim.width));
            io::write_png(out / (with_term ? "with_term.png" : "without_term.png"),
                          io::tone_map(d.fitted.histogram.to_image()));
        }
        std::printf("irradiance images in %s/\n", out.string().c_str());
        return 0;
    } catch (const InputError& e) {
        std::fprintf(stderr, "custom_term: %s\n", e.what());
        return 2;
    } catch (const std::exception& e) {
        std::fprintf(stderr, "custom_term: %s\n", e.what());
        return 1;
    }
}
