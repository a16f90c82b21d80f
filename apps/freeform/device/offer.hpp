#pragma once
// The CUDA device the command line offers a design (optimise.device, --device;
// docs/cuda.md). One definition per build: cuda.cu, compiled by nvcc where CMake enables
// CUDA (FREEFORM_WITH_CUDA), or none.cpp, which offers nothing and says why.
#include <freeform/design/device.hpp>

namespace freeform::cli {

// Asks the CUDA runtime for a device (only when a design asks for one: the runtime's
// start takes a moment). Never throws for a missing device or driver: the offer then
// says why it is unusable.
DeviceOffer cuda_offer();

}  // namespace freeform::cli
