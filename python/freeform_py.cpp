// The Python module `freeform` (docs/python.md): the library's one-call design and render
// with NumPy arrays in and out.
//
//     import freeform
//     scene = freeform.Scene.load("examples/scenes/letter-e.json")
//     d = freeform.design(scene, time_budget=20)
//     d.heightmap, d.irradiance, d.metrics["error_physical"]
//     d.write("results/letter-e")    # the files of `freeform design --out results/letter-e`
//
// Each call does what the command line does with the same arguments: the same checks with
// the same messages, the same design (bit for bit at the same seed, threads and fixed
// iterations) and the same files (io::write_design_outputs). The GIL is released while a
// design or render runs; a design's progress callback re-acquires it at most ten times a
// second, to look for Ctrl-C and, at most twice a second, to call the user's function.
// Python.h (through pybind11) comes before the standard headers.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <pybind11/stl/filesystem.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <random>
#include <sstream>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include <freeform/freeform.hpp>
#include <freeform/io/outputs.hpp>
#include <nlohmann/json.hpp>

#ifndef FREEFORM_VERSION
#error "FREEFORM_VERSION is set by CMake (the project's version)"
#endif

namespace py = pybind11;
namespace fs = std::filesystem;
using json = nlohmann::json;
using namespace py::literals;

namespace {

// ------------------------------------------------------------------------- errors

// A file that is not there: FileNotFoundError; any other IoError: OSError; any other
// InputError: ValueError. The messages are the library's, as the command line prints them.
bool names_a_missing_file(const std::string& message) {
    return message.find("does not exist") != std::string::npos || message.find("not found") != std::string::npos;
}

void translate_errors(std::exception_ptr p) {
    try {
        if (p) std::rethrow_exception(p);
    } catch (const freeform::IoError& e) {
        PyErr_SetString(names_a_missing_file(e.what()) ? PyExc_FileNotFoundError : PyExc_OSError, e.what());
    } catch (const freeform::InputError& e) {
        PyErr_SetString(PyExc_ValueError, e.what());
    }
}

std::string type_name(const py::handle& obj) { return py::str(py::type::handle_of(obj).attr("__name__")); }

// --------------------------------------------------------------------------- scene

// A scene file's scene and design options (its "optimise" block), and the file it came
// from (metrics.json's "scene"; empty for a dict or text).
struct PyScene {
    freeform::DesignJob job;
    std::optional<std::string> path;

