#pragma once
// Builds the kernel-side parameters of a scene (all in the surface frame).
#include <cmath>
#include <variant>

#include "../scene/rays.hpp"
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

// How far the light source's own extent smears an image point on the receiver, in cells
// of `receiver` (the larger of its two cell sides): a distant source of angular radius a
// smears over D tan a at the receiver's distance D from the surface, a disc of radius R at
// distance d over R D / d; a point source not at all.
inline double source_blur_cells(const Scene& scene, const Receiver& receiver) {
    const double D = length(receiver.frame.origin - scene.surface.frame.origin);
    double blur = 0;
    if (const auto* c = std::get_if<CollimatedLight>(&scene.light.shape)) {
        blur = D * std::tan(degrees_to_radians(c->angular_radius));
    } else if (const auto* disk = std::get_if<DiskLight>(&scene.light.shape)) {
        const double d = length(disk->center - scene.surface.frame.origin);
        blur = d > 0 ? disk->radius * D / d : 0;
    }
    const double cell = std::fmax(receiver.size.x / receiver.width, receiver.size.y / receiver.height);
    return blur / cell;
}

// fine_bilinear's k for this scene and receiver (core/deposit.hpp): the narrow ramp,
// unless the source blurs every image point over a cell or more. Then the surface cannot
// place light finely enough to exploit the wide ramp, and the wide ramp averages more of
// the rays' noise.
inline int fine_deposit_factor_for(const Scene& scene, const Receiver& receiver) {
    return source_blur_cells(scene, receiver) >= 1.0 ? fine_deposit_factor_blurred : fine_deposit_factor;
}

// A lens body's side walls stand `rim` beyond the face's edges (lens_rim).
inline MaterialView make_material_view(const Material& m, Vec2d size, double rim = 0) {
    MaterialView v;
    if (const auto* lens = std::get_if<Lens>(&m)) {
        v.lens = true;
        v.ior = float(lens->ior);
        v.back_w = float(-lens->thickness);
        v.half_u = float(0.5 * size.x + rim);
        v.half_v = float(0.5 * size.y + rim);
    }
    return v;
}

// `receiver`: the scene's receiver plane, at its own resolution or at another one (a
// design level's, design/designer.hpp): its frame and size must be the scene's (the lens
// rim depends on them).
inline PathParams make_path_params(const Scene& scene, const Receiver& receiver) {
    PathParams p;
    p.material = make_material_view(scene.surface.material, scene.surface.size, lens_rim(scene));
    p.receiver = make_receiver_view(receiver, scene.surface.frame);
    p.receiver.fine_factor = float(fine_deposit_factor_for(scene, receiver));
    p.phong_alpha = float(scene.surface.phong_alpha);
    p.max_depth = scene.trace.max_depth;
    p.fresnel = scene.trace.fresnel;
    return p;
}

inline PathParams make_path_params(const Scene& scene) { return make_path_params(scene, scene.receiver); }

// The total a target is scaled to (N of docs/measures.md): the weight of the rays that
// reach the surface. With Fresnel losses on a lens, the part of it that a flat lens of the
// same glass lets through, each ray at its own incidence on the front face and, refracted,
// on the back face (0.9216 of it at normal incidence for n = 1.5). A design is then judged
// on how it spreads the light its faces can pass, and must send more light where its
// slopes lose more than a flat face does (docs/scene.md, "Fresnel losses").
inline Fixed target_total(const RaySet& rays, const PathParams& pp) {
    if (!pp.fresnel || !pp.material.lens) return rays.total;
    const float n = pp.material.ior;
    Fixed total = 0;
    for (std::size_t k = 0; k < rays.direction.size(); ++k) {
        const Vec3 d = rays.direction[k];
        const float cos_front = std::fabs(d.z) / std::sqrt(dot(d, d));
        const float cos_inside = std::sqrt(std::fmax(0.0f, 1.0f - (1.0f - cos_front * cos_front) / (n * n)));
        const float pass = fresnel_transmittance(cos_front, 1.0f, n) * fresnel_transmittance(cos_inside, n, 1.0f);
        total += fixed_part(rays.weight[k], pass);
    }
    return total;
}

}  // namespace freeform
