#pragma once
// A device that the program running a design offers for its windows (optimise.device,
// design/options.hpp; docs/cuda.md). The library itself is compiled by the host compiler
// and cannot make a device backend: a program built with nvcc makes it (the command
// line's apps/freeform/device/cuda.cu makes cuda::DeviceWindowBackend) and hands it to
// the design through DesignSetup::cuda (design/pipeline.hpp). Only declarations here, so
// that nvcc compiles this header in that translation unit without the design's headers.
#include <functional>
#include <memory>
#include <string>

namespace freeform {

class WindowBackend;
class Heightmap;
struct RaySet;
struct PathParams;

// A backend for a stage's windows over the stage's surface, rays and path parameters
// (which outlive it).
using WindowBackendFactory =
    std::function<std::unique_ptr<WindowBackend>(const Heightmap&, const RaySet&, const PathParams&)>;

// What a program offers: a usable device and how to make its backend, or why there is none.
struct DeviceOffer {
    std::string name;         // the device in words, for reports ("NVIDIA H200"); empty when none
    std::string unavailable;  // why there is no usable device; empty when there is one
    WindowBackendFactory make;
    int window = 0;  // proposals per window that suit the device; 0: default_device_window
    bool usable() const { return unavailable.empty() && static_cast<bool>(make); }
};

// Proposals per speculative window on a device when neither the offer nor
// optimise.speculative says: enough to keep a device busy at the acceptance rates of a
// cooled schedule. The trajectory does not depend on it (anneal/annealer.hpp), only speed.
inline constexpr int default_device_window = 32;

}  // namespace freeform
