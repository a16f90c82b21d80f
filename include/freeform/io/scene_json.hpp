#pragma once
// Scene <-> JSON (the schema is documented key by key in docs/scene.md).
//
// scene_from_json validates everything it reads: every bad value throws InputError
// whose message starts with the dotted key path ("surface.size[1]: must be > 0, got
// -0.1"), unknown keys included (with a did-you-mean). It does no file I/O: file names
// are resolved against `base_dir` but not opened; io/scene_file.hpp checks that they
// exist. scene_to_json writes the effective scene with every default filled in, so a
// run can be reproduced from it: scene_from_json(scene_to_json(s)) gives back the same
// JSON.
#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <limits>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include <nlohmann/json.hpp>

#include "../core/enum_names.hpp"
#include "../core/error.hpp"
#include "../core/math.hpp"
#include "../core/frame.hpp"
#include "../design/options.hpp"
#include "../scene/scene.hpp"

namespace freeform {

namespace scene_json {

using json = nlohmann::json;

// Grid sizes beyond this are certainly mistakes and would overflow int arithmetic in
// the tracers (cells × rays); the limit keeps a wild value from becoming a crash.
inline constexpr std::int64_t max_grid_side = 16384;
inline constexpr std::int64_t max_rays = std::int64_t(1) << 32;
inline constexpr double max_rays_per_cell = 1 << 20;

inline InputError error(const std::string& path, const std::string& what) {
    return InputError((path.empty() ? std::string("scene") : path) + ": " + what);
}

inline std::string format_number(double x) {
    if (std::isnan(x)) return "NaN";
    if (std::isinf(x)) return x > 0 ? "inf" : "-inf";
    // Whole numbers without the ".0" that JSON's shortest form would add.
    if (x == std::floor(x) && std::abs(x) < 1e15) return std::to_string(std::int64_t(x));
    return json(x).dump();
}

// A short rendering of a value for messages ("got ..."), safe for any JSON content.
inline std::string describe(const json& v) {
    switch (v.type()) {
        case json::value_t::null: return "null";
        case json::value_t::boolean: return v.get<bool>() ? "true" : "false";
        case json::value_t::string: {
            std::string s = v.dump(-1, ' ', false, json::error_handler_t::replace);
            if (s.size() > 48) s = s.substr(0, 44) + "...\"";
            return s;
        }
        case json::value_t::number_integer:
        case json::value_t::number_unsigned: return v.dump();
        case json::value_t::number_float: return format_number(v.get<double>());
        case json::value_t::array:
            return v.empty() ? "an empty array" : "an array of " + std::to_string(v.size()) + " elements";
        case json::value_t::object: return v.empty() ? "an empty object" : "an object";
        default: return "an unsupported value";
    }
}

inline std::string index_path(const std::string& path, std::size_t k) { return path + "[" + std::to_string(k) + "]"; }

inline std::string key_path(const std::string& path, std::string_view key) {
    return path.empty() ? std::string(key) : path + "." + std::string(key);
}

inline std::size_t edit_distance(std::string_view a, std::string_view b) {
    std::vector<std::size_t> row(b.size() + 1);
    for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
    for (std::size_t i = 1; i <= a.size(); ++i) {
        std::size_t diag = row[0];
        row[0] = i;
        for (std::size_t j = 1; j <= b.size(); ++j) {
            const std::size_t up = row[j];
            const char ca = char(std::tolower(static_cast<unsigned char>(a[i - 1])));
            const char cb = char(std::tolower(static_cast<unsigned char>(b[j - 1])));
            row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (ca == cb ? 0 : 1)});
            diag = up;
        }
    }
    return row[b.size()];
}

// The closest allowed key, if it is close enough to be a plausible typo.
inline std::optional<std::string_view> closest_key(std::string_view key, std::span<const std::string_view> allowed) {
    std::optional<std::string_view> best;
    // No key is longer than 40 characters: a longer one is no typo of any (and the
    // distance costs its length times each key's).
    if (key.size() > 64) return best;
    std::size_t best_d = std::numeric_limits<std::size_t>::max();
    for (std::string_view a : allowed) {
        const std::size_t d = edit_distance(key, a);
        if (d < best_d) best_d = d, best = a;
    }
    if (best && 3 * best_d <= std::max(key.size(), best->size()) + 1) return best;
    return std::nullopt;
}

inline bool is_comment_key(std::string_view key) {
    return key == "comment" || key == "$schema" || (!key.empty() && key.front() == '_');
}

// ---- scalar readers ---------------------------------------------------------------

inline double number(const json& v, const std::string& path) {
    if (!v.is_number()) throw error(path, "expected a number, got " + describe(v));
    const double x = v.get<double>();
    if (!std::isfinite(x)) throw error(path, "must be a finite number, got " + format_number(x));
    return x;
}

inline double positive(const json& v, const std::string& path) {
    const double x = number(v, path);
    if (!(x > 0)) throw error(path, "must be > 0, got " + describe(v));
    return x;
}

// x in [lo, hi] or [lo, hi) when hi_open.
inline double number_in(const json& v, const std::string& path, double lo, double hi, bool hi_open = false) {
    const double x = number(v, path);
    if (x < lo || x > hi || (hi_open && x == hi))
        throw error(path, "must be in [" + format_number(lo) + ", " + format_number(hi) + (hi_open ? ")" : "]") +
                              ", got " + describe(v));
    return x;
}

// An integer in [lo, hi]. Integral floats (16.0, 1e3) are accepted, as JSON does not
// distinguish them.
inline std::int64_t integer(const json& v, const std::string& path, std::int64_t lo,
                            std::int64_t hi = std::numeric_limits<std::int64_t>::max()) {
    const std::string range = hi == std::numeric_limits<std::int64_t>::max()
                                  ? "an integer >= " + std::to_string(lo)
                                  : "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
    std::int64_t k = 0;
    if (v.is_number_unsigned()) {
        const std::uint64_t u = v.get<std::uint64_t>();
        if (u > std::uint64_t(hi)) throw error(path, "must be " + range + ", got " + describe(v));
        k = std::int64_t(u);
    } else if (v.is_number_integer()) {
        k = v.get<std::int64_t>();
    } else if (v.is_number_float()) {
        const double x = v.get<double>();
        if (!std::isfinite(x)) throw error(path, "must be a finite number, got " + format_number(x));
        if (x != std::floor(x)) throw error(path, "expected an integer, got " + describe(v));
        // 2^63 is the first double outside int64.
        if (!(x >= -9223372036854775808.0 && x < 9223372036854775808.0))
            throw error(path, "must be " + range + ", got " + describe(v));
        k = std::int64_t(x);
    } else {
        throw error(path, "expected an integer, got " + describe(v));
    }
    if (k < lo || k > hi) throw error(path, "must be " + range + ", got " + describe(v));
    return k;
}

