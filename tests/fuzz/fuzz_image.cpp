// Fuzz target: raster images (io::decode_image_grey: its structure checks, then stb_image
// for PNG, JPEG, BMP, binary PGM/PPM and HDR; other formats are refused before stb sees
// them, docs/limits.md). stb finds the format from the bytes; the name only appears in
// messages (a ".pfm" name would route to the PFM reader, which fuzz_pfm covers).
// stb_image itself is compiled into this program (stb_image_impl.cpp), so that its
// decoders are instrumented and checked by the sanitizers too.
#include <cstddef>
#include <cstdint>
#include <string>

#include <freeform/core/error.hpp>
#include <freeform/io/image.hpp>

#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace freeform;
    const Limits limits = fuzz::fuzz_limits();
    try {
        const ImageF image = io::decode_image_grey(fuzz::bytes_of(data, size), "fuzz.png", limits);
        // A decoded image has pixels, and no more than the limit allows.
        if (image.rows() <= 0 || image.cols() <= 0 ||
            std::uint64_t(image.rows()) * std::uint64_t(image.cols()) > limits.pixels)
            fuzz::property_failed("fuzz_image", "decoded image of " + std::to_string(image.cols()) + " x " +
                                                    std::to_string(image.rows()) + " pixels");
    } catch (const InputError&) {
    }
    return 0;
}
