#pragma once
// Scene files: reading a JSON scene from disk (io/scene_json.hpp does the validation),
// checking that the files it names exist, and building the initial surface it asks for.
#include <cmath>
#include <cstddef>
#include <filesystem>
#include <set>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <nlohmann/json.hpp>

#include "../core/error.hpp"
#include "../core/limits.hpp"
#include "../design/initial.hpp"
#include "scene_json.hpp"
#include "../scene/scene.hpp"
#include "../surface/heightmap.hpp"
#include "file.hpp"
#include "pfm.hpp"

namespace freeform::io {

namespace detail {

// nlohmann::json keeps the last of duplicated keys without a word; a scene that sets a
// key twice is almost always an editing mistake, so the parser callback rejects it.
class DuplicateKeyCheck {
public:
    bool operator()(int, nlohmann::json::parse_event_t event, nlohmann::json& parsed) {
        using E = nlohmann::json::parse_event_t;
        switch (event) {
            case E::object_start:
            case E::array_start: levels_.push_back({event == E::object_start, {}, {}, 0}); break;
            case E::key: {
                Level& top = levels_.back();
                top.pending_key = parsed.get<std::string>();
                if (!top.keys.insert(top.pending_key).second)
                    throw InputError(path_to(levels_.size()) +
                                     ": duplicate key (a key may appear only once in an object)");
                break;
            }
            case E::object_end:
            case E::array_end:
                levels_.pop_back();
                count_element();
                break;
            case E::value: count_element(); break;
        }
        return true;
    }

private:
    // Each level keeps only its own key or index (memory linear in the depth); the
    // path of an element is assembled when an error needs it.
    struct Level {
        bool object;
        std::set<std::string> keys;
        std::string pending_key;
        std::size_t index;
    };

    // The path of the element being read at the first `depth` levels ("a.b[2].c").
    std::string path_to(std::size_t depth) const {
        std::string path;
        for (std::size_t k = 0; k < depth && k < levels_.size(); ++k)
            path = levels_[k].object ? scene_json::key_path(path, levels_[k].pending_key)
                                     : scene_json::index_path(path, levels_[k].index);
        return path;
    }
    void count_element() {
        if (!levels_.empty() && !levels_.back().object) ++levels_.back().index;
    }