    // The name errors begin with, as the command line names the file it read.
    std::string name() const { return path ? *path : std::string("scene"); }
};

PyScene load_scene(const fs::path& file) { return PyScene{freeform::io::load_job(file), file.string()}; }

// Python's json module writes the dict; NumPy numbers and arrays become plain numbers and lists.
std::string json_text(const py::handle& data) {
    const py::cpp_function plain([](const py::object& o) -> py::object {
        if (py::hasattr(o, "tolist")) return o.attr("tolist")();
        throw py::type_error("Object of type " + type_name(o) + " is not JSON serializable");
    });
    return py::module_::import("json").attr("dumps")(data, "default"_a = plain).cast<std::string>();
}

// The scene of `data` (a dict, or the text of a scene file), checked as a scene file is,
// with its relative file names resolved against `base_dir` (default: the working folder).
PyScene scene_from_json(const py::object& data, std::optional<fs::path> base_dir) {
    std::string text;
    if (py::isinstance<py::str>(data))
        text = data.cast<std::string>();
    else if (py::isinstance<py::dict>(data))
        text = json_text(data);
    else
        throw py::type_error("Scene.from_json: expected a dict or the text of a scene (str), got " + type_name(data));
    std::error_code ec;
    const fs::path base = base_dir ? *base_dir : fs::current_path(ec);
    PyScene s{freeform::io::parse_job(text, "scene", base), std::nullopt};
    try {
        freeform::io::check_scene_files(s.job.scene);
    } catch (const freeform::IoError& e) {
        throw freeform::IoError("scene: " + std::string(e.what()));
    }
    return s;
}

py::object json_to_python(const json& j) { return py::module_::import("json").attr("loads")(j.dump()); }

// --------------------------------------------------------------------------- arrays

// A 2-D array of real numbers (any float or integer dtype) as float64 in C order.
py::array_t<double, py::array::c_style | py::array::forcecast> real_matrix(const py::handle& obj,
                                                                           const std::string& what) {
    py::array a = py::array::ensure(obj);
    if (!a) throw py::type_error(what + ": expected a NumPy array, got " + type_name(obj));
    const char kind = a.dtype().kind();
    if (kind != 'f' && kind != 'i' && kind != 'u')
        throw py::type_error(what + ": expected an array of floats or integers, got dtype " +
                             std::string(py::str(a.dtype())));
    if (a.ndim() != 2)
        throw py::value_error(what + ": expected a 2-D array (rows x columns), got " + std::to_string(a.ndim()) +
                              " dimension(s)");
    if (a.shape(0) < 1 || a.shape(1) < 1)
        throw py::value_error(what + ": the array is empty (" + std::to_string(a.shape(0)) + " x " +
                              std::to_string(a.shape(1)) + ")");
    return py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(a);
}

// A target image from an array, checked as io::load_target_image checks an image file
// (relative irradiance, any size: array_target below brings it up to the receiver's pixel
// count where it has fewer, and the design area-averages it down, as with a file).
freeform::ImageD target_from_array(const py::handle& obj) {
    const auto a = real_matrix(obj, "target");
    const auto v = a.unchecked<2>();
    freeform::ImageD img(v.shape(0), v.shape(1));
    for (py::ssize_t r = 0; r < v.shape(0); ++r)
        for (py::ssize_t c = 0; c < v.shape(1); ++c) img(r, c) = v(r, c);
    if (!img.isFinite().all()) throw freeform::InputError("target: the array has non-finite values");
    if ((img < 0).any()) throw freeform::InputError("target: the array has negative values");
    if (!(img.sum() > 0)) throw freeform::InputError("target: the array is entirely black");
    return img;
}

// What the effective scene (metrics.json) records for a target given as an array.
freeform::TargetSpec array_target_spec(const freeform::ImageD& img) {
    freeform::TargetSpec t;
    t.image = "(NumPy array, " + std::to_string(img.cols()) + " x " + std::to_string(img.rows()) + ")";
    return t;
}

// A target array made the scene's target: recorded as given, and framed and brought up
// to the receiver as io::load_target_image does a file (the scene's target.fit and
// target.upsample, where it has an image target, apply to the array too).
freeform::io::LoadedTarget array_target(const py::handle& obj, freeform::Scene& scene) {
    const freeform::ImageD raw = target_from_array(obj);
    freeform::TargetSpec spec = array_target_spec(raw);
    if (scene.target && !scene.target->image.empty()) {
        spec.fit = scene.target->fit;
        spec.upsample = scene.target->upsample;
    }
    scene.target = spec;
    return freeform::io::picture_target(raw, scene);
}

// The height map of an array, row 0 the surface's +v edge (as heightmap.pfm, Design.heightmap).
freeform::Heightmap heightmap_from_array(const freeform::Scene& scene, const py::handle& obj) {
    const auto a = real_matrix(obj, "heightmap");
    const auto v = a.unchecked<2>();
    freeform::ImageF img(v.shape(0), v.shape(1));
    for (py::ssize_t r = 0; r < v.shape(0); ++r)
        for (py::ssize_t c = 0; c < v.shape(1); ++c) img(r, c) = float(v(r, c));
    return freeform::io::heightmap_from_image(scene, img, "heightmap: the array");
}

// A triangle mesh in world coordinates from (vertices N x 3, triangles M x 3), checked as
// the OBJ reader checks a file: finite coordinates, integer indices of existing vertices.
freeform::TriangleMesh mesh_from_arrays(const py::handle& obj) {
    if (!py::isinstance<py::sequence>(obj) || py::isinstance<py::str>(obj) || py::len(obj) != 2)
        throw py::type_error("mesh: expected (vertices, triangles), e.g. a Design's mesh, got " + type_name(obj));
    const py::sequence pair = py::reinterpret_borrow<py::sequence>(obj);
    const py::object vertices_arg = pair[0], triangles_arg = pair[1];
    const auto vertices = real_matrix(vertices_arg, "mesh vertices");
    py::array triangles = py::array::ensure(triangles_arg);
    if (!triangles) throw py::type_error("mesh triangles: expected a NumPy array, got " + type_name(triangles_arg));
    const char kind = triangles.dtype().kind();
    if (kind != 'i' && kind != 'u')
        throw py::type_error("mesh triangles: expected an array of integers (vertex indices), got dtype " +
                             std::string(py::str(triangles.dtype())));
    if (vertices.shape(1) != 3)
        throw py::value_error("mesh vertices: expected an N x 3 array, got " + std::to_string(vertices.shape(0)) +
                              " x " + std::to_string(vertices.shape(1)));
    if (triangles.ndim() != 2 || triangles.shape(1) != 3 || triangles.shape(0) < 1)
        throw py::value_error("mesh triangles: expected an M x 3 array with M >= 1");
    const auto n = vertices.shape(0);
    if (n > std::numeric_limits<std::int32_t>::max())
        throw py::value_error("mesh vertices: more than 2^31 - 1 vertices");
    freeform::TriangleMesh mesh;
    const auto v = vertices.unchecked<2>();
    mesh.vertices.reserve(std::size_t(n));
    for (py::ssize_t k = 0; k < n; ++k) {
        const freeform::Vec3d p{v(k, 0), v(k, 1), v(k, 2)};
        if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
            throw freeform::InputError("mesh vertices: vertex " + std::to_string(k) + " has a non-finite coordinate");
        mesh.vertices.push_back(p);
    }
    const auto t = py::array_t<std::int64_t, py::array::c_style | py::array::forcecast>::ensure(triangles);
    if (!t) throw py::type_error("mesh triangles: the indices do not fit 64-bit integers");
    const auto ti = t.unchecked<2>();
    mesh.triangles.reserve(std::size_t(ti.shape(0)));
    for (py::ssize_t k = 0; k < ti.shape(0); ++k) {
        std::array<std::int32_t, 3> tri{};
        for (int c = 0; c < 3; ++c) {
            const std::int64_t index = ti(k, c);
            if (index < 0 || index >= n)
                throw freeform::InputError("mesh triangles: triangle " + std::to_string(k) + " refers to vertex " +
                                           std::to_string(index) + " of " + std::to_string(n));
            tri[std::size_t(c)] = std::int32_t(index);
        }
        mesh.triangles.push_back(tri);
    }
    return mesh;
}

template <class Image>
py::array_t<double> image_array(const Image& img) {
    py::array_t<double> out({py::ssize_t(img.rows()), py::ssize_t(img.cols())});
    auto o = out.template mutable_unchecked<2>();
    for (py::ssize_t r = 0; r < o.shape(0); ++r)
        for (py::ssize_t c = 0; c < o.shape(1); ++c) o(r, c) = double(img(r, c));
    return out;
}

py::object mesh_tuple(const py::object& mesh_type, const freeform::TriangleMesh& mesh) {
    py::array_t<double> vertices({py::ssize_t(mesh.vertices.size()), py::ssize_t(3)});
    auto v = vertices.mutable_unchecked<2>();
    for (std::size_t k = 0; k < mesh.vertices.size(); ++k) {
        const auto i = py::ssize_t(k);
        v(i, 0) = mesh.vertices[k].x, v(i, 1) = mesh.vertices[k].y, v(i, 2) = mesh.vertices[k].z;
    }
    py::array_t<std::int64_t> triangles({py::ssize_t(mesh.triangles.size()), py::ssize_t(3)});
    auto t = triangles.mutable_unchecked<2>();
    for (std::size_t k = 0; k < mesh.triangles.size(); ++k)
        for (int c = 0; c < 3; ++c) t(py::ssize_t(k), c) = mesh.triangles[k][std::size_t(c)];
    return mesh_type(vertices, triangles);
}

// -------------------------------------------------------------------------- design

// A finished design: arrays, metrics.json, and the command line's files, held in memory
// so that write() puts exactly those files (and metrics) in a folder.
struct PyDesign {
    py::object heightmap, mesh, irradiance, target, metrics, convergence;
    bool interrupted = false;
    std::map<std::string, std::string> files;  // name -> bytes, as write_design_outputs made them