inline std::uint64_t unsigned_integer(const json& v, const std::string& path) {
    if (v.is_number_unsigned()) return v.get<std::uint64_t>();
    if (v.is_number_float()) {
        const double x = v.get<double>();
        if (std::isfinite(x) && x == std::floor(x) && x >= 0 && x < 18446744073709551616.0) return std::uint64_t(x);
    }
    // Everything else is negative, fractional or not a number: let integer() word it.
    return std::uint64_t(integer(v, path, 0));
}

inline std::string string_value(const json& v, const std::string& path) {
    if (!v.is_string()) throw error(path, "expected a string, got " + describe(v));
    return v.get<std::string>();
}

inline std::filesystem::path file_path(const json& v, const std::string& path, const std::filesystem::path& base) {
    const std::string s = string_value(v, path);
    if (s.empty()) throw error(path, "expected a file path, got an empty string");
    std::filesystem::path p(s);
    if (base.empty() || p.is_absolute()) return p;
    return (base / p).lexically_normal();
}

// An enumeration's value from its name in `names` (the enum's own table, core/enum_names.hpp).
template <class E, std::size_t N>
E enumeration(const json& v, const std::string& path, const std::array<EnumName<E>, N>& names) {
    const std::string allowed = enum_list(names, "\"");
    if (!v.is_string()) throw error(path, "expected one of " + allowed + ", got " + describe(v));
    if (const std::optional<E> e = enum_value(v.get<std::string>(), names)) return *e;
    throw error(path, "must be one of " + allowed + ", got " + describe(v));
}

inline const json& array_of(const json& v, const std::string& path, std::size_t n, const char* what) {
    if (!v.is_array() || v.size() != n)
        throw error(path, "expected an array of " + std::to_string(n) + " " + what + ", got " + describe(v));
    return v;
}

inline Vec3d vec3(const json& v, const std::string& path) {
    array_of(v, path, 3, "numbers");
    return {number(v[0], index_path(path, 0)), number(v[1], index_path(path, 1)), number(v[2], index_path(path, 2))};
}

inline Vec3d nonzero_vec3(const json& v, const std::string& path) {
    const Vec3d d = vec3(v, path);
    if (!(length(d) > 0) || !std::isfinite(length(d))) throw error(path, "must be a non-zero vector, got " + v.dump());
    return d;
}

inline Vec2d positive_vec2(const json& v, const std::string& path) {
    array_of(v, path, 2, "numbers");
    return {positive(v[0], index_path(path, 0)), positive(v[1], index_path(path, 1))};
}

inline std::array<std::int64_t, 2> int_pair(const json& v, const std::string& path, std::int64_t lo, std::int64_t hi) {
    array_of(v, path, 2, "integers");
    return {integer(v[0], index_path(path, 0), lo, hi), integer(v[1], index_path(path, 1), lo, hi)};
}

// ---- objects ----------------------------------------------------------------------

// A JSON object being read, with its key path for messages.
class Object {
public:
    Object(const json& j, std::string path) : j_(j), path_(std::move(path)) {
        if (!j.is_object()) throw error(path_, "expected an object, got " + describe(j));
    }

    const std::string& path() const { return path_; }
    std::string at(std::string_view key) const { return key_path(path_, key); }

    const json* find(std::string_view key) const {
        const auto it = j_.find(std::string(key));
        return it == j_.end() ? nullptr : &*it;
    }
    const json& require(std::string_view key) const {
        if (const json* v = find(key)) return *v;
        throw error(at(key), "missing required key");
    }

    // Every key must be allowed or a comment. `foreign(key)` may explain why a key that
    // is valid elsewhere does not belong here.
    template <class Foreign>
    void only(std::span<const std::string_view> allowed, Foreign&& foreign) const {
        for (const auto& item : j_.items()) {
            const std::string& key = item.key();
            if (is_comment_key(key)) continue;
            if (std::find(allowed.begin(), allowed.end(), key) != allowed.end()) continue;
            if (std::optional<std::string> why = foreign(key)) throw error(at(key), *why);
            std::string msg = "unknown key";
            if (auto near = closest_key(key, allowed)) msg += " (did you mean '" + std::string(*near) + "'?)";
            std::string list;
            for (std::string_view a : allowed) list += (list.empty() ? "" : ", ") + std::string(a);
            throw error(at(key), msg + "; allowed keys: " + list);
        }
    }
    void only(std::span<const std::string_view> allowed) const {
        only(allowed, [](const std::string&) { return std::optional<std::string>{}; });
    }

private:
    const json& j_;
    std::string path_;
};

// A saved scene holds the frame's own unit vectors; keep inputs that already are (to
// rounding) those vectors verbatim, so that a saved scene reloads bit for bit.
inline Frame read_frame(const Object& o, Vec3d center, Vec3d normal, Vec3d up, const std::string& what) {
    if (const json* v = o.find("center")) center = vec3(*v, o.at("center"));
    if (const json* v = o.find("normal")) normal = nonzero_vec3(*v, o.at("normal"));
    if (const json* v = o.find("up")) up = nonzero_vec3(*v, o.at("up"));
    Frame f = make_frame(center, normal, up, what);
    const auto close = [](Vec3d a, Vec3d b) {
        return std::abs(a.x - b.x) <= 1e-14 && std::abs(a.y - b.y) <= 1e-14 && std::abs(a.z - b.z) <= 1e-14;
    };
    if (close(f.w, normal)) f.w = normal;
    if (close(f.v, up)) f.v = up;
    f.u = cross(f.v, f.w);
    return f;
}

inline json vec_json(Vec3d v) { return json::array({v.x, v.y, v.z}); }
inline json vec_json(Vec2d v) { return json::array({v.x, v.y}); }

// ---- blocks -----------------------------------------------------------------------

