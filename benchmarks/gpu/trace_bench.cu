// GPU tracing benchmark (benchmarks/gpu/run.sh): the GPU height-field tracer against the
// CPU one on a scene's final mesh, its transport start as the surface.
//
//   trace_bench OUT.json [--repeats N] SCENE[@RESOLUTION] ...
//
// For each scene: a full trace (every ray traced and deposited, as a design's judgement
// and each level's rebuild do) on 2 CPU threads (the project's reference machine), on
// every CPU thread here, and on the GPU; and one move's retrace (the rays over a 5 × 5
// vertex patch, through the move's overlay), which the annealer does per proposal; and a
// window of 64 such moves (trace/window.hpp): one by one on the CPU as the annealer
// evaluates them, together on 2 CPU threads, their rays retraced in one GPU launch, and
// the whole window (selection, retrace, sums) on the GPU.
// The GPU's histogram, the move's records and the window's records must equal the CPU's
// bit for bit. Writes one JSON object per scene into OUT.json and a table on standard
// output.
//
// Exit status: 0 done, 1 a mismatch or an error, 2 bad arguments. Without a CUDA device
// the CPU figures are still written, with "gpu": null.
#include <charconv>
#include <chrono>
#include <cstdio>
#include <exception>
#include <fstream>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <freeform/cuda.hpp>

#include "trace_bench.hpp"

namespace {

using namespace freeform;
using namespace freeform::gpu_bench;
using clock_type = std::chrono::steady_clock;

double since(clock_type::time_point t0) { return std::chrono::duration<double>(clock_type::now() - t0).count(); }

struct GpuTiming {
    double full_seconds = 0, move_seconds = 0, upload_seconds = 0, window_seconds = 0;
    bool same_histogram = false, same_move = false, same_window = false;
    // The whole window on the device (cuda::DeviceWindowEvaluation): selection to sums,
    // and the copy of the state it reads (the index and the records, after a commit).
    double device_window_seconds = 0, state_seconds = 0, commit_seconds = 0;
    bool same_device_window = false, device_commit_fits = false;
};

// The whole window on the device, timed, its pairs and changes compared with the host's;
// and the commit of the window's first move on the device, timed.
void time_device_window(const BenchCase& c, const cuda::DeviceHeightfieldTracer& gpu, const WindowTiming& window,
                        int repeats, GpuTiming& g) {
    cuda::DeviceWindowEvaluation dw;
    std::vector<double> state, windows, commits;
    for (int r = 0; r < std::max(repeats, 20); ++r) {
        const auto t1 = clock_type::now();
        dw.upload_state(window.slotted, window.maintained);
        state.push_back(since(t1));
        const auto t2 = clock_type::now();
        dw.evaluate(exec::cuda, gpu, c.window, window.patches, window.slot_proposal, window.pad);
        windows.push_back(since(t2));
    }
    std::vector<std::int32_t> proposals, rays;
    dw.download_pairs(proposals, rays);
    g.same_device_window =
        proposals == window.slotted_proposals && rays == window.slotted_rays && dw.size() == window.changes.size();
    for (std::size_t p = 0; g.same_device_window && p < dw.size(); ++p) {
        const WindowChange &a = dw.change(p), &b = window.changes[p];
        g.same_device_window = a.cells == b.cells && a.values == b.values && a.status_delta == b.status_delta &&
                               a.rays_moved == b.rays_moved;
    }
    for (int r = 0; r < std::max(repeats, 20); ++r) {
        dw.upload_state(window.slotted, window.maintained);
        const auto t1 = clock_type::now();
        g.device_commit_fits =
            dw.commit(exec::cuda, window.commit_rays, window.commit_records, window.commit_begin, window.commit_cells);
        commits.push_back(since(t1));
    }
    g.device_window_seconds = median(windows);
    g.state_seconds = median(state);
    g.commit_seconds = median(commits);
}

GpuTiming time_gpu(const BenchCase& c, const CpuTiming& cpu, const WindowTiming& window, int repeats) {
    GpuTiming g;
    const auto t0 = clock_type::now();
    cuda::DeviceHeightfieldTracer gpu(c.surface, c.rays, c.params);
    g.upload_seconds = since(t0);
    std::vector<double> full, move;
    Histogram h(c.scene.receiver.width, c.scene.receiver.height);
    TraceTotals totals;
    gpu.trace_all(exec::cuda, h, totals);  // warm-up
    for (int r = 0; r < repeats; ++r) {
        Histogram hr(c.scene.receiver.width, c.scene.receiver.height);
        const auto t1 = clock_type::now();
        gpu.trace_all(exec::cuda, hr, totals);
        full.push_back(since(t1));
        h = std::move(hr);
    }
    g.same_histogram = h.cells == cpu.histogram.cells;
    std::vector<RayRecord> records(c.move_rays.size());
    gpu.trace(exec::cuda, c.move_rays, records, c.move);  // warm-up
    for (int r = 0; r < std::max(repeats, 20); ++r) {
        const auto t1 = clock_type::now();
        gpu.trace(exec::cuda, c.move_rays, records, c.move);
        move.push_back(since(t1));
    }
    g.same_move = records == cpu.move_records;
    // The window's pairs in one launch (overlays, views and pairs uploaded, records back).
    std::vector<RayRecord> window_records(window.rays.size());
    std::vector<double> windows;
    gpu.trace_window(exec::cuda, c.window, window.proposals, window.rays, window_records);  // warm-up
    for (int r = 0; r < std::max(repeats, 20); ++r) {
        const auto t1 = clock_type::now();
        gpu.trace_window(exec::cuda, c.window, window.proposals, window.rays, window_records);
        windows.push_back(since(t1));
    }
    g.same_window = window_records == window.records;
    g.window_seconds = median(windows);
    time_device_window(c, gpu, window, repeats, g);
    g.full_seconds = median(full);
    g.move_seconds = median(move);
    return g;
}

// A whole number ≥ 1 from an argument, or nothing (the caller names the argument).
std::optional<int> positive(const std::string& text) {
    int v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc{} || end != text.data() + text.size() || v < 1) return std::nullopt;
    return v;
}

