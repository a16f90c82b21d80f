#pragma once
// Triangle meshes in and out: Wavefront OBJ (text) and STL (binary out; binary or ASCII
// in). These carry the fabrication surface to CAD/CAM tools and meshes into the tracer.
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <limits>
#include <string>
#include <string_view>
#include <unordered_map>
#include <vector>

#include "../core/error.hpp"
#include "../core/limits.hpp"
#include "../core/math.hpp"
#include "../surface/triangle_mesh.hpp"
#include "file.hpp"

namespace freeform::io {

namespace detail {

inline std::vector<std::string_view> split_whitespace(std::string_view line) {
    std::vector<std::string_view> tokens;
    std::size_t i = 0;
    while (i < line.size()) {
        while (i < line.size() && (line[i] == ' ' || line[i] == '\t' || line[i] == '\v' || line[i] == '\f')) ++i;
        const std::size_t start = i;
        while (i < line.size() && !(line[i] == ' ' || line[i] == '\t' || line[i] == '\v' || line[i] == '\f')) ++i;
        if (i > start) tokens.push_back(line.substr(start, i - start));
    }
    return tokens;
}

// Locale-independent number parsing; a leading '+' is accepted as some exporters write it.
inline bool parse_double(std::string_view token, double& value) {
    if (!token.empty() && token.front() == '+') token.remove_prefix(1);
    const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
    return ec == std::errc{} && end == token.data() + token.size() && std::isfinite(value);
}

inline bool parse_int(std::string_view token, long long& value) {
    if (!token.empty() && token.front() == '+') token.remove_prefix(1);
    const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
    return ec == std::errc{} && end == token.data() + token.size();
}

// Calls f(line_number, line) for each line, without the line terminator.
template <class F>
void for_each_line(std::string_view text, F&& f) {
    int number = 0;
    while (!text.empty()) {
        const std::size_t eol = text.find('\n');
        std::string_view line = text.substr(0, eol);
        if (!line.empty() && line.back() == '\r') line.remove_suffix(1);
        f(++number, line);
        if (eol == std::string_view::npos) break;
        text.remove_prefix(eol + 1);
    }
}

// Shortest text that parses back to the same double: exact round trips, and short
// numbers for short values (0.1 stays "0.1"). Independent of the C locale.
inline void append_number(std::string& out, double value) {
    char buffer[32];
    const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
    out.append(buffer, result.ptr);
}

// Throws IoError naming `file` when the mesh is not self-consistent.
inline void check_mesh(const TriangleMesh& mesh, const std::filesystem::path& file, const char* what) {
    const std::string prefix = std::string("cannot write ") + what + " '" + file.string() + "': ";
    if (mesh.triangles.empty()) throw IoError(prefix + "the mesh has no triangles");
    if (!mesh.normals.empty() && mesh.normals.size() != mesh.vertices.size())
        throw IoError(prefix + std::to_string(mesh.normals.size()) + " normals for " +
                      std::to_string(mesh.vertices.size()) + " vertices");
    const auto n = static_cast<std::int64_t>(mesh.vertices.size());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        for (std::int32_t v : mesh.triangles[t])
            if (v < 0 || v >= n)
                throw IoError(prefix + "triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) +
                              " of " + std::to_string(n));
}

// Merges vertices with bit-identical positions (after folding -0 into +0), which is how
// STL files, storing each triangle's corners separately, encode shared vertices.
class VertexWelder {
public:
    std::int32_t index_of(Vec3d p, TriangleMesh& mesh) {
        const Key key{bits(p.x), bits(p.y), bits(p.z)};
        const auto [it, inserted] = index_.try_emplace(key, static_cast<std::int32_t>(mesh.vertices.size()));
        if (inserted) mesh.vertices.push_back(p);
        return it->second;
    }

private:
    using Key = std::array<std::uint64_t, 3>;
    struct KeyHash {
        std::size_t operator()(const Key& k) const {
            std::uint64_t h = 0xcbf29ce484222325ull;
            for (std::uint64_t v : k) h = (h ^ v) * 0x100000001b3ull;
            return std::size_t(h ^ (h >> 29));
        }
    };
    static std::uint64_t bits(double v) { return std::bit_cast<std::uint64_t>(v + 0.0); }