// surface.material at path p: "mirror" or a lens (whose back face must lie below h_min).
inline Material read_material(const json& v, const std::string& p, double h_min) {
    if (v.is_string() && v.get<std::string>() == "mirror") return Mirror{};
    if (!v.is_object())
        throw error(p, "expected \"mirror\" or {\"refractive\": ior, \"thickness\": metres, \"rim\": metres}, got " +
                           describe(v));
    const Object m(v, p);
    static constexpr std::array<std::string_view, 3> lens_keys{"refractive", "thickness", "rim"};
    m.only(lens_keys, [](const std::string& k) -> std::optional<std::string> {
        if (k == "mirror") return "a mirror is written \"material\": \"mirror\"";
        return std::nullopt;
    });
    Lens lens;
    lens.ior = number(m.require("refractive"), m.at("refractive"));
    if (!(lens.ior > 1)) throw error(m.at("refractive"), "the refractive index must be > 1, got " + format_number(lens.ior));
    if (const json* t = m.find("thickness")) lens.thickness = positive(*t, m.at("thickness"));
    if (!(lens.thickness > -h_min))
        throw error(m.at("thickness"), "must be > " + format_number(-h_min) +
                                           " (minus surface.height_bounds[0]) so that the flat back face lies below "
                                           "the lowest height, got " +
                                           format_number(lens.thickness));
    if (const json* r = m.find("rim")) {
        if (r->is_string() && r->get<std::string>() == "auto") lens.rim = -1;
        else if (r->is_string()) throw error(m.at("rim"), "expected \"auto\" or metres >= 0, got " + describe(*r));
        else lens.rim = number_in(*r, m.at("rim"), 0, 1);
    }
    return lens;
}

