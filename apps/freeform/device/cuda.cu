// The command line's CUDA device (device/offer.hpp), compiled by nvcc: the first device
// the runtime lists, and a factory for its window backend (cuda::DeviceWindowBackend,
// cuda/window_cuda.cuh), which the design's CopiedStateWindowEvaluator drives.
#include <memory>
#include <string>

#include <freeform/cuda/window_cuda.cuh>

#include "offer.hpp"

namespace freeform::cli {

DeviceOffer cuda_offer() {
    DeviceOffer offer;
    int count = 0;
    const cudaError_t status = cudaGetDeviceCount(&count);
    if (status != cudaSuccess || count == 0) {
        (void)cudaGetLastError();
        offer.unavailable = status != cudaSuccess
                                ? std::string("no usable CUDA device (") + cudaGetErrorString(status) + ")"
                                : std::string("no CUDA device on this machine");
        return offer;
    }
    cudaDeviceProp properties{};
    if (cudaGetDeviceProperties(&properties, 0) != cudaSuccess) {
        (void)cudaGetLastError();
        offer.unavailable = "the CUDA runtime could not describe device 0";
        return offer;
    }
    offer.name = properties.name;
    offer.make = [](const Heightmap& surface, const RaySet& rays,
                    const PathParams& params) -> std::unique_ptr<WindowBackend> {
        return std::make_unique<cuda::DeviceWindowBackend>(surface, rays, params);
    };
    return offer;
}

}  // namespace freeform::cli
