# ctest driver (cmake -P) for the CUDA tests. Prints "freeform-cuda-check: skipped" (the
# tests' SKIP_REGULAR_EXPRESSION) when there is no nvcc, or for MODE=run no GPU, so that
# machines without CUDA report the tests as skipped rather than failed.
#
#   MODE=compile (ctest `cuda_compile`, the default): compiles kernels_check.cu with nvcc,
#     every FREEFORM_HD header and every .cuh pre-included, and compiles (does not run)
#     both halves of the GPU-against-CPU test.
#   MODE=run (ctest `cuda_gpu_vs_cpu`): if `nvidia-smi -L` lists a device, builds the
#     GPU-against-CPU test and runs it; its exit status 77 means "no usable device".
#
# Inputs (-D): MODE, NVCC, HOST_COMPILER, SOURCE, OUTPUT, GPU_SOURCE, GPU_HOST_SOURCE,
# BENCH_SOURCE, BENCH_HOST_SOURCE (compile mode: benchmarks/gpu's two halves),
# INCLUDE_DIRS ('|'-separated), EXTRA_FLAGS (a command-line string).
#
# Both sides are compiled without FMA contraction (--fmad=false, -ffp-contract=off): the
# GPU tracer reproduces the CPU one bit for bit only then (docs/cuda.md).
cmake_minimum_required(VERSION 3.25)

if(NOT MODE)
  set(MODE compile)
endif()
if(NOT MODE MATCHES "^(compile|run)$")
  message(FATAL_ERROR "freeform-cuda-check: MODE must be compile or run, got '${MODE}'")
endif()

if(NOT NVCC OR NOT EXISTS "${NVCC}")
  message("freeform-cuda-check: skipped (no nvcc; set FREEFORM_NVCC or CUDACXX to enable)")
  return()
endif()

if(MODE STREQUAL "run")
  find_program(nvidia_smi nvidia-smi PATHS /usr/bin /usr/local/nvidia/bin /usr/lib/wsl/lib)
  set(devices "")
  if(nvidia_smi)
    execute_process(COMMAND "${nvidia_smi}" -L RESULT_VARIABLE smi_rc OUTPUT_VARIABLE devices ERROR_QUIET)
    if(NOT smi_rc EQUAL 0)
      set(devices "")
    endif()
  endif()
  if(NOT devices MATCHES "GPU [0-9]+:")
    message("freeform-cuda-check: skipped (no CUDA device: `nvidia-smi -L` lists none)")
    return()
  endif()
  string(STRIP "${devices}" devices)
  message(STATUS "freeform-cuda-check: ${devices}")
endif()

string(REPLACE "|" ";" include_dirs "${INCLUDE_DIRS}")
set(include_flags "")
list(GET include_dirs 0 project_include)
list(REMOVE_AT include_dirs 0)
list(APPEND include_flags "-I${project_include}")
# Third-party headers are system headers: their warnings are not ours to fix.
# The compiler's own directories stay out: -isystem /usr/include breaks #include_next.
list(REMOVE_DUPLICATES include_dirs)
list(REMOVE_ITEM include_dirs "" /usr/include /usr/local/include)
foreach(dir IN LISTS include_dirs)
  if(dir)
    list(APPEND include_flags -isystem "${dir}")
  endif()
endforeach()
separate_arguments(extra UNIX_COMMAND "${EXTRA_FLAGS}")

get_filename_component(output_dir "${OUTPUT}" DIRECTORY)
# The two tests may run at the same time: each writes into a folder of its own.
set(work_dir "${output_dir}/${MODE}")
file(MAKE_DIRECTORY "${work_dir}")

# Host/device call mistakes are errors: a host function called from FREEFORM_HD code
# (cross-execution-space-call, 20011/20014) or a constexpr host function such as
# std::min called from it (20013). Eigen itself triggers 20012 (annotations on
# defaulted members) and 20015 (constexpr host calls inside its own templates); those
# come from Eigen's host-side code and are silenced.
set(nvcc_flags
  -std=c++20 --extended-lambda --fmad=false
  -ccbin "${HOST_COMPILER}"
  ${include_flags}
  --Werror cross-execution-space-call
  -diag-error 20013
  -diag-suppress 20012,20015
  -Xcompiler -Wall,-Wextra,-Werror
  ${extra})
