// The `freeform` command line: render a scene, design its surface, or export a surface.
//
//   freeform render SCENE.json --out DIR [--heightmap H.pfm | --mesh M.obj [--material refractive:N] [--mesh-normals]]
//                   [--tracer T] [--threads N]
//   freeform design SCENE.json --out DIR [--seed N] [--time-budget S] [--threads N] [--device D] [--quiet]
//   freeform export SCENE.json --heightmap H.pfm --format step|sag|stl|obj --out FILE [--no-check]
//
// Built with MPI (CMake finds it) the same source also makes `freeform_mpi`: run under
// `mpirun -np N freeform_mpi design ...` it designs by replica exchange, one replica per
// rank (mpi::design, freeform/mpi/design.hpp); rank 0 alone prints and writes the outputs.
// The plain `freeform` never needs an MPI runtime.
//
// Bad input (a scene key, a file, an option) prints one line on stderr and exits with 2;
// all input is read and checked before any output file is written.
#include <unistd.h>

#include <array>
#include <atomic>
#include <cctype>
#include <charconv>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iostream>
#include <limits>
#include <optional>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <freeform/freeform.hpp>
#include <freeform/io/forms.hpp>
#include <freeform/io/outputs.hpp>
#include <freeform/io/scene_json.hpp>

#include "device/offer.hpp"
#if defined(FREEFORM_WITH_MPI)
#include <cstdlib>

#include <freeform/mpi/design.hpp>
#endif

namespace fs = std::filesystem;
using namespace freeform;
using json = nlohmann::json;

