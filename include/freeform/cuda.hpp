#pragma once
// The CUDA back end (docs/cuda.md): the exec::cuda policy for for_each and the GPU
// height-field tracer cuda::DeviceHeightfieldTracer, and a window of moves evaluated on
// the device, cuda::DeviceWindowEvaluation.
//
// Safe to include from any translation unit: under nvcc it brings in the .cuh headers;
// a host compiler sees nothing here, so code shared between .cpp and .cu files can
// include it unconditionally and test FREEFORM_HAS_CUDA_POLICY before using exec::cuda.
#if defined(__CUDACC__)
#include "cuda/exec_cuda.cuh"
#include "cuda/trace_cuda.cuh"
#include "cuda/window_cuda.cuh"
#define FREEFORM_HAS_CUDA_POLICY 1
#else
#define FREEFORM_HAS_CUDA_POLICY 0
#endif
