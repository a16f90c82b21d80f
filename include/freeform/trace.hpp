#pragma once
// Umbrella header of the trace module: the per-ray physics (path.hpp), the height-field
// tracer and its SIMD packet twin, incremental bookkeeping, tracer choice and set-up.
// The Embree tracer has its own umbrella (embree.hpp; link freeform::embree).
#include "trace/heightfield.hpp"
#include "trace/incremental.hpp"
#include "trace/packet.hpp"
#include "trace/path.hpp"
#include "trace/select.hpp"
#include "trace/setup.hpp"
#include "trace/tracer.hpp"
