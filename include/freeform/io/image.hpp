#pragma once
// Raster images in and out (stb_image / stb_image_write, linked from libstb), plus the
// small colour helpers that turn irradiance and difference images into viewable PNGs.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <stb_image.h>
#include <stb_image_write.h>

#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "../core/limits.hpp"
#include "file.hpp"
#include "pfm.hpp"

namespace freeform::io {

// An 8-bit RGB image: rgb holds width × height × 3 bytes, row-major, row 0 at the top.
struct RgbImage {
    int width = 0;
    int height = 0;
    std::vector<std::uint8_t> rgb;

    bool operator==(const RgbImage&) const = default;
};

namespace detail {

inline std::string lower_extension(const std::filesystem::path& file) {
    std::string ext = file.extension().string();
    for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return ext;
}

inline std::uint8_t to_byte(double v01) {
    if (!(v01 > 0)) return 0;  // also maps NaN to black
    if (v01 >= 1) return 255;
    return static_cast<std::uint8_t>(std::lround(v01 * 255.0));
}

inline void check_rgb(const RgbImage& img, const std::string& where) {
    if (img.width < 0 || img.height < 0 ||
        img.rgb.size() != std::size_t(img.width) * std::size_t(img.height) * 3)
        throw InputError(where + ": RgbImage of " + std::to_string(img.width) + " x " +
                         std::to_string(img.height) + " pixels holds " + std::to_string(img.rgb.size()) +
                         " bytes instead of width * height * 3");
}

// Encodes interleaved 8-bit pixels as PNG in memory, then writes them atomically.
inline void write_png_pixels(const std::filesystem::path& file, const std::uint8_t* pixels, int width,
                             int height, int channels) {
    if (width <= 0 || height <= 0)
        throw IoError("cannot write PNG '" + file.string() + "': the image is empty");
    std::string encoded;
    auto append = [](void* context, void* data, int size) {
        static_cast<std::string*>(context)->append(static_cast<const char*>(data), std::size_t(size));
    };
    if (!stbi_write_png_to_func(append, &encoded, width, height, channels, pixels, width * channels))
        throw IoError("cannot write PNG '" + file.string() + "': encoding failed");
    write_file_atomically(file, encoded);
}

// Big-endian reads of the file's bytes; the callers check the bounds.
inline unsigned image_byte(std::string_view b, std::size_t k) { return static_cast<unsigned char>(b[k]); }
inline std::size_t image_be16(std::string_view b, std::size_t k) {
    return std::size_t(image_byte(b, k)) << 8 | image_byte(b, k + 1);
}
inline std::size_t image_be32(std::string_view b, std::size_t k) {
    return image_be16(b, k) << 16 | image_be16(b, k + 2);
}

// A PNG: every chunk inside the file, no empty IDAT.
inline std::string png_structure_problem(std::string_view b) {
    for (std::size_t at = 8; at < b.size();) {
        if (b.size() - at < 12 || image_be32(b, at) > b.size() - at - 12)
            return "a PNG chunk runs past the end of the file";
        const std::size_t length = image_be32(b, at);
        if (b.substr(at + 4, 4) == "IDAT" && length == 0) return "an empty PNG IDAT chunk";
        if (b.substr(at + 4, 4) == "IEND") break;
        at += 12 + length;
    }
    return "";
}

// The Huffman tables of a JPEG DHT segment (`length` bytes from `at`, marker excluded):
// each inside the segment, with at most 256 codes. Marks the tables it defines in
// `defined` (bit k: DC (0) / AC (1) Huffman table k).
inline std::string jpeg_huffman_problem(std::string_view b, std::size_t at, std::size_t length,
                                        unsigned (&defined)[2]) {
    for (std::size_t t = at + 4; t < at + 2 + length;) {
        if (t + 17 > at + 2 + length) return "a truncated JPEG Huffman table";
        std::size_t codes = 0;
        for (std::size_t k = 1; k <= 16; ++k) codes += image_byte(b, t + k);
        if (codes > 256) return "a JPEG Huffman table with more than 256 codes";
        const unsigned c = image_byte(b, t);
        if ((c >> 4) <= 1 && (c & 15) <= 3) defined[c >> 4] |= 1u << (c & 15);
        t += 17 + codes;
        if (t > at + 2 + length) return "a truncated JPEG Huffman table";
    }
    return "";
}

// A JPEG SOS segment (at `at`, `length` bytes): a scan decodes with tables it names; stb
// reads an undefined one from uninitialised memory. Baseline scans use both; a
// progressive scan the DC table (first DC pass) or the AC table (spectral bands above 0).
inline std::string jpeg_scan_problem(std::string_view b, std::size_t at, std::size_t length, bool progressive,
                                     const unsigned (&defined)[2]) {
    const std::size_t count = length >= 3 ? image_byte(b, at + 4) : 0;
    if (length < 6 + 2 * count) return "a truncated JPEG scan header";
    const std::size_t after = at + 5 + 2 * count;
    const bool dc_scan = image_byte(b, after) == 0, first_pass = (image_byte(b, after + 2) >> 4) == 0;
    for (std::size_t c = 0; c < count; ++c) {
        const unsigned dc = image_byte(b, at + 6 + 2 * c) >> 4, ac = image_byte(b, at + 6 + 2 * c) & 15;
        const bool need_dc = !progressive || (dc_scan && first_pass), need_ac = !progressive || !dc_scan;
        if ((need_dc && (dc > 3 || !(defined[0] >> dc & 1))) || (need_ac && (ac > 3 || !(defined[1] >> ac & 1))))
            return "a JPEG scan that uses an undefined Huffman table";
    }
    return "";
}

// A JPEG: walk the markers (and past entropy-coded data) to every Huffman table and scan.
inline std::string jpeg_structure_problem(std::string_view b) {
    std::size_t at = 2;
    bool progressive = false;
    unsigned defined[2] = {0, 0};  // bit k: DC (0) / AC (1) Huffman table k seen so far
    while (at + 4 <= b.size()) {
        if (image_byte(b, at) != 0xFF) {  // entropy-coded data: up to the next real marker
            ++at;
            continue;
        }
        const unsigned marker = image_byte(b, at + 1);
        if (marker == 0xFF || marker == 0x00 || (marker >= 0xD0 && marker <= 0xD8) || marker == 0x01) {
            at += marker == 0xFF ? 1 : 2;
            continue;
        }
        if (marker == 0xD9) break;  // end of image
        const std::size_t length = image_be16(b, at + 2);
        if (length < 2 || at + 2 + length > b.size()) return "a JPEG segment runs past the end of the file";
        if (marker == 0xC4)
            if (std::string problem = jpeg_huffman_problem(b, at, length, defined); !problem.empty()) return problem;
        if (marker >= 0xC0 && marker <= 0xC2) progressive = marker == 0xC2;
        if (marker == 0xDA)
            if (std::string problem = jpeg_scan_problem(b, at, length, progressive, defined); !problem.empty())
                return problem;
        at += 2 + length;
    }
    return "";
}

// A binary PGM/PPM: width, height and maximum value, plain numbers that fit an int.
inline std::string pnm_structure_problem(std::string_view b) {
    std::size_t at = 2;
    for (int field = 0; field < 3; ++field) {
        while (at < b.size() && (std::isspace(image_byte(b, at)) || b[at] == '#')) {
            if (b[at] == '#')
                while (at < b.size() && b[at] != '\n' && b[at] != '\r') ++at;
            else
                ++at;
        }
        std::size_t digits = 0;
        while (at < b.size() && std::isdigit(image_byte(b, at))) ++at, ++digits;
        if (digits == 0 || digits > 9) return "a PNM header with a missing or oversized number";
    }
    return "";
}

// What stb_image is trusted to decode. Its decoders (Debian's libstb, v2.27) have known
// memory errors on crafted files, found by fuzzing (tests/fuzz/regressions/image): a
// JPEG Huffman table whose code counts exceed 256 writes past a 257-entry array, a PNG
// whose first IDAT is empty copies from a null pointer, a JPEG scan that names a Huffman
// table no DHT segment has defined decodes with uninitialised memory and indexes out of bounds, a PNM width of more than nine
// digits overflows an int, a cut Radiance HDR file makes its run-length decoder loop
// forever. The formats a target comes in are checked here before stb sees them, and the
// formats nobody designs a target in (PSD, GIF, TGA, PIC, and HDR, whose linear values
// PFM carries) are not passed to it at all. Returns the reason a file is refused, or "" to decode it.
inline std::string image_structure_problem(std::string_view b) {
    if (b.substr(0, 8) == std::string_view("\x89PNG\r\n\x1a\n", 8)) return png_structure_problem(b);
    if (b.size() >= 3 && image_byte(b, 0) == 0xFF && image_byte(b, 1) == 0xD8 && image_byte(b, 2) == 0xFF)
        return jpeg_structure_problem(b);
    if (b.size() >= 2 && b[0] == 'P' && (b[1] == '5' || b[1] == '6')) return pnm_structure_problem(b);
    if (b.substr(0, 2) == "BM") return "";
    if (b.substr(0, 2) == "#?") return "a Radiance HDR image (not taken: stb loops forever on some; use PFM)";
    return "not a PNG, JPEG, BMP, binary PGM/PPM or PFM image";
}

struct StbiFree {
    void operator()(void* p) const { stbi_image_free(p); }
};

}  // namespace detail

// Decodes the bytes of an image as grey luminance. PNG, JPEG, BMP, binary PGM/PPM:
// 8-bit values are divided by 255 and 16-bit ones by 65535, colour becomes Rec. 709
// luma of the stored (gamma-encoded) values, and alpha composites over black
// (transparent = no light). Linear values come as PFM: a ".pfm" extension of `file`
// (which names the bytes in messages) dispatches to parse_pfm. Radiance HDR, GIF, TGA and
// PSD are refused (image_structure_problem). Throws IoError naming the file and stb's reason on failure, and InputError
// when the header announces more than limits.pixels (checked before decoding).
inline ImageF decode_image_grey(std::string_view bytes, const std::filesystem::path& file,
                                const Limits& limits = {}) {
    if (detail::lower_extension(file) == ".pfm") return parse_pfm(bytes, file, limits);
    if (bytes.size() > std::size_t(std::numeric_limits<int>::max()))
        throw IoError("cannot read image '" + file.string() + "': file too large");
    if (const std::string problem = detail::image_structure_problem(bytes); !problem.empty())
        throw IoError("cannot read image '" + file.string() + "': " + problem);
    const auto* data = reinterpret_cast<const stbi_uc*>(bytes.data());
    const int size = static_cast<int>(bytes.size());
    const auto failure = [&] {
        const char* reason = stbi_failure_reason();
        // stb leaves the reason empty for some truncated files.
        const std::string why = reason && *reason ? reason : "corrupt or truncated image data";
        return IoError("cannot read image '" + file.string() + "': " + why);
    };

    int width = 0, height = 0, channels = 0;
    if (!stbi_info_from_memory(data, size, &width, &height, &channels)) throw failure();
    if (width <= 0 || height <= 0) throw IoError("cannot read image '" + file.string() + "': no pixels");
    detail::check_pixel_count(width, height, "image '" + file.string() + "'", limits);
    // No format taken here packs more than about a thousand pixels into a byte (deflate's
    // limit is 1032:1 on PNG's raw bytes; a uniform JPEG needs a byte per 85-130 pixels);
    // a header that announces more is a cut file or a forged one, and stb would fill the
    // missing pixels with zeros (a 2 KB JPEG announcing 8000 x 8000: 2.4 s, 440 MB).
    if (std::uint64_t(width) * std::uint64_t(height) > 2048 * std::uint64_t(bytes.size()))
        throw IoError("cannot read image '" + file.string() + "': its header announces " + std::to_string(width) +
                      " x " + std::to_string(height) + " pixels in " + std::to_string(bytes.size()) +
                      " bytes, more than any PNG, JPEG, BMP or PGM/PPM can hold (a cut file or a forged header)");
    const bool hdr = stbi_is_hdr_from_memory(data, size) != 0;
    const bool sixteen = !hdr && stbi_is_16_bit_from_memory(data, size) != 0;
    std::unique_ptr<void, detail::StbiFree> pixels;
    if (hdr)
        pixels.reset(stbi_loadf_from_memory(data, size, &width, &height, &channels, 0));
    else if (sixteen)
        pixels.reset(stbi_load_16_from_memory(data, size, &width, &height, &channels, 0));
    else
        pixels.reset(stbi_load_from_memory(data, size, &width, &height, &channels, 0));
    if (!pixels) throw failure();
    if (std::uint64_t(width) * std::uint64_t(height) > limits.pixels || channels < 1 || channels > 4)
        throw IoError("cannot read image '" + file.string() + "': the decoded image differs from its header");

    auto sample = [&](std::size_t i) -> float {
        if (hdr) return static_cast<const float*>(pixels.get())[i];
        if (sixteen) return static_cast<const std::uint16_t*>(pixels.get())[i] / 65535.0f;
        return static_cast<const stbi_uc*>(pixels.get())[i] / 255.0f;
    };
    ImageF img(height, width);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            const std::size_t p = (std::size_t(y) * width + x) * channels;
            float value = 0;
            switch (channels) {
                case 1: value = sample(p); break;
                case 2: value = sample(p) * sample(p + 1); break;
                default: {
                    value = 0.2126f * sample(p) + 0.7152f * sample(p + 1) + 0.0722f * sample(p + 2);
                    if (channels == 4) value *= sample(p + 3);
                }
            }
            img(y, x) = value;
        }
    return img;
}

