#pragma once
// An indexed triangle mesh with optional per-vertex normals: what OBJ/STL files hold,
// what the fabrication export produces and what the Embree tracer can trace.
#include <array>
#include <cstdint>
#include <vector>

#include "../core/math.hpp"

namespace freeform {

struct TriangleMesh {
    std::vector<Vec3d> vertices;
    std::vector<Vec3d> normals;  // empty, or one unit normal per vertex
    std::vector<std::array<std::int32_t, 3>> triangles;

    // Area-weighted vertex normals, for meshes that come without them.
    void compute_normals() {
        normals.assign(vertices.size(), Vec3d{0, 0, 0});
        for (const auto& t : triangles) {
            const Vec3d n = cross(vertices[t[1]] - vertices[t[0]], vertices[t[2]] - vertices[t[0]]);
            for (int k = 0; k < 3; ++k) normals[t[k]] = normals[t[k]] + n;
        }
        for (auto& n : normals) {
            const double l = length(n);
            n = l > 0 ? n / l : Vec3d{0, 0, 1};
        }
    }
};

}  // namespace freeform