namespace {

constexpr const char* version = "0.1.0";

// Set by SIGINT; the design loop polls it and stops at the next iteration.
std::atomic<bool> interrupted{false};
extern "C" void on_sigint(int) { interrupted.store(true); }

bool stderr_is_terminal() { return ::isatty(2) == 1; }

// This process's rank and the number of ranks (0 and 1 without MPI).
int world_rank = 0;
int world_size = 1;

// One self-overwriting status line on a terminal, at most ten updates a second.
class StatusLine {
public:
    explicit StatusLine(bool enabled) : enabled_(enabled && stderr_is_terminal()) {}
    ~StatusLine() { finish(); }
    void show(const std::string& text, bool force = false) {
        if (!enabled_) return;
        const auto now = std::chrono::steady_clock::now();
        if (!force && now - last_ < std::chrono::milliseconds(100)) return;
        last_ = now;
        std::fprintf(stderr, "\r\033[K%s", text.c_str());
        std::fflush(stderr);
        shown_ = true;
    }
    void finish() {
        if (shown_) std::fprintf(stderr, "\n");
        shown_ = false;
    }

private:
    bool enabled_;
    bool shown_ = false;
    std::chrono::steady_clock::time_point last_{};
};

std::string bar(double fraction, int width = 30) {
    const int filled = int(std::clamp(fraction, 0.0, 1.0) * width + 0.5);
    return "[" + std::string(std::size_t(filled), '#') + std::string(std::size_t(width - filled), '.') + "]";
}

std::string fixed(double v, int digits) {
    std::ostringstream s;
    s.setf(std::ios::fixed);
    s.precision(digits);
    s << v;
    return s.str();
}

// The exported facets' k: "2", or "2.47" where a fractional k fills the triangle budget
// (design/fabrication.hpp).
std::string subdivisions_text(const Fabrication& fab) {
    return fab.whole() ? std::to_string(int(fab.subdivisions)) : fixed(fab.subdivisions, 2);
}

// --material: "refractive:IOR" makes --mesh a closed solid of that index (the whole
// lens), in place of the scene's surface and its material.
MeshMaterial parse_mesh_material(const std::string& s) {
    constexpr std::string_view prefix = "refractive:";
    const auto bad = [&](const std::string& why) {
        return InputError("--material: " + why + ", got '" + s + "' (expected refractive:IOR, e.g. refractive:1.49)");
    };
    if (s.rfind(prefix, 0) != 0) throw bad("unknown material");
    const std::string number = s.substr(prefix.size());
    double ior = 0;
    const auto [end, ec] = std::from_chars(number.data(), number.data() + number.size(), ior);
    if (number.empty() || ec != std::errc{} || end != number.data() + number.size())
        throw bad("the refractive index is not a number");
    if (!(ior > 1) || !std::isfinite(ior)) throw bad("the refractive index must be a finite number > 1");
    return MeshMaterial::refractive(ior);
}

TracerChoice parse_tracer(const std::string& s) {
    if (s.empty()) return TracerChoice::automatic;
    if (const std::optional<TracerChoice> t = enum_value(s, tracer_names)) return *t;
    throw InputError("--tracer: must be one of " + enum_list(tracer_names) + "; got '" + s + "'");
}

// A byte count with an optional unit (K/M/G/T with or without "iB"/"B": powers of 1024),
// or a plain count; npos when the text is neither.
std::optional<double> parse_amount(std::string text, bool bytes) {
    double scale = 1;
    if (bytes) {
        for (const char* suffix : {"iB", "B"})
            if (text.size() > std::strlen(suffix) && text.ends_with(suffix)) {
                text.resize(text.size() - std::strlen(suffix));
                break;
            }
        if (!text.empty()) {
            const std::string units = "KMGT";
            if (const auto u = units.find(char(std::toupper(static_cast<unsigned char>(text.back()))));
                u != std::string::npos) {
                scale = std::pow(1024.0, double(u + 1));
                text.pop_back();
            }
        }
    }
    double value = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
    if (text.empty() || ec != std::errc{} || end != text.data() + text.size() || !std::isfinite(value) ||
        !(value >= 1) || value * scale > 9.0e18)
        return std::nullopt;
    return value * scale;
}

// --limit NAME=VALUE (repeatable): raises or lowers one of the Limits (docs/limits.md).
Limits parse_limits(const std::vector<std::string>& settings) {
    Limits limits;
    for (const std::string& setting : settings) {
        const std::size_t eq = setting.find('=');
        const std::string name = setting.substr(0, eq);
        const auto bad = [&](const std::string& why) {
            return InputError("--limit " + setting + ": " + why +
                              " (names: json_depth, scene_file_bytes, data_file_bytes, pixels, triangles, "
                              "memory_bytes; sizes take K/M/G/T suffixes, e.g. memory_bytes=32GiB)");
        };
        if (eq == std::string::npos) throw bad("expected NAME=VALUE");
        const bool bytes = name.ends_with("_bytes");
        const std::optional<double> value = parse_amount(setting.substr(eq + 1), bytes);
        if (!value) throw bad("the value must be a whole number >= 1");
        const auto whole = std::uint64_t(*value);
        if (name == "json_depth")
            limits.json_depth = int(std::min<std::uint64_t>(whole, 1u << 20));
        else if (name == "scene_file_bytes")
            limits.scene_file_bytes = whole;
        else if (name == "data_file_bytes")
            limits.data_file_bytes = whole;
        else if (name == "pixels")
            limits.pixels = whole;
        else if (name == "triangles")
            limits.triangles = whole;
        else if (name == "memory_bytes")
            limits.memory_bytes = whole;
        else
            throw bad("unknown limit '" + name + "'");
    }
    return limits;
}

constexpr bool mpi_built =
#if defined(FREEFORM_WITH_MPI)
    true;
#else
    false;
#endif

// Refuses an output directory that cannot be created or written before any work is done,
// so that a long design never fails at its end (nothing is created here), and one where
// an output file's name is taken by a folder.
void check_output_dir(const fs::path& out, std::initializer_list<const char*> names) {
    std::error_code ec;
    if (fs::exists(out, ec) && !fs::is_directory(out, ec))
        throw InputError("--out: " + out.string() + " exists and is not a directory");
    fs::path p = fs::absolute(out, ec);
    while (!p.empty() && !fs::exists(p, ec)) {
        if (p == p.parent_path()) break;
        p = p.parent_path();
    }
    if (!fs::is_directory(p, ec))
        throw InputError("--out: cannot create " + out.string() + " (" + p.string() + " is not a directory)");
    if (::access(p.c_str(), W_OK) != 0)
        throw InputError("--out: cannot create " + out.string() + " (" + p.string() + " is not writable)");
    for (const char* name : names)
        if (fs::is_directory(out / name, ec))
            throw InputError("--out: " + (out / name).string() + " is a folder, where an output file would go");
}

constexpr std::initializer_list<const char*> render_outputs = {"irradiance.pfm", "irradiance.png", "comparison.png",
                                                              "metrics.json"};
constexpr std::initializer_list<const char*> design_outputs = {
    "metrics.json",   "convergence.csv", "heightmap.pfm", "irradiance.pfm", "irradiance.png",
    "target.png",     "comparison.png",  "surface.obj",   "surface.stl",    "surface.step", "surface.dat"};

// ---------------------------------------------------------------------------- render

struct RenderArgs {
    fs::path scene, out, heightmap, mesh;
    std::string tracer;
    std::string material;
    int threads = 0;
    std::optional<std::int64_t> seed;
    bool mesh_normals = false;
    std::vector<std::string> limits;  // --limit NAME=VALUE
};

// A render's files: irradiance.pfm is the render with the scene's deposit and rays; the
// PNGs show cell means where a target asked for them (docs/measures.md).
void write_render_outputs(const fs::path& out, const json& m, const Histogram& render,
                          const std::optional<CellMeans>& cells, const Receiver& receiver) {
    const ImageD irradiance = render.to_image();
    const ImageD shown = io::shown_square(cells ? cells->histogram.to_image() : irradiance, receiver);
    io::StagedOutput staged(out);
    staged.write("irradiance.pfm", [&](const fs::path& f) { io::write_pfm(f, irradiance.cast<float>()); });
    staged.write("irradiance.png", [&](const fs::path& f) { io::write_png(f, io::tone_map(shown)); });
    if (cells)
        staged.write("comparison.png", [&](const fs::path& f) {
            io::write_png(f,
                          io::comparison_image(shown, io::shown_square(io::target_image_of(cells->target), receiver)));
        });
    staged.write("metrics.json", [&](const fs::path& f) { io::write_json(f, m); });
    staged.commit("metrics.json");
}

// The line that says a picture was stretched by more than 1% to fill the receiver, empty
// when it was not (docs/scene.md, target.fit).
std::string target_stretch_text(const Scene& scene, const io::LoadedTarget& t) {
    if (!(t.stretch > 1.01)) return {};
    return "target: the picture (" + std::to_string(t.picture_width) + " x " + std::to_string(t.picture_height) +
           " pixels) is stretched " + fixed(t.stretch, 2) + " times to fill the receiver (" +
           fixed(scene.receiver.size.x, 3) + " x " + fixed(scene.receiver.size.y, 3) +
           " m); target.fit \"contain\" keeps its shape with dark bars, \"cover\" crops it";
}

// What `freeform render` traces, read from the files the arguments name: the scene, the
// surface (a heightmap, or the scene's start; the grid that places the rays when a mesh
// replaces it), the meshes, and the target.
RenderRequest render_request(const RenderArgs& a, const Limits& limits) {
    RenderRequest job;
    DesignJob scene_file = io::load_job(a.scene, limits);
    if (a.seed) scene_file.options.seed = std::uint64_t(*a.seed);
    job.scene = scene_file.scene;
    job.options = scene_file.options;
    Scene& scene = job.scene;
    check_output_dir(a.out, render_outputs);
    job.threads = thread_count(exec::omp_t{a.threads});
    check_resources(scene_file, RunKind::render, job.threads, limits);
    if (!a.heightmap.empty() && !a.mesh.empty())
        throw InputError("--heightmap and --mesh are alternatives: give one of them");
    if (!a.material.empty()) {
        if (a.mesh.empty()) throw InputError("--material: applies to the mesh of --mesh, and none was given");
        job.mesh_material = parse_mesh_material(a.material);
    }
    job.tracer = a.tracer.empty() ? scene.trace.tracer : parse_tracer(a.tracer);
    choose_tracer(scene, !a.mesh.empty(), job.tracer, embree_available);  // refuses before any reading
    if (a.mesh_normals && a.mesh.empty() && scene.meshes.empty())
        throw InputError("--mesh-normals: the scene has no mesh to shade (give --mesh or meshes[])");
    if (scene.target) {
        const io::LoadedTarget target = io::load_target(scene, limits);
        if (const std::string note = target_stretch_text(scene, target); !note.empty())
            std::fprintf(stderr, "freeform: warning: %s\n", note.c_str());
        job.target = target.image;
    }
    if (!a.heightmap.empty()) {
        try {
            job.surface = io::read_heightmap(scene, a.heightmap, limits);
        } catch (const InputError& e) {
            throw InputError(std::string("--heightmap: ") + e.what());
        }
    } else {
        job.surface = io::scene_surface(scene_file, limits);
        job.surface_is_scene_start = true;
    }
    // A solid is one surface: corners repeated per face (OBJ with face normals, STL) are
    // merged before its edges are matched.
    if (!a.mesh.empty()) {
        job.mesh = io::read_mesh(a.mesh, limits);
        job.mesh_name = a.mesh.string();
        if (job.mesh_material) job.mesh = io::welded(*job.mesh);
    }
    for (const auto& m : scene.meshes) {
        job.scene_meshes.push_back(io::read_mesh(m.file, limits));
        if (m.material.is_refractive()) job.scene_meshes.back() = io::welded(job.scene_meshes.back());
    }
    job.mesh_normals = a.mesh_normals;
    return job;
}

// metrics.json of a render (io::render_metrics_json) with the command and the scene's path.
json render_metrics(const RenderArgs& a, bool mesh, const std::optional<MeshMaterial>& mesh_material,
                    const RenderResult& r) {
    json m = io::render_metrics_json(r, mesh, mesh_material, a.mesh_normals);
    m["command"] = "render";
    m["scene"] = a.scene.string();
    return m;
}

int run_render(const RenderArgs& a) {
    // Under mpirun every rank would render the same: rank 0 does it alone.
    if (world_rank != 0) return 0;
    const Limits limits = parse_limits(a.limits);
    RenderRequest job = render_request(a, limits);
    StatusLine status(true);
    const auto t0 = std::chrono::steady_clock::now();
    RenderCallbacks callbacks;
    callbacks.progress = [&](std::int64_t traced, std::int64_t total) {
        if (std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() > 1.0)
            status.show("tracing " + bar(double(traced) / double(total)) + " " + std::to_string(traced) + "/" +
                        std::to_string(total) + " rays");
    };
    callbacks.phase = [&](const std::string& what) { status.show(what); };
    const bool mesh = job.mesh.has_value();
    const std::optional<MeshMaterial> mesh_material = job.mesh_material;
    const RenderResult r = render(std::move(job), callbacks);
    status.finish();
    const json m = render_metrics(a, mesh, mesh_material, r);
    write_render_outputs(a.out, m, r.histogram, r.cells, r.scene.receiver);
    std::printf("rendered %s with the %s tracer (%s)\n", a.scene.string().c_str(),
                std::string(to_string(r.decision.tracer)).c_str(), r.decision.reason.c_str());
    if (r.cells)
        std::printf("  error_physical %.4f, energy %.4f: cell means, nearest deposit, %.0f rays per cell\n",
                    r.cells->error, r.cells->totals.energy(), r.cells->rays_per_cell);
    std::printf("  %lld rays, energy on the receiver %.4f%s, %.3f s (%.1f M rays/s)\n", (long long)r.rays,
                r.totals.energy(), r.error ? (", error " + fixed(*r.error, 4)).c_str() : "", r.seconds,
                m["rays_per_second"].get<double>() / 1e6);
    if (r.start)
        std::printf("  traced the scene's start: %s (a flat surface: error %.4f)\n", to_string(r.start->used),
                    r.start->flat_error);
    std::printf("  results in %s/\n", a.out.string().c_str());
    return 0;
}

// ---------------------------------------------------------------------------- design


struct DesignArgs {
    fs::path scene, out;
    std::optional<std::int64_t> seed;
    std::optional<double> time_budget;
    std::optional<int> threads;
    std::optional<std::string> device;  // cpu, cuda or auto (optimise.device)
    bool quiet = false;
    bool start_only = false;
    std::string replica_mode = "domains";  // freeform_mpi only
    double ladder_ratio = 1.5;        // freeform_mpi only
    std::int64_t exchange_every = 0;  // freeform_mpi only; 0 = automatic
    double merge_coverage = 30;       // freeform_mpi only
    std::vector<std::string> limits;  // --limit NAME=VALUE
};

#if defined(FREEFORM_WITH_MPI)
// Test hook: FREEFORM_TEST_ABORT_RANK=k makes rank k die (std::abort) at its first
// progress report, to check that a dead rank ends the run without output files.
bool abort_requested_here() {
    const char* v = std::getenv("FREEFORM_TEST_ABORT_RANK");
    return v && *v && std::atoi(v) == world_rank;
}

// Rank 0 warns when a rank runs more threads than the cores mpirun bound it to.
void warn_of_overloaded_rank(const mpi::RankLayout& l) {
    const int r = l.overloaded_rank();
    if (r < 0) return;
    const int threads = l.threads[std::size_t(r)], cores = l.cores[std::size_t(r)];
    std::fprintf(stderr,
                 "freeform: warning: rank %d runs %d threads on the %d core(s) mpirun bound it to; give each "
                 "rank its cores (mpirun --map-by slot:PE=%d, or --bind-to none) or use --threads %d\n",
                 r, threads, cores, threads, cores);
}
#endif

// One form's figure for the summary: "0.0358" and how it was traced.
std::string form_figure(const json& forms, const std::string& name) {
    if (!forms.contains(name) || forms[name]["error_physical"].is_null()) return "not traced";
    return fixed(forms[name]["error_physical"].get<double>(), 4);
}

// The summary's lines on the exported forms, the scene's first format leading.
void print_forms(const CompletedDesign& d, const json& m) {
    const json& exported = m["export"];
    const json& forms = exported["forms"];
    const Fabrication& fab = d.exported.fabrication;
    const std::optional<CellMeans>& cells = d.exported.cells;
    bool first = true;
    for (const json& f : exported["formats"]) {
        const std::string name = f.get<std::string>();
        std::printf("  %s ", first ? "error_physical" : "        also:");
        if (name == "mesh" && cells) {
            std::printf("%.4f, energy %.4f: surface.obj/.stl (%zu flat triangles) traced, %.0f rays per cell\n",
                        cells->error, cells->totals.energy(), fab.mesh.triangles.size(), cells->rays_per_cell);
        } else if (name == "mesh") {
            std::printf("not traced (a build without Embree): surface.obj/.stl, %zu triangles\n",
                        fab.mesh.triangles.size());
        } else {
            const json& fj = forms[name];
            std::printf("%s: %s (%.1f MB, valid: %s) read back and traced with its own normals\n",
                        form_figure(forms, name).c_str(), fj["file"].get<std::string>().c_str(),
                        double(fj["bytes"].get<std::uintmax_t>()) / 1e6, fj["valid"].get<std::string>().c_str());
        }
        first = false;
    }
    if (forms.contains("designed")) {
        // optimise.keep_better_start: the other surface's figure too.
        std::string other;
        if (d.delivered && d.delivered->start)
            other = ": the start, delivered because the annealed surface traced worse, " +
                    fixed(d.delivered->annealed_error, 4) + " (optimise.keep_better_start)";
        else if (d.delivered)
            other = "; its start " + fixed(d.delivered->start_error, 4);
        std::printf("  the designed surface itself (heightmap.pfm): %s%s\n", form_figure(forms, "designed").c_str(),
                    other.c_str());
    }
    if (!fab.tolerance_met)
        std::printf("  the facets miss their tolerance: %.3f mrad at the 90th percentile against %.3f mrad at "
                    "k = %s (%s); surface.step / surface.dat keep the designed surface\n",
                    fab.normal_error * 1e3, fab.normal_tolerance * 1e3, subdivisions_text(fab).c_str(),
                    what_stopped_k(fab).c_str());
}

// The summary a design prints (always, --quiet or not): error_physical first, then the
// diagnostics, the machining figures, the start and where the results are.
void print_design_summary(const CompletedDesign& d, const json& m, const fs::path& out, double writing_seconds,
                          const std::string& target_note) {
    const DesignResult& result = d.result;
    const double error = d.fitted.error, energy = d.fitted.totals.energy();
    const std::optional<double>& error_held_out = d.error_held_out;
    const std::optional<double>& error_exported = d.exported.error_exported;
    std::printf("%s after %lld iterations in %.1f s (%.0f it/s)%s\n", result.stopped_early ? "interrupted" : "done",
                (long long)result.iterations, result.seconds, m["iterations_per_second"].get<double>(),
                result.stopped_early ? " -- best result so far written" : "");
    // Where the time went: the budget bounds the design, its start included; the final
    // traces, the export checks and the writing of the files come after it.
    // The smooth forms are read back and traced while they are written (io/outputs.hpp):
    // that share of the writing is named.
    std::string checks;
    if (m.contains("export") && m["export"].contains("forms"))
        for (const auto& [name, form] : m["export"]["forms"].items())
            if (form.contains("check_seconds") && form.contains("file"))
                checks += std::string(checks.empty() ? " (" : ", ") + form["file"].get<std::string>() +
                          " read back and traced: " + fixed(form["check_seconds"].get<double>(), 1) + " s";
    if (!checks.empty()) checks += ")";
    const double budget = d.options.time_budget;
    std::printf("  time: %.1f s designing%s, then %.1f s for the final traces and the export checks, %.1f s writing "
                "the files%s\n",
                result.seconds,
                budget > 0 ? (" (time budget " + fixed(budget, 1) + " s, the start included)").c_str() : "",
                d.finish_seconds, writing_seconds, checks.c_str());
    if (!result.device_failure.empty())
        std::printf("  device: %s failed at %s; the CPU went on with the same design\n", result.device.c_str(),
                    result.device_failure.c_str());
    // A level the budget could not afford (design/designer.hpp, trace_affordable): say so.
    if (!result.start.left_out.empty()) std::printf("  time budget: %s\n", result.start.left_out.c_str());
    if (!target_note.empty()) std::printf("  %s\n", target_note.c_str());
    print_forms(d, m);
    std::printf("  diagnostics: fitted error %.4f, energy %.4f", error, energy);
    if (error_held_out) std::printf("; held-out rays %.4f", *error_held_out);
    if (error_exported) std::printf("; exported mesh with the design's rays %.4f", *error_exported);
    std::printf(" (docs/measures.md)\n");
    const json& fab_report = m["fabrication"];
    std::printf("  machining: smallest concave radius %s, steepest slope %.1f deg, sag %.2f mm%s\n",
                fab_report["min_concave_radius"].is_null()
                    ? "none (nothing concave from the cutter's side)"
                    : (fixed(fab_report["min_concave_radius"].get<double>() * 1e3, 1) + " mm").c_str(),
                fab_report["max_slope_degrees"].get<double>(), fab_report["sag"]["range"].get<double>() * 1e3,
                fab_report.contains("min_glass_thickness")
                    ? (", thinnest glass " + fixed(fab_report["min_glass_thickness"].get<double>() * 1e3, 2) + " mm")
                          .c_str()
                    : "");
    if (fab_report.contains("lens_rim") && fab_report["lens_rim"].get<double>() > 0)
        std::printf("  lens body: %.1f mm wider than the face on every side (surface.material.rim), so that the light "
                    "the face spreads leaves through the back face, not the side walls\n",
                    fab_report["lens_rim"].get<double>() * 1e3);
    const StartReport& st = result.start;
    std::printf("  start: %s%s%s", to_string(st.used),
                st.error >= 0 ? (", error " + fixed(st.error, 4)).c_str() : "",
                st.fallback_reason.empty() ? "" : (" (transport not used: " + st.fallback_reason + ")").c_str());
    if (st.used == StartKind::transport && st.transport.height_excess > 0)
        std::printf("; it needs %.1f mm of height range, surface.height_bounds allow %.1f mm, so it was clamped "
                    "(widen the bounds to keep the whole map)",
                    st.transport.height_range * 1e3,
                    (st.transport.height_range - st.transport.height_excess) * 1e3);
    if (st.used == StartKind::transport && st.target_offset && st.surface_weighted_error < st.plane_weighted_error)
        std::printf("; solved again for the target moved against where its first surface landed the light "
                    "(%.1f px from the map's goals on average; docs/architecture.md §4b)",
                    st.landing_offset);
    if (st.levels_planned > 0) std::printf("; %d of %d planned levels run", st.levels_used, st.levels_planned);
    std::printf("\n");
    std::string files;
    for (const json& f : m["export"]["files"]) files += ", " + f.get<std::string>();
    std::printf("  results in %s/ (metrics.json, comparison.png%s, heightmap.pfm)\n", out.string().c_str(),
                files.c_str());
}

#if defined(FREEFORM_WITH_MPI)
// The replica options of the command line (freeform_mpi only).
mpi::ReplicaOptions replica_options(const DesignArgs& a) {
    mpi::ReplicaOptions o;
    // The mode's name is read here, at the command line (the library takes the enum).
    if (const std::optional<mpi::ReplicaMode> mode = enum_value(a.replica_mode, mpi::replica_mode_names))
        o.mode = *mode;
    else
        throw InputError("--replica-mode: expected " + enum_list(mpi::replica_mode_names, "\"", " or ") +
                         ", got \"" + a.replica_mode + "\"");
    o.ladder_ratio = a.ladder_ratio;
    o.exchange_every = a.exchange_every;
    o.merge_coverage = a.merge_coverage;
    // CLI11's range checks let NaN through: name the option, not the library's field.
    if (!std::isfinite(a.ladder_ratio)) throw InputError("--ladder-ratio: must be a finite number >= 1, got nan");
    if (!std::isfinite(a.merge_coverage)) throw InputError("--merge-coverage: must be a finite number > 0, got nan");
    mpi::validate(o);
    return o;
}
#endif

// The job of a design run: the scene file with the command line's settings.
DesignJob design_job(const DesignArgs& a, const Limits& limits) {
    DesignJob job = io::load_job(a.scene, limits);
    DesignOptions& o = job.options;
    if (a.seed) o.seed = std::uint64_t(*a.seed);
    if (a.time_budget) {
        if (!(*a.time_budget > 0)) throw InputError("--time-budget: must be > 0 seconds");
        o.time_budget = *a.time_budget;
    }
    if (a.threads) o.threads = *a.threads;
    if (a.device) o.device = *enum_value(*a.device, device_names);  // CLI11 checked the name
    try {
        check_designable(job.scene);  // before any work (the target image is loaded next)
    } catch (const InputError& e) {
        throw InputError(a.scene.string() + ": " + e.what());
    }
    o.progress_every = 500;  // the live line's pace
    return job;
}

// What a design run shows while it works: its header line, the live status line (on a
// terminal, unless --quiet), and Ctrl-C. Under MPI rank 0 alone reports.
class DesignMonitor {
public:
    // `plan`: read here (its line is made now; the plan itself goes on to the design).
    // `device`: the name of the device the windows run on; empty: the CPU.
    DesignMonitor(const DesignArgs& a, const PlannedDesign& plan, const std::string& device)
        : header_line_(header_line(a, plan) + (device.empty() ? std::string() : ", on " + device)),
          quiet_(a.quiet || world_rank != 0),
          status_(!quiet_) {}