// Reads an image file (decode_image_grey), refusing files larger than
// limits.data_file_bytes before reading them.
inline ImageF read_image_grey(const std::filesystem::path& file, const Limits& limits = {}) {
    return decode_image_grey(read_file_bytes(file, limits.data_file_bytes), file, limits);
}

// Writes an 8-bit grey PNG; values are clamped to [0, 1] (NaN becomes 0).
inline void write_png(const std::filesystem::path& file, const ImageF& grey01) {
    std::vector<std::uint8_t> pixels(std::size_t(grey01.size()));
    for (Eigen::Index y = 0; y < grey01.rows(); ++y)
        for (Eigen::Index x = 0; x < grey01.cols(); ++x)
            pixels[std::size_t(y * grey01.cols() + x)] = detail::to_byte(grey01(y, x));
    detail::write_png_pixels(file, pixels.data(), int(grey01.cols()), int(grey01.rows()), 1);
}

// Writes an 8-bit RGB PNG.
inline void write_png(const std::filesystem::path& file, const RgbImage& img) {
    detail::check_rgb(img, "write_png('" + file.string() + "')");
    detail::write_png_pixels(file, img.rgb.data(), img.width, img.height, 3);
}

// Writes an 8-bit RGB PNG from interleaved bytes: `rgb_interleaved` holds height rows of
// width × 3 bytes (r, g, b per pixel), row 0 at the top.
inline void write_png_rgb(const std::filesystem::path& file,
                          const Eigen::Array<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>&
                              rgb_interleaved,
                          int width, int height) {
    if (width <= 0 || height <= 0 || rgb_interleaved.rows() != height || rgb_interleaved.cols() != 3 * width)
        throw InputError("write_png_rgb('" + file.string() + "'): expected a " + std::to_string(height) +
                         " x " + std::to_string(3 * std::max(width, 0)) + " byte array for a " +
                         std::to_string(width) + " x " + std::to_string(height) + " image, got " +
                         std::to_string(rgb_interleaved.rows()) + " x " + std::to_string(rgb_interleaved.cols()));
    detail::write_png_pixels(file, rgb_interleaved.data(), width, height, 3);
}

