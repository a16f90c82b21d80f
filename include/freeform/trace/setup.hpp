#pragma once
// Builds the kernel-side parameters of a scene (all in the surface frame).
#include <variant>

#include "../scene/scene.hpp"
#include "path.hpp"

namespace freeform {

inline ReceiverView make_receiver_view(const Receiver& r, const Frame& surface_frame) {
    ReceiverView v;
    v.center = static_cast<Vec3>(surface_frame.to_local(r.frame.origin));
    v.u = static_cast<Vec3>(surface_frame.dir_to_local(r.frame.u));
    v.v = static_cast<Vec3>(surface_frame.dir_to_local(r.frame.v));
    v.n = static_cast<Vec3>(surface_frame.dir_to_local(r.frame.w));
    v.inv_cell_u = float(r.width / r.size.x);
    v.inv_cell_v = float(r.height / r.size.y);
    v.width = r.width;
    v.height = r.height;
    v.deposit = r.deposit;
    return v;
}

inline MaterialView make_material_view(const Material& m, Vec2d size) {
    MaterialView v;
    if (const auto* lens = std::get_if<Lens>(&m)) {
        v.lens = true;
        v.ior = float(lens->ior);
        v.back_w = float(-lens->thickness);
        v.half_u = float(0.5 * size.x);
        v.half_v = float(0.5 * size.y);
    }
    return v;
}

inline PathParams make_path_params(const Scene& scene) {
    PathParams p;
    p.material = make_material_view(scene.surface.material, scene.surface.size);
    p.receiver = make_receiver_view(scene.receiver, scene.surface.frame);
    p.phong_alpha = float(scene.surface.phong_alpha);
    p.max_depth = scene.trace.max_depth;
    p.fresnel = scene.trace.fresnel;
    return p;
}

}  // namespace freeform
