#pragma once
// Portable Float Map (PFM): the float32 format in which height maps and irradiance
// images are exchanged. PFM stores the bottom row first; ImageF keeps row 0 at the top,
// so rows are flipped on the way in and out.
//
// Header: "Pf" (grey) or "PF" (RGB), whitespace, width, whitespace, height, whitespace,
// scale, one whitespace byte, then width × height × channels float32 values. A negative
// scale means little-endian data, a positive one big-endian; its magnitude is ignored.
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <string>
#include <string_view>

#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "../core/limits.hpp"
#include "file.hpp"

namespace freeform::io {

namespace detail {

// Reads the whitespace-separated header tokens of a PFM file and reports where the
// pixel data starts.
class PfmHeaderReader {
public:
    PfmHeaderReader(std::string_view bytes, const std::filesystem::path& file)
        : bytes_(bytes), file_(file) {}

    std::string_view next_token(const char* what) {
        while (pos_ < bytes_.size() && is_space(bytes_[pos_])) ++pos_;
        const std::size_t start = pos_;
        while (pos_ < bytes_.size() && !is_space(bytes_[pos_])) ++pos_;
        if (start == pos_) fail(std::string("missing ") + what);
        return bytes_.substr(start, pos_ - start);
    }

    // The header ends with exactly one whitespace byte after the scale.
    std::size_t data_offset() {
        if (pos_ >= bytes_.size() || !is_space(bytes_[pos_])) fail("missing whitespace after the scale");
        return pos_ + 1;
    }

    [[noreturn]] void fail(const std::string& problem) const {
        throw IoError("bad PFM file '" + file_.string() + "': " + problem);
    }

private:
    static bool is_space(char c) { return std::isspace(static_cast<unsigned char>(c)) != 0; }

    std::string_view bytes_;
    const std::filesystem::path& file_;
    std::size_t pos_ = 0;
};

// Refuses an image of width × height pixels over limits.pixels (`what` names the format
// and the file in the message), before anything is decoded.
inline void check_pixel_count(std::int64_t width, std::int64_t height, const std::string& what,
                              const Limits& limits) {
    if (std::uint64_t(width) * std::uint64_t(height) > limits.pixels)
        over_limit(what + ": " + std::to_string(width) + " x " + std::to_string(height) + " pixels", "pixels",
                   std::to_string(limits.pixels));
}

// Largest accepted side: keeps width × height × 12 far from overflow and rejects
// garbage headers before they turn into huge allocations.
inline constexpr long long pfm_max_side = 1 << 20;

}  // namespace detail

// Parses the bytes of a grey ("Pf") or RGB ("PF", averaged to grey) PFM of either
// endianness; `file` names it in messages. Throws IoError naming the file and the
// problem (bad header, bad dimensions, truncated or surplus data, non-finite values) and
// InputError when the header asks for more than limits.pixels, before any allocation.
inline ImageF parse_pfm(std::string_view bytes, const std::filesystem::path& file, const Limits& limits = {}) {
    detail::PfmHeaderReader header(bytes, file);

    const std::string_view magic = header.next_token("the 'Pf'/'PF' magic");
    if (magic != "Pf" && magic != "PF") header.fail("the file does not start with 'Pf' or 'PF'");
    const int channels = magic == "PF" ? 3 : 1;

    auto parse_side = [&](const char* what) {
        const std::string_view token = header.next_token(what);
        long long value = 0;
        const auto [end, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
        if (ec != std::errc{} || end != token.data() + token.size())
            header.fail(std::string(what) + " '" + std::string(token) + "' is not an integer");
        if (value <= 0 || value > detail::pfm_max_side)
            header.fail(std::string(what) + " " + std::to_string(value) + " is out of range [1, " +
                        std::to_string(detail::pfm_max_side) + "]");
        return static_cast<int>(value);
    };
    const int width = parse_side("width");
    const int height = parse_side("height");
    detail::check_pixel_count(width, height, "PFM '" + file.string() + "'", limits);

    const std::string_view scale_token = header.next_token("scale");
    double scale = 0;
    const auto [end, ec] = std::from_chars(scale_token.data(), scale_token.data() + scale_token.size(), scale);
    if (ec != std::errc{} || end != scale_token.data() + scale_token.size() || !std::isfinite(scale) ||
        scale == 0)
        header.fail("scale '" + std::string(scale_token) + "' is not a finite non-zero number");
    const bool little_endian = scale < 0;

    const std::size_t offset = header.data_offset();
    const std::size_t expected = std::size_t(width) * std::size_t(height) * std::size_t(channels) * 4;
    const std::size_t available = bytes.size() - offset;
    if (available < expected)
        header.fail("truncated data: " + std::to_string(width) + " x " + std::to_string(height) + " x " +
                    std::to_string(channels) + " floats need " + std::to_string(expected) + " bytes, found " +
                    std::to_string(available));
    if (available > expected)
        header.fail(std::to_string(available - expected) + " unexpected bytes after the pixel data (" +
                    std::to_string(width) + " x " + std::to_string(height) + " image)");

    ImageF img(height, width);
    const char* data = bytes.data() + offset;
    for (int stored_row = 0; stored_row < height; ++stored_row) {
        const int y = height - 1 - stored_row;
        for (int x = 0; x < width; ++x) {
            const char* p = data + (std::size_t(stored_row) * width + x) * channels * 4;
            float value = detail::load_float(p, little_endian);
            if (channels == 3)
                value = (value + detail::load_float(p + 4, little_endian) + detail::load_float(p + 8, little_endian)) /
                        3.0f;
            if (!std::isfinite(value))
                header.fail("non-finite value at pixel (x " + std::to_string(x) + ", y " + std::to_string(y) +
                            " from the top)");
            img(y, x) = value;
        }
    }
    return img;
}

// Reads a PFM file (parse_pfm), refusing files larger than limits.data_file_bytes
// before reading them. Throws IoError for a missing or unreadable file.
inline ImageF read_pfm(const std::filesystem::path& file, const Limits& limits = {}) {
    return parse_pfm(read_file_bytes(file, limits.data_file_bytes), file, limits);
}

// Writes a grey little-endian PFM ("Pf", scale -1) through a temporary file. Throws
// IoError naming the file for an empty image, a non-finite value or a failed write.
inline void write_pfm(const std::filesystem::path& file, const ImageF& img) {
    if (img.rows() == 0 || img.cols() == 0)
        throw IoError("cannot write PFM '" + file.string() + "': the image is empty");
    for (Eigen::Index y = 0; y < img.rows(); ++y)
        for (Eigen::Index x = 0; x < img.cols(); ++x)
            if (!std::isfinite(img(y, x)))
                throw IoError("cannot write PFM '" + file.string() + "': non-finite value at pixel (x " +
                              std::to_string(x) + ", y " + std::to_string(y) + ")");

    std::string bytes =
        "Pf\n" + std::to_string(img.cols()) + " " + std::to_string(img.rows()) + "\n-1.0\n";
    const std::size_t offset = bytes.size();
    bytes.resize(offset + std::size_t(img.size()) * 4);
    char* out = bytes.data() + offset;
    for (Eigen::Index y = img.rows() - 1; y >= 0; --y)
        for (Eigen::Index x = 0; x < img.cols(); ++x, out += 4) detail::store_float_le(out, img(y, x));
    write_file_atomically(file, bytes);
}

}  // namespace freeform::io