    std::vector<Level> levels_;
};

// "line L, column C" of the 1-based byte offset that nlohmann reports.
inline std::string text_position(std::string_view text, std::size_t byte) {
    const std::size_t end = std::min(byte == 0 ? 0 : byte - 1, text.size());
    std::size_t line = 1, line_start = 0;
    for (std::size_t k = 0; k < end; ++k)
        if (text[k] == '\n') ++line, line_start = k + 1;
    return "line " + std::to_string(line) + ", column " + std::to_string(end - line_start + 1) + " (byte " +
           std::to_string(byte) + ")";
}

// nlohmann's message without its "[json.exception...] parse error at ...: " prefix.
inline std::string parse_error_detail(const std::string& what) {
    const std::size_t at = what.find("parse error");
    if (at != std::string::npos) {
        const std::size_t colon = what.find(": ", at);
        if (colon != std::string::npos) return what.substr(colon + 2);
    }
    const std::size_t bracket = what.find("] ");
    return bracket == std::string::npos ? what : what.substr(bracket + 2);
}

// Byte offset of the first '[' or '{' that opens a level deeper than `max_depth`
// (outside strings and comments), or npos. Run before parsing so that a file of nested
// brackets is refused in one pass over its bytes, with no allocation.
inline std::size_t first_too_deep(std::string_view text, int max_depth) {
    int depth = 0;
    for (std::size_t k = 0; k < text.size(); ++k) {
        const char c = text[k];
        const char next = k + 1 < text.size() ? text[k + 1] : '\0';
        if (c == '"') {
            for (++k; k < text.size() && text[k] != '"'; ++k)
                if (text[k] == '\\') ++k;
        } else if (c == '/' && next == '/') {
            k = text.find('\n', k);
            if (k == std::string_view::npos) break;
        } else if (c == '/' && next == '*') {
            k = text.find("*/", k + 2);
            if (k == std::string_view::npos) break;
            ++k;
        } else if (c == '[' || c == '{') {
            if (++depth > max_depth) return k;
        } else if ((c == ']' || c == '}') && depth > 0) {
            --depth;
        }
    }
    return std::string_view::npos;
}

inline std::filesystem::path resolve(const Scene& scene, const std::filesystem::path& p) {
    if (p.empty() || p.is_absolute() || scene.base_dir.empty()) return p;
    return (scene.base_dir / p).lexically_normal();
}

inline void require_file(const std::filesystem::path& p, const std::string& key) {
    std::error_code ec;
    const auto status = std::filesystem::status(p, ec);
    if (ec || !std::filesystem::exists(status)) throw IoError(key + ": file not found: " + p.string());
    if (!std::filesystem::is_regular_file(status)) throw IoError(key + ": not a regular file: " + p.string());
}

}  // namespace detail

// Checks that every file the scene names exists (surface.initial, target.image,
// meshes[k].file). Throws IoError naming the key and the path.
inline void check_scene_files(const Scene& scene) {
    if (!scene.surface.initial_pfm.empty())
        detail::require_file(detail::resolve(scene, scene.surface.initial_pfm), "surface.initial");
    if (scene.target && !scene.target->image.empty())
        detail::require_file(detail::resolve(scene, scene.target->image), "target.image");
    for (std::size_t k = 0; k < scene.meshes.size(); ++k)
        detail::require_file(detail::resolve(scene, scene.meshes[k].file), "meshes[" + std::to_string(k) + "].file");
}

// Parses and validates the text of a scene file (the scene and its design options,
// DesignJob); `name` names it in messages and
// relative file names resolve against `base_dir`. JSON comments (// and /* */) are
// allowed. Every error names the file: syntax errors with line and column, bad values
// with the key ("scene.json: surface.size[1]: must be > 0, got -0.1"), nesting deeper
// than limits.json_depth (found before parsing). Throws InputError. Does no I/O: the
// files the scene names are not checked (load_job does that).
inline DesignJob parse_job(std::string_view text, const std::string& name, const std::filesystem::path& base_dir,
                           const Limits& limits = {}) {
    if (const std::size_t at = detail::first_too_deep(text, limits.json_depth); at != std::string_view::npos)
        over_limit(name + ": arrays and objects nested deeper than " + std::to_string(limits.json_depth) +
                       " levels at " + detail::text_position(text, at + 1),
                   "json_depth", std::to_string(limits.json_depth));
    nlohmann::json j;
    try {
        j = nlohmann::json::parse(text, detail::DuplicateKeyCheck{}, /*allow_exceptions=*/true,
                                  /*ignore_comments=*/true);
    } catch (const nlohmann::json::parse_error& e) {
        throw InputError(name + ": invalid JSON at " + detail::text_position(text, e.byte) + ": " +
                         detail::parse_error_detail(e.what()));
    } catch (const nlohmann::json::exception& e) {
        // e.g. a number too large for a double (1e999): reported without a position.
        throw InputError(name + ": invalid JSON: " + detail::parse_error_detail(e.what()));
    } catch (const IoError&) {
        throw;
    } catch (const InputError& e) {
        throw InputError(name + ": " + e.what());
    }
    try {
        return job_from_json(j, base_dir);
    } catch (const InputError& e) {
        throw InputError(name + ": " + e.what());
    }
}

// Reads, parses (parse_job) and validates a scene file, refusing one larger than
// limits.scene_file_bytes before reading it; relative file names in it resolve against
// the file's directory (Scene::base_dir, absolute). Missing files, the scene's or those
// it names, throw IoError, everything else InputError.
inline DesignJob load_job(const std::filesystem::path& file, const Limits& limits = {}) {
    const std::string text = read_file_bytes(file, limits.scene_file_bytes, "scene_file_bytes");
    const std::string name = file.string();
    DesignJob job = parse_job(text, name, std::filesystem::absolute(file).parent_path(), limits);
    try {
        check_scene_files(job.scene);
    } catch (const IoError& e) {
        throw IoError(name + ": " + e.what());
    }
    return job;
}

// The scene of a scene file alone (load_job(file, limits).scene), for a caller that does
// not design it; the whole file is still read and checked.
inline Scene load_scene(const std::filesystem::path& file, const Limits& limits = {}) {
    return load_job(file, limits).scene;
}

// The scene in the text of a scene file alone (parse_job(...).scene).
inline Scene parse_scene(std::string_view text, const std::string& name, const std::filesystem::path& base_dir,
                         const Limits& limits = {}) {
    return parse_job(text, name, base_dir, limits).scene;
}

// The heights of `img` (metres; image row 0 is the +v edge) on `scene`'s surface, on the
// grid the image has, clamped to surface.height_bounds. `what` names the image in errors
// ("surface.initial: heightmap 'h.pfm'"). Throws InputError for fewer than 2 x 2 pixels
// or a non-finite value.
inline Heightmap heightmap_from_image(const Scene& scene, const ImageF& img, const std::string& what) {
    const SurfaceSpec& s = scene.surface;
    const int cols = int(img.cols()), rows = int(img.rows());
    if (cols < 2 || rows < 2)
        throw InputError(what + " is " + std::to_string(cols) + " x " + std::to_string(rows) +
                         " pixels; at least 2 x 2 are needed");
    std::vector<float> heights(std::size_t(cols) * std::size_t(rows));
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
            const float value = img(r, c);
            if (!std::isfinite(value))
                throw InputError(what + " has a non-finite value at row " + std::to_string(r) + ", column " +
                                 std::to_string(c));
            // Image row 0 is the top, the +v edge of the surface: grid row ny-1.
            heights[std::size_t(rows - 1 - r) * cols + c] = value;
        }
    Heightmap h(cols, rows, s.size, s.h_min, s.h_max, s.frame, s.aperture);
    h.set_heights(heights);
    return h;
}

// The starting surface of a design on an nx × ny vertex grid: flat (height 0, clamped
// to the bounds), the paraboloid h = r²/(4f), or the PFM heightmap of surface.initial
// (values in metres; image row 0 is the +v edge), resampled bilinearly when its size
// differs. Heights are clamped to surface.height_bounds.
// limits.data_file_bytes and limits.pixels bound the PFM.
inline Heightmap make_initial_heightmap(const Scene& scene, int nx, int ny, const Limits& limits = {}) {
    const SurfaceSpec& s = scene.surface;
    if (s.initial_pfm.empty() || s.initial_paraboloid) return initial_surface(scene, nx, ny);
    const std::filesystem::path path = detail::resolve(scene, s.initial_pfm);
    ImageF img;
    try {
        img = read_pfm(path, limits);
    } catch (const IoError& e) {
        throw IoError(std::string("surface.initial: ") + e.what());
    }
    Heightmap from_file = heightmap_from_image(scene, img, "surface.initial: heightmap '" + path.string() + "'");
    if (from_file.nx() == nx && from_file.ny() == ny) return from_file;
    return from_file.resampled(nx, ny);
}

}  // namespace freeform::io