    bool quiet() const { return quiet_; }
    StatusLine& status() { return status_; }

    // The line that opens a design, once, when the design starts (its first phase).
    void header() {
        if (quiet_ || header_shown_) return;
        header_shown_ = true;
        std::printf("%s\n", header_line_.c_str());
    }

    // The phases and the live line; the progress callback stops the design after Ctrl-C.
    DesignCallbacks callbacks() {
        DesignCallbacks callbacks;
        callbacks.phase = [this](const std::string& what) {
            header();
            if (!quiet_) status_.show(what);
        };
        callbacks.progress = [this](const DesignProgress& p) {
            status_.show("level " + std::to_string(p.level + 1) + "/" + std::to_string(p.levels) + " kernel " +
                         std::to_string(p.kernel_support) + " | it " + std::to_string(p.iteration) + " | T " +
                         fixed(p.temperature * 1e6, 2) + "e-6 | error " + fixed(p.error, 4) + " | energy " +
                         fixed(p.energy, 3) + " | " + std::to_string(std::int64_t(p.iterations_per_second)) +
                         " it/s | " + fixed(p.time_left, 1) + " s left");
            return interrupted.load();
        };
        return callbacks;
    }

private:
    // The plan's scene has its rays per cell raised for the final mesh.
    static std::string header_line(const DesignArgs& a, const PlannedDesign& plan) {
        const Scene& s = plan.scene;
        const auto [nx, ny] = final_mesh(s, plan.levels);
        char line[512];
        std::snprintf(line, sizeof line, "%d x %d mesh, %d x %d receiver, %g rays per cell, %.0f s budget, seed %llu",
                      nx, ny, s.receiver.width, s.receiver.height, s.light.rays_per_cell, plan.options.time_budget,
                      (unsigned long long)plan.options.seed);
        return "designing " + a.scene.string() + ": " + line;
    }