    void write(const fs::path& folder) const {
        py::gil_scoped_release released;
        freeform::io::StagedOutput staged(folder);
        for (const auto& file : files)
            staged.write(file.first, [&](const fs::path& f) { freeform::io::write_file_atomically(f, file.second); });
        staged.commit("metrics.json");
    }
};

// What a design's progress callback shares with the caller: the user's function, when it
// was last called, and the Python exception (KeyboardInterrupt, or the function's own)
// that stopped the design.
struct ProgressState {
    using Clock = std::chrono::steady_clock;
    py::object function;  // None or a callable
    Clock::time_point last_check{}, last_call{};
    bool called = false;
    bool stop = false;  // the function returned True
    std::optional<py::error_already_set> stopped_by;

    static constexpr auto check_every = std::chrono::milliseconds(100);
    static constexpr auto call_every = std::chrono::milliseconds(500);

    // Called without the GIL, from the design's progress reports. Returns true to stop.
    bool report(const freeform::DesignProgress& p) {
        if (stop || stopped_by) return true;
        const Clock::time_point now = Clock::now();
        const bool call_due = !function.is_none() && (!called || now - last_call >= call_every);
        if (!call_due && now - last_check < check_every) return false;
        py::gil_scoped_acquire gil;
        last_check = now;
        try {
            if (PyErr_CheckSignals() != 0) throw py::error_already_set();
            if (call_due) {
                called = true;
                last_call = now;
                const py::object answer = function(p.iteration, p.seconds, p.error);
                if (PyObject_IsTrue(answer.ptr()) == 1) return stop = true;
                if (PyErr_Occurred()) throw py::error_already_set();
            }
        } catch (py::error_already_set& e) {
            stopped_by = std::move(e);
            return true;
        }
        return false;
    }
};

// Reads every file of `folder` (the design's outputs, staging folders excluded).
std::map<std::string, std::string> read_folder(const fs::path& folder) {
    std::map<std::string, std::string> files;
    for (const auto& entry : fs::directory_iterator(folder)) {
        if (!entry.is_regular_file()) continue;
        std::string bytes(std::size_t(entry.file_size()), '\0');
        std::ifstream in(entry.path(), std::ios::binary);
        if (!in || !in.read(bytes.data(), std::streamsize(bytes.size())))
            throw freeform::IoError("cannot read back '" + entry.path().string() + "'");
        files.emplace(entry.path().filename().string(), std::move(bytes));
    }
    return files;
}

// A fresh private folder under the system's temporary folder, removed with the object.
class ScratchFolder {
public:
    ScratchFolder() {
        std::random_device entropy;
        std::error_code ec;
        const fs::path base = fs::temp_directory_path(ec);
        if (ec) throw freeform::IoError("no temporary folder: " + ec.message());
        for (int attempt = 0; attempt < 16 && path_.empty(); ++attempt) {
            const fs::path p = base / ("freeform-python-" + std::to_string(entropy()) + std::to_string(entropy()));
            if (fs::create_directory(p, ec) && !ec) path_ = p;
        }
        if (path_.empty()) throw freeform::IoError("cannot create a folder in '" + base.string() + "'");
    }
    ScratchFolder(const ScratchFolder&) = delete;
    ScratchFolder& operator=(const ScratchFolder&) = delete;
    ~ScratchFolder() {
        std::error_code ignored;
        fs::remove_all(path_, ignored);
    }
    const fs::path& path() const { return path_; }

private:
    fs::path path_;
};

py::object convergence_dict(const freeform::DesignResult& r) {
    const auto n = py::ssize_t(r.convergence.size());
    py::array_t<double> seconds(n), error(n), energy(n), objective(n), temperature(n);
    py::array_t<std::int64_t> iteration(n), level(n), stage(n);
    for (py::ssize_t i = 0; i < n; ++i) {
        const auto& c = r.convergence[std::size_t(i)];
        seconds.mutable_at(i) = c.seconds, iteration.mutable_at(i) = c.iteration;
        level.mutable_at(i) = c.level, stage.mutable_at(i) = c.stage;
        error.mutable_at(i) = c.error, energy.mutable_at(i) = c.energy;
        objective.mutable_at(i) = c.objective, temperature.mutable_at(i) = c.temperature;
    }
    py::dict d;
    d["seconds"] = seconds, d["iteration"] = iteration, d["level"] = level, d["stage"] = stage;
    d["error"] = error, d["energy"] = energy, d["objective"] = objective, d["temperature"] = temperature;
    return d;
}

// freeform.design: `freeform design SCENE --out DIR [--seed] [--time-budget] [--threads]`
// as one call (apps/freeform/main.cpp, run_design), its files kept in memory.
PyDesign design(const PyScene& ps, const py::object& target_arg, std::optional<double> time_budget,
                std::optional<std::int64_t> seed, std::optional<int> threads, const py::object& progress,
                const py::object& mesh_type) {
    if (!progress.is_none() && !PyCallable_Check(progress.ptr()))
        throw py::type_error("progress: expected a function progress(iteration, seconds, error) or None, got " +
                             type_name(progress));
    freeform::DesignJob job = ps.job;
    freeform::Scene& scene = job.scene;
    freeform::DesignOptions& options = job.options;
    if (seed) {
        if (*seed < 0) throw freeform::InputError("seed: must be >= 0, got " + std::to_string(*seed));
        options.seed = std::uint64_t(*seed);
    }
    if (time_budget) {
        if (!(*time_budget > 0) || !std::isfinite(*time_budget))
            throw freeform::InputError("time_budget: must be > 0 seconds (and finite)");
        options.time_budget = *time_budget;
    }
    if (threads) {
        if (*threads < 0 || *threads > 65536)
            throw freeform::InputError("threads: must be in [0, 65536] (0 = all cores), got " +
                                       std::to_string(*threads));
        options.threads = *threads;
    }
    std::optional<freeform::io::LoadedTarget> target;
    if (!target_arg.is_none()) {
        target = array_target(target_arg, scene);
    }
    try {
        freeform::check_designable(scene);
    } catch (const freeform::InputError& e) {
        throw freeform::InputError(ps.name() + ": " + e.what());
    }
    options.progress_every = 500;  // as the command line's: the same convergence.csv
    const freeform::Limits limits;
    // Planned once, as the command line does: the memory check (before any surface is
    // made) and the design read the same levels.
    std::vector<freeform::LevelPlan> levels = freeform::plan_levels(scene, options);
    freeform::check_resources(job, freeform::RunKind::design,
                              freeform::thread_count(freeform::exec::omp_t{options.threads}), limits, &levels);
    if (!target) target = freeform::io::load_target(scene, limits);
    const std::vector<freeform::ExportFormat> formats = freeform::io::export_formats(options.exports);
    std::optional<freeform::Heightmap> start = freeform::io::load_start_surface(scene, levels, limits);
    freeform::PlannedDesign plan = freeform::plan_design(job, std::move(start), std::move(levels));
    freeform::DesignSetup setup;

    ProgressState state;
    state.function = progress;
    std::optional<freeform::CompletedDesign> done;
    freeform::io::DesignImages images;
    std::map<std::string, std::string> files;
    {
        py::gil_scoped_release released;
        setup.callbacks.progress = [&](const freeform::DesignProgress& p) { return state.report(p); };
        done = freeform::design(std::move(plan), target->image, setup);
        json m = freeform::io::design_metrics_json(*done);
        m["command"] = "design";
        m["scene"] = ps.path ? json(*ps.path) : json(nullptr);
        m["target_fit"] = freeform::io::target_fit_json(done->scene, *target);
        const ScratchFolder scratch;
        images = freeform::io::write_design_outputs(scratch.path(), m, *done, target->image, formats);
        files = read_folder(scratch.path());
    }
    const freeform::CompletedDesign& d = *done;
    PyDesign out;
    out.heightmap = image_array(freeform::io::heightmap_image(d.result.surface));
    out.mesh = mesh_tuple(mesh_type, d.exported.fabrication.mesh);
    out.irradiance = image_array(images.irradiance);
    out.target = image_array(images.target);
    out.metrics = py::module_::import("json").attr("loads")(py::bytes(files.at("metrics.json")));
    out.convergence = convergence_dict(d.result);
    out.interrupted = d.result.stopped_early;
    out.files = std::move(files);
    // Ctrl-C while the design was finishing: stopped like one during the annealing.
    if (!state.stopped_by && PyErr_CheckSignals() != 0) state.stopped_by = py::error_already_set();
    if (state.stopped_by) {
        // The design stopped with its best surface, finished and judged: the exception
        // carries it (e.design) for a caller that wants what was done.
        py::error_already_set& e = *state.stopped_by;
        if (PyObject_SetAttrString(e.value().ptr(), "design", py::cast(std::move(out)).ptr()) != 0)
            PyErr_Clear();  // an exception that takes no attributes is raised as it is
        throw e;
    }
    return out;
}

// ---------------------------------------------------------------------------- render

// freeform.render: `freeform render SCENE --out DIR [--heightmap H | --mesh M] [--seed]
// [--threads]` as one call (run_render), without the files.
py::tuple render(const PyScene& ps, const py::object& heightmap, const py::object& mesh, const py::object& target_arg,
                 std::optional<std::int64_t> seed, std::optional<int> threads) {
    freeform::RenderRequest job;
    freeform::DesignJob scene_file = ps.job;
    if (seed) {
        if (*seed < 0) throw freeform::InputError("seed: must be >= 0, got " + std::to_string(*seed));
        scene_file.options.seed = std::uint64_t(*seed);
    }
    job.scene = scene_file.scene;
    job.options = scene_file.options;
    freeform::Scene& scene = job.scene;
    if (threads && (*threads < 0 || *threads > 65536))
        throw freeform::InputError("threads: must be in [0, 65536] (0 = all cores), got " + std::to_string(*threads));
    job.threads = freeform::thread_count(freeform::exec::omp_t{threads.value_or(0)});
    const freeform::Limits limits;
    freeform::check_resources(scene_file, freeform::RunKind::render, job.threads, limits);
    if (!heightmap.is_none() && !mesh.is_none())
        throw freeform::InputError("heightmap and mesh are alternatives: give one of them");
    job.tracer = scene.trace.tracer;
    freeform::choose_tracer(scene, !mesh.is_none(), job.tracer, freeform::embree_available);
    if (!target_arg.is_none()) {
        job.target = array_target(target_arg, scene).image;
    } else if (scene.target) {
        job.target = freeform::io::load_target_image(scene, limits);
    }
    if (!heightmap.is_none()) {
        job.surface = heightmap_from_array(scene, heightmap);
    } else {
        job.surface = freeform::io::scene_surface(scene_file, limits);
        job.surface_is_scene_start = true;
    }
    if (!mesh.is_none()) {
        job.mesh = mesh_from_arrays(mesh);
        job.mesh_name = "the mesh";
    }
    for (const auto& m : scene.meshes) {
        job.scene_meshes.push_back(freeform::io::read_mesh(m.file, limits));
        if (m.material.is_refractive()) job.scene_meshes.back() = freeform::io::welded(job.scene_meshes.back());
    }
    const bool traced_mesh = job.mesh.has_value();
    std::optional<freeform::RenderResult> r;
    {
        py::gil_scoped_release released;
        r = freeform::render(std::move(job));
    }
    json m = freeform::io::render_metrics_json(*r, traced_mesh, std::nullopt, false);
    m["command"] = "render";
    m["scene"] = ps.path ? json(*ps.path) : json(nullptr);
    return py::make_tuple(image_array(r->histogram.to_image()), json_to_python(m));
}

}  // namespace

