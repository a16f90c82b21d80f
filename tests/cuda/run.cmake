# ctest driver for the `cuda_compile` test (cmake -P): compiles kernels_check.cu with nvcc.
# Prints "freeform-cuda-check: skipped" (the test's SKIP_REGULAR_EXPRESSION) when there is
# no nvcc, so machines without CUDA report the test as skipped rather than failed.
#
# Inputs (-D): NVCC, HOST_COMPILER, SOURCE, OUTPUT, INCLUDE_DIRS ('|'-separated),
# EXTRA_FLAGS (a command-line string).
cmake_minimum_required(VERSION 3.25)

if(NOT NVCC OR NOT EXISTS "${NVCC}")
  message("freeform-cuda-check: skipped (no nvcc; set FREEFORM_NVCC or CUDACXX to enable)")
  return()
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

get_filename_component(output_dir "${OUTPUT}" DIRECTORY)
file(MAKE_DIRECTORY "${output_dir}")

# Host/device call mistakes are errors: a host function called from FREEFORM_HD code
# (cross-execution-space-call, 20011/20014) or a constexpr host function such as
# std::min called from it (20013). Eigen itself triggers 20012 (annotations on
# defaulted members) and 20015 (constexpr host calls inside its own templates); those
# come from Eigen's host-side code and are silenced.
set(command
  "${NVCC}" -std=c++20 --extended-lambda -x cu -c "${SOURCE}" -o "${OUTPUT}"
  -ccbin "${HOST_COMPILER}"
  ${include_flags}
  ${hd_headers}
  --Werror cross-execution-space-call
  -diag-error 20013
  -diag-suppress 20012,20015
  -Xcompiler -Wall,-Wextra,-Werror
  ${extra})
list(JOIN command " " shown)
message(STATUS "${shown}")
execute_process(COMMAND ${command} RESULT_VARIABLE rc)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "freeform-cuda-check: nvcc failed (${rc}) on ${SOURCE}")
endif()
execute_process(COMMAND "${NVCC}" --version OUTPUT_VARIABLE version)
string(REGEX MATCH "release [0-9.]+" version "${version}")
message(STATUS "freeform-cuda-check: passed (nvcc ${version}, host compiler ${HOST_COMPILER})")
