// The shortest path through the library: describe a scene in code (no JSON), design a
// mirror that throws the letter "A" onto a screen, and save what a user needs.
//
//   build/release/bin/minimal_api [OUTPUT_DIR]    (default: minimal_api_out)
//
// Writes heightmap.pfm (heights in metres), surface.obj (the part to mill: the exported
// facets) and irradiance.png, then prints the design's errors and energy.
#include <cstdio>
#include <exception>
#include <filesystem>

#include <freeform/design/pipeline.hpp>
#include <freeform/io.hpp>

int main(int argc, char** argv) try {
    using namespace freeform;
    const std::filesystem::path out = argc > 1 ? argv[1] : "minimal_api_out";
    std::filesystem::create_directories(out);  // before the design: fail early on a bad path

    // 1. The scene: light falling straight down on a 10 cm mirror at the origin, and a
    //    20 cm screen 0.5 m above it looking down (it does not block the light). A job
    //    is the scene and the design's options (a scene file's "optimise" block).
    DesignJob job;
    Scene& scene = job.scene;
    scene.light.shape = CollimatedLight{{0, 0, -1}};
    scene.light.rays_per_cell = 16;  // rays per receiver cell: fixes the noise per pixel
    scene.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    scene.surface.size = {0.1, 0.1};
    scene.surface.nx = scene.surface.ny = 51;  // final mesh; coarser levels derive from it
    scene.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    scene.receiver.size = {0.2, 0.2};
    scene.receiver.width = scene.receiver.height = 100;

    // 2. The target: the letter A (any grey image would do: relative irradiance, any
    //    resolution; only its shape matters, the designer scales it to the light that
    //    reaches the mirror).
    TargetSpec a;
    a.text = "A";
    scene.target = a;
    const ImageD target = io::load_target_image(scene);

    // 3. Design: the transport start, annealing, the part exported and judged. A time
    //    budget bounds the run; set max_iterations as well for a run that does not depend
    //    on the machine's speed.
    job.options.time_budget = 10;
    job.options.progress_every = 20000;
    DesignSetup setup;
    setup.callbacks.progress = [](const DesignProgress& p) {
        std::printf("level %d/%d (mesh %3d, %3d px) kernel %2d  iteration %6lld  error %.4f  energy %.4f\n",
                    p.level + 1, p.levels, p.mesh, p.resolution, p.kernel_support, static_cast<long long>(p.iteration),
                    p.error, p.energy);
        return false;  // true would stop the design (the best state so far is finished and returned)
    };
    const CompletedDesign d = design(job, target, setup);

    // 4. Save (heightmap.pfm: image row 0 is the +v edge, io/heightmap.hpp).
    io::write_heightmap(out / "heightmap.pfm", d.result.surface);
    io::write_obj(out / "surface.obj", d.exported.fabrication.mesh);
    io::write_png(out / "irradiance.png", io::tone_map(d.fitted.histogram.to_image()));
    std::printf("error %.4f, energy %.4f (error_physical %.4f) after %lld iterations in %.1f s; results in %s/\n",
                d.fitted.error, d.fitted.totals.energy(), d.error_physical().value_or(-1.0),
                static_cast<long long>(d.result.iterations), d.result.seconds, out.string().c_str());
    return 0;
} catch (const freeform::InputError& e) {  // bad input or a file problem (IoError)
    std::fprintf(stderr, "minimal_api: %s\n", e.what());
    return 2;
} catch (const std::exception& e) {  // e.g. the output directory cannot be created
    std::fprintf(stderr, "minimal_api: %s\n", e.what());
    return 1;
}
