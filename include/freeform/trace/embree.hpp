#pragma once
// EmbreeTracer: traces the scene with Embree 3 instead of the BVH-free height-field walk,
// so that the height field can share the scene with extra triangle meshes (mirrors that
// fold the light, absorbers that block it, closed refractive solids that it crosses) or
// be replaced by an imported mesh, or be left out so that meshes alone are traced.
//
// The physics is not duplicated: Embree only finds the nearest admissible triangle of a
// segment, and the shared `advance` (trace/path.hpp) does the rest, exactly as in
// HeightfieldTracer. The height field is triangulated exactly like the height-field
// kernel (same vertices, same diagonal, same triangle ids), its shading normals are read
// from the Heightmap at hit time, and it is cut into square tiles, one Embree geometry
// each, so that a height change refits only the tiles it touches.
//
// By default each tile sits in a scene of its own, instanced with the identity transform
// in the top scene (EmbreeTileLayout::instanced). Embree 3 rebuilds a scene's top level
// on every commit; over several triangle geometries that top level is built from opened
// nodes of their BVHs (a thousand references at least), which made one refit cost about
// ten times more than over instances. The identity transform is exact (x·1 + y·0 + ... ),
// so both layouts find the same hits.
//
// Rays are traced in 16-wide packets of consecutive ray ids (the ray set is a stratified
// grid, so consecutive rays are coherent). Which triangles a segment may hit (not the one
// it starts on; only the front of a mirror or of a lens seen from outside, only the back
// from inside a lens; a refractive solid's outside from air, its inside from within) is
// decided per lane by an intersection filter that reads the lane's state from an
// extended RTCIntersectContext. Refractive meshes are CPU only: the CUDA policy traces
// the height field alone, and path.hpp's crossing code is plain arithmetic either way.
//
// Triangle ids: the height field's triangles keep the kernel's ids
// 2·(cj·(nx-1) + ci) + k; a surface mesh's triangles keep their index; the triangles of
// extra mesh m follow, offset by the triangles of everything before it. One id space means
// PathState::exclude names a triangle of any geometry unambiguously.
#include <embree3/rtcore.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../core/frame.hpp"
#include "../core/material.hpp"
#include "../surface/export.hpp"
#include "../surface/triangle_mesh.hpp"
#include "heightfield_kernel.hpp"
#include "tracer.hpp"

namespace freeform {

// A triangle mesh sharing the scene with the designed surface, in the SURFACE frame, with
// one unit normal per vertex. A mirror mesh reflects on both sides; an absorber absorbs
// what hits it; a refractive mesh is the closed, outward-oriented boundary of a solid
// (check_refractive_solid, surface/export.hpp), crossed by Snell's law. All are traced as
// their flat facets unless PathParams::interpolated_normals asks for the vertex normals.
//
// smooth_triangles: with interpolated normals, only the mesh's first smooth_triangles
// triangles are shaded with their vertex normals and the rest stay flat (their facet
// normal). A lens solid traced as a smooth front (design/exported.hpp) needs this: its
// walls and back face are flat, and their rim vertices are shared with the front.
// Negative: every triangle.
struct ExtraMesh {
    TriangleMesh mesh;
    MeshMaterial material{};
    std::int64_t smooth_triangles = -1;
};

// Moves a mesh given in world coordinates into the frame of the surface (the tracing
// frame); vertex normals are computed when the mesh has none.
inline ExtraMesh to_surface_frame(const TriangleMesh& world_mesh, const Frame& surface_frame,
                                  const MeshMaterial& material) {
    ExtraMesh out;
    out.material = material;
    out.mesh.triangles = world_mesh.triangles;
    out.mesh.vertices.reserve(world_mesh.vertices.size());
    for (const Vec3d& p : world_mesh.vertices) out.mesh.vertices.push_back(surface_frame.to_local(p));
    if (world_mesh.normals.size() == world_mesh.vertices.size() && !world_mesh.normals.empty()) {
        out.mesh.normals.reserve(world_mesh.normals.size());
        for (const Vec3d& n : world_mesh.normals) out.mesh.normals.push_back(surface_frame.dir_to_local(n));
    } else {
        out.mesh.compute_normals();
    }
    return out;
}
inline ExtraMesh to_surface_frame(const TriangleMesh& world_mesh, const Frame& surface_frame, bool mirror) {
    return to_surface_frame(world_mesh, surface_frame, mirror ? MeshMaterial::mirror() : MeshMaterial::absorber());
}

// A collimated beam starts just above the surface's height bounds (generate_rays); a
// solid traced in the surface's place (`solid`, surface frame) may rise higher. Starts
// the beam above it, clear of its top by a millionth of the surface's larger side.
inline void start_above(const Light& light, Vec2d surface_size, const TriangleMesh& solid, RaySet& rays) {
    double top = -std::numeric_limits<double>::infinity();
    for (const Vec3d& p : solid.vertices) top = std::max(top, p.z);
    start_collimated_above(light, top + 1e-6 * std::max(surface_size.x, surface_size.y), rays);
}

// An Embree device whose errors become exceptions. Embree reports errors through a
// callback that must not throw (it is called from inside the library), so the callback
// only records the error and `check` turns it into a std::runtime_error at our API
// boundary.
class EmbreeDevice {
public:
    // `build_threads`: the threads Embree may use to build its BVHs (its "threads=N"
    // device setting); 0: every hardware thread, Embree's default.
    explicit EmbreeDevice(int build_threads)
        : EmbreeDevice(build_threads > 0 ? ("threads=" + std::to_string(build_threads)).c_str() : nullptr) {}