std::string number(double v) {
    char b[64];
    std::snprintf(b, sizeof b, "%.6g", v);
    return b;
}

}  // namespace

int main(int argc, char** argv) try {
    if (argc < 3) {
        std::fprintf(stderr, "usage: trace_bench OUT.json [--repeats N] SCENE[@RESOLUTION] ...\n");
        return 2;
    }
    const std::string out_path = argv[1];
    int repeats = 5;
    std::vector<std::pair<std::string, int>> scenes;
    for (int a = 2; a < argc; ++a) {
        const std::string arg = argv[a];
        if (arg == "--repeats") {
            const std::string value = a + 1 < argc ? argv[++a] : "";
            const auto n = positive(value);
            if (!n) {
                std::fprintf(stderr, "trace_bench: --repeats: expected a whole number >= 1, got \"%s\"\n",
                             value.c_str());
                return 2;
            }
            repeats = *n;
            continue;
        }
        const auto at = arg.rfind('@');
        const auto resolution = at == std::string::npos ? std::optional<int>(0) : positive(arg.substr(at + 1));
        if (!resolution) {
            std::fprintf(stderr, "trace_bench: %s: the resolution after '@' must be a whole number >= 1\n",
                         arg.c_str());
            return 2;
        }
        scenes.emplace_back(arg.substr(0, at), *resolution);
    }
    const int threads = std::max(1u, std::thread::hardware_concurrency());
    const bool device = cuda::device_count() > 0;
    std::printf("%s; %d CPU threads here\n", device ? "CUDA device found" : "no CUDA device: CPU figures only",
                threads);
    std::ofstream out(out_path);
    out << "[\n";
    int failures = 0;
    for (std::size_t k = 0; k < scenes.size(); ++k) {
        const BenchCase c = make_case(scenes[k].first, scenes[k].second, threads);
        const CpuTiming cpu2 = time_cpu(c, 2, repeats);
        const CpuTiming cpun = time_cpu(c, threads, repeats);
        const WindowTiming win = time_window_cpu(c, repeats);
        const double moves = double(c.window.size());
        const double rays = double(c.rays.size()), move_rays = double(c.move_rays.size());
        std::printf("%s: %.0f rays, a move retraces %.0f\n", c.name.c_str(), rays, move_rays);
        std::printf("  full trace: CPU 2 threads %.4f s, CPU %d threads %.4f s\n", cpu2.full_seconds, threads,
                    cpun.full_seconds);
        std::printf(
            "  window of %.0f moves (%zu rays): one by one %.0f moves/s (1 thread), together %.0f moves/s "
            "(2 threads: select %.2f ms, retrace %.2f ms, sum %.2f ms); changes %s\n",
            moves, win.rays.size(), moves / win.per_move_seconds, moves / win.window_seconds, 1e3 * win.select_seconds,
            1e3 * win.retrace_seconds, 1e3 * win.sum_seconds, win.same_changes ? "equal" : "DIFFER");
        std::printf("  kernel forms on 2 threads: select from the flat index %.2f ms, atomic sums %.2f ms (the index "
                    "flattened in %.2f ms); %s\n",
                    1e3 * win.flat_select_seconds, 1e3 * win.atomic_sum_seconds, 1e3 * win.flatten_seconds,
                    win.same_kernel_forms ? "equal to the host forms" : "DIFFER from the host forms");
        failures += !win.same_changes + !win.same_kernel_forms;
        out << " {\"scene\": \"" << scenes[k].first << "\", \"name\": \"" << c.name << "\", \"rays\": " << c.rays.size()
            << ", \"move_rays\": " << c.move_rays.size() << ", \"cpu2_full_s\": " << number(cpu2.full_seconds)
            << ", \"cpu_threads\": " << threads << ", \"cpu_full_s\": " << number(cpun.full_seconds)
            << ", \"cpu_move_s\": " << number(cpu2.move_seconds) << ", \"window_moves\": " << c.window.size()
            << ", \"window_rays\": " << win.rays.size()
            << ", \"cpu_window_one_by_one_s\": " << number(win.per_move_seconds)
            << ", \"cpu2_window_s\": " << number(win.window_seconds)
            << ", \"window_select_s\": " << number(win.select_seconds)
            << ", \"cpu2_window_retrace_s\": " << number(win.retrace_seconds)
            << ", \"window_sum_s\": " << number(win.sum_seconds)
            << ", \"cpu2_flat_select_s\": " << number(win.flat_select_seconds)
            << ", \"cpu2_atomic_sum_s\": " << number(win.atomic_sum_seconds)
            << ", \"flatten_s\": " << number(win.flatten_seconds)
            << ", \"window_same_kernel_forms\": " << (win.same_kernel_forms ? "true" : "false")
            << ", \"window_same_changes\": " << (win.same_changes ? "true" : "false") << ", \"gpu\": ";
        if (!device) {
            out << "null}";
        } else {
            const GpuTiming g = time_gpu(c, cpu2, win, repeats);
            std::printf("  full trace: GPU %.5f s (%.1fx 2 CPU threads), upload %.3f s; histogram %s\n", g.full_seconds,
                        cpu2.full_seconds / g.full_seconds, g.upload_seconds, g.same_histogram ? "equal" : "DIFFERS");
            std::printf("  one move: CPU 1 thread %.1f us, GPU %.1f us (a launch each); records %s\n",
                        1e6 * cpu2.move_seconds, 1e6 * g.move_seconds, g.same_move ? "equal" : "DIFFER");
            // A window on the GPU: the host's selection and sums around the device's retrace.
            const double gpu_window = win.select_seconds + g.window_seconds + win.sum_seconds;
            std::printf(
                "  window on the GPU: retrace %.2f ms (a launch), %.0f moves/s with the host's select and sum "
                "(%.1fx one by one on 1 CPU thread); records %s\n",
                1e3 * g.window_seconds, moves / gpu_window, win.per_move_seconds / gpu_window,
                g.same_window ? "equal" : "DIFFER");
            std::printf(
                "  window on the GPU, selection to sums: %.2f ms, %.0f moves/s (%.1fx one by one on 1 CPU thread); "
                "state upload %.2f ms, a commit %.3f ms%s; pairs and changes %s\n",
                1e3 * g.device_window_seconds, moves / g.device_window_seconds,
                win.per_move_seconds / g.device_window_seconds, 1e3 * g.state_seconds, 1e3 * g.commit_seconds,
                g.device_commit_fits ? "" : " (OUT OF ROOM)", g.same_device_window ? "equal" : "DIFFER");
            failures += !g.same_histogram + !g.same_move + !g.same_window + !g.same_device_window + !g.device_commit_fits;
            out << "{\"full_s\": " << number(g.full_seconds) << ", \"move_s\": " << number(g.move_seconds)
                << ", \"upload_s\": " << number(g.upload_seconds)
                << ", \"window_retrace_s\": " << number(g.window_seconds)
                << ", \"same_window\": " << (g.same_window ? "true" : "false")
                << ", \"device_window_s\": " << number(g.device_window_seconds)
                << ", \"state_upload_s\": " << number(g.state_seconds)
                << ", \"commit_s\": " << number(g.commit_seconds)
                << ", \"same_device_window\": " << (g.same_device_window ? "true" : "false")
                << ", \"same_histogram\": " << (g.same_histogram ? "true" : "false")
                << ", \"same_move\": " << (g.same_move ? "true" : "false") << "}}";
        }
        out << (k + 1 < scenes.size() ? ",\n" : "\n");
    }
    out << "]\n";
    return failures == 0 ? 0 : 1;
} catch (const std::exception& e) {
    std::fprintf(stderr, "trace_bench: %s\n", e.what());
    return 1;
}
