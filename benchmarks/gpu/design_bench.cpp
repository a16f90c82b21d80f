// A whole design on the GPU against the CPU (issue 34's goals; docs/cuda.md): the scene's
// design at a fixed iteration count on the CPU and with its windows on the device, their
// speeds and whether the heights are the same bit for bit; then, optionally, a timed design
// on each, the GPU with less time, and their errors.
//
//   design_bench OUT.json SCENE [--iterations N] [--threads T] [--gpu-seconds S --cpu-seconds S]
//
// The device is the command line's (apps/freeform/device/offer.hpp): built with
// device/cuda.cu (benchmarks/gpu/run.sh on a lent machine) it is the first CUDA device,
// built with device/none.cpp (CMake without CUDA) there is none and only the CPU runs.
// The CPU runs on T threads (default 2, the project's reference machine). The accuracy
// figure is the cell-mean error of the designed surface (the height field with its Phong
// patches, nearest deposit, traced to convergence: what every exported form is compared
// with, docs/measures.md); the exported part's error_physical needs Embree, which the
// lent machine does not have, so the export checks are skipped. Exit status 0 done, 1
// the designs differ or an error, 2 bad arguments.
#include <charconv>
#include <cstdio>
#include <cstring>
#include <exception>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include <freeform/design/pipeline.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/target.hpp>
#include <nlohmann/json.hpp>

#include "../../apps/freeform/device/offer.hpp"

using namespace freeform;
using json = nlohmann::json;

namespace {

struct Run {
    CompletedDesign design;
    json summary;  // what design_bench.json records of it
    double per_second() const { return summary["iterations_per_second"].get<double>(); }
    double error() const { return summary["error_cell_means"].get<double>(); }
};

// The speeds and errors of a finished design.
json summarise(const CompletedDesign& c, const ImageD& target) {
    const DesignResult& d = c.result;
    // All stages (the start and the checks left out), and the final level's alone: the
    // goal's "moves/s on the E's own final level".
    double seconds = 0, final_iterations = 0, final_seconds = 0;
    for (const StageReport& s : d.stages) {
        seconds += s.seconds;
        if (s.level == d.stages.back().level) final_iterations += double(s.iterations), final_seconds += s.seconds;
    }
    const CellMeans means =
        designed_cell_means(c.scene, d.surface, target, physical_cell_mean_options(c.options.seed), c.options.threads);
    return {{"device", d.device},
            {"final_level_iterations_per_second", final_seconds > 0 ? final_iterations / final_seconds : 0.0},
            {"iterations", d.iterations},
            {"seconds", d.seconds},
            {"anneal_seconds", seconds},
            {"iterations_per_second", seconds > 0 ? double(d.iterations) / seconds : 0.0},
            {"error_cell_means", means.error},
            {"error_fitted", c.fitted.error}};
}

Run run(const DesignJob& base, const ImageD& target, Device device, const std::optional<DeviceOffer>& offer,
        int threads, std::int64_t iterations, double seconds) {
    DesignJob job = base;
    job.options.device = device;
    job.options.threads = threads;
    job.options.max_iterations = iterations;
    if (seconds > 0) job.options.time_budget = seconds;
    DesignSetup setup;
    setup.export_checks = false;
    setup.cuda = offer;
    Run r{design(job, target, setup), {}};
    r.summary = summarise(r.design, target);
    return r;
}

std::optional<double> number_arg(const std::string& s) {
    double v = 0;
    const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
    if (ec != std::errc() || end != s.data() + s.size() || !(v > 0)) return std::nullopt;
    return v;
}

}  // namespace