    explicit EmbreeDevice(const char* config = nullptr) : log_(std::make_unique<ErrorLog>()) {
        device_.reset(rtcNewDevice(config));
        if (!device_) {
            throw std::runtime_error(std::string("Embree error in rtcNewDevice: ") +
                                     error_name(rtcGetDeviceError(nullptr)) +
                                     (config ? std::string(" (config \"") + config + "\")" : std::string()));
        }
        rtcSetDeviceErrorFunction(device_.get(), &EmbreeDevice::record, log_.get());
    }

    RTCDevice get() const { return device_.get(); }

    // Throws the first error Embree reported since the last check, naming the call.
    void check(std::string_view what) const {
        std::string message;
        {
            const std::lock_guard<std::mutex> lock(log_->mutex);
            if (log_->code == RTC_ERROR_NONE) return;
            message = "Embree error in " + std::string(what) + ": " + error_name(log_->code) +
                      (log_->text.empty() ? std::string() : ": " + log_->text);
            log_->code = RTC_ERROR_NONE;
            log_->text.clear();
        }
        throw std::runtime_error(message);
    }

    static const char* error_name(RTCError code) {
        switch (code) {
            case RTC_ERROR_NONE: return "RTC_ERROR_NONE";
            case RTC_ERROR_INVALID_ARGUMENT: return "RTC_ERROR_INVALID_ARGUMENT";
            case RTC_ERROR_INVALID_OPERATION: return "RTC_ERROR_INVALID_OPERATION";
            case RTC_ERROR_OUT_OF_MEMORY: return "RTC_ERROR_OUT_OF_MEMORY";
            case RTC_ERROR_UNSUPPORTED_CPU: return "RTC_ERROR_UNSUPPORTED_CPU";
            case RTC_ERROR_CANCELLED: return "RTC_ERROR_CANCELLED";
            default: return "RTC_ERROR_UNKNOWN";
        }
    }

private:
    struct ErrorLog {
        std::mutex mutex;  // Embree may report from its worker threads
        RTCError code = RTC_ERROR_NONE;
        std::string text;
    };
    struct Release {
        void operator()(RTCDevice d) const { rtcReleaseDevice(d); }
    };

    static void record(void* user, RTCError code, const char* text) {
        auto* log = static_cast<ErrorLog*>(user);
        const std::lock_guard<std::mutex> lock(log->mutex);
        if (log->code != RTC_ERROR_NONE) return;  // the first error explains the rest
        log->code = code;
        log->text = text ? text : "";
    }

