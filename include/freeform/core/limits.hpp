#pragma once
// Resource limits: how much a scene, an input file or a run may ask for before anything
// is allocated for it. Every reader and the run planner check the relevant limit first
// and throw InputError with a one-line message that names the file or key, the amount
// asked for, the limit and how to raise it. docs/limits.md lists each limit, its default
// and why it has that value.
//
// The limits protect a process that reads files it did not write (a batch system, a
// service): a 400 KB file of nested brackets, a 100-byte PNG header that announces
// 10^10 pixels, an STL that claims four billion triangles, or a scene whose rays need a
// terabyte must be refused in well under a second and with little memory. None of the
// defaults is reached by a real design on a workstation; the CLI's --max-* options and
// this struct raise them where a user needs more.
#include <cstdint>
#include <cstdio>
#include <string>

#include "error.hpp"

namespace freeform {

struct Limits {
    // Nesting of arrays and objects in a scene file. Real scenes nest 4 deep; the JSON
    // parser's memory grows with the depth, so the text is scanned before parsing.
    int json_depth = 64;
    // Size of a scene file in bytes (the examples are under 2 KB).
    std::uint64_t scene_file_bytes = std::uint64_t(16) << 20;
    // Size of any other input file: target images, heightmaps, meshes.
    std::uint64_t data_file_bytes = std::uint64_t(4) << 30;
    // Pixels of an image or a heightmap (8192 x 8192). Checked from the header, before
    // the pixels are decoded.
    std::uint64_t pixels = std::uint64_t(1) << 26;
    // Triangles of a mesh file (an STL of 2^26 triangles is 3.4 GB). Counted before the
    // mesh is built.
    std::uint64_t triangles = std::uint64_t(1) << 26;
    // Memory a render or a design may plan for its rays, grids, meshes and exported
    // part (design/resources.hpp estimates it from the scene before allocating).
    std::uint64_t memory_bytes = std::uint64_t(16) << 30;
};

// "1.5 GiB", "300 MiB", "12 KiB", "100 bytes": a byte count as people read it.
inline std::string format_bytes(double bytes) {
    const char* units[] = {"bytes", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
    int u = 0;
    while (bytes >= 1024 && u < 6) bytes /= 1024, ++u;
    char buffer[48];
    if (u == 0)
        std::snprintf(buffer, sizeof buffer, "%.0f %s", bytes, units[u]);
    else
        std::snprintf(buffer, sizeof buffer, "%.3g %s", bytes, units[u]);
    return buffer;
}

// Throws the InputError of a request over a limit: "`what` exceeds the limit NAME =
// VALUE (...)". `what` names the file or key and the amount asked for.
[[noreturn]] inline void over_limit(const std::string& what, const char* limit_name, const std::string& limit_value) {
    throw InputError(what + ", over the limit " + limit_name + " = " + limit_value +
                     " (raise it with the CLI's --limit " + limit_name + "=VALUE, or Limits::" + limit_name +
                     "; docs/limits.md)");
}

}  // namespace freeform
