#pragma once
// Loading a scene's target as a relative-irradiance image.
#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "../core/enum_names.hpp"
#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "../core/limits.hpp"
#include "../objective/target.hpp"
#include "../scene/scene.hpp"
#include "font.hpp"
#include "image.hpp"

namespace freeform::io {

// A scene's target as loaded: the image the design fits, and for an image file the size
// of the picture as stored (0 × 0 for text), which the summary and metrics.json use to say
// how it was laid on the receiver (target.fit).
struct LoadedTarget {
    ImageD image;
    int picture_width = 0, picture_height = 0;
    // How much the picture was stretched to fill the receiver (aspect_stretch; 1: not
    // at all, or framed by target.fit "contain" or "cover", or text).
    double stretch = 1.0;
};

// The pixels a text target is drawn on: square on the receiver (its own pixels need not
// be: 200 x 200 of them on a 0.3 x 0.2 m receiver), so that the letters keep the font's
// shape, a quarter of the receiver's finer pixel pitch (area resampling to its pixels then
// anti-aliases the edges), at most 4096 along the longer side. Before 2026-12-01 the canvas
// was 4x the receiver's pixels along each axis, capped at 4096 each, which stretched the
// text wherever the receiver's pixels were not square or one side passed 1024 of them.
inline std::pair<int, int> text_canvas(const Receiver& r) {
    const double pitch = std::min(r.pitch().x, r.pitch().y) / 4.0;
    double w = r.size.x / pitch, h = r.size.y / pitch;
    const double shrink = std::min(1.0, 4096.0 / std::max(w, h));
    w *= shrink, h *= shrink;
    return {int(std::clamp<long long>(std::llround(w), 1, 4096)), int(std::clamp<long long>(std::llround(h), 1, 4096))};
}

// A picture (relative irradiance, checked) made the target of `scene`'s receiver as its
// target block says (objective/target.hpp, target_for_receiver), with what is recorded of
// how it was laid on the receiver. The Python module's arrays come through here too.
inline LoadedTarget picture_target(const ImageD& picture, const Scene& scene) {
    LoadedTarget loaded;
    loaded.picture_width = int(picture.cols());
    loaded.picture_height = int(picture.rows());
    if (!scene.target || scene.target->fit == TargetFit::stretch)
        loaded.stretch = aspect_stretch(picture.cols(), picture.rows(), scene.receiver.aspect());
    loaded.image = target_for_receiver(picture, scene);
    return loaded;
}

// What metrics.json records of how an image target was laid on the receiver (`target_fit`,
// docs/cli.md; null for text).
inline nlohmann::json target_fit_json(const Scene& scene, const LoadedTarget& t) {
    if (t.picture_width == 0) return nullptr;
    const TargetFit fit = scene.target ? scene.target->fit : TargetFit::stretch;
    return nlohmann::json{{"picture", nlohmann::json::array({t.picture_width, t.picture_height})},
                          {"fit", enum_name(fit, target_fit_names)},
                          {"stretch", t.stretch}};
}

// The target of `scene` at a resolution fine enough for its receiver: an image file as
// stored (grey levels are relative irradiance; a PFM is taken linearly), framed to the
// receiver's aspect ratio as target.fit says and brought up to the receiver's pixel count
// along an axis where it has fewer (objective/target.hpp, target_for_receiver), or text
// rendered on square pixels at 4x the receiver's resolution (text_canvas), so that area
// resampling anti-aliases its edges.
// limits.data_file_bytes and limits.pixels bound the image file, and limits.pixels the
// framed picture.
inline LoadedTarget load_target(const Scene& scene, const Limits& limits = {}) {
    if (!scene.target) throw InputError("target: the scene has no target (add a \"target\" block)");
    const TargetSpec& t = *scene.target;
    ImageF img;
    if (!t.text.empty()) {
        const auto [w, h] = text_canvas(scene.receiver);
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
    if (!t.text.empty()) return {out, 0, 0, 1.0};
    // Checked before the padded picture is made.
    if (const std::uint64_t n = framed_pixels(out.cols(), out.rows(), scene.receiver.aspect(), t.fit);
        n > limits.pixels)
        throw InputError("target.fit: \"contain\" pads " + t.image.string() + " to " + std::to_string(n) +
                         " pixels, over the limit of " + std::to_string(limits.pixels) +
                         " (--limit pixels=N raises it)");
    return picture_target(out, scene);
}

// The target image alone (load_target).
inline ImageD load_target_image(const Scene& scene, const Limits& limits = {}) {
    return load_target(scene, limits).image;
}

}  // namespace freeform::io