    // Declared before the device so that it outlives it (the callback points at it).
    std::unique_ptr<ErrorLog> log_;
    std::unique_ptr<RTCDeviceTy, Release> device_;
};

// How the height-field tiles are put into the Embree scene (see the file comment).
enum class EmbreeTileLayout {
    instanced,  // a one-geometry scene per tile, instanced in the top scene
    flat,       // the tile geometries directly in the top scene
};

namespace embree_detail {

inline constexpr int packet_width = 16;

struct SceneRelease {
    void operator()(RTCScene s) const { rtcReleaseScene(s); }
};
struct GeometryRelease {
    void operator()(RTCGeometry g) const { rtcReleaseGeometry(g); }
};
using ScenePtr = std::unique_ptr<RTCSceneTy, SceneRelease>;
using GeometryPtr = std::unique_ptr<RTCGeometryTy, GeometryRelease>;

// What the filter and the hit decoding need to know about one geometry of the top scene
// (a tile's instance stands for the tile's triangle geometry).
struct GeometryInfo {
    HitKind kind = HitKind::surface;
    bool one_sided = true;                      // front/back rule of the designed surface
    std::int32_t tri_offset = 0;                // global id of primitive 0 (meshes)
    const std::int32_t* prim_to_tri = nullptr;  // height-field tiles: primitive -> global id
    const std::uint8_t* flip = nullptr;         // per primitive: Ng points to the back side
    int mesh = -1;                              // index into the tracer's meshes, -1 for tiles
};

// The documented Embree 3 way to hand per-ray data to a filter: a context whose first
// member is the RTCIntersectContext Embree receives. Lanes are found by RTCRay::id.
struct PacketContext {
    RTCIntersectContext base;
    const GeometryInfo* geometries;
    std::int32_t exclude[packet_width];
    std::uint8_t front[packet_width];
    std::uint8_t in_solid[packet_width];  // inside a refractive mesh's solid
};

// Rejects the triangle a segment starts on and, on the designed surface, triangles seen
// from the wrong side. Mirror and absorbing meshes are two-sided. A refractive mesh is
// met from outside by a ray in air and from inside by a ray in its solid (solids do not
// nest): this also keeps a ray that crossed a facet near an edge from meeting the
// neighbouring facet again at t ~ 0 on the wrong side.
inline void intersect_filter(const RTCFilterFunctionNArguments* args) {
    const auto* ctx = reinterpret_cast<const PacketContext*>(args->context);
    const unsigned n = args->N;
    for (unsigned i = 0; i < n; ++i) {
        if (args->valid[i] == 0) continue;
        const unsigned lane = RTCRayN_id(args->ray, n, i);
        const unsigned inst = RTCHitN_instID(args->hit, n, i, 0);
        const unsigned geom = inst != RTC_INVALID_GEOMETRY_ID ? inst : RTCHitN_geomID(args->hit, n, i);
        const unsigned prim = RTCHitN_primID(args->hit, n, i);
        const GeometryInfo& g = ctx->geometries[geom];
        const std::int32_t tri = g.prim_to_tri ? g.prim_to_tri[prim] : g.tri_offset + std::int32_t(prim);
        if (tri == ctx->exclude[lane]) {
            args->valid[i] = 0;
            continue;
        }
        const bool solid = g.kind == HitKind::refractive_mesh;
        if (!g.one_sided && !solid) continue;
        // Embree's Ng is (v1 - v0) x (v2 - v0), +w for the height field's triangles and
        // outward for a refractive solid.
        float dn = RTCRayN_dir_x(args->ray, n, i) * RTCHitN_Ng_x(args->hit, n, i) +
                   RTCRayN_dir_y(args->ray, n, i) * RTCHitN_Ng_y(args->hit, n, i) +
                   RTCRayN_dir_z(args->ray, n, i) * RTCHitN_Ng_z(args->hit, n, i);
        if (g.flip && g.flip[prim]) dn = -dn;
        const bool front = solid ? ctx->in_solid[lane] == 0 : ctx->front[lane] != 0;
        const bool ok = front ? dn < 0.0f : dn > 0.0f;
        if (!ok) args->valid[i] = 0;
    }
}

// Calls visit(ci, cj) for every cell the segment o + t·d, 0 <= t <= t_end, crosses inside
// the slab and the grid, in walking order: the height-field tracer's walk
// (hf_detail::walk_cells), so both tracers index a ray by the same cells. Used to tell
// which rays a height change in a patch can affect; it errs on the side of visiting one
// cell too many, and reports no height range (Embree's hits are not the walk's).
template <class Visitor>
inline void visit_slab_cells(const HeightfieldView& hf, Vec3 o, Vec3 d, float t_end, Visitor&& visit) {
    const hf_detail::Grid g = hf_detail::grid_of(hf);
    // A hit computed by Embree may sit a rounding error past a cell border: walk a ten
    // thousandth of a cell (or of a unit of t) beyond the end so that its cell is visited.
    const float ad = fabsf(d.x * g.inv_du), bd = fabsf(d.y * g.inv_dv);
    float t_per_cell = 1.0f;
    if (ad > 0.0f) t_per_cell = min_f(t_per_cell, 1.0f / ad);
    if (bd > 0.0f) t_per_cell = min_f(t_per_cell, 1.0f / bd);
    hf_detail::GridSegment s;
    if (!hf_detail::grid_segment(hf, g, o, d, t_end, 1e-4f * t_per_cell, s)) return;
    hf_detail::walk_cells(g, s, [&](int ci, int cj, float, float) {
        visit(ci, cj);
        return false;
    });
}

}  // namespace embree_detail

class EmbreeTracer {
public:
    // Traces `surface` (split into tiles of tile_cells × tile_cells cells) and `meshes`
    // (surface frame). The tracer keeps references to `surface` and `rays`: both must
    // outlive it, and every height change must be followed by surface_changed().
    // `build_threads` (every constructor): the threads Embree builds and refits its BVHs
    // with, 0 for all; a design passes its own thread count (the rays themselves are
    // traced by the policy given to trace()).
    EmbreeTracer(const Heightmap& surface, const RaySet& rays, const PathParams& params,
                 std::vector<ExtraMesh> meshes = {}, int tile_cells = 32,
                 EmbreeTileLayout layout = EmbreeTileLayout::instanced, int build_threads = 0)
        : device_(build_threads), surface_(&surface), rays_(&rays), params_(params), tile_cells_(tile_cells),
          layout_(layout) {
        if (tile_cells < 1)
            throw InputError("EmbreeTracer: tile_cells must be at least 1, got " + std::to_string(tile_cells));
        const std::int64_t tris = 2 * std::int64_t(surface.nx() - 1) * (surface.ny() - 1);
        create_scene();
        build_tiles();
        add_meshes(std::move(meshes), tris);
        commit("rtcCommitScene");
    }