inline SurfaceSpec read_surface(const json& j, const std::filesystem::path& base) {
    const Object o(j, "surface");
    static constexpr std::array<std::string_view, 11> keys{"center",   "normal",      "up",     "size",
                                                           "mesh",     "height_bounds", "aperture", "material",
                                                           "phong_alpha", "initial",    "tool_radius"};
    o.only(keys);
    SurfaceSpec s;
    s.frame = read_frame(o, {0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
    if (const json* v = o.find("size")) s.size = positive_vec2(*v, o.at("size"));
    if (const json* v = o.find("mesh")) {
        if (!(v->is_string() && v->get<std::string>() == "auto")) {
            if (v->is_string()) throw error(o.at("mesh"), "expected \"auto\" or an array of 2 integers, got " + describe(*v));
            const auto m = int_pair(*v, o.at("mesh"), 2, max_grid_side);
            s.nx = int(m[0]);
            s.ny = int(m[1]);
        }
    }
    if (const json* v = o.find("height_bounds")) {
        const std::string p = o.at("height_bounds");
        array_of(*v, p, 2, "numbers");
        s.h_min = number((*v)[0], index_path(p, 0));
        s.h_max = number((*v)[1], index_path(p, 1));
        if (!(s.h_min < s.h_max))
            throw error(p, "inverted: the minimum " + format_number(s.h_min) + " must be below the maximum " +
                               format_number(s.h_max));
    }
    if (const json* v = o.find("aperture")) s.aperture = enumeration(*v, o.at("aperture"), aperture_names);
    if (const json* v = o.find("material")) s.material = read_material(*v, o.at("material"), s.h_min);
    if (const json* v = o.find("phong_alpha")) s.phong_alpha = number_in(*v, o.at("phong_alpha"), 0, 1);
    if (const json* v = o.find("tool_radius")) s.tool_radius = number_in(*v, o.at("tool_radius"), 0, 1);
    if (const json* v = o.find("initial")) {
        const std::string p = o.at("initial");
        const char* expected =
            "expected \"transport\", \"flat\", the path of a .pfm heightmap or {\"paraboloid\": {\"focal_length\": f}}";
        if (v->is_string()) {
            const std::string str = v->get<std::string>();
            if (str == "flat") {
                s.initial_shape = InitialShape::flat;
            } else if (str == "transport") {
                s.initial_shape = InitialShape::transport;
            } else {
                std::string ext = std::filesystem::path(str).extension().string();
                std::transform(ext.begin(), ext.end(), ext.begin(),
                               [](unsigned char c) { return char(std::tolower(c)); });
                if (ext != ".pfm") throw error(p, std::string(expected) + ", got " + describe(*v));
                s.initial_pfm = file_path(*v, p, base);
            }
        } else if (v->is_object()) {
            const Object init(*v, p);
            static constexpr std::array<std::string_view, 1> init_keys{"paraboloid"};
            init.only(init_keys);
            const Object para(init.require("paraboloid"), init.at("paraboloid"));
            static constexpr std::array<std::string_view, 1> para_keys{"focal_length"};
            para.only(para_keys);
            InitialParaboloid pb;
            if (const json* f = para.find("focal_length")) pb.focal_length = positive(*f, para.at("focal_length"));
            s.initial_paraboloid = pb;
        } else {
            throw error(p, std::string(expected) + ", got " + describe(*v));
        }
    }
    return s;
}

inline Receiver read_receiver(const json& j) {
    const Object o(j, "receiver");
    static constexpr std::array<std::string_view, 6> keys{"center", "normal", "up", "size", "resolution", "deposit"};
    o.only(keys);
    Receiver r;
    r.frame = read_frame(o, {0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
    if (const json* v = o.find("size")) r.size = positive_vec2(*v, o.at("size"));
    if (const json* v = o.find("resolution")) {
        const auto res = int_pair(*v, o.at("resolution"), 1, max_grid_side);
        r.width = int(res[0]);
        r.height = int(res[1]);
    }
    if (const json* v = o.find("deposit")) r.deposit = enumeration(*v, o.at("deposit"), deposit_names);
    return r;
}

inline std::vector<std::pair<double, double>> read_profile(const json& v, const std::string& path) {
    if (!v.is_array() || v.size() < 2)
        throw error(path, "expected an array of at least 2 [angle in degrees, intensity] rows, got " + describe(v));
    std::vector<std::pair<double, double>> rows;
    bool any_light = false;
    for (std::size_t k = 0; k < v.size(); ++k) {
        const std::string p = index_path(path, k);
        array_of(v[k], p, 2, "numbers ([angle in degrees, intensity])");
        const double deg = number_in(v[k][0], index_path(p, 0), 0, 180);
        const double intensity = number(v[k][1], index_path(p, 1));
        if (!(intensity >= 0)) throw error(index_path(p, 1), "the intensity must be >= 0, got " + describe(v[k][1]));
        if (!rows.empty() && !(deg > rows.back().first))
            throw error(index_path(p, 0), "angles must be strictly increasing, got " + format_number(deg) + " after " +
                                              format_number(rows.back().first));
        any_light = any_light || intensity > 0;
        rows.emplace_back(deg, intensity);
    }
    if (!any_light) throw error(path, "every intensity is zero: the light emits nothing");
    return rows;
}

// Sources behind the surface or inside its height slab cannot light it; say so
// here, with the key, rather than when rays are generated.
inline void check_in_front(Vec3d p, const std::string& key, const SurfaceSpec& surface) {
    if (!(surface.frame.to_local(p).z > surface.h_max))
        throw error(key,
                    "must lie in front of the surface (on the side surface.normal points to) and above "
                    "its highest allowed height, got " +
                        vec_json(p).dump());
}

inline CollimatedLight read_collimated_light(const Object& o, const SurfaceSpec& surface) {
    const Frame& sf = surface.frame;
    CollimatedLight c;
    if (const json* v = o.find("direction")) c.direction = nonzero_vec3(*v, o.at("direction"));
    if (!(dot(normalize(c.direction), sf.w) < -1e-9))
        throw error(o.at("direction"), "must point towards the surface's front (against surface.normal), got " +
                                           vec_json(c.direction).dump());
    if (const json* v = o.find("angular_radius"))
        c.angular_radius = number_in(*v, o.at("angular_radius"), 0, max_angular_radius);
    const double tilt = std::acos(std::clamp(-dot(normalize(c.direction), sf.w), -1.0, 1.0)) * 180.0 / pi;
    if (c.angular_radius > 0 && tilt + c.angular_radius >= 89.0)
        throw error(o.at("angular_radius"), "the source's edge, " + format_number(c.angular_radius) +
                                                " degrees around light.direction, would graze the surface "
                                                "(it is tilted " + format_number(tilt) + " degrees from its normal)");
    return c;
}

inline PointLight read_point_light(const Object& o, const SurfaceSpec& surface) {
    PointLight p;
    p.position = vec3(o.require("position"), o.at("position"));
    check_in_front(p.position, o.at("position"), surface);
    if (const json* v = o.find("axis"))
        p.axis = nonzero_vec3(*v, o.at("axis"));
    else if (!(length(surface.frame.origin - p.position) > 0))
        throw error(o.at("axis"),
                    "cannot default to \"towards the surface centre\": light.position is "
                    "the surface centre");
    if (const json* v = o.find("profile")) p.profile = read_profile(*v, o.at("profile"));
    return p;
}

inline DiskLight read_disk_light(const Object& o, const SurfaceSpec& surface) {
    DiskLight d;
    d.center = vec3(o.require("center"), o.at("center"));
    check_in_front(d.center, o.at("center"), surface);
    if (const json* v = o.find("normal")) d.normal = nonzero_vec3(*v, o.at("normal"));
    d.radius = positive(o.require("radius"), o.at("radius"));
    return d;
}

inline Light read_light(const json& j, const SurfaceSpec& surface) {
    const Object o(j, "light");
    const std::size_t type = enumeration(o.require("type"), o.at("type"), light_type_names);
    static constexpr std::array<std::string_view, 3> common{"type", "rays_per_cell", "rays"};
    static constexpr std::array<std::array<std::string_view, 3>, 3> own{
        {{"direction", "angular_radius", ""}, {"position", "axis", "profile"}, {"center", "normal", "radius"}}};
    std::vector<std::string_view> allowed(common.begin(), common.end());
    for (std::string_view k : own[type])
        if (!k.empty()) allowed.push_back(k);
    o.only(allowed, [&](const std::string& key) -> std::optional<std::string> {
        if (key.empty()) return std::nullopt;  // "" pads the key table, it is no key
        for (std::size_t t = 0; t < own.size(); ++t)
            if (t != type && std::find(own[t].begin(), own[t].end(), key) != own[t].end())
                return "not a key of a " + std::string(enum_name(type, light_type_names)) + " light (it belongs to a " +
                       std::string(enum_name(t, light_type_names)) + " light)";
        return std::nullopt;
    });

    Light light;
    if (const json* v = o.find("rays_per_cell")) {
        light.rays_per_cell = positive(*v, o.at("rays_per_cell"));
        if (light.rays_per_cell > max_rays_per_cell)
            throw error(o.at("rays_per_cell"),
                        "must be at most " + format_number(max_rays_per_cell) + ", got " + describe(*v));
    }
    if (const json* v = o.find("rays")) light.rays = integer(*v, o.at("rays"), 1, max_rays);

    switch (type) {
        case 0: light.shape = read_collimated_light(o, surface); break;
        case 1: light.shape = read_point_light(o, surface); break;
        default: light.shape = read_disk_light(o, surface); break;
    }
    return light;
}

inline TargetSpec read_target(const json& j, const std::filesystem::path& base) {
    const Object o(j, "target");
    static constexpr std::array<std::string_view, 6> keys{"image", "text", "font", "margin", "upsample", "fit"};
    o.only(keys);
    const json* image = o.find("image");
    const json* text = o.find("text");
    if (image && text) throw error("target", "give either target.image or target.text, not both");
    if (!image && !text) throw error("target", "needs target.image (a picture file) or target.text");
    TargetSpec t;
    if (image) {
        for (std::string_view k : {"font", "margin"})
            if (o.find(k)) throw error(o.at(k), "only applies to a text target (target.text)");
        t.image = file_path(*image, o.at("image"), base);
        if (const json* v = o.find("upsample")) t.upsample = enumeration(*v, o.at("upsample"), target_upsample_names);
        if (const json* v = o.find("fit")) t.fit = enumeration(*v, o.at("fit"), target_fit_names);
        return t;
    }
    for (std::string_view k : {"upsample", "fit"})
        if (o.find(k)) throw error(o.at(k), "only applies to an image target (target.image)");
    t.text = string_value(*text, o.at("text"));
    if (t.text.empty()) throw error(o.at("text"), "must not be empty");
    if (const json* v = o.find("font")) {
        t.font = string_value(*v, o.at("font"));
        if (t.font.empty()) throw error(o.at("font"), "must not be empty");
    }
    if (const json* v = o.find("margin")) t.margin = number_in(*v, o.at("margin"), 0, 0.45, true);
    return t;
}

// "absorber", "mirror" or {"refractive": ior} (a closed solid, see MeshMaterial).
inline MeshMaterial read_mesh_material(const json& v, const std::string& p) {
    if (v.is_object()) {
        const Object m(v, p);
        static constexpr std::array<std::string_view, 1> keys{"refractive"};
        m.only(keys, [](const std::string& k) -> std::optional<std::string> {
            if (k == "thickness") return "a refractive mesh is a closed solid: its shape gives the thickness";
            return std::nullopt;
        });
        const double ior = number(m.require("refractive"), m.at("refractive"));
        if (!(ior > 1))
            throw error(m.at("refractive"), "the refractive index must be > 1, got " + format_number(ior));
        return MeshMaterial::refractive(ior);
    }
    if (v.is_string())
        if (const std::optional<MeshKind> kind = enum_value(v.get<std::string>(), mesh_material_names))
            return MeshMaterial{*kind, 1.49};
    throw error(p, "expected " + enum_list(mesh_material_names, "\"") + " or {\"refractive\": ior}, got " + describe(v));
}

inline std::vector<MeshSpec> read_meshes(const json& j, const std::filesystem::path& base) {
    if (!j.is_array())
        throw error("meshes", "expected an array of {\"file\": ..., \"material\": ...}, got " + describe(j));
    std::vector<MeshSpec> meshes;
    for (std::size_t k = 0; k < j.size(); ++k) {
        const Object o(j[k], index_path("meshes", k));
        static constexpr std::array<std::string_view, 2> keys{"file", "material"};
        o.only(keys);
        MeshSpec m;
        m.file = file_path(o.require("file"), o.at("file"), base);
        if (const json* v = o.find("material")) m.material = read_mesh_material(*v, o.at("material"));
        meshes.push_back(std::move(m));
    }
    return meshes;
}

inline bool boolean(const json& v, const std::string& path) {
    if (!v.is_boolean()) throw error(path, "expected true or false, got " + describe(v));
    return v.get<bool>();
}

inline TraceSpec read_trace(const json& j) {
    const Object o(j, "trace");
    static constexpr std::array<std::string_view, 3> keys{"tracer", "max_depth", "fresnel"};
    o.only(keys);
    TraceSpec t;
    if (const json* v = o.find("tracer")) t.tracer = enumeration(*v, o.at("tracer"), tracer_names);
    if (const json* v = o.find("max_depth")) t.max_depth = int(integer(*v, o.at("max_depth"), 1, 64));
    if (const json* v = o.find("fresnel")) t.fresnel = boolean(*v, o.at("fresnel"));
    return t;
}

// An integer n or a pair [x, y] of integers in [lo, hi].
inline std::array<std::int64_t, 2> int_or_pair(const json& v, const std::string& path, std::int64_t lo,
                                               std::int64_t hi) {
    if (v.is_number()) {
        const std::int64_t n = integer(v, path, lo, hi);
        return {n, n};
    }
    return int_pair(v, path, lo, hi);
}

inline std::vector<LevelPlan> read_levels(const json& v, const std::string& path) {
    if (!v.is_array() || v.empty()) throw error(path, "expected a non-empty array of level objects, got " + describe(v));
    std::vector<LevelPlan> levels;
    for (std::size_t k = 0; k < v.size(); ++k) {
        const Object o(v[k], index_path(path, k));
        static constexpr std::array<std::string_view, 5> keys{"mesh", "resolution", "kernels", "time_share",
                                                              "iterations"};
        o.only(keys);
        LevelPlan l;
        const auto m = int_or_pair(o.require("mesh"), o.at("mesh"), 2, max_grid_side);
        l.mesh_x = int(m[0]), l.mesh_y = int(m[1]);
        const auto r = int_or_pair(o.require("resolution"), o.at("resolution"), 1, max_grid_side);
        l.resolution_x = int(r[0]), l.resolution_y = int(r[1]);
        if (const json* ks = o.find("kernels")) {
            const std::string kp = o.at("kernels");
            if (!ks->is_array() || ks->empty()) throw error(kp, "expected a non-empty array of odd integers, got " + describe(*ks));
            for (std::size_t i = 0; i < ks->size(); ++i) {
                const std::int64_t s = integer((*ks)[i], index_path(kp, i), 1, 2001);
                if (s % 2 == 0) throw error(index_path(kp, i), "must be odd, got " + std::to_string(s));
                l.kernel_supports.push_back(int(s));
            }
        }
        if (const json* t = o.find("time_share")) l.time_share = number_in(*t, o.at("time_share"), 0, 1);
        if (const json* t = o.find("iterations")) l.iterations = integer(*t, o.at("iterations"), 0);
        levels.push_back(l);
    }
    return levels;
}

inline json levels_json(const std::vector<LevelPlan>& levels) {
    json out = json::array();
    for (const auto& l : levels) {
        json j = json::object();
        j["mesh"] = json::array({l.mesh_x, l.mesh_y});
        j["resolution"] = json::array({l.resolution_x, l.resolution_y});
        if (!l.kernel_supports.empty()) j["kernels"] = l.kernel_supports;
        j["time_share"] = l.time_share;
        j["iterations"] = l.iterations;
        out.push_back(j);
    }
    return out;
}

// The optimiser keys, one row each, each a field of DesignOptions or of the option
// struct of the module it belongs to (design/options.hpp). Most are a plain field (a
// number, an integer or a flag) read within [lo, hi] ([lo, hi) when hi_open) and written
// as it is, reached through field<...> (the path of members from DesignOptions down); the
// rest name a reader and a writer of their own. Adding a setting is adding a row (and a
// field to its module's options).
template <auto... Members>
auto& field(DesignOptions& o) {
    return (o.*....*Members);
}

using OptimiseField =
    std::variant<std::monostate, double& (*)(DesignOptions&), int& (*)(DesignOptions&),
                 std::int64_t& (*)(DesignOptions&), std::uint64_t& (*)(DesignOptions&), bool& (*)(DesignOptions&)>;

struct OptimiseKey {
    std::string_view name;
    OptimiseField field{};
    double lo = 0, hi = std::numeric_limits<double>::infinity();  // integers: hi = inf is no upper bound
    bool hi_open = false;
    void (*read)(const json& v, const std::string& path, DesignOptions& o) = nullptr;
    void (*write)(const DesignOptions& o, std::string_view name, json& j) = nullptr;
};

// Keys that are not a plain field.
inline void read_time_budget(const json& v, const std::string& p, DesignOptions& o) { o.time_budget = positive(v, p); }
inline void write_time_budget(const DesignOptions& o, std::string_view n, json& j) {
    j[std::string(n)] = o.time_budget;
}

inline void read_levels_key(const json& v, const std::string& p, DesignOptions& o) { o.levels = read_levels(v, p); }
inline void write_levels_key(const DesignOptions& o, std::string_view n, json& j) {
    if (!o.levels.empty()) j[std::string(n)] = levels_json(o.levels);
}

inline void read_start_level(const json& v, const std::string& p, DesignOptions& o) {
    if (v.is_string() && v.get<std::string>() == "auto")
        o.start_level = -1;
    else if (v.is_number_integer())
        o.start_level = int(integer(v, p, 0, 16));
    else
        throw error(p, "expected \"auto\" or the index of the first planned level to run (0 = the coarsest), got " +
                           describe(v));
}
inline void write_start_level(const DesignOptions& o, std::string_view n, json& j) {
    j[std::string(n)] = o.start_level < 0 ? json("auto") : json(o.start_level);
}

inline void read_export_subdivisions(const json& v, const std::string& p, DesignOptions& o) {
    if (v.is_string() && v.get<std::string>() == "auto")
        o.exports.subdivisions = 0;
    else if (v.is_number_integer())
        o.exports.subdivisions = int(integer(v, p, 1, 64));
    else
        throw error(p, "expected \"auto\" or a subdivision level from 1 to 64, got " + describe(v));
}
inline void write_export_subdivisions(const DesignOptions& o, std::string_view n, json& j) {
    j[std::string(n)] = o.exports.subdivisions <= 0 ? json("auto") : json(o.exports.subdivisions);
}

// "auto" or a list of distinct format names.
inline void read_export_formats(const json& v, const std::string& p, DesignOptions& o) {
    std::vector<ExportFormat>& formats = o.exports.formats;
    formats.clear();
    if (v.is_string() && v.get<std::string>() == "auto") return;
    if (!v.is_array() || v.empty())
        throw error(p, "expected \"auto\" or a non-empty list of " + enum_list(export_format_names, "\"") + ", got " +
                           describe(v));
    for (std::size_t k = 0; k < v.size(); ++k) {
        const ExportFormat f = enumeration(v[k], p + "[" + std::to_string(k) + "]", export_format_names);
        if (std::find(formats.begin(), formats.end(), f) != formats.end())
            throw error(p, "\"" + std::string(to_string(f)) + "\" is listed twice");
        formats.push_back(f);
    }
}
inline void write_export_formats(const DesignOptions& o, std::string_view n, json& j) {
    if (o.exports.formats.empty()) {
        j[std::string(n)] = "auto";
        return;
    }
    json list = json::array();
    for (const ExportFormat f : o.exports.formats) list.push_back(std::string(to_string(f)));
    j[std::string(n)] = list;
}

// An enum field reached by Members whose names are Names (the table beside the enum).
template <const auto& Names, auto... Members>
void read_enum_key(const json& v, const std::string& p, DesignOptions& o) {
    field<Members...>(o) = enumeration(v, p, Names);
}
template <const auto& Names, auto... Members>
void write_enum_key(const DesignOptions& o, std::string_view n, json& j) {
    DesignOptions copy = o;
    j[std::string(n)] = enum_name(field<Members...>(copy), Names);
}

inline std::span<const OptimiseKey> optimise_keys() {
    using S = DesignOptions;
    using O = ObjectiveWeights;
    using W = PenaltyWeights;
    using P = ProposalOptions;
    using C = ScheduleOptions;
    static constexpr double any = std::numeric_limits<double>::infinity();
    static constexpr OptimiseKey table[] = {
        {.name = "time_budget", .read = read_time_budget, .write = write_time_budget},
        {"seed", &field<&S::seed>},
        {"max_iterations", &field<&S::max_iterations>, 0, any},
        {"target_error", &field<&S::target_error>, 0, 1, true},
        {"threads", &field<&S::threads>, 0, 65536},
        {"speculative", &field<&S::speculative>, 0, 256},
        {.name = "levels", .read = read_levels_key, .write = write_levels_key},
        {"multilevel", &field<&S::multilevel>},
        {.name = "start_level", .read = read_start_level, .write = write_start_level},
        {"refine_initial_acceptance", &field<&S::schedule, &C::refine_initial_acceptance>, 1e-6, 0.999},
        {"refine_max_shift_cells", &field<&S::proposals, &P::refine_max_shift_cells>, 0.01, 100},
        {"coarse_rays_per_cell", &field<&S::coarse_rays_per_cell>, 0, 1 << 20},
        {"min_rays_per_mesh_cell", &field<&S::min_rays_per_mesh_cell>, 0, 1 << 16},
        {"initial_temperature_scale", &field<&S::schedule, &C::initial_temperature_scale>, 1e-6, 1e6},
        {"held_out_checks", &field<&S::held_out_checks>},
        {"sobel_weight", &field<&S::objective, &O::sobel>, 0, 10},
        {"energy_threshold", &field<&S::objective, &O::energy_threshold>, 0, 1},
        {"lost_light_weight", &field<&S::objective, &O::lost_light>, 0, 100},
        {"height_bound_weight", &field<&S::penalties, &W::height_bound>, 0, 1e6},
        {"valley_weight", &field<&S::penalties, &W::valley>, 0, 1e6},
        {"valley_min_angle", &field<&S::penalties, &W::valley_min_angle>, 0, 180},
        {"smoothness_weight", &field<&S::penalties, &W::smoothness>, 0, 1e6},
        {.name = "evaluation",
         .read = read_enum_key<evaluation_names, &S::evaluation>,
         .write = write_enum_key<evaluation_names, &S::evaluation>},
        {.name = "device",
         .read = read_enum_key<device_names, &S::device>,
         .write = write_enum_key<device_names, &S::device>},
        {.name = "kernel_shapes",
         .read = read_enum_key<kernel_shape_names, &S::proposals, &P::kernel_shapes>,
         .write = write_enum_key<kernel_shape_names, &S::proposals, &P::kernel_shapes>},
        {.name = "bandit",
         .read = read_enum_key<bandit_kind_names, &S::proposals, &P::bandit>,
         .write = write_enum_key<bandit_kind_names, &S::proposals, &P::bandit>},
        {"bandit_sync", &field<&S::proposals, &P::bandit_sync>, 1, 1 << 20},
        {"preprocess_iterations", &field<&S::proposals, &P::preprocess_iterations>, 0, any},
        {"preprocess_keep", &field<&S::proposals, &P::preprocess_keep>, 1, 64},
        {"error_guided", &field<&S::proposals, &P::error_guided>},
        {"single_vertex", &field<&S::proposals, &P::single_vertex>},
        {"max_shift_cells", &field<&S::proposals, &P::max_shift_cells>, 1e-6, 1e4},
        {"min_shift_cells", &field<&S::proposals, &P::min_shift_cells>, 0, 1e4},
        {"initial_acceptance", &field<&S::schedule, &C::initial_acceptance>, 1e-6, 0.999},
        {"cooling", &field<&S::schedule, &C::cooling>, 1e-6, 1},
        {"temperature_steps", &field<&S::schedule, &C::temperature_steps>, 1, 1 << 24},
        {"reheat_factor", &field<&S::schedule, &C::reheat_factor>, 1e-6, 1},
        {"patience_fraction", &field<&S::schedule, &C::patience_fraction>, 0, 1},
        {"smooth_iterations", &field<&S::smooth_iterations>, 0, 10000},
        {"keep_better_start", &field<&S::keep_better_start>},
        {.name = "export_subdivisions", .read = read_export_subdivisions, .write = write_export_subdivisions},
        {"export_tolerance", &field<&S::exports, &ExportOptions::tolerance>, 0.01, 10},
        {"export_max_triangles", &field<&S::exports, &ExportOptions::max_triangles>, 1000, 1'000'000'000},
        {.name = "export_formats", .read = read_export_formats, .write = write_export_formats},
        {.name = "export_spline",
         .read = read_enum_key<spline_form_names, &S::exports, &ExportOptions::spline>,
         .write = write_enum_key<spline_form_names, &S::exports, &ExportOptions::spline>},
    };
    return table;
}

// Reads key k from v into o: its own reader, or its field within [lo, hi].
inline void read_optimise_key(const OptimiseKey& k, const json& v, const std::string& p, DesignOptions& o) {
    if (k.read) return k.read(v, p, o);
    const auto bound = [](double x) {  // an integer bound; inf: none
        return x >= 9.2e18 ? std::numeric_limits<std::int64_t>::max() : std::int64_t(x);
    };
    std::visit(
        [&](auto get) {
            using M = decltype(get);
            if constexpr (std::is_same_v<M, double& (*)(DesignOptions&)>)
                get(o) = number_in(v, p, k.lo, k.hi, k.hi_open);
            else if constexpr (std::is_same_v<M, bool& (*)(DesignOptions&)>)
                get(o) = boolean(v, p);
            else if constexpr (std::is_same_v<M, std::uint64_t& (*)(DesignOptions&)>)
                get(o) = unsigned_integer(v, p);
            else if constexpr (!std::is_same_v<M, std::monostate>)  // int or int64
                get(o) = std::remove_reference_t<decltype(get(o))>(integer(v, p, bound(k.lo), bound(k.hi)));
        },
        k.field);
}

// Writes key k of `o` into j (the fields are reached through the readers' accessors, so
// `o` is the writer's own copy).
inline void write_optimise_key(const OptimiseKey& k, DesignOptions& o, json& j) {
    if (k.write) return k.write(o, k.name, j);
    std::visit(
        [&](auto get) {
            if constexpr (!std::is_same_v<decltype(get), std::monostate>) j[std::string(k.name)] = get(o);
        },
        k.field);
}

inline DesignOptions read_optimise(const json& j, const std::string& path) {
    const Object o(j, path);
    std::vector<std::string_view> keys;
    for (const auto& k : optimise_keys()) keys.push_back(k.name);
    o.only(keys);
    DesignOptions spec;
    for (const auto& k : optimise_keys())
        if (const json* v = o.find(k.name)) read_optimise_key(k, *v, o.at(k.name), spec);
    return spec;
}

}  // namespace scene_json

// Parses and validates a scene file: the scene and its design options (the "optimise"
// block). Relative file names are resolved against `base_dir` (made absolute when given;
// left relative to the working directory when empty) and stored resolved;
// Scene::base_dir is set to it. Throws InputError naming the key.
inline DesignJob job_from_json(const nlohmann::json& j, const std::filesystem::path& base_dir = {}) {
    using namespace scene_json;
    const Object top(j, "");
    static constexpr std::array<std::string_view, 10> keys{"light", "surface",  "receiver", "target", "meshes",
                                                           "trace", "optimise", "optimize", "name",   "description"};
    top.only(keys);
    DesignJob job;
    Scene& s = job.scene;
    if (!base_dir.empty()) {
        std::error_code ec;  // absolute() only fails without a working directory; keep the name then
        const std::filesystem::path abs = std::filesystem::absolute(base_dir, ec);
        s.base_dir = (ec ? base_dir : abs).lexically_normal();
    }
    // The surface comes first: the light is checked against its frame and bounds.
    s.surface = read_surface(top.require("surface"), s.base_dir);
    s.receiver = read_receiver(top.require("receiver"));
    s.light = read_light(top.require("light"), s.surface);
    if (const json* v = top.find("target")) s.target = read_target(*v, s.base_dir);
    if (const json* v = top.find("meshes")) s.meshes = read_meshes(*v, s.base_dir);
    if (const json* v = top.find("trace")) s.trace = read_trace(*v);
    if (top.find("optimise") && top.find("optimize"))
        throw error("optimize", "give either \"optimise\" or \"optimize\", not both");
    if (const json* v = top.find("optimise")) job.options = read_optimise(*v, "optimise");
    if (const json* v = top.find("optimize")) job.options = read_optimise(*v, "optimize");
    if (const json* v = top.find("name")) s.name = string_value(*v, "name");
    if (const json* v = top.find("description")) s.description = string_value(*v, "description");

    if (!s.meshes.empty() && s.trace.tracer == TracerChoice::heightfield)
        throw error("trace.tracer", "\"heightfield\" cannot trace the " + std::to_string(s.meshes.size()) +
                                        " extra mesh(es) in \"meshes\"; use \"embree\" or \"auto\"");
    // Said now, not after a whole budget spent designing at zero energy.
    if (s.meshes.empty() && surface_behind_receiver(s))
        throw error("receiver.normal",
                    "the receiver faces away from the surface: every point of the surface lies behind its "
                    "plane, so no light can reach its front (the normal points from the receiver towards the "
                    "surface; check receiver.center and receiver.normal)");
    return job;
}

// The scene of a scene file alone (job_from_json(j, base_dir).scene): the whole file is
// still read and checked, its "optimise" block included.
inline Scene scene_from_json(const nlohmann::json& j, const std::filesystem::path& base_dir = {}) {
    return job_from_json(j, base_dir).scene;
}

namespace scene_json {

inline json light_to_json(const Scene& s) {
    json light = json::object();
    light["type"] = light_type_name(s.light.shape);
    light["rays_per_cell"] = s.light.rays_per_cell;
    if (s.light.rays > 0) light["rays"] = s.light.rays;
    if (const auto* c = std::get_if<CollimatedLight>(&s.light.shape)) {
        light["direction"] = vec_json(c->direction);
        if (c->angular_radius > 0) light["angular_radius"] = c->angular_radius;
    } else if (const auto* p = std::get_if<PointLight>(&s.light.shape)) {
        light["position"] = vec_json(p->position);
        // The default axis (towards the surface centre) is written out explicitly.
        Vec3d axis = p->axis;
        if (!(length(axis) > 0)) axis = s.surface.frame.origin - p->position;
        if (length(axis) > 0) light["axis"] = vec_json(axis);
        if (!p->profile.empty()) {
            json rows = json::array();
            for (const auto& [deg, intensity] : p->profile) rows.push_back(json::array({deg, intensity}));
            light["profile"] = rows;
        }
    } else {
        const auto& d = std::get<DiskLight>(s.light.shape);
        light["center"] = vec_json(d.center);
        light["normal"] = vec_json(d.normal);
        light["radius"] = d.radius;
    }
    return light;
}

inline json surface_to_json(const Scene& s) {
    const SurfaceSpec& sf = s.surface;
    json surface = json::object();
    surface["center"] = vec_json(sf.frame.origin);
    surface["normal"] = vec_json(sf.frame.w);
    surface["up"] = vec_json(sf.frame.v);
    surface["size"] = vec_json(sf.size);
    surface["mesh"] = sf.nx > 0 ? json::array({sf.nx, sf.ny}) : json("auto");
    surface["height_bounds"] = json::array({sf.h_min, sf.h_max});
    surface["aperture"] = enum_name(sf.aperture, aperture_names);
    if (const auto* lens = std::get_if<Lens>(&sf.material))
        surface["material"] = json{{"refractive", lens->ior},
                                   {"thickness", lens->thickness},
                                   {"rim", lens->rim < 0 ? json("auto") : json(lens->rim)}};
    else
        surface["material"] = "mirror";
    surface["phong_alpha"] = sf.phong_alpha;
    if (sf.tool_radius > 0) surface["tool_radius"] = sf.tool_radius;
    if (!sf.initial_pfm.empty())
        surface["initial"] = sf.initial_pfm.string();
    else if (sf.initial_paraboloid)
        surface["initial"] = json{{"paraboloid", {{"focal_length", sf.initial_paraboloid->focal_length}}}};
    else
        surface["initial"] = starts_from_transport(s) ? "transport" : "flat";
    return surface;
}

}  // namespace scene_json

// The effective scene with every default written out (file names as given to the
// Scene, i.e. resolved when it was loaded), without an "optimise" block (job_to_json
// writes one). Reading it back gives the same JSON.
inline nlohmann::json scene_to_json(const Scene& s) {
    using namespace scene_json;
    json out = json::object();
    if (!s.name.empty()) out["name"] = s.name;
    if (!s.description.empty()) out["description"] = s.description;
    out["light"] = light_to_json(s);
    out["surface"] = surface_to_json(s);

    const Receiver& r = s.receiver;
    out["receiver"] = json{{"center", vec_json(r.frame.origin)},
                           {"normal", vec_json(r.frame.w)},
                           {"up", vec_json(r.frame.v)},
                           {"size", vec_json(r.size)},
                           {"resolution", json::array({r.width, r.height})},
                           {"deposit", enum_name(r.deposit, deposit_names)}};

    if (s.target) {
        if (!s.target->image.empty())
            out["target"] = json{{"image", s.target->image.string()},
                                 {"upsample", enum_name(s.target->upsample, target_upsample_names)},
                                 {"fit", enum_name(s.target->fit, target_fit_names)}};
        else
            out["target"] = json{{"text", s.target->text}, {"font", s.target->font}, {"margin", s.target->margin}};
    }
    json meshes = json::array();
    for (const auto& m : s.meshes)
        meshes.push_back(json{{"file", m.file.string()},
                              {"material", m.material.is_refractive() ? json{{"refractive", m.material.ior}}
                                                                      : json(enum_name(m.material.kind, mesh_material_names))}});
    out["meshes"] = meshes;
    out["trace"] = json{{"tracer", enum_name(s.trace.tracer, tracer_names)}, {"max_depth", s.trace.max_depth}};
    if (s.trace.fresnel) out["trace"]["fresnel"] = true;
    return out;
}

// A job as a scene file: the scene (scene_to_json) and its "optimise" block with every
// default written out. Reading it back (job_from_json) gives the same JSON.
inline nlohmann::json job_to_json(const DesignJob& job) {
    nlohmann::json out = scene_to_json(job.scene);
    nlohmann::json opt = nlohmann::json::object();
    DesignOptions options = job.options;  // write_optimise_key's own copy
    for (const auto& k : scene_json::optimise_keys()) scene_json::write_optimise_key(k, options, opt);
    out["optimise"] = opt;
    return out;
}

}  // namespace freeform