int main(int argc, char** argv) try {
    if (argc < 3) {
        std::fprintf(stderr,
                     "usage: design_bench OUT.json SCENE [--iterations N] [--threads T] "
                     "[--gpu-seconds S --cpu-seconds S]\n");
        return 2;
    }
    const std::string out_path = argv[1], scene = argv[2];
    double iterations = 20000, threads = 2, gpu_seconds = 0, cpu_seconds = 0;
    for (int a = 3; a < argc; a += 2) {  // NAME VALUE pairs
        const std::string name = argv[a];
        double* target = name == "--iterations"    ? &iterations
                         : name == "--threads"     ? &threads
                         : name == "--gpu-seconds" ? &gpu_seconds
                         : name == "--cpu-seconds" ? &cpu_seconds
                                                   : nullptr;
        const std::optional<double> v = a + 1 < argc ? number_arg(argv[a + 1]) : std::nullopt;
        if (!target || !v) {
            std::fprintf(stderr, "design_bench: %s: unknown option or not a positive number\n", name.c_str());
            return 2;
        }
        *target = *v;
    }
    const DesignJob job = io::load_job(scene);
    const ImageD target = io::load_target_image(job.scene);
    const DeviceOffer offer = cli::cuda_offer();
    const bool device = offer.usable();
    std::printf("%s: %s\n", scene.c_str(),
                device ? ("CUDA device " + offer.name).c_str() : ("no device: " + offer.unavailable).c_str());
    json out = {{"scene", scene}, {"cpu_threads", int(threads)}, {"device", device ? json(offer.name) : json(nullptr)}};

    // Fixed iterations: the same design on both, and each one's speed.
    const auto n = std::int64_t(iterations);
    const Run cpu = run(job, target, Device::cpu, std::nullopt, int(threads), n, 0);
    std::printf("  %lld iterations: CPU (%d threads) %.0f it/s (final level %.0f), cell-mean error %.4f\n",
                (long long)n, int(threads), cpu.per_second(),
                cpu.summary["final_level_iterations_per_second"].get<double>(), cpu.error());
    out["fixed_iterations"] = {{"iterations", n}, {"cpu", cpu.summary}};
    bool same = true;
    if (device) {
        const Run gpu = run(job, target, Device::cuda, offer, int(threads), n, 0);
        const std::vector<float>&a = gpu.design.result.surface.heights(), &b = cpu.design.result.surface.heights();
        same = a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
        const double ratio = gpu.per_second() / cpu.per_second();
        std::printf(
            "  %lld iterations: GPU %.0f it/s (%.1fx the CPU; final level %.0f), cell-mean error %.4f; heights %s\n",
            (long long)n, gpu.per_second(), ratio, gpu.summary["final_level_iterations_per_second"].get<double>(),
            gpu.error(), same ? "equal" : "DIFFER");
        out["fixed_iterations"]["gpu"] = gpu.summary;
        out["fixed_iterations"]["speedup"] = ratio;
        out["fixed_iterations"]["same_heights"] = same;
    }

    // Timed: the GPU with its seconds, the CPU with its own (more, as the goal sets them).
    if (gpu_seconds > 0 && cpu_seconds > 0) {
        const Run cpu_timed = run(job, target, Device::cpu, std::nullopt, int(threads), 0, cpu_seconds);
        std::printf("  timed: CPU %.0f s, cell-mean error %.4f (%lld iterations)\n", cpu_seconds, cpu_timed.error(),
                    (long long)cpu_timed.design.result.iterations);
        out["timed"] = {{"cpu_seconds", cpu_seconds}, {"cpu", cpu_timed.summary}};
        if (device) {
            const Run gpu_timed = run(job, target, Device::cuda, offer, int(threads), 0, gpu_seconds);
            std::printf("  timed: GPU %.0f s, cell-mean error %.4f (%lld iterations)\n", gpu_seconds, gpu_timed.error(),
                        (long long)gpu_timed.design.result.iterations);
            out["timed"]["gpu_seconds"] = gpu_seconds;
            out["timed"]["gpu"] = gpu_timed.summary;
        }
    }
    std::ofstream(out_path) << out.dump(2) << "\n";
    return same ? 0 : 1;
} catch (const std::exception& e) {
    std::fprintf(stderr, "design_bench: %s\n", e.what());
    return 1;
}
