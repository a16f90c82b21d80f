// The packet tracer (eight rays in SIMD lanes) must give every ray the scalar kernel's
// record bit for bit, and report the same crossed cells with the same height ranges.
#include <doctest/doctest.h>

#include <cmath>
#include <string>
#include <vector>

#include <freeform/core/rng.hpp>
#include <freeform/surface/overlay.hpp>
#include <freeform/trace/heightfield.hpp>
#include <freeform/trace/packet.hpp>

#include "support.hpp"

using namespace freeform;
using namespace freeform::testing;

namespace {

struct Crossing {
    int ci, cj;
    float zlo, zhi;
    bool operator==(const Crossing&) const = default;
};

struct ScalarCells {
    std::vector<Crossing>* out;
    void operator()(int ci, int cj, float zlo, float zhi) const { out->push_back({ci, cj, zlo, zhi}); }
};

struct LaneCells {
    static constexpr bool active = true;
    std::vector<Crossing>* lanes;  // packet::width of them
    void operator()(int l, int ci, int cj, float zlo, float zhi) const { lanes[l].push_back({ci, cj, zlo, zhi}); }
};

// Traces every ray with the scalar kernel and in packets (the last one partly filled)
// and counts the rays whose record or crossed cells differ.
template <class View>
std::int64_t mismatches(const View& view, const PathParams& pp, const RaySet& rays, std::int64_t& depth2) {
    const hf_detail::Grid g = hf_detail::grid_of(view);
    std::int64_t bad = 0;
    depth2 = 0;
    const std::int64_t n = rays.size();
    std::vector<Crossing> lane_cells[packet::width];
    RayRecord packet_records[packet::width];
    for (std::int64_t k0 = 0; k0 < n; k0 += packet::width) {
        const int count = int(std::min<std::int64_t>(packet::width, n - k0));
        for (auto& c : lane_cells) c.clear();
        LaneCells visit{lane_cells};
        packet::trace_rays(view, g, pp, rays.origin.data() + k0, rays.direction.data() + k0, count, packet_records,
                           visit);
        for (int l = 0; l < count; ++l) {
            std::vector<Crossing> cells;
            const RayRecord r = trace_heightfield_ray(view, pp, rays.origin[std::size_t(k0 + l)],
                                                      rays.direction[std::size_t(k0 + l)], ScalarCells{&cells});
            if (!(r == packet_records[l]) || cells != lane_cells[l]) ++bad;
            depth2 += r.depth >= 2 ? 1 : 0;
        }
    }
    return bad;
}

}  // namespace

TEST_CASE("packet lanes trace exactly as the scalar kernel") {
    struct Case {
        std::string name;
        Scene scene;
        int mesh;
    };
    std::vector<Case> cases;
    cases.push_back({"collimated mirror, Phong", basic_scene(40, 8), 31});
    {
        Scene s = basic_scene(40, 8);
        s.surface.phong_alpha = 0;
        cases.push_back({"collimated mirror, flat triangles", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.light.shape = PointLight{{0.01, -0.02, 0.3}, {}, {}};
        cases.push_back({"point light", s, 25});
    }
    {
        // Steep bumps under grazing light: long walks, rays that enter beside the grid,
        // interreflections.
        Scene s = basic_scene(40, 8);
        const double a = degrees_to_radians(75.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.1, -std::cos(a)}};
        s.receiver.frame = make_frame({0.3, 0, 0.3}, {-1, 0, -1}, {0, 1, 0}, "receiver");
        s.receiver.size = {0.4, 0.4};
        cases.push_back({"grazing light", s, 31});
    }
    {
        Scene s = basic_scene(40, 8);
        s.surface.aperture = Aperture::ellipse;
        cases.push_back({"elliptical aperture", s, 31});
    }
    {
        // Light parallel to the grid's rows (a direction component that is exactly 0).
        Scene s = basic_scene(40, 8);
        const double a = degrees_to_radians(30.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.0, -std::cos(a)}};
        s.receiver.frame = make_frame({0.25, 0, 0.45}, {-0.5, 0, -0.866}, {0, 1, 0}, "receiver");
        cases.push_back({"light along the rows", s, 31});
    }
    std::int64_t interreflected = 0;
    for (const Case& c : cases) {
        CAPTURE(c.name);
        Heightmap hm = surface_for(c.scene, c.mesh);
        shape(hm, [](double u, double v) { return 0.003 * std::sin(80 * u) * std::cos(70 * v) - 0.2 * u * u; });
        const RaySet rays = generate_rays(c.scene.light, hm, c.scene.receiver, 3);
        const PathParams pp = make_path_params(c.scene);
        REQUIRE(packet::supports(pp));
        std::int64_t depth2 = 0;
        CHECK(mismatches(hm.view(), pp, rays, depth2) == 0);
        interreflected += depth2;
        // Through an overlay (a move held beside the heights), as the incremental
        // evaluation traces.
        HeightOverlay o;
        o.patch = Patch{8, 6, 17, 15}.clipped(hm.nx(), hm.ny());
        for (int j = o.patch.j0; j <= o.patch.j1; ++j)
            for (int i = o.patch.i0; i <= o.patch.i1; ++i)
                o.heights.push_back(hm.clamp_height(hm(i, j) + 0.002f * float((i + j) % 3) - 0.002f));
        o.finish(hm);
        CHECK(mismatches(overlay_view(hm, o), pp, rays, depth2) == 0);
    }
    // The scenes exercise interreflection (a second surface hit in some lane).
    CHECK(interreflected > 0);
}