    // Traces the triangle mesh `surface_mesh` (surface frame; vertex normals are computed
    // when missing) in place of a height field, with the scene's material: a mirror, or
    // the front face of a lens. Only `rays` is referenced, the meshes are copied.
    EmbreeTracer(const TriangleMesh& surface_mesh, const RaySet& rays, const PathParams& params,
                 std::vector<ExtraMesh> meshes = {}, int build_threads = 0)
        : device_(build_threads), surface_(nullptr), rays_(&rays), params_(params), tile_cells_(0) {
        create_scene();
        TriangleMesh m = surface_mesh;
        if (m.normals.empty()) m.compute_normals();
        MeshData data = to_mesh_data(m, "surface mesh");
        if (data.tri.empty()) throw InputError("EmbreeTracer: the surface mesh has no triangles");
        data.kind = HitKind::surface;
        // A front side is where the vertex normals point: make the filter independent of
        // the winding the mesh file happens to use.
        data.flip.resize(data.tri.size());
        for (std::size_t t = 0; t < data.tri.size(); ++t) {
            const auto& v = data.tri[t];
            const Vec3 ng = cross(data.p[std::size_t(v[1])] - data.p[std::size_t(v[0])],
                                  data.p[std::size_t(v[2])] - data.p[std::size_t(v[0])]);
            const Vec3 nv = data.n[std::size_t(v[0])] + data.n[std::size_t(v[1])] + data.n[std::size_t(v[2])];
            data.flip[t] = dot(ng, nv) < 0.0f ? 1 : 0;
        }
        const std::int64_t tris = std::int64_t(data.tri.size());
        meshes_.reserve(1 + meshes.size());  // GeometryInfo points into the flip tables
        meshes_.push_back(std::move(data));
        attach_mesh(0, 0);
        add_meshes(std::move(meshes), tris);
        commit("rtcCommitScene");
    }

    // Traces `meshes` alone (surface frame), with no designed surface: a lens solid given
    // as a refractive mesh, say, lit by the scene's rays. Only `rays` is referenced.
    EmbreeTracer(const RaySet& rays, const PathParams& params, std::vector<ExtraMesh> meshes, int build_threads = 0)
        : device_(build_threads), surface_(nullptr), rays_(&rays), params_(params), tile_cells_(0) {
        if (meshes.empty()) throw InputError("EmbreeTracer: no mesh to trace");
        create_scene();
        add_meshes(std::move(meshes), 0);
        commit("rtcCommitScene");
    }

    EmbreeTracer(const EmbreeTracer&) = delete;
    EmbreeTracer& operator=(const EmbreeTracer&) = delete;
    EmbreeTracer(EmbreeTracer&&) noexcept = default;
    EmbreeTracer& operator=(EmbreeTracer&&) noexcept = default;
    ~EmbreeTracer() = default;

    static constexpr std::string_view name() { return "embree"; }
    const RaySet& rays() const { return *rays_; }
    const PathParams& params() const { return params_; }
    // The traced height field (nullptr when a surface mesh is traced).
    const Heightmap* surface() const { return surface_; }

    int tile_cells() const { return tile_cells_; }
    EmbreeTileLayout layout() const { return layout_; }
    // Embree geometries holding the height field (tiles without active cells have none).
    int tile_count() const {
        return int(std::count_if(tiles_.begin(), tiles_.end(), [](const Tile& t) { return bool(t.geometry); }));
    }
    int tiles_touched_last_update() const { return tiles_touched_; }

    // Refits the tiles holding vertices of `patch` (vertex indices, clipped to the grid;
    // pass a patch that covers every changed height) to the heights now in the surface.
    // Normals need no update here: they are read from the Heightmap at hit time.
    void surface_changed(const Patch& patch) {
        tiles_touched_ = 0;
        if (!surface_) return;
        const Heightmap& s = *surface_;
        const Patch p = patch.clipped(s.nx(), s.ny());
        if (p.empty()) return;
        const int t = tile_cells_;
        const int a_lo = std::max(0, (p.i0 + t - 1) / t - 1), a_hi = std::min(tiles_x_ - 1, p.i1 / t);
        const int b_lo = std::max(0, (p.j0 + t - 1) / t - 1), b_hi = std::min(tiles_y_ - 1, p.j1 / t);
        for (int b = b_lo; b <= b_hi; ++b) {
            for (int a = a_lo; a <= a_hi; ++a) {
                Tile& tile = tiles_[std::size_t(b) * tiles_x_ + a];
                if (!tile.geometry) continue;
                const int i0 = std::max(p.i0, tile.ci0), i1 = std::min(p.i1, tile.ci1);
                const int j0 = std::max(p.j0, tile.cj0), j1 = std::min(p.j1, tile.cj1);
                if (i0 > i1 || j0 > j1) continue;
                const int row = tile.ci1 - tile.ci0 + 1;
                for (int j = j0; j <= j1; ++j)
                    for (int i = i0; i <= i1; ++i)
                        tile.vertices[3 * (std::size_t(j - tile.cj0) * row + std::size_t(i - tile.ci0)) + 2] = s(i, j);
                rtcUpdateGeometryBuffer(tile.geometry.get(), RTC_BUFFER_TYPE_VERTEX, 0);
                rtcCommitGeometry(tile.geometry.get());
                if (tile.scene) {
                    rtcCommitScene(tile.scene.get());  // refits the tile's BVH
                    rtcCommitGeometry(tile.instance.get());  // new bounds for the top level
                }
                device_.check("rtcCommitGeometry (refit of a height-field tile)");
                ++tiles_touched_;
            }
        }
        if (tiles_touched_ > 0) commit("rtcCommitScene (refit)");
    }