    std::unordered_map<Key, std::int32_t, KeyHash> index_;
};

inline void store_u32_le(char* p, std::uint32_t v) {
    if constexpr (std::endian::native != std::endian::little) v = byte_swap(v);
    std::memcpy(p, &v, 4);
}

inline std::uint32_t load_u32_le(const char* p) {
    std::uint32_t v;
    std::memcpy(&v, p, 4);
    if constexpr (std::endian::native != std::endian::little) v = byte_swap(v);
    return v;
}

inline constexpr std::size_t stl_header_bytes = 84;  // 80-byte comment + triangle count
inline constexpr std::size_t stl_triangle_bytes = 50;

inline void check_triangle_count(std::uint64_t count, const std::filesystem::path& file, const char* format,
                                 const Limits& limits) {
    if (count > limits.triangles)
        over_limit(std::string(format) + " file '" + file.string() + "': " + std::to_string(count) + " triangles",
                   "triangles", std::to_string(limits.triangles));
}

inline TriangleMesh read_stl_binary(std::string_view bytes, const std::filesystem::path& file, const Limits& limits) {
    const std::string prefix = "bad STL file '" + file.string() + "': ";
    if (bytes.size() < stl_header_bytes)
        throw IoError(prefix + "truncated: " + std::to_string(bytes.size()) +
                      " bytes is shorter than the 84-byte binary header");
    const std::uint32_t count = load_u32_le(bytes.data() + 80);
    const std::uint64_t needed = stl_header_bytes + std::uint64_t(count) * stl_triangle_bytes;
    if (bytes.size() < needed)
        throw IoError(prefix + "truncated: the header announces " + std::to_string(count) + " triangles (" +
                      std::to_string(needed) + " bytes) but the file has " + std::to_string(bytes.size()) +
                      " bytes");
    if (count == 0) throw IoError(prefix + "the file contains no triangles");
    if (count > std::uint32_t(std::numeric_limits<std::int32_t>::max() / 3))
        throw IoError(prefix + "too many triangles (" + std::to_string(count) + ")");
    check_triangle_count(count, file, "STL", limits);

    TriangleMesh mesh;
    VertexWelder welder;
    mesh.triangles.reserve(count);
    for (std::uint32_t t = 0; t < count; ++t) {
        const char* record = bytes.data() + stl_header_bytes + std::size_t(t) * stl_triangle_bytes;
        std::array<std::int32_t, 3> tri{};
        for (int k = 0; k < 3; ++k) {
            const char* p = record + 12 + 12 * k;  // skip the stored facet normal
            const Vec3d v{load_float(p, true), load_float(p + 4, true), load_float(p + 8, true)};
            if (!std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z))
                throw IoError(prefix + "non-finite coordinate in triangle " + std::to_string(t));
            tri[k] = welder.index_of(v, mesh);
        }
        mesh.triangles.push_back(tri);
    }
    return mesh;
}

// Lines whose first word is `keyword` (counted before a reader allocates for them).
inline std::uint64_t count_records(std::string_view text, std::string_view keyword) {
    std::uint64_t n = 0;
    for_each_line(text, [&](int, std::string_view line) {
        const std::size_t first = line.find_first_not_of(" \t\v\f");
        if (first == std::string_view::npos) return;
        line.remove_prefix(first);
        if (line.substr(0, keyword.size()) != keyword) return;
        const char next = line.size() == keyword.size() ? ' ' : line[keyword.size()];
        if (next == ' ' || next == '\t' || next == '\v' || next == '\f' || next == '\r') ++n;
    });
    return n;
}

inline TriangleMesh read_stl_ascii(std::string_view bytes, const std::filesystem::path& file, const Limits& limits) {
    check_triangle_count(count_records(bytes, "facet"), file, "ASCII STL", limits);
    TriangleMesh mesh;
    VertexWelder welder;
    std::vector<std::int32_t> facet;
    bool in_facet = false;
    for_each_line(bytes, [&](int line_number, std::string_view line) {
        const auto fail = [&](const std::string& problem) {
            throw IoError("bad ASCII STL file '" + file.string() + "' line " + std::to_string(line_number) + ": " +
                          problem);
        };
        const auto tokens = split_whitespace(line);
        if (tokens.empty()) return;
        if (tokens[0] == "facet") {
            if (in_facet) fail("'facet' inside an unfinished facet");
            in_facet = true;
            facet.clear();
        } else if (tokens[0] == "vertex") {
            if (!in_facet) fail("'vertex' outside a facet");
            Vec3d v;
            if (tokens.size() != 4 || !parse_double(tokens[1], v.x) || !parse_double(tokens[2], v.y) ||
                !parse_double(tokens[3], v.z))
                fail("expected 'vertex x y z' with three finite numbers");
            facet.push_back(welder.index_of(v, mesh));
        } else if (tokens[0] == "endfacet") {
            if (!in_facet) fail("'endfacet' without 'facet'");
            if (facet.size() != 3) fail("facet with " + std::to_string(facet.size()) + " vertices instead of 3");
            mesh.triangles.push_back({facet[0], facet[1], facet[2]});
            in_facet = false;
        }
    });
    if (in_facet) throw IoError("bad ASCII STL file '" + file.string() + "': truncated inside a facet");
    if (mesh.triangles.empty())
        throw IoError("bad STL file '" + file.string() +
                      "': no facets found (neither an ASCII STL nor a binary STL of consistent size)");
    return mesh;
}

}  // namespace detail

