#pragma once
// What fuzz_obj and fuzz_stl check on a mesh that was read: it is self-consistent, and
// the closed-solid test that a refractive mesh must pass (welded, then
// check_refractive_solid) either accepts it or says why with an InputError.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include <freeform/core/error.hpp>
#include <freeform/io/mesh.hpp>
#include <freeform/surface/export.hpp>

#include "fuzz_common.hpp"

namespace freeform::fuzz {

inline void check_read_mesh(const TriangleMesh& mesh, const char* harness) {
    if (mesh.triangles.empty()) property_failed(harness, "a mesh without triangles was accepted");
    if (!mesh.normals.empty() && mesh.normals.size() != mesh.vertices.size())
        property_failed(harness, std::to_string(mesh.normals.size()) + " normals for " +
                                     std::to_string(mesh.vertices.size()) + " vertices");
    for (const Vec3d& v : mesh.vertices)
        if (!std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z))
            property_failed(harness, "a non-finite vertex was accepted");
    const auto n = std::int64_t(mesh.vertices.size());
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
        for (const std::int32_t v : mesh.triangles[t])
            if (v < 0 || v >= n)
                property_failed(harness, "triangle " + std::to_string(t) + " refers to vertex " + std::to_string(v) +
                                             " of " + std::to_string(n));

    try {
        const TriangleMesh solid = io::welded(mesh);
        if (solid.triangles.size() != mesh.triangles.size() || solid.vertices.size() > mesh.vertices.size())
            property_failed(harness, "welding changed the triangle count or added vertices");
        (void)check_refractive_solid(solid, "fuzz");
    } catch (const InputError&) {
    }
}

}  // namespace freeform::fuzz
