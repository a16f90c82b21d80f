// Fuzz target: Portable Float Maps (io::parse_pfm), the heightmap and irradiance format.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>

#include <freeform/core/error.hpp>
#include <freeform/io/pfm.hpp>

#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace freeform;
    const Limits limits = fuzz::fuzz_limits();
    try {
        const ImageF image = io::parse_pfm(fuzz::bytes_of(data, size), "fuzz.pfm", limits);
        // parse_pfm promises a non-empty image within the limit, with finite values only.
        if (image.rows() <= 0 || image.cols() <= 0 ||
            std::uint64_t(image.rows()) * std::uint64_t(image.cols()) > limits.pixels)
            fuzz::property_failed("fuzz_pfm", "image of " + std::to_string(image.cols()) + " x " +
                                                  std::to_string(image.rows()) + " pixels");
        for (Eigen::Index k = 0; k < image.size(); ++k)
            if (!std::isfinite(image.data()[k]))
                fuzz::property_failed("fuzz_pfm", "non-finite value at index " + std::to_string(k));
    } catch (const InputError&) {
    }
    return 0;
}
