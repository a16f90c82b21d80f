// Fuzz target: Wavefront OBJ meshes (io::parse_obj), then the refractive-solid checks.
#include <cstddef>
#include <cstdint>

#include <freeform/core/error.hpp>
#include <freeform/io/mesh.hpp>

#include "fuzz_common.hpp"
#include "fuzz_mesh.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace freeform;
    try {
        const TriangleMesh mesh = io::parse_obj(fuzz::bytes_of(data, size), "fuzz.obj", fuzz::fuzz_limits());
        fuzz::check_read_mesh(mesh, "fuzz_obj");
    } catch (const InputError&) {
    }
    return 0;
}