// A viewable image of an irradiance histogram: scales so that the `exposure_percentile`
// quantile of the positive cells maps to 1, clamps to [0, 1] and applies 1/gamma.
// An image with no positive cell maps to black. Throws InputError for a percentile
// outside (0, 1] or a non-positive gamma.
inline ImageF tone_map(const ImageD& irradiance, double exposure_percentile = 0.995, double gamma = 2.2) {
    if (!(exposure_percentile > 0 && exposure_percentile <= 1))
        throw InputError("tone_map: exposure_percentile " + std::to_string(exposure_percentile) +
                         " is outside (0, 1]");
    if (!(gamma > 0) || !std::isfinite(gamma))
        throw InputError("tone_map: gamma " + std::to_string(gamma) + " must be a positive number");

    std::vector<double> positive;
    positive.reserve(std::size_t(irradiance.size()));
    for (Eigen::Index i = 0; i < irradiance.size(); ++i) {
        const double v = irradiance.data()[i];
        if (v > 0 && std::isfinite(v)) positive.push_back(v);
    }
    ImageF out = ImageF::Zero(irradiance.rows(), irradiance.cols());
    if (positive.empty()) return out;

    const auto rank = static_cast<std::ptrdiff_t>(std::llround(exposure_percentile * double(positive.size() - 1)));
    std::nth_element(positive.begin(), positive.begin() + rank, positive.end());
    const double white = positive[std::size_t(rank)];
    for (Eigen::Index i = 0; i < irradiance.size(); ++i) {
        const double v = irradiance.data()[i] / white;
        out.data()[i] = v > 0 ? static_cast<float>(std::pow(std::min(v, 1.0), 1.0 / gamma)) : 0.0f;
    }
    return out;
}

