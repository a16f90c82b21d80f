# ctest driver for the `consumer` test (cmake -P, so it works with any generator):
#   1. installs the freeform build tree into a fresh prefix,
#   2. configures tests/consumer against that prefix only,
#   3. builds it and runs the program.
#
# Inputs (-D): FREEFORM_BUILD_DIR, FREEFORM_CONSUMER_SOURCE_DIR, FREEFORM_CONSUMER_WORK_DIR,
# FREEFORM_CONFIG, FREEFORM_GENERATOR, FREEFORM_MAKE_PROGRAM, FREEFORM_CXX_COMPILER,
# FREEFORM_EXPECT_EMBREE, FREEFORM_WERROR (the consumer's warnings are errors, as the build's),
# FREEFORM_EXPECT_MPI and FREEFORM_MPIEXEC (freeform was built with MPI: the package must
# give freeform::mpi, and a program using it runs under `mpiexec -np 2`).
cmake_minimum_required(VERSION 3.25)

foreach(var IN ITEMS FREEFORM_BUILD_DIR FREEFORM_CONSUMER_SOURCE_DIR FREEFORM_CONSUMER_WORK_DIR FREEFORM_GENERATOR)
  if(NOT DEFINED ${var} OR "${${var}}" STREQUAL "")
    message(FATAL_ERROR "consumer test: ${var} is not set")
  endif()
endforeach()

set(prefix "${FREEFORM_CONSUMER_WORK_DIR}/prefix")
set(build "${FREEFORM_CONSUMER_WORK_DIR}/build")
file(REMOVE_RECURSE "${FREEFORM_CONSUMER_WORK_DIR}")
file(MAKE_DIRECTORY "${FREEFORM_CONSUMER_WORK_DIR}")

function(run_step what)
  message(STATUS "consumer test: ${what}: ${ARGN}")
  execute_process(COMMAND ${ARGN} RESULT_VARIABLE rc)
  if(NOT rc EQUAL 0)
    message(FATAL_ERROR "consumer test: ${what} failed (${rc})")
  endif()
endfunction()

set(config_args "")
if(FREEFORM_CONFIG)
  set(config_args --config "${FREEFORM_CONFIG}")
endif()
run_step("install" "${CMAKE_COMMAND}" --install "${FREEFORM_BUILD_DIR}" --prefix "${prefix}" ${config_args})

foreach(f IN ITEMS include/freeform/trace/heightfield.hpp share/cmake/freeform/freeformConfig.cmake
               share/cmake/freeform/freeformConfigVersion.cmake share/cmake/freeform/freeformTargets.cmake)
  if(NOT EXISTS "${prefix}/${f}")
    message(FATAL_ERROR "consumer test: the install is missing ${f}")
  endif()
endforeach()
if(FREEFORM_EXPECT_MPI AND NOT EXISTS "${prefix}/share/cmake/freeform/freeformMpiTargets.cmake")
  message(FATAL_ERROR "consumer test: freeform was built with MPI but the install has no freeformMpiTargets.cmake")
endif()

set(configure_args
  -S "${FREEFORM_CONSUMER_SOURCE_DIR}" -B "${build}"
  -G "${FREEFORM_GENERATOR}"
  -DCMAKE_BUILD_TYPE=Release
  "-DCMAKE_PREFIX_PATH=${prefix}"
  "-DFREEFORM_EXPECTED_PREFIX=${prefix}"
  "-DFREEFORM_EXPECT_EMBREE=${FREEFORM_EXPECT_EMBREE}"
  "-DFREEFORM_EXPECT_MPI=${FREEFORM_EXPECT_MPI}"
  "-DFREEFORM_CONSUMER_WERROR=${FREEFORM_WERROR}"
  # Only the fresh prefix may provide freeform: no package registries.
  -DCMAKE_FIND_USE_PACKAGE_REGISTRY=OFF
  -DCMAKE_FIND_USE_SYSTEM_PACKAGE_REGISTRY=OFF)
if(FREEFORM_MAKE_PROGRAM)
  list(APPEND configure_args "-DCMAKE_MAKE_PROGRAM=${FREEFORM_MAKE_PROGRAM}")
endif()
if(FREEFORM_CXX_COMPILER)
  list(APPEND configure_args "-DCMAKE_CXX_COMPILER=${FREEFORM_CXX_COMPILER}")
endif()
run_step("configure" "${CMAKE_COMMAND}" ${configure_args})
run_step("build" "${CMAKE_COMMAND}" --build "${build}" --config Release)
run_step("run" "${build}/bin/freeform_consumer")

# README's library program: the README shows examples/design_letter_e.cpp verbatim, and the
# installed package builds and runs it (on a small scene: the letter E takes a minute).
get_filename_component(root "${FREEFORM_CONSUMER_SOURCE_DIR}/../.." ABSOLUTE)
file(READ "${root}/examples/design_letter_e.cpp" program)
file(READ "${root}/README.md" readme)
string(FIND "${readme}" "${program}" at)
if(at EQUAL -1)
  message(FATAL_ERROR "consumer test: README.md does not show examples/design_letter_e.cpp as it is")
endif()
set(stl "${FREEFORM_CONSUMER_WORK_DIR}/tiny.stl")
message(STATUS "consumer test: design: ${build}/bin/freeform_design_letter_e")
execute_process(COMMAND "${build}/bin/freeform_design_letter_e" "${root}/tests/data/cli/design-tiny.json" "${stl}"
                RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
if(NOT rc EQUAL 0)
  message(FATAL_ERROR "consumer test: the README program failed (${rc}): ${out}${err}")
endif()
if(FREEFORM_EXPECT_EMBREE)
  set(expected "^error_physical 0\\.[0-9]+, [1-9][0-9]* triangles")
else()
  set(expected "^error_physical -1\\.0000, [1-9][0-9]* triangles")  # no Embree: not traced
endif()
if(NOT out MATCHES "${expected}")
  message(FATAL_ERROR "consumer test: the README program printed '${out}', expected ${expected}")
endif()
file(SIZE "${stl}" stl_bytes)
if(stl_bytes LESS 1000)
  message(FATAL_ERROR "consumer test: ${stl} has ${stl_bytes} bytes")
endif()
message(STATUS "consumer test: the README program designed the tiny scene: ${out}")
if(FREEFORM_EXPECT_MPI)
  # As root (CI containers), more ranks than cores, no cross-memory attach (containers).
  set(ENV{OMPI_MCA_btl_vader_single_copy_mechanism} none)
  run_step("run under MPI" "${FREEFORM_MPIEXEC}" --allow-run-as-root --oversubscribe -np 2
           "${build}/bin/freeform_consumer_mpi")
endif()
message(STATUS "consumer test: passed")