    // Traces every ray and deposits it; `totals` receives where the weight went. Packets
    // are fixed groups of 16 consecutive rays whatever the thread count, and the sums are
    // exact integers, so the result does not depend on the number of threads.
    template <HostPolicy P>
    void trace_all(P policy, Histogram& out, TraceTotals& totals) const {
        const int chunks = thread_count(policy);
        std::vector<Histogram> partial(std::size_t(chunks), Histogram(out.width, out.height));
        std::vector<TraceTotals> partial_totals(static_cast<std::size_t>(chunks));
        const RaySet& r = *rays_;
        const HeightfieldView hf = surface_ ? surface_->view() : HeightfieldView{};
        const std::int64_t packets = (r.size() + embree_detail::packet_width - 1) / embree_detail::packet_width;
        for_each_chunk(policy, packets, chunks, [&](int c, std::int64_t begin, std::int64_t end) {
            Histogram& h = partial[std::size_t(c)];
            TraceTotals& t = partial_totals[std::size_t(c)];
            RayRecord rec[embree_detail::packet_width];
            for (std::int64_t p = begin; p < end; ++p) {
                const std::int64_t first = p * embree_detail::packet_width;
                const int count = int(std::min<std::int64_t>(embree_detail::packet_width, r.size() - first));
                trace_packet(hf, count, [&](int k) { return first + k; }, rec, NoPathVisitor{});
                for (int k = 0; k < count; ++k) {
                    const Fixed w = r.weight[std::size_t(first + k)];
                    t.add(rec[k], w);
                    deposit_record(params_.receiver, rec[k], w, h.cells);
                }
            }
        });
        device_.check("rtcIntersect16");
        totals.emitted = r.total;
        merge_partials(partial, partial_totals, out, totals);
    }

    // Traces the rays `ids` into `records` (records[k] belongs to ids[k]), 16 at a time in
    // the order given: pass ids sorted to keep packets coherent.
    template <HostPolicy P>
    void trace(P policy, std::span<const std::int32_t> ids, std::span<RayRecord> records) const {
        const HeightfieldView hf = surface_ ? surface_->view() : HeightfieldView{};
        const std::int64_t n = std::int64_t(ids.size());
        const std::int64_t packets = (n + embree_detail::packet_width - 1) / embree_detail::packet_width;
        for_each(policy, packets, [&](std::int64_t p) {
            const std::int64_t first = p * embree_detail::packet_width;
            const int count = int(std::min<std::int64_t>(embree_detail::packet_width, n - first));
            trace_packet(
                hf, count, [&](int k) { return std::int64_t(ids[std::size_t(first + k)]); },
                records.data() + first, NoPathVisitor{});
        });
        device_.check("rtcIntersect16");
    }

    // Traces one ray, reporting every height-field cell its path crosses inside the slab
    // (up to each segment's hit), as HeightfieldTracer::trace_one does: the rays a height
    // change in a patch can affect are those that visited a cell of the patch.
    template <class Visitor>
    RayRecord trace_one(std::int32_t id, Visitor&& visit) const {
        const HeightfieldView hf = surface_ ? surface_->view() : HeightfieldView{};
        RayRecord rec[1];
        trace_packet(hf, 1, [&](int) { return std::int64_t(id); }, rec, CellPathVisitor<Visitor>{hf, visit});
        device_.check("rtcIntersect16");
        return rec[0];
    }

private:
    struct Tile {
        int ci0 = 0, cj0 = 0, ci1 = 0, cj1 = 0;  // vertex range (inclusive)
        embree_detail::GeometryPtr geometry;     // null when no cell of the tile is active
        embree_detail::ScenePtr scene;           // instanced layout: the tile's own scene
        embree_detail::GeometryPtr instance;     // instanced layout: its instance in the top scene
        float* vertices = nullptr;               // Embree-owned vertex buffer (x, y, z)
        std::vector<std::int32_t> prim_to_tri;
    };

    struct MeshData {
        std::vector<Vec3> p, n;
        std::vector<std::array<std::int32_t, 3>> tri;
        std::vector<std::uint8_t> flip;  // only for a traced surface mesh
        std::int64_t smooth = std::numeric_limits<std::int64_t>::max();  // ExtraMesh::smooth_triangles
        HitKind kind = HitKind::absorber;
        float ior = 1;  // refractive meshes
    };

    struct NoPathVisitor {
        void operator()(Vec3, Vec3, float) const {}
    };
    template <class Visitor>
    struct CellPathVisitor {
        const HeightfieldView& hf;
        Visitor& visit;
        void operator()(Vec3 o, Vec3 d, float t_end) const {
            if (hf.h) embree_detail::visit_slab_cells(hf, o, d, t_end, visit);
        }
    };

    embree_detail::ScenePtr new_scene() {
        embree_detail::ScenePtr scene(rtcNewScene(device_.get()));
        device_.check("rtcNewScene");
        // Dynamic: tiles are refit after height changes. Robust: a ray through a shared
        // edge or vertex always finds one of the triangles (no leaks between tiles).
        rtcSetSceneFlags(scene.get(), RTC_SCENE_FLAG_DYNAMIC | RTC_SCENE_FLAG_ROBUST);
        rtcSetSceneBuildQuality(scene.get(), RTC_BUILD_QUALITY_LOW);
        device_.check("rtcSetSceneFlags");
        return scene;
    }

