// The command line of a build without CUDA (FREEFORM_WITH_CUDA off, or no nvcc when it
// was configured): no device to offer (device/offer.hpp).
#include "offer.hpp"

namespace freeform::cli {

DeviceOffer cuda_offer() {
    DeviceOffer offer;
    offer.unavailable =
        "this freeform was built without CUDA (configure with -DFREEFORM_WITH_CUDA=ON on a machine with nvcc; "
        "docs/cuda.md)";
    return offer;
}

}  // namespace freeform::cli