namespace detail {

// Counts the OBJ's faces (as triangles) and vertex records before anything is built, so
// that a file asking for more than the limits is refused up front.
inline void check_obj_size(std::string_view text, const std::filesystem::path& file, const Limits& limits) {
    std::uint64_t triangles = 0, vertex_records = 0;
    for_each_line(text, [&](int, std::string_view line) {
        const auto tokens = split_whitespace(line.substr(0, line.find('#')));
        if (tokens.empty()) return;
        if (tokens[0] == "f" && tokens.size() >= 4) triangles += tokens.size() - 3;
        if (tokens[0] == "v" || tokens[0] == "vn") ++vertex_records;
    });
    check_triangle_count(triangles, file, "OBJ", limits);
    if (vertex_records > 3 * limits.triangles)
        over_limit("OBJ file '" + file.string() + "': " + std::to_string(vertex_records) +
                       " vertex records (v and vn), more than 3 x triangles,",
                   "triangles", std::to_string(limits.triangles));
}

inline IoError obj_error(const std::filesystem::path& file, int line_number, const std::string& problem) {
    return IoError("bad OBJ file '" + file.string() + "' line " + std::to_string(line_number) + ": " + problem);
}

// An OBJ file as read, before its indices are checked against what the file holds.
struct ObjRecords {
    struct Corner {
        std::int64_t vertex;
        std::int64_t normal;  // -1: none given
        int line;
    };
    std::vector<Vec3d> positions;
    std::vector<Vec3d> normals;
    std::vector<std::array<Corner, 3>> faces;
};

// Appends the triangles of one 'f' record (a polygon, fan-triangulated) to obj.faces.
inline void read_obj_face(const std::vector<std::string_view>& tokens, int line_number,
                          const std::filesystem::path& file, ObjRecords& obj) {
    using Corner = ObjRecords::Corner;
    if (tokens.size() < 4)
        throw obj_error(file, line_number,
                        "a face needs at least three vertices, found " + std::to_string(tokens.size() - 1));
    std::vector<Corner> polygon;
    for (std::size_t k = 1; k < tokens.size(); ++k) {
        const std::string_view ref = tokens[k];
        const std::size_t slash1 = ref.find('/');
        const std::size_t slash2 = slash1 == std::string_view::npos ? slash1 : ref.find('/', slash1 + 1);
        const auto resolve = [&](std::string_view index_text, std::size_t count, const char* what) {
            long long index = 0;
            if (!parse_int(index_text, index) || index == 0)
                throw obj_error(file, line_number,
                                std::string("bad ") + what + " index '" + std::string(index_text) + "' in '" +
                                    std::string(ref) + "'");
            // Negative indices count back from the elements read so far; positive
            // ones are checked once the whole file is read.
            return index > 0 ? std::int64_t(index - 1) : std::int64_t(count) + index;
        };
        Corner corner{resolve(ref.substr(0, slash1), obj.positions.size(), "vertex"), -1, line_number};
        if (slash1 != std::string_view::npos) {
            const std::string_view texture = ref.substr(slash1 + 1, slash2 - slash1 - 1);
            long long ignored = 0;
            if (!texture.empty() && !parse_int(texture, ignored))
                throw obj_error(file, line_number, "bad texture index in '" + std::string(ref) + "'");
            if (slash2 != std::string_view::npos)
                corner.normal = resolve(ref.substr(slash2 + 1), obj.normals.size(), "normal");
        }
        polygon.push_back(corner);
    }
    for (std::size_t k = 1; k + 1 < polygon.size(); ++k) obj.faces.push_back({polygon[0], polygon[k], polygon[k + 1]});
}

// The 'v', 'vn' and 'f' records of an OBJ text; other records are skipped.
inline ObjRecords read_obj_records(std::string_view text, const std::filesystem::path& file) {
    ObjRecords obj;
    for_each_line(text, [&](int line_number, std::string_view line) {
        if (const std::size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
        const auto tokens = split_whitespace(line);
        if (tokens.empty()) return;
        const std::string_view keyword = tokens[0];

        if (keyword == "v" || keyword == "vn") {
            // 'v' may carry a w or a colour after x y z; 'vn' has exactly three values.
            if (tokens.size() < 4 || (keyword == "vn" && tokens.size() != 4))
                throw obj_error(file, line_number, "'" + std::string(keyword) + "' needs three coordinates");
            Vec3d p;
            if (!parse_double(tokens[1], p.x) || !parse_double(tokens[2], p.y) || !parse_double(tokens[3], p.z))
                throw obj_error(file, line_number, "'" + std::string(keyword) + "' coordinates must be finite numbers");
            (keyword == "v" ? obj.positions : obj.normals).push_back(p);
        } else if (keyword == "f") {
            read_obj_face(tokens, line_number, file, obj);
        }
    });
    return obj;
}

// The mesh of the records: indices checked against the vertices and normals the file
// holds, and vertex normals kept only when each vertex has one consistent non-zero one.
inline TriangleMesh assemble_obj(ObjRecords&& obj, const std::filesystem::path& file) {
    using Corner = ObjRecords::Corner;
    const std::vector<Vec3d>& normals = obj.normals;
    TriangleMesh mesh;
    mesh.vertices = std::move(obj.positions);
    mesh.triangles.reserve(obj.faces.size());
    constexpr std::int64_t unset = -2;
    std::vector<std::int64_t> normal_of(mesh.vertices.size(), unset);
    bool consistent_normals = true;
    for (const auto& face : obj.faces) {
        std::array<std::int32_t, 3> tri{};
        for (int k = 0; k < 3; ++k) {
            const Corner& c = face[k];
            if (c.vertex < 0 || c.vertex >= std::int64_t(mesh.vertices.size()))
                throw obj_error(file, c.line,
                                "vertex index out of range (" + std::to_string(mesh.vertices.size()) + " vertices)");
            if (c.normal != -1 && (c.normal < 0 || c.normal >= std::int64_t(normals.size())))
                throw obj_error(file, c.line,
                                "normal index out of range (" + std::to_string(normals.size()) + " normals)");
            tri[k] = static_cast<std::int32_t>(c.vertex);

            std::int64_t& chosen = normal_of[std::size_t(c.vertex)];
            if (c.normal == -1)
                consistent_normals = false;
            else if (chosen == unset)
                chosen = c.normal;
            else if (chosen != c.normal && !(normals[std::size_t(chosen)] == normals[std::size_t(c.normal)]))
                consistent_normals = false;
        }
        mesh.triangles.push_back(tri);
    }

    for (std::size_t v = 0; v < mesh.vertices.size() && consistent_normals; ++v)
        if (normal_of[v] == unset || !(length(normals[std::size_t(normal_of[v])]) > 0)) consistent_normals = false;
    if (consistent_normals) {
        mesh.normals.resize(mesh.vertices.size());
        for (std::size_t v = 0; v < mesh.vertices.size(); ++v) mesh.normals[v] = normalize(normals[std::size_t(normal_of[v])]);
    }
    return mesh;
}

}  // namespace detail

// Parses a Wavefront OBJ: 'v', 'vn' and 'f' records (faces as "a", "a/b", "a/b/c" or
// "a//c", negative indices relative to the end; polygons fan-triangulated); all other
// records are ignored. Vertex normals are kept only when every vertex gets one
// consistent (normalised) 'vn' from the faces; otherwise mesh.normals is empty.
// Throws IoError naming the file (`file` names the text in messages) and the line on
// malformed records or indices out of range, and when the file holds no face; InputError
// when the records (counted before anything is built) ask for more than limits.triangles
// triangles or 3 × limits.triangles vertex records.
inline TriangleMesh parse_obj(std::string_view text, const std::filesystem::path& file, const Limits& limits = {}) {
    detail::check_obj_size(text, file, limits);
    detail::ObjRecords obj = detail::read_obj_records(text, file);
    if (obj.faces.empty()) throw IoError("bad OBJ file '" + file.string() + "': no faces");
    if (obj.positions.size() > std::size_t(std::numeric_limits<std::int32_t>::max()))
        throw IoError("bad OBJ file '" + file.string() + "': too many vertices");
    return detail::assemble_obj(std::move(obj), file);
}

// The mesh with vertices at bit-identical positions merged (normals dropped): an OBJ
// that repeats a corner per face (to give each face its own normal, say) becomes one
// connected surface whose edges can be matched, as check_mesh needs.
inline TriangleMesh welded(const TriangleMesh& mesh) {
    TriangleMesh out;
    detail::VertexWelder welder;
    out.triangles.reserve(mesh.triangles.size());
    for (const auto& t : mesh.triangles) {
        std::array<std::int32_t, 3> w{};
        for (int k = 0; k < 3; ++k) w[std::size_t(k)] = welder.index_of(mesh.vertices[std::size_t(t[std::size_t(k)])], out);
        out.triangles.push_back(w);
    }
    return out;
}

// Writes a Wavefront OBJ with coordinates that read back bit-exact, 'vn' records when mesh.normals is
// non-empty ("f a//a b//b c//c"), through a temporary file. Throws IoError naming the
// file for an inconsistent mesh or a failed write.
inline void write_obj(const std::filesystem::path& file, const TriangleMesh& mesh) {
    detail::check_mesh(mesh, file, "OBJ");
    const bool with_normals = !mesh.normals.empty();
    std::string out = "# freeform mesh: " + std::to_string(mesh.vertices.size()) + " vertices, " +
                      std::to_string(mesh.triangles.size()) + " triangles\n";
    out.reserve(out.size() + mesh.vertices.size() * (with_normals ? 80 : 40) + mesh.triangles.size() * 40);
    const auto append_vec = [&out](const char* keyword, Vec3d v) {
        out += keyword;
        for (double c : {v.x, v.y, v.z}) {
            out += ' ';
            detail::append_number(out, c);
        }
        out += '\n';
    };
    for (const Vec3d& v : mesh.vertices) append_vec("v", v);
    for (const Vec3d& n : mesh.normals) append_vec("vn", n);
    for (const auto& t : mesh.triangles) {
        out += 'f';
        for (std::int32_t v : t) {
            const std::string index = std::to_string(std::int64_t(v) + 1);
            out += ' ';
            out += index;
            if (with_normals) out += "//" + index;
        }
        out += '\n';
    }
    write_file_atomically(file, out);
}

// Writes a binary STL (80-byte header starting "freeform", facet normals computed from
// the geometry, zero for degenerate triangles) through a temporary file. Throws IoError
// naming the file for an inconsistent mesh or a failed write.
inline void write_stl(const std::filesystem::path& file, const TriangleMesh& mesh) {
    detail::check_mesh(mesh, file, "STL");
    if (mesh.triangles.size() > std::numeric_limits<std::uint32_t>::max())
        throw IoError("cannot write STL '" + file.string() + "': too many triangles");
    std::string out(detail::stl_header_bytes + mesh.triangles.size() * detail::stl_triangle_bytes, '\0');
    const char header[] = "freeform";
    std::memcpy(out.data(), header, sizeof header - 1);
    detail::store_u32_le(out.data() + 80, static_cast<std::uint32_t>(mesh.triangles.size()));
    char* p = out.data() + detail::stl_header_bytes;
    for (const auto& t : mesh.triangles) {
        const Vec3d a = mesh.vertices[std::size_t(t[0])];
        const Vec3d b = mesh.vertices[std::size_t(t[1])];
        const Vec3d c = mesh.vertices[std::size_t(t[2])];
        const Vec3d n = cross(b - a, c - a);
        const double l = length(n);
        const Vec3d unit = l > 0 ? n / l : Vec3d{0, 0, 0};
        for (const Vec3d& v : {unit, a, b, c}) {
            detail::store_float_le(p, static_cast<float>(v.x));
            detail::store_float_le(p + 4, static_cast<float>(v.y));
            detail::store_float_le(p + 8, static_cast<float>(v.z));
            p += 12;
        }
        p += 2;  // attribute byte count: zero
    }
    write_file_atomically(file, out);
}

// Reads a binary or ASCII STL; vertices with identical positions are welded. Stored
// facet normals are ignored (mesh.normals stays empty; compute_normals() rebuilds
// them). A file is binary when its size matches the triangle count in its header,
// otherwise ASCII if it starts with "solid". Throws IoError naming the file on
// truncation, malformed records or a file without triangles.
inline TriangleMesh parse_stl(std::string_view bytes, const std::filesystem::path& file, const Limits& limits = {}) {
    const bool consistent_binary =
        bytes.size() >= detail::stl_header_bytes &&
        bytes.size() == detail::stl_header_bytes +
                            std::uint64_t(detail::load_u32_le(bytes.data() + 80)) * detail::stl_triangle_bytes;
    const std::size_t first = bytes.find_first_not_of(" \t\r\n");
    const bool starts_with_solid = first != std::string::npos && bytes.substr(first, 5) == "solid";
    if (!consistent_binary && starts_with_solid) return detail::read_stl_ascii(bytes, file, limits);
    return detail::read_stl_binary(bytes, file, limits);
}

// Reads an STL file (parse_stl) or an OBJ file (parse_obj), refusing files larger than
// limits.data_file_bytes before reading them.
inline TriangleMesh read_stl(const std::filesystem::path& file, const Limits& limits = {}) {
    return parse_stl(read_file_bytes(file, limits.data_file_bytes), file, limits);
}

inline TriangleMesh read_obj(const std::filesystem::path& file, const Limits& limits = {}) {
    return parse_obj(read_file_bytes(file, limits.data_file_bytes), file, limits);
}

// Reads a mesh file by its extension: .stl (binary or ASCII), anything else as OBJ.
inline TriangleMesh read_mesh(const std::filesystem::path& file, const Limits& limits = {}) {
    std::string ext = file.extension().string();
    for (char& c : ext) c = char(std::tolower(static_cast<unsigned char>(c)));
    return ext == ".stl" ? read_stl(file, limits) : read_obj(file, limits);
}

}  // namespace freeform::io
