#pragma once
// Loading a scene's target as a relative-irradiance image.
#include <algorithm>
#include <string>

#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "../core/limits.hpp"
#include "../objective/target.hpp"
#include "../scene/scene.hpp"
#include "font.hpp"
#include "image.hpp"

namespace freeform::io {

// The target of `scene` at a resolution fine enough for its receiver: an image file as
// stored (grey levels are relative irradiance; a PFM is taken linearly), brought up to the
// receiver's pixel count along an axis where it has fewer (target.upsample: the linear
// reconstruction by default, objective/target.hpp upsample_linear), or text rendered at
// 4x the receiver resolution so that area resampling anti-aliases its edges.
// limits.data_file_bytes and limits.pixels bound the image file.
inline ImageD load_target_image(const Scene& scene, const Limits& limits = {}) {
    if (!scene.target) throw InputError("target: the scene has no target (add a \"target\" block)");
    const TargetSpec& t = *scene.target;
    ImageF img;
    if (!t.text.empty()) {
        const int w = std::min(4 * scene.receiver.width, 4096), h = std::min(4 * scene.receiver.height, 4096);
        img = render_text(t.text, find_font(t.font), w, h, t.margin);
    } else {
        try {
            img = read_image_grey(t.image, limits);
        } catch (const IoError& e) {
            throw IoError(std::string("target.image: ") + e.what());
        }
    }
    ImageD out = img.cast<double>();
    if (!out.isFinite().all()) throw InputError("target.image: " + t.image.string() + " has non-finite values");
    if ((out < 0).any()) throw InputError("target.image: " + t.image.string() + " has negative values");
    if (!(out.sum() > 0)) throw InputError("target: " + (t.text.empty() ? t.image.string() : "the text") + " is entirely black");
    if (t.text.empty() && t.upsample == TargetUpsample::bilinear)
        return upsample_linear(out, scene.receiver.width, scene.receiver.height);
    return out;
}

}  // namespace freeform::io