# The CPU half is built as the library's CPU build is, with contraction off.
set(host_flags -std=c++20 -O2 -ffp-contract=off -Wall -Wextra -Wpedantic -Werror ${include_flags})

function(run_step what)
  list(JOIN ARGN " " shown)
  message(STATUS "${shown}")
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "freeform-cuda-check: ${what} failed (${rc})")
  endif()
endfunction()

execute_process(COMMAND "${NVCC}" --version OUTPUT_VARIABLE version)
string(REGEX MATCH "release [0-9.]+" version "${version}")

if(MODE STREQUAL "compile")
  # Every header that has FREEFORM_HD code is compiled as CUDA, including ones added after
  # kernels_check.cu was written (pre-included ahead of it); the .cuh headers too.
  file(GLOB_RECURSE headers "${project_include}/freeform/*.hpp" "${project_include}/freeform/*.cuh")
  list(SORT headers)
  set(hd_headers "")
  foreach(header IN LISTS headers)
    file(STRINGS "${header}" uses_hd REGEX "FREEFORM_HD|__device__|__global__" LIMIT_COUNT 1)
    if(uses_hd OR header MATCHES "\\.cuh$")
      list(APPEND hd_headers --pre-include "${header}")
    endif()
  endforeach()
  run_step("nvcc on ${SOURCE}"
    "${NVCC}" ${nvcc_flags} ${hd_headers} -x cu -c "${SOURCE}" -o "${OUTPUT}")
  # The halves of the GPU-against-CPU test, and of the GPU tracing benchmark
  # (benchmarks/gpu/run.sh), which must keep compiling where no device is lent to run it.
  foreach(source IN ITEMS "${GPU_SOURCE}" "${BENCH_SOURCE}")
    if(source)
      get_filename_component(name "${source}" NAME_WE)
      run_step("nvcc on ${source}" "${NVCC}" ${nvcc_flags} -x cu -c "${source}" -o "${work_dir}/${name}.o")
    endif()
  endforeach()
  foreach(source IN ITEMS "${GPU_HOST_SOURCE}" "${BENCH_HOST_SOURCE}")
    if(source)
      get_filename_component(name "${source}" NAME_WE)
      run_step("${HOST_COMPILER} on ${source}" "${HOST_COMPILER}" ${host_flags} -c "${source}" -o "${work_dir}/${name}.o")
    endif()
  endforeach()
  message(STATUS "freeform-cuda-check: passed (nvcc ${version}, host compiler ${HOST_COMPILER})")
  return()
endif()

# MODE run: build for the GPU at hand unless the flags name an architecture.
if(NOT EXTRA_FLAGS MATCHES "(-arch|--gpu-architecture|-gencode|--generate-code)")
  list(APPEND nvcc_flags -arch=native)
endif()
set(program "${work_dir}/gpu_vs_cpu")
run_step("nvcc on ${GPU_SOURCE}"
  "${NVCC}" ${nvcc_flags} -x cu -c "${GPU_SOURCE}" -o "${work_dir}/gpu_vs_cpu.o")
run_step("${HOST_COMPILER} on ${GPU_HOST_SOURCE}"
  "${HOST_COMPILER}" ${host_flags} -c "${GPU_HOST_SOURCE}" -o "${work_dir}/gpu_vs_cpu_host.o")
run_step("linking ${program}"
  "${NVCC}" -ccbin "${HOST_COMPILER}" "${work_dir}/gpu_vs_cpu.o" "${work_dir}/gpu_vs_cpu_host.o" -o "${program}")
execute_process(COMMAND "${program}" RESULT_VARIABLE rc)
if(rc EQUAL 77)
  message("freeform-cuda-check: skipped (the test program found no usable CUDA device)")
elseif(NOT rc EQUAL 0)
  message(FATAL_ERROR "freeform-cuda-check: ${program} failed (${rc})")
else()
  message(STATUS "freeform-cuda-check: passed (GPU == CPU bit for bit; nvcc ${version})")
endif()
