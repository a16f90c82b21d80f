// Uses an installed freeform: a flat mirror under collimated light sends every ray to
// the receiver, so the traced energy must be exactly 1 (fixed-point sums are exact),
// and the serial and OpenMP traces must agree bit for bit.
#include <cstdio>

#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/setup.hpp>

int main() {
    using namespace freeform;
    try {
        Scene scene;
        scene.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
        scene.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
        scene.receiver.width = 64;
        scene.receiver.height = 64;
        scene.light.shape = CollimatedLight{{0, 0, -1}};
        scene.light.rays_per_cell = 4;

        const SurfaceSpec& s = scene.surface;
        const Heightmap mirror(33, 33, s.size, s.h_min, s.h_max, s.frame, s.aperture);
        const RaySet rays = generate_rays(scene.light, mirror, scene.receiver, 1);
        const HeightfieldTracer tracer(mirror, rays, make_path_params(scene));

        Histogram parallel(scene.receiver.width, scene.receiver.height);
        TraceTotals parallel_totals;
        tracer.trace_all(exec::omp, parallel, parallel_totals);
        Histogram serial(scene.receiver.width, scene.receiver.height);
        TraceTotals serial_totals;
        tracer.trace_all(exec::seq, serial, serial_totals);

        const double energy = parallel_totals.energy();
        std::printf("rays %lld, energy %.17g\n", static_cast<long long>(rays.size()), energy);
        if (rays.size() == 0 || energy != 1.0 || parallel.total() != rays.total) {
            std::fprintf(stderr, "FAIL: a flat mirror must send all of the light to the receiver\n");
            return 1;
        }
        if (!(parallel == serial) || serial_totals.energy() != energy) {
            std::fprintf(stderr, "FAIL: serial and OpenMP traces differ\n");
            return 1;
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "FAIL: %s\n", e.what());
        return 1;
    }
    std::printf("consumer OK\n");
    return 0;
}