TEST_CASE("packet tracing applies to mirrors with true patch normals") {
    Scene s = basic_scene(20, 4);
    CHECK(packet::supports(make_path_params(s)));
    s.surface.material = Lens{1.49, 0.01};
    CHECK_FALSE(packet::supports(make_path_params(s)));
}

TEST_CASE("walks that skip tiles find the scalar kernel's hits bit for bit") {
    // A plain trace skips the 8 x 8-cell tiles its segment passes above or below
    // (heightfield_kernel.hpp, skip_tile; HeightfieldTracer attaches TileRanges). The jump
    // must land where the cell-by-cell walk goes: records equal to those of the walk
    // without tiles, in the scalar kernel and in packets, on deep slabs crossed at steep
    // angles, meshes whose cells do not fill their last tile, and a masked aperture.
    struct Case {
        std::string name;
        Scene scene;
        int mesh;
    };
    std::vector<Case> cases;
    {
        Scene s = basic_scene(40, 8);  // the side lamp's geometry: beside and just above
        s.light.shape = PointLight{{0.0, -0.09, 0.06}, {}, {}};
        s.surface.h_min = -0.03, s.surface.h_max = 0.03;
        cases.push_back({"point light beside a deep mirror", s, 101});
    }
    {
        Scene s = basic_scene(40, 8);
        const double a = degrees_to_radians(75.0);
        s.light.shape = CollimatedLight{{std::sin(a), 0.1, -std::cos(a)}};
        s.receiver.frame = make_frame({0.3, 0, 0.3}, {-1, 0, -1}, {0, 1, 0}, "receiver");
        s.receiver.size = {0.4, 0.4};
        s.surface.h_min = -0.02, s.surface.h_max = 0.02;
        cases.push_back({"grazing light", s, 43});
    }
    {
        Scene s = basic_scene(40, 8);
        s.light.shape = CollimatedLight{normalize(Vec3d{-0.5, -0.6, -0.6})};
        s.receiver.frame = make_frame({-0.25, -0.3, 0.45}, {0.5, 0.6, -0.6}, {0, 0, 1}, "receiver");
        s.surface.aperture = Aperture::ellipse;
        s.surface.h_min = -0.02, s.surface.h_max = 0.02;
        cases.push_back({"elliptical aperture, light from the far corner", s, 58});
    }
    for (const Case& c : cases) {
        CAPTURE(c.name);
        Heightmap hm = surface_for(c.scene, c.mesh);
        shape(hm, [](double u, double v) {
            return 0.004 * std::sin(90 * u) * std::cos(60 * v) - 1.5 * u * u + 0.1 * v;
        });
        const RaySet rays = generate_rays(c.scene.light, hm, c.scene.receiver, 5);
        const PathParams pp = make_path_params(c.scene);
        const HeightfieldView plain = hm.view();
        const TileRanges tiles(plain);
        const HeightfieldView tiled = tiles.attach(plain);
        const hf_detail::Grid g = hf_detail::grid_of(tiled);
        std::int64_t scalar_bad = 0, packet_bad = 0, hits = 0;
        RayRecord packet_records[packet::width];
        for (std::int64_t k0 = 0; k0 < rays.size(); k0 += packet::width) {
            const int count = int(std::min<std::int64_t>(packet::width, rays.size() - k0));
            packet::NoLaneVisitor none;
            packet::trace_rays(tiled, g, pp, rays.origin.data() + k0, rays.direction.data() + k0, count,
                               packet_records, none);
            for (int l = 0; l < count; ++l) {
                const Vec3 o = rays.origin[std::size_t(k0 + l)], d = rays.direction[std::size_t(k0 + l)];
                const RayRecord want = trace_heightfield_ray(plain, pp, o, d, NoCellVisitor{});
                scalar_bad += trace_heightfield_ray(tiled, pp, o, d, NoCellVisitor{}) == want ? 0 : 1;
                packet_bad += packet_records[l] == want ? 0 : 1;
                hits += want.depth >= 1 ? 1 : 0;
            }
        }
        CHECK(hits > rays.size() / 2);
        CHECK(scalar_bad == 0);
        CHECK(packet_bad == 0);
        // The skip is taken: tiles that claim every height lies a metre up lose every hit.
        std::vector<float> up(tiles.lo.size(), 1.0f);
        HeightfieldView lying = plain;
        lying.tiles = {up.data(), up.data(), tiles.tiles_x};
        std::int64_t lost = 0, packet_lost = 0;
        for (std::int64_t k0 = 0; k0 < rays.size(); k0 += packet::width) {
            const int count = int(std::min<std::int64_t>(packet::width, rays.size() - k0));
            packet::NoLaneVisitor none;
            packet::trace_rays(lying, g, pp, rays.origin.data() + k0, rays.direction.data() + k0, count,
                               packet_records, none);
            for (int l = 0; l < count; ++l) {
                const Vec3 o = rays.origin[std::size_t(k0 + l)], d = rays.direction[std::size_t(k0 + l)];
                const int depth = trace_heightfield_ray(plain, pp, o, d, NoCellVisitor{}).depth;
                lost += trace_heightfield_ray(lying, pp, o, d, NoCellVisitor{}).depth < depth ? 1 : 0;
                packet_lost += packet_records[l].depth < depth ? 1 : 0;
            }
        }
        CHECK(lost > rays.size() / 2);
        CHECK(packet_lost > rays.size() / 2);
    }
}