// Diverging blue-white-red colour map for signed differences: 0 is white, -limit and
// below full blue, +limit and above full red. limit = 0 shows only the sign (any
// non-zero value saturates); NaN is black. Throws InputError for a negative or
// non-finite limit.
inline RgbImage diverging(const ImageD& signed_values, double limit) {
    if (!(limit >= 0) || !std::isfinite(limit))
        throw InputError("diverging: limit " + std::to_string(limit) + " must be finite and >= 0");
    constexpr double blue[3] = {33, 102, 172};
    constexpr double red[3] = {178, 24, 43};

    RgbImage img{int(signed_values.cols()), int(signed_values.rows()), {}};
    img.rgb.resize(std::size_t(signed_values.size()) * 3);
    for (Eigen::Index i = 0; i < signed_values.size(); ++i) {
        const double v = signed_values.data()[i];
        std::uint8_t* px = &img.rgb[std::size_t(i) * 3];
        if (std::isnan(v)) {
            px[0] = px[1] = px[2] = 0;
            continue;
        }
        double t = limit > 0 ? v / limit : (v > 0 ? 1.0 : (v < 0 ? -1.0 : 0.0));
        t = std::clamp(t, -1.0, 1.0);
        const double* end = t < 0 ? blue : red;
        const double a = std::abs(t);
        for (int c = 0; c < 3; ++c) px[c] = static_cast<std::uint8_t>(std::lround(255.0 + a * (end[c] - 255.0)));
    }
    return img;
}