    std::string header_line_;
    bool quiet_;
    StatusLine status_;
    bool header_shown_ = false;
};

// A design as this process sees it: the design (empty on MPI ranks other than 0, which
// write nothing) and, under MPI, metrics.json's "replicas" block.
struct DesignRun {
    std::optional<CompletedDesign> design;
    bool stopped_early = false;
    json replicas;  // null: no replicas ran
};

// The design itself: freeform::design, or mpi::design in freeform_mpi.
DesignRun design_run(const DesignArgs& a, PlannedDesign plan, const ImageD& target, DesignSetup setup,
                     DesignMonitor& monitor) {
#if defined(FREEFORM_WITH_MPI)
    mpi::ReplicaSetup replicas;
    if (!a.start_only) replicas.options = replica_options(a);
    replicas.layout = [&](const mpi::RankLayout& layout) {
        monitor.header();
        warn_of_overloaded_rank(layout);
    };
    if (abort_requested_here())
        setup.callbacks.progress = [](const DesignProgress&) -> bool {
            std::fprintf(stderr, "freeform: rank %d: dying on purpose (FREEFORM_TEST_ABORT_RANK)\n", world_rank);
            std::abort();
        };
    mpi::ReplicaDesign r = mpi::design(std::move(plan), target, setup, MPI_COMM_WORLD, replicas);
    return {std::move(r.design), r.stopped_early, r.replicas ? mpi::replicas_json(*r.replicas) : json()};
#else
    (void)a;
    (void)monitor;
    CompletedDesign d = design(std::move(plan), target, setup);
    const bool stopped_early = d.result.stopped_early;
    return {std::move(d), stopped_early, json()};
#endif
}

// metrics.json, the files, and the summary of a finished design.
void write_design(const DesignArgs& a, const CompletedDesign& d, const json& replicas, const io::LoadedTarget& target,
                  const std::vector<ExportFormat>& formats, DesignMonitor& monitor) {
    json m = io::design_metrics_json(d);
    m["command"] = "design";
    m["scene"] = a.scene.string();
    m["target_fit"] = io::target_fit_json(d.scene, target);
    if (!replicas.is_null()) m["replicas"] = replicas;
    // Keep catching Ctrl-C until the results are written: a second one must not leave
    // half-written files (each file is written atomically, but the set should be whole).
    StatusLine& status = monitor.status();
    if (!monitor.quiet()) status.show("writing the results");
    const auto writing = std::chrono::steady_clock::now();
    io::write_design_outputs(a.out, m, d, target.image, formats, [&](const std::string& what) {
        if (!monitor.quiet()) status.show(what);
    });
    status.finish();
    print_design_summary(d, m, a.out, std::chrono::duration<double>(std::chrono::steady_clock::now() - writing).count(),
                         target_stretch_text(d.scene, target));
}

// `freeform design`: everything is read and checked before the design starts.
int run_design(const DesignArgs& a) {
    const Limits limits = parse_limits(a.limits);
    const DesignJob job = design_job(a, limits);
    const Scene& scene = job.scene;
    // The device: one asked for but not there is an input error (exit 2), before any work.
    DesignSetup setup;
    std::string device;  // its name for the first line; empty: the CPU
    if (job.options.device != Device::cpu && !a.start_only) {
        setup.cuda = cli::cuda_offer();
        const std::string key = a.device ? "--device" : "optimise.device";
        if (const DeviceOffer* chosen = choose_device(job.options, setup.cuda, key)) device = chosen->name;
    }
    check_output_dir(a.out, design_outputs);
    // Planned once: the memory check (before any surface is made), the header line, the
    // start surface's mesh and the design read the same levels.
    std::vector<LevelPlan> levels = plan_levels(scene, job.options);
    check_resources(job, RunKind::design, thread_count(exec::omp_t{job.options.threads}), limits, &levels);
    const io::LoadedTarget target = io::load_target(scene, limits);
    // Said before the design too, so that a user can stop it and frame the picture.
    if (const std::string note = target_stretch_text(scene, target); !note.empty() && !a.quiet && world_rank == 0)
        std::fprintf(stderr, "freeform: warning: %s\n", note.c_str());
    // A format this build lacks: exit 2 now.
    const std::vector<ExportFormat> formats = io::export_formats(job.options.exports);
    std::optional<Heightmap> start = io::load_start_surface(scene, levels, limits);
    PlannedDesign plan = plan_design(job, std::move(start), std::move(levels));
    setup.start_only = a.start_only;

    std::signal(SIGINT, on_sigint);
    DesignMonitor monitor(a, plan, device);
    setup.callbacks = monitor.callbacks();
    DesignRun run = design_run(a, std::move(plan), target.image, std::move(setup), monitor);
    // Another MPI rank: rank 0 writes the winner's design.
    if (!run.design) return run.stopped_early ? 130 : 0;
    monitor.status().finish();
    write_design(a, *run.design, run.replicas, target, formats, monitor);
    std::signal(SIGINT, SIG_DFL);
    return run.design->result.stopped_early ? 130 : 0;
}

// An error message as one readable line, whatever the input put in it: control bytes
// (a newline in a key, say) are escaped, and a message longer than 1,000 characters (a
// megabyte-long key) keeps its start and end around a count of what was left out.
std::string one_line(const std::string& message) {
    std::string out;
    for (const char c : message) {
        const auto u = static_cast<unsigned char>(c);
        if (c == '\n')
            out += "\\n";
        else if (c == '\t' || c == '\r' || u < 0x20 || u == 0x7f) {
            char hex[8];
            std::snprintf(hex, sizeof hex, "\\x%02x", u);
            out += hex;
        } else {
            out += c;
        }
    }
    constexpr std::size_t keep = 480;
    if (out.size() > 2 * keep + 40)
        out = out.substr(0, keep) + " ... (" + std::to_string(out.size() - 2 * keep) + " characters left out) ... " +
              out.substr(out.size() - keep);
    return out;
}

// ---------------------------------------------------------------------------- export
struct ExportArgs {
    fs::path scene, heightmap, out;
    std::string format;
    int threads = 0;
    bool no_check = false;
    std::vector<std::string> limits;  // --limit NAME=VALUE
};

enum class ExportFile { step, sag, stl, obj };
constexpr std::array<EnumName<ExportFile>, 4> export_file_names{
    {{"step", ExportFile::step}, {"sag", ExportFile::sag}, {"stl", ExportFile::stl}, {"obj", ExportFile::obj}}};

ExportFile parse_export_format(const std::string& f) {
    if (const std::optional<ExportFile> e = enum_value(f, export_file_names)) return *e;
    throw InputError("--format: expected " + enum_list(export_file_names, "", " or ") + ", got '" + f + "'");
}

// The exported facets of `hm` (stl/obj), written, and judged when `target` is given.
void export_mesh(const ExportArgs& a, ExportFile kind, const DesignJob& job, const Heightmap& hm,
                 const std::optional<ImageD>& target) {
    const Scene& scene = job.scene;
    const Fabrication fab = make_fabrication(scene, job.options.exports, hm);
    if (kind == ExportFile::stl)
        io::write_stl(a.out, fab.mesh);
    else
        io::write_obj(a.out, fab.mesh);
    const std::string k = subdivisions_text(fab);
    std::printf("wrote %s: %zu triangles, %s x %s facet pairs per cell%s, facet normal error %.3f mrad (90th "
                "percentile) against a tolerance of %.3f mrad%s\n",
                a.out.string().c_str(), fab.mesh.triangles.size(), k.c_str(), k.c_str(),
                fab.whole() ? "" : " on average",
                fab.normal_error * 1e3, fab.normal_tolerance * 1e3,
                fab.tolerance_met ? "" : (": MISSED (" + what_stopped_k(fab) + ")").c_str());
#if defined(FREEFORM_WITH_EMBREE)
    if (!target) return;
    const CellMeans c = exported_cell_means(exec::omp_t{a.threads}, scene, hm, exported_geometry(scene, hm, fab.subdivisions),
                                            &*target, physical_cell_mean_options(job.options.seed));
    std::printf("  error_physical %.4f: the facets traced as flat triangles, %.0f rays per cell\n", c.error,
                c.rays_per_cell);
#endif
}

// `freeform export`: a height map's surface in one of the exported forms, without designing.
int run_export(const ExportArgs& a) {
    const Limits limits = parse_limits(a.limits);
    const ExportFile kind = parse_export_format(a.format);
    DesignJob job = io::load_job(a.scene, limits);
    job.options.threads = a.threads;
    const Scene& scene = job.scene;
    const Heightmap hm = io::read_heightmap(scene, a.heightmap, limits);
    std::error_code ec;
    if (fs::is_directory(a.out, ec)) throw InputError("--out: " + a.out.string() + " is a folder; name the file");
    std::optional<ImageD> target;
    if (scene.target && !a.no_check) target = io::load_target_image(scene, limits);
    if (kind == ExportFile::stl || kind == ExportFile::obj) {
        export_mesh(a, kind, job, hm, target);
    } else {
        const double alpha = scene.surface.phong_alpha;
        const Heightmap top = export_blank(scene, hm);  // a lens's rim too
        const bool step = kind == ExportFile::step;
        // The sag table carries the height map's vertices; only STEP needs the spline.
        const BSplineSurface spline = step ? step_spline(top, alpha, job.options.exports.spline) : BSplineSurface{};
        const io::FormCheck fc = io::write_and_check_form(step ? ExportFormat::step : ExportFormat::sag, a.out, scene,
                                                          hm, spline, target ? &*target : nullptr,
                                                          job.options.seed, a.threads);
        std::printf("wrote %s: %.1f MB in %.1f s, valid: %s; ", a.out.string().c_str(), double(fc.bytes) / 1e6,
                    fc.write_seconds, fc.valid.c_str());
        if (step) {
            const SplineFitReport fit = check_spline_fit(spline, top, alpha, spline_samples_per_cell);
            std::printf("a bicubic B-spline of %d x %d poles (%s) within %.2g um (max) of the designed surface, "
                        "normals within %.3f mrad (90th percentile), %.2f mrad (max)\n",
                        spline.nu, spline.nv,
                        spline.hermite ? "C1 Hermite through the vertices and their normals" : "C2 least squares",
                        fit.max_height_error * 1e6, fit.p90_normal_error * 1e3, fit.max_normal_error * 1e3);
        } else {
            std::printf("the %d x %d vertices of the height map with their normals' slopes (bicubic Hermite "
                        "between them)\n",
                        top.nx(), top.ny());
        }
        if (fc.cells)
            std::printf("  error_physical %.4f: the file read back, tessellated (%lld triangles) and traced with its "
                        "normals, %.0f rays per cell\n",
                        fc.cells->error, (long long)fc.triangles, fc.cells->rays_per_cell);
    }
    if (target) {
        const CellMeans designed = designed_physical_cell_means(scene, job.options, hm, *target, a.threads);
        std::printf("  the designed surface itself (%s): %.4f\n", a.heightmap.string().c_str(), designed.error);
    }
    return 0;
}

// The parsed command line: which command, and its arguments.
struct CommandLine {
    RenderArgs render;
    DesignArgs design;
    ExportArgs export_;
    bool is_render = false;
    bool is_export = false;
};

// --limit's help, the same for every command.
constexpr const char* limit_help =
    "NAME=VALUE: raise or lower a resource limit (repeatable): json_depth (64), scene_file_bytes (16MiB), "
    "data_file_bytes (4GiB), pixels (67108864), triangles (67108864), memory_bytes (16GiB); docs/limits.md";

// The `export` subcommand's options.
CLI::App* add_export_command(CLI::App& app, ExportArgs& ea) {
    CLI::App* cmd = app.add_subcommand(
        "export", "write a height map's surface as STEP, a grid sag table, STL or OBJ, without designing (docs/export.md)");
    cmd->add_option("scene", ea.scene, "scene file (JSON): the surface's placement, material and target")->required();
    cmd->add_option("--heightmap", ea.heightmap, "the surface (PFM, e.g. a design's heightmap.pfm)")->required();
    cmd->add_option("--format", ea.format, "step, sag (OpticStudio grid sag .dat), stl or obj")->required();
    cmd->add_option("--out", ea.out, "the file to write")->required();
    cmd->add_option("--threads", ea.threads, "worker threads (0 = all cores)")->check(CLI::Range(0, 65536));
    cmd->add_flag("--no-check", ea.no_check,
                  "skip tracing the exported form (by default it is judged against the scene's target)");
    cmd->add_option("--limit", ea.limits, limit_help)->allow_extra_args(false);
    return cmd;
}

// The `render` subcommand's options.
CLI::App* add_render_command(CLI::App& app, RenderArgs& ra) {
    CLI::App* render = app.add_subcommand("render", "trace a scene's surface (or a heightmap / mesh) and write its irradiance");
    render->add_option("scene", ra.scene, "scene file (JSON)")->required();
    render->add_option("--out", ra.out, "output directory (irradiance.pfm/.png, metrics.json)")->required();
    render->add_option("--heightmap", ra.heightmap, "trace this heightmap (PFM, surface frame heights in metres)");
    render->add_option("--mesh", ra.mesh, "trace this triangle mesh (OBJ, world coordinates) in place of the surface");
    render->add_option("--material", ra.material,
                       "what the --mesh is: refractive:IOR (e.g. refractive:1.49) traces it as a closed solid of "
                       "that index (the whole lens, e.g. a design's exported surface.obj, or a lens from another "
                       "tool; Snell at every crossing, total internal reflection followed, Fresnel losses when the scene asks for them), "
                       "replacing the scene's lens model; the mesh must be closed, consistently oriented and "
                       "outward-facing. Default: the mesh is the surface, with the scene's material");
    render->add_flag("--mesh-normals", ra.mesh_normals,
                     "shade meshes with their interpolated vertex normals (Phong), as some renderers do; not "
                     "physical: a milled part has only its geometry, which is what is traced by default");
    render->add_option("--tracer", ra.tracer, "auto (default), heightfield or embree");
    render->add_option("--threads", ra.threads, "worker threads (0 = all cores)")->check(CLI::Range(0, 65536));
    render->add_option("--seed", ra.seed, "ray jitter seed (default: the scene's optimise.seed)")
        ->check(CLI::Range(std::int64_t{0}, std::numeric_limits<std::int64_t>::max()));
    render->add_option("--limit", ra.limits, limit_help)->allow_extra_args(false);
    return render;
}

#if defined(FREEFORM_WITH_MPI)
// The `design` subcommand's replica options (freeform_mpi only).
void add_replica_options(CLI::App* design_cmd, DesignArgs& da) {
    design_cmd->add_option("--replica-mode", da.replica_mode,
                           "domains (default): the ranks share one design, each moving a strip of the mesh, merged "
                           "at exchange points; tempering: each rank a replica of the design at its own temperature, "
                           "the best one wins");
    design_cmd->add_option("--ladder-ratio", da.ladder_ratio,
                           "replica exchange: temperature scale of rung k is RATIO^k (default 1.5)")
        ->check(CLI::Range(1.0, 1e6));
    design_cmd->add_option("--exchange-every", da.exchange_every,
                           "iterations between exchanges (tempering) or merges (domains); 0 = automatic (default): "
                           "500 for tempering, for domains as many as move each vertex of a rank's strip about "
                           "--merge-coverage times")
        ->check(CLI::Range(std::int64_t{0}, std::numeric_limits<std::int64_t>::max()));
    design_cmd->add_option("--merge-coverage", da.merge_coverage,
                           "domains: moves per vertex of a strip between merges, when --exchange-every is 0 "
                           "(default 30)")
        ->check(CLI::Range(1e-3, 1e6));
}
#endif

// The `design` subcommand's options.
CLI::App* add_design_command(CLI::App& app, DesignArgs& da) {
    CLI::App* design_cmd = app.add_subcommand("design", "optimise the surface so that its light matches the target");
    design_cmd->add_option("scene", da.scene, "scene file (JSON) with a target")->required();
    design_cmd->add_option("--out", da.out,
                           "output directory (metrics.json, convergence.csv, heightmap.pfm, surface.obj/.stl, "
                           "irradiance.png, target.png, comparison.png)")
        ->required();
    design_cmd->add_option("--seed", da.seed, "random seed (default: the scene's optimise.seed)")
        ->check(CLI::Range(std::int64_t{0}, std::numeric_limits<std::int64_t>::max()));
    design_cmd->add_option("--time-budget", da.time_budget, "seconds (default: the scene's optimise.time_budget)");
    design_cmd->add_option("--threads", da.threads,
                           mpi_built
                               ? "worker threads per rank (0 = the cores mpirun bound the rank to)"
                               : "worker threads (0 = all cores)")
        ->check(CLI::Range(0, 65536));
    design_cmd->add_option("--device", da.device,
                           "where moves are judged: cpu, cuda (a GPU; needs a build with CUDA) or auto (the GPU when "
                           "there is one); default: the scene's optimise.device (docs/cuda.md)")
        ->check(CLI::IsMember({"cpu", "cuda", "auto"}));
    design_cmd->add_flag("--quiet", da.quiet, "no live progress line");
    design_cmd->add_option("--limit", da.limits, limit_help)->allow_extra_args(false);
    design_cmd->add_flag("--start-only", da.start_only,
                         "write the start surface alone (the transport surface by default), without annealing");
#if defined(FREEFORM_WITH_MPI)
    add_replica_options(design_cmd, da);
#endif
    return design_cmd;
}

// Parses argv into `cl`. Returns the exit code when parsing ends the program (help,
// version, a usage error: one line on stderr, exit 2), nothing when the command runs.
std::optional<int> parse_command_line(int argc, const char* const* argv, CommandLine& cl) {
    CLI::App app{"freeform: design freeform reflectors and lenses that throw a target image onto a plane.\n"
                 "Scene files are described in docs/scene.md.",
                 "freeform"};
    app.set_version_flag("--version", version);
    app.require_subcommand(1);
    CLI::App* render = add_render_command(app, cl.render);
    add_design_command(app, cl.design);
    CLI::App* export_cmd = add_export_command(app, cl.export_);
    app.footer("Ctrl-C during a design stops it at the next iteration and writes the best result so far.\n"
               "Exit codes: 0 success, 2 bad input, a limit exceeded (docs/limits.md) or a file that cannot be read or "
               "written, 1 internal error, 130 design interrupted (results written).");

    try {
        app.parse(argc, argv);
    } catch (const CLI::CallForHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForAllHelp& e) {
        return app.exit(e);
    } catch (const CLI::CallForVersion& e) {
        return app.exit(e);
    } catch (const CLI::ParseError& e) {
        // One line, like every other input error (CLI11's own report adds a help hint).
        if (world_rank == 0) std::fprintf(stderr, "freeform: %s (see freeform --help)\n", one_line(e.what()).c_str());
        return 2;
    }
    cl.is_render = render->parsed();
    cl.is_export = export_cmd->parsed();
    return std::nullopt;
}

// The values of options that are checked without reading any file; the run functions
// call the same parsers, so this only makes them fail before any work (and gives the
// command-line fuzzer, tests/fuzz, the whole argument layer).
void check_arguments(const CommandLine& cl) {
    if (cl.is_export) {
        parse_limits(cl.export_.limits);
        parse_export_format(cl.export_.format);
    } else if (cl.is_render) {
        parse_limits(cl.render.limits);
        if (!cl.render.material.empty()) parse_mesh_material(cl.render.material);
        if (!cl.render.tracer.empty()) parse_tracer(cl.render.tracer);
    } else {
        parse_limits(cl.design.limits);
        if (cl.design.time_budget && !(*cl.design.time_budget > 0))
            throw InputError("--time-budget: must be > 0 seconds");
    }
}

int cli_main(int argc, char** argv) {
    CommandLine cl;
    if (const std::optional<int> exit_code = parse_command_line(argc, argv, cl)) return *exit_code;
    try {
        check_arguments(cl);
        if (cl.is_export) return world_rank == 0 ? run_export(cl.export_) : 0;
        if (cl.is_render) return run_render(cl.render);
        return run_design(cl.design);
    } catch (const InputError& e) {
        // Every rank reads the same input and finds the same error: one message.
        if (world_rank == 0) std::fprintf(stderr, "freeform: %s\n", one_line(e.what()).c_str());
        return 2;
    } catch (const std::exception& e) {
        if (world_size > 1)
            std::fprintf(stderr, "freeform: rank %d: internal error: %s\n", world_rank, one_line(e.what()).c_str());
        else
            std::fprintf(stderr, "freeform: internal error: %s\n", one_line(e.what()).c_str());
        return 1;
    }
}

}  // namespace

#if !defined(FREEFORM_CLI_NO_MAIN)  // tests/fuzz/fuzz_cli.cpp includes this file for its parser
int main(int argc, char** argv) {
#if defined(FREEFORM_WITH_MPI)
    // OpenMP threads evaluate moves; only the main thread calls MPI.
    int provided = 0;
    if (MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
        std::fprintf(stderr, "freeform: MPI_Init_thread failed\n");
        return 1;
    }
    MPI_Comm_rank(MPI_COMM_WORLD, &world_rank);
    MPI_Comm_size(MPI_COMM_WORLD, &world_size);
    // Rank 0 alone prints results (and help); the others' stdout goes nowhere.
    if (world_rank != 0 && !std::freopen("/dev/null", "w", stdout)) return 1;
    const int rc = cli_main(argc, argv);
    // An internal error on one rank may leave the others waiting in a collective.
    if (rc == 1 && world_size > 1) MPI_Abort(MPI_COMM_WORLD, 1);
    MPI_Finalize();
    return rc;
#else
    return cli_main(argc, argv);
#endif
}
#endif