    void create_scene() { scene_ = new_scene(); }

    void commit(std::string_view what) {
        rtcCommitScene(scene_.get());
        device_.check(what);
    }

    unsigned next_geometry_id() const { return unsigned(geometries_.size()); }

    void build_tiles() {
        const Heightmap& s = *surface_;
        const int cells_x = s.nx() - 1, cells_y = s.ny() - 1, t = tile_cells_;
        tiles_x_ = (cells_x + t - 1) / t;
        tiles_y_ = (cells_y + t - 1) / t;
        tiles_.resize(std::size_t(tiles_x_) * tiles_y_);
        // Geometry infos point into the tiles' id tables: size both before taking pointers.
        std::vector<std::size_t> with_geometry;
        for (int b = 0; b < tiles_y_; ++b) {
            for (int a = 0; a < tiles_x_; ++a) {
                Tile& tile = tiles_[std::size_t(b) * tiles_x_ + a];
                tile.ci0 = a * t;
                tile.cj0 = b * t;
                tile.ci1 = std::min((a + 1) * t, cells_x);
                tile.cj1 = std::min((b + 1) * t, cells_y);
                if (make_tile_geometry(tile)) with_geometry.push_back(std::size_t(b) * tiles_x_ + a);
            }
        }
        for (std::size_t k : with_geometry) attach_tile(tiles_[k]);
    }

