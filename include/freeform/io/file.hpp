#pragma once
// Whole-file reads and crash-safe writes shared by every reader and writer in io/.
// Writers go through write_file_atomically so that a failed or interrupted write
// never leaves a truncated file where a user (or the next run) would pick it up.
#include <bit>
#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <random>
#include <string>
#include <string_view>
#include <system_error>

#include "../core/error.hpp"
#include "../core/limits.hpp"

namespace freeform::io {

namespace detail {

// Binary formats (PFM, STL) fix their byte order; these convert on big-endian hosts.
inline std::uint32_t byte_swap(std::uint32_t v) {
    return (v >> 24) | ((v >> 8) & 0x0000ff00u) | ((v << 8) & 0x00ff0000u) | (v << 24);
}

inline float load_float(const char* p, bool little_endian) {
    std::uint32_t bits;
    std::memcpy(&bits, p, 4);
    if (little_endian != (std::endian::native == std::endian::little)) bits = byte_swap(bits);
    return std::bit_cast<float>(bits);
}

inline void store_float_le(char* p, float value) {
    std::uint32_t bits = std::bit_cast<std::uint32_t>(value);
    if constexpr (std::endian::native != std::endian::little) bits = byte_swap(bits);
    std::memcpy(p, &bits, 4);
}

}  // namespace detail

// The bytes of a file. Throws IoError naming the file when it is missing, is not a
// regular file, or cannot be read completely, and InputError naming the limit when the
// file is larger than `max_bytes` (`limit_name` is the Limits field that sets it): the
// size is checked before anything is read, and again while reading (a file may grow).
inline std::string read_file_bytes(const std::filesystem::path& file,
                                   std::uint64_t max_bytes = Limits{}.data_file_bytes,
                                   const char* limit_name = "data_file_bytes") {
    std::error_code ec;
    const auto status = std::filesystem::status(file, ec);
    if (ec || !std::filesystem::exists(status))
        throw IoError("cannot read '" + file.string() + "': file does not exist");
    if (!std::filesystem::is_regular_file(status))
        throw IoError("cannot read '" + file.string() + "': not a regular file");
    const auto too_large = [&](std::uint64_t size, const char* qualifier) {
        over_limit("cannot read '" + file.string() + "': the file is " + qualifier + format_bytes(double(size)),
                   limit_name, format_bytes(double(max_bytes)));
    };
    const std::uintmax_t size = std::filesystem::file_size(file, ec);
    if (!ec && size > max_bytes) too_large(size, "");

    std::FILE* f = std::fopen(file.string().c_str(), "rb");
    if (!f) throw IoError("cannot open '" + file.string() + "' for reading");
    std::string bytes;
    if (!ec) bytes.reserve(std::size_t(size));
    char buffer[1 << 16];
    std::size_t n = 0;
    while ((n = std::fread(buffer, 1, sizeof buffer, f)) > 0) {
        if (bytes.size() + n > max_bytes) {
            std::fclose(f);
            too_large(bytes.size() + n, "over ");
        }
        bytes.append(buffer, n);
    }
    const bool failed = std::ferror(f) != 0;
    std::fclose(f);
    if (failed) throw IoError("error while reading '" + file.string() + "'");
    return bytes;
}

// Writes `bytes` to `file`: creates the parent directory if needed, writes a temporary
// file next to the target and renames it over the target. Throws IoError naming the
// path on any failure, after removing the temporary file.
inline void write_file_atomically(const std::filesystem::path& file, std::string_view bytes) {
    namespace fs = std::filesystem;
    if (file.empty()) throw IoError("cannot write a file with an empty path");
    if (!file.has_filename() || file.filename() == "." || file.filename() == "..")
        throw IoError("cannot write '" + file.string() + "': the path names a directory");

    std::error_code ec;
    const fs::path parent = file.parent_path();
    if (!parent.empty()) {
        fs::create_directories(parent, ec);
        if (ec)
            throw IoError("cannot write '" + file.string() + "': cannot create directory '" +
                          parent.string() + "': " + ec.message());
    }

    // A random suffix plus exclusive creation keeps concurrent writers (threads or
    // processes writing the same target) from sharing a temporary file.
    std::random_device entropy;
    fs::path temp;
    std::FILE* f = nullptr;
    for (int attempt = 0; attempt < 16 && !f; ++attempt) {
        temp = file;
        temp += ".tmp" + std::to_string(entropy());
        f = std::fopen(temp.string().c_str(), "wbx");
    }
    if (!f)
        throw IoError("cannot write '" + file.string() + "': cannot create a temporary file in '" +
                      (parent.empty() ? std::string(".") : parent.string()) + "'");

    int error = 0;  // the first errno of a failed write, flush or close (disk full, file too large)
    const auto note = [&](bool ok) {
        if (!ok && error == 0) error = errno != 0 ? errno : EIO;
        return ok;
    };
    errno = 0;
    bool ok = note(std::fwrite(bytes.data(), 1, bytes.size(), f) == bytes.size());
    ok = note(std::fflush(f) == 0) && ok;
    ok = note(std::fclose(f) == 0) && ok;  // buffered data may only fail to reach disk here
    if (ok) {
        fs::rename(temp, file, ec);
        ok = !ec;
    }
    if (!ok) {
        std::error_code ignored;
        fs::remove(temp, ignored);
        const std::string reason = ec ? ec.message() : std::generic_category().message(error);
        throw IoError("cannot write '" + file.string() + "': " + reason);
    }
}

}  // namespace freeform::io
