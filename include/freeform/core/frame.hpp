#pragma once
// A placed, right-handed orthonormal frame: `w` is the plane normal, `v` the in-plane
// "up" direction and `u = v × w` the in-plane "right" direction, so (u, v, w) is
// right-handed. For a receiver this is the view of an observer facing the receiver's
// front (standing on the side its normal points to): image columns grow along u, and
// image row 0 is the top (largest v).
#include <cmath>
#include <string>

#include "error.hpp"
#include "math.hpp"

namespace freeform {

struct Frame {
    Vec3d origin{};
    Vec3d u{1, 0, 0};
    Vec3d v{0, 1, 0};
    Vec3d w{0, 0, 1};

    Vec3d to_local(Vec3d p) const {
        const Vec3d q = p - origin;
        return {dot(q, u), dot(q, v), dot(q, w)};
    }
    Vec3d dir_to_local(Vec3d d) const { return {dot(d, u), dot(d, v), dot(d, w)}; }
    Vec3d to_world(Vec3d p) const { return origin + p.x * u + p.y * v + p.z * w; }
    Vec3d dir_to_world(Vec3d d) const { return d.x * u + d.y * v + d.z * w; }
};

// Builds a frame from a centre, a normal and an up hint. `what` names the scene block
// ("surface", "receiver") for error messages.
inline Frame make_frame(Vec3d center, Vec3d normal, Vec3d up, const std::string& what) {
    const double nl = length(normal);
    if (!(nl > 0) || !std::isfinite(nl))
        throw InputError(what + ".normal must be a finite non-zero vector");
    const double ul = length(up);
    if (!(ul > 0) || !std::isfinite(ul))
        throw InputError(what + ".up must be a finite non-zero vector");
    Frame f;
    f.origin = center;
    f.w = normal / nl;
    const Vec3d up_n = up / ul;
    const Vec3d v_raw = up_n - dot(up_n, f.w) * f.w;
    const double vl = length(v_raw);
    if (vl < 1e-6)
        throw InputError(what + ".up is parallel to " + what +
                         ".normal: the frame is degenerate (choose an up direction across the normal)");
    f.v = v_raw / vl;
    f.u = cross(f.v, f.w);
    return f;
}

}  // namespace freeform