    // The triangles of a tile's active cells as an Embree geometry (refitted when heights
    // change); false, and no geometry, when none of its cells is active.
    bool make_tile_geometry(Tile& tile) {
        const Heightmap& s = *surface_;
        const HeightfieldView hf = s.view();
        const int cells_x = s.nx() - 1;
        const int row = tile.ci1 - tile.ci0 + 1;
        std::vector<unsigned> index;
        for (int cj = tile.cj0; cj < tile.cj1; ++cj) {
            for (int ci = tile.ci0; ci < tile.ci1; ++ci) {
                if (!hf.cell_active(ci, cj)) continue;
                const std::int32_t base = 2 * (cj * cells_x + ci);
                for (std::int32_t k = 0; k < 2; ++k) {
                    int vi[3], vj[3];
                    triangle_vertices(s.nx(), base + k, vi, vj);
                    for (int m = 0; m < 3; ++m) index.push_back(unsigned((vj[m] - tile.cj0) * row + (vi[m] - tile.ci0)));
                    tile.prim_to_tri.push_back(base + k);
                }
            }
        }
        if (index.empty()) return false;
        tile.geometry.reset(rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_TRIANGLE));
        device_.check("rtcNewGeometry (height-field tile)");
        RTCGeometry g = tile.geometry.get();
        const std::size_t nv = std::size_t(row) * std::size_t(tile.cj1 - tile.cj0 + 1);
        tile.vertices = static_cast<float*>(
            rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), nv));
        auto* idx = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                   3 * sizeof(unsigned), index.size() / 3));
        device_.check("rtcSetNewGeometryBuffer (height-field tile)");
        for (int j = tile.cj0; j <= tile.cj1; ++j) {
            for (int i = tile.ci0; i <= tile.ci1; ++i) {
                // The kernel's own vertex positions, bit for bit.
                const Vec3 v = hf.vertex(i, j);
                float* dst = tile.vertices + 3 * (std::size_t(j - tile.cj0) * row + std::size_t(i - tile.ci0));
                dst[0] = v.x, dst[1] = v.y, dst[2] = v.z;
            }
        }
        std::copy(index.begin(), index.end(), idx);
        rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_REFIT);
        return true;
    }

    // Puts a tile's geometry into the top scene: directly (flat layout) or as an instance
    // of a scene of its own.
    void attach_tile(Tile& tile) {
        embree_detail::GeometryInfo info;
        info.kind = HitKind::surface;
        info.one_sided = true;
        info.prim_to_tri = tile.prim_to_tri.data();
        if (layout_ == EmbreeTileLayout::flat) {
            attach(tile.geometry.get(), info, "height-field tile");
            return;
        }
        tile.scene = new_scene();
        rtcSetGeometryIntersectFilterFunction(tile.geometry.get(), &embree_detail::intersect_filter);
        rtcCommitGeometry(tile.geometry.get());
        rtcAttachGeometryByID(tile.scene.get(), tile.geometry.get(), 0);
        rtcCommitScene(tile.scene.get());
        device_.check("rtcCommitScene (height-field tile)");
        tile.instance.reset(rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_INSTANCE));
        device_.check("rtcNewGeometry (tile instance)");
        rtcSetGeometryInstancedScene(tile.instance.get(), tile.scene.get());
        constexpr float identity[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};  // 3x4, column major
        rtcSetGeometryTransform(tile.instance.get(), 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, identity);
        rtcCommitGeometry(tile.instance.get());
        rtcAttachGeometryByID(scene_.get(), tile.instance.get(), next_geometry_id());
        device_.check("rtcAttachGeometryByID (tile instance)");
        geometries_.push_back(info);
    }

    // Attaches a triangle geometry to the top scene, with the filter, as the next id.
    void attach(RTCGeometry g, const embree_detail::GeometryInfo& info, std::string_view what) {
        rtcSetGeometryIntersectFilterFunction(g, &embree_detail::intersect_filter);
        rtcCommitGeometry(g);
        rtcAttachGeometryByID(scene_.get(), g, next_geometry_id());
        device_.check("rtcAttachGeometryByID (" + std::string(what) + ")");
        geometries_.push_back(info);
    }

    static MeshData to_mesh_data(const TriangleMesh& m, const std::string& what) {
        MeshData d;
        if (m.normals.size() != m.vertices.size())
            throw InputError("EmbreeTracer: " + what + " has " + std::to_string(m.normals.size()) +
                             " normals for " + std::to_string(m.vertices.size()) + " vertices");
        const auto nv = std::int64_t(m.vertices.size());
        for (std::size_t k = 0; k < m.vertices.size(); ++k) {
            const Vec3d p = m.vertices[k], n = m.normals[k];
            if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
                throw InputError("EmbreeTracer: " + what + " vertex " + std::to_string(k) + " is not finite");
            const double nl = length(n);
            if (!(nl > 0) || !std::isfinite(nl))
                throw InputError("EmbreeTracer: " + what + " normal " + std::to_string(k) +
                                 " is zero or not finite");
            d.p.push_back(Vec3(p));
            d.n.push_back(Vec3(n / nl));
        }
        for (std::size_t t = 0; t < m.triangles.size(); ++t) {
            for (std::int32_t v : m.triangles[t])
                if (v < 0 || v >= nv)
                    throw InputError("EmbreeTracer: " + what + " triangle " + std::to_string(t) +
                                     " uses vertex " + std::to_string(v) + " of " + std::to_string(nv));
            d.tri.push_back(m.triangles[t]);
        }
        return d;
    }

    // Creates and attaches the Embree geometry of meshes_[m], whose first triangle gets
    // global id `tri_offset`.
    void attach_mesh(std::size_t m, std::int64_t tri_offset) {
        MeshData& d = meshes_[m];
        embree_detail::GeometryPtr geometry(rtcNewGeometry(device_.get(), RTC_GEOMETRY_TYPE_TRIANGLE));
        device_.check("rtcNewGeometry (mesh)");
        RTCGeometry g = geometry.get();
        auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                                               3 * sizeof(float), d.p.size()));
        auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                                                  3 * sizeof(unsigned), d.tri.size()));
        device_.check("rtcSetNewGeometryBuffer (mesh)");
        for (std::size_t k = 0; k < d.p.size(); ++k) vb[3 * k] = d.p[k].x, vb[3 * k + 1] = d.p[k].y, vb[3 * k + 2] = d.p[k].z;
        for (std::size_t t = 0; t < d.tri.size(); ++t)
            for (int k = 0; k < 3; ++k) ib[3 * t + std::size_t(k)] = unsigned(d.tri[t][std::size_t(k)]);
        rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_MEDIUM);
        embree_detail::GeometryInfo info;
        info.kind = d.kind;
        info.one_sided = d.kind == HitKind::surface;
        info.tri_offset = std::int32_t(tri_offset);
        info.flip = d.flip.empty() ? nullptr : d.flip.data();
        info.mesh = int(m);
        attach(g, info, "mesh");
        mesh_geometries_.push_back(std::move(geometry));
    }

    void add_meshes(std::vector<ExtraMesh> meshes, std::int64_t tri_offset) {
        const std::size_t first = meshes_.size();
        meshes_.reserve(first + meshes.size());  // GeometryInfo points into the flip tables
        for (std::size_t k = 0; k < meshes.size(); ++k) {
            TriangleMesh& m = meshes[k].mesh;
            if (m.normals.empty()) m.compute_normals();
            const std::string what = "mesh " + std::to_string(k);
            const MeshMaterial& material = meshes[k].material;
            if (material.is_refractive()) {
                if (!(material.ior > 1) || !std::isfinite(material.ior))
                    throw InputError("EmbreeTracer: " + what + ": the refractive index must be > 1, got " +
                                     std::to_string(material.ior));
                check_refractive_solid(m, what);
            }
            MeshData d = to_mesh_data(m, what);
            d.kind = material.is_refractive() ? HitKind::refractive_mesh
                     : material.is_mirror()   ? HitKind::mirror_mesh
                                              : HitKind::absorber;
            d.ior = float(material.ior);
            if (meshes[k].smooth_triangles >= 0) d.smooth = meshes[k].smooth_triangles;
            meshes_.push_back(std::move(d));
        }
        for (std::size_t m = first; m < meshes_.size(); ++m) {
            if (meshes_[m].tri.empty()) continue;
            if (tri_offset + std::int64_t(meshes_[m].tri.size()) > std::numeric_limits<std::int32_t>::max())
                throw InputError("EmbreeTracer: too many triangles in the scene (more than 2^31)");
            attach_mesh(m, tri_offset);
            tri_offset += std::int64_t(meshes_[m].tri.size());
        }
    }

    SurfaceHit make_hit(const HeightfieldView& hf, const RTCRayHit16& rh, int lane) const {
        SurfaceHit hit;
        if (rh.hit.geomID[lane] == RTC_INVALID_GEOMETRY_ID) return hit;
        const unsigned inst = rh.hit.instID[0][lane];
        const unsigned geom = inst != RTC_INVALID_GEOMETRY_ID ? inst : rh.hit.geomID[lane];
        const embree_detail::GeometryInfo& g = geometries_[geom];
        const unsigned prim = rh.hit.primID[lane];
        const float u = rh.hit.u[lane], v = rh.hit.v[lane];
        hit.t = rh.ray.tfar[lane];
        hit.kind = g.kind;
        hit.b0 = 1.0f - u - v;
        hit.b1 = u;
        hit.b2 = v;
        if (g.prim_to_tri) {
            hit.tri = g.prim_to_tri[prim];
            fill_hit_vertices(hf, hit);
        } else {
            hit.tri = g.tri_offset + std::int32_t(prim);
            const MeshData& m = meshes_[std::size_t(g.mesh)];
            const auto& t = m.tri[prim];
            hit.ior = m.ior;
            for (int k = 0; k < 3; ++k) {
                hit.p[k] = m.p[std::size_t(t[std::size_t(k)])];
                hit.n[k] = m.n[std::size_t(t[std::size_t(k)])];
            }
            if (std::int64_t(prim) >= m.smooth) {
                const Vec3 facet = normalize(cross(hit.p[1] - hit.p[0], hit.p[2] - hit.p[0]));
                hit.n[0] = hit.n[1] = hit.n[2] = facet;
            }
        }
        return hit;
    }

    // Traces `count` <= 16 rays (ray_of(k) gives the id of lane k) to their ends, one
    // segment per Embree call for all lanes still active. `path(o, d, t_end)` sees every
    // segment before it is advanced (t_end = infinity when it hits nothing).
    template <class RayOf, class PathVisitor>
    void trace_packet(const HeightfieldView& hf, int count, RayOf&& ray_of, RayRecord* records,
                      PathVisitor&& path) const {
        constexpr int w = embree_detail::packet_width;
        const RaySet& r = *rays_;
        PathState state[w];
        bool active[w] = {};
        int remaining = 0;
        for (int k = 0; k < count; ++k) {
            const auto id = std::size_t(ray_of(k));
            state[k].o = r.origin[id];
            state[k].d = r.direction[id];
            records[k] = RayRecord{};
            active[k] = true;
            ++remaining;
        }
        alignas(64) int valid[w];
        alignas(64) RTCRayHit16 rh;
        embree_detail::PacketContext ctx;
        while (remaining > 0) {
            rtcInitIntersectContext(&ctx.base);
            ctx.base.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
            ctx.geometries = geometries_.data();
            for (int k = 0; k < w; ++k) {
                const PathState& s = state[k];
                valid[k] = active[k] ? -1 : 0;
                rh.ray.org_x[k] = s.o.x;
                rh.ray.org_y[k] = s.o.y;
                rh.ray.org_z[k] = s.o.z;
                rh.ray.dir_x[k] = s.d.x;
                rh.ray.dir_y[k] = s.d.y;
                rh.ray.dir_z[k] = s.d.z;
                rh.ray.tnear[k] = 0.0f;
                rh.ray.tfar[k] = active[k] ? std::numeric_limits<float>::infinity() : -1.0f;
                rh.ray.time[k] = 0.0f;
                rh.ray.mask[k] = 0xFFFFFFFFu;
                rh.ray.id[k] = unsigned(k);
                rh.ray.flags[k] = 0;
                rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
                rh.hit.instID[0][k] = RTC_INVALID_GEOMETRY_ID;
                ctx.exclude[k] = s.exclude;
                ctx.front[k] = wants_front(s) ? 1 : 0;
                ctx.in_solid[k] = s.medium > 1.0f ? 1 : 0;
            }
            rtcIntersect16(valid, scene_.get(), &ctx.base, &rh);
            for (int k = 0; k < w; ++k) {
                if (!active[k]) continue;
                const SurfaceHit hit = make_hit(hf, rh, k);
                path(state[k].o, state[k].d,
                     hit.kind == HitKind::none ? std::numeric_limits<float>::infinity() : hit.t);
                if (!advance(params_, state[k], hit, records[k])) {
                    active[k] = false;
                    --remaining;
                }
            }
        }
    }

    // Declaration order is release order reversed: geometries go before the scene, the
    // scene before the device.
    EmbreeDevice device_;
    embree_detail::ScenePtr scene_;
    const Heightmap* surface_ = nullptr;
    const RaySet* rays_ = nullptr;
    PathParams params_;
    int tile_cells_ = 32;
    EmbreeTileLayout layout_ = EmbreeTileLayout::instanced;
    int tiles_x_ = 0, tiles_y_ = 0;
    int tiles_touched_ = 0;
    std::vector<Tile> tiles_;
    std::vector<MeshData> meshes_;
    std::vector<embree_detail::GeometryPtr> mesh_geometries_;
    std::vector<embree_detail::GeometryInfo> geometries_;  // indexed by Embree geometry id
};

static_assert(Tracer<EmbreeTracer>, "EmbreeTracer must satisfy the Tracer concept");

}  // namespace freeform