// Grey [0, 1] (clamped) to RGB, for composing with colour images.
inline RgbImage grey_to_rgb(const ImageF& grey01) {
    RgbImage img{int(grey01.cols()), int(grey01.rows()), {}};
    img.rgb.resize(std::size_t(grey01.size()) * 3);
    for (Eigen::Index i = 0; i < grey01.size(); ++i) {
        const std::uint8_t v = detail::to_byte(grey01.data()[i]);
        for (int c = 0; c < 3; ++c) img.rgb[std::size_t(i) * 3 + c] = v;
    }
    return img;
}

// Places images side by side, top-aligned, separated by gap_px black columns; shorter
// images are padded with black below. Throws InputError for a negative gap or a part
// whose byte count does not match its size.
inline RgbImage hconcat(const std::vector<RgbImage>& parts, int gap_px = 4) {
    if (gap_px < 0) throw InputError("hconcat: gap_px " + std::to_string(gap_px) + " must be >= 0");
    RgbImage out;
    for (std::size_t k = 0; k < parts.size(); ++k) {
        detail::check_rgb(parts[k], "hconcat part " + std::to_string(k));
        out.width += parts[k].width + (k > 0 ? gap_px : 0);
        out.height = std::max(out.height, parts[k].height);
    }
    out.rgb.assign(std::size_t(out.width) * out.height * 3, 0);
    int x0 = 0;
    for (const RgbImage& part : parts) {
        for (int y = 0; y < part.height && part.width > 0; ++y)
            std::copy_n(&part.rgb[std::size_t(y) * part.width * 3], std::size_t(part.width) * 3,
                        &out.rgb[(std::size_t(y) * out.width + x0) * 3]);
        x0 += part.width + gap_px;
    }
    return out;
}

}  // namespace freeform::io