PYBIND11_MODULE(freeform, m) {
    m.doc() =
        "freeform: design freeform reflectors and lenses that throw a target image onto a plane "
        "(docs/python.md). Scene.load / Scene.from_json read a scene as the command line does; "
        "design() and render() are `freeform design` and `freeform render` with NumPy arrays.";
    m.attr("__version__") = FREEFORM_VERSION;
    py::register_exception_translator(&translate_errors);
    // pybind11 (before 2.11) finds NumPy's C API on first use, in a static initialised
    // while NumPy may release the GIL: two threads making their first arrays at once (two
    // designs started together) deadlock there. Done here, under the import lock, it is
    // done once before any thread can race for it.
    py::module_::import("numpy");
    (void)py::array_t<double>(0);
    (void)py::array_t<std::int64_t>(0);
    (void)py::dtype::of<double>();

    const py::object mesh_type =
        py::module_::import("collections").attr("namedtuple")("Mesh", py::make_tuple("vertices", "triangles"));
    mesh_type.attr("__module__") = "freeform";
    mesh_type.attr("__doc__") =
        "A triangle mesh in world coordinates (metres): vertices (N x 3 float64) and triangles "
        "(M x 3 int64 vertex indices), as surface.obj holds it.";
    m.attr("Mesh") = mesh_type;

    py::class_<PyScene>(m, "Scene",
                        "A scene (docs/scene.md): the light, the surface, the receiver and the target. "
                        "Make one with Scene.load(path) or Scene.from_json(dict or str).")
        .def_static("load", &load_scene, "path"_a,
                    "Reads and checks a scene file, as `freeform design PATH` does (same messages: ValueError "
                    "for a bad key or value, FileNotFoundError for a missing file).")
        .def_static("from_json", &scene_from_json, "data"_a, "base_dir"_a = py::none(),
                    "A scene from a dict or the text of a scene file, checked key by key as a file is. "
                    "Relative file names resolve against base_dir (default: the working folder).")
        .def(
            "to_json", [](const PyScene& s) { return json_to_python(freeform::job_to_json(s.job)); },
            "The scene as a dict with every default written out (Scene.from_json reads it back).")
        .def_property_readonly(
            "path", [](const PyScene& s) { return s.path ? py::object(py::str(*s.path)) : py::object(py::none()); },
            "The file the scene was read from (None for Scene.from_json).")
        .def("__repr__", [](const PyScene& s) {
            const freeform::Receiver& r = s.job.scene.receiver;
            return "<freeform.Scene " + (s.path ? "'" + *s.path + "'" : std::string("from JSON")) + ": receiver " +
                   std::to_string(r.width) + " x " + std::to_string(r.height) + ">";
        });

    py::class_<PyDesign>(m, "Design", "A finished design, as `freeform design` writes it.")
        .def_readonly("heightmap", &PyDesign::heightmap,
                      "Heights in metres along the surface normal (float64, rows x columns = ny x nx); row 0 "
                      "is the surface's +v edge, as in heightmap.pfm.")
        .def_readonly("mesh", &PyDesign::mesh, "The exported facets (surface.obj): Mesh(vertices, triangles).")
        .def_readonly("irradiance", &PyDesign::irradiance,
                      "The light on the receiver (float64, rows x columns), as irradiance.pfm: the cell means "
                      "of the exported part (metrics['export']['images_show']).")
        .def_readonly("target", &PyDesign::target,
                      "The target the irradiance is judged against, scaled to the same total.")
        .def_readonly("metrics", &PyDesign::metrics, "metrics.json as a dict.")
        .def_readonly("convergence", &PyDesign::convergence,
                      "convergence.csv as a dict of arrays: seconds, iteration, level, stage, error, energy, "
                      "objective, temperature.")
        .def_readonly("interrupted", &PyDesign::interrupted,
                      "True when progress() or Ctrl-C stopped the design (the best surface was kept).")
        .def("write", &PyDesign::write, "folder"_a,
             "Writes the command line's files (metrics.json, heightmap.pfm, surface.obj, ...) into folder, "
             "all together (metrics.json last).");

    m.def(
        "design",
        [mesh_type](const PyScene& scene, const py::object& target, std::optional<double> time_budget,
                    std::optional<std::int64_t> seed, std::optional<int> threads, const py::object& progress) {
            return design(scene, target, time_budget, seed, threads, progress, mesh_type);
        },
        "scene"_a, "target"_a = py::none(), py::kw_only(), "time_budget"_a = py::none(), "seed"_a = py::none(),
        "threads"_a = py::none(), "progress"_a = py::none(),
        "Designs the scene's surface: `freeform design` in one call. target: None (the scene's own) or a 2-D "
        "array of non-negative numbers, resampled to the receiver as an image file is. time_budget, seed, "
        "threads: as --time-budget, --seed, --threads. progress(iteration, seconds, error) is called at most "
        "twice a second; returning True stops the design, keeping the best surface. Ctrl-C stops it the same "
        "way and raises KeyboardInterrupt, whose .design is the finished design. The GIL is released while it "
        "runs.");

    m.def("render", &render, "scene"_a, "heightmap"_a = py::none(), "mesh"_a = py::none(), py::kw_only(),
          "target"_a = py::none(), "seed"_a = py::none(), "threads"_a = py::none(),
          "Traces the scene's light: `freeform render` in one call. heightmap: a 2-D array (row 0 the +v "
          "edge, as Design.heightmap); mesh: (vertices, triangles) in world coordinates, traced in the "
          "surface's place; neither: the scene's own start. Returns (irradiance, metrics): the image as "
          "irradiance.pfm and metrics.json as a dict. The GIL is released while it runs.");
}
