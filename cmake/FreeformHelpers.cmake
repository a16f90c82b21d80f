# Helpers that give every test, example and benchmark of the project the same setup:
# the library (and freeform::embree / freeform::step when they exist), warnings (errors
# with FREEFORM_WERROR) and a common output place. Only the project's own targets use
# them; nothing here is installed.
include_guard(GLOBAL)

# Settings shared by all of the project's executables.
function(_freeform_setup_executable target)
  target_link_libraries(${target} PRIVATE freeform::freeform $<BUILD_INTERFACE:freeform_warnings>)
  if(TARGET freeform::embree)
    target_link_libraries(${target} PRIVATE freeform::embree)
  endif()
  if(TARGET freeform::step)
    target_link_libraries(${target} PRIVATE freeform::step)
  endif()
endfunction()

# freeform_add_test(<topic> SOURCES <files>... [LIBRARIES <targets>...])
#
# Builds test_<topic> with the shared doctest main and registers it with ctest as
# <topic>. The test runs in a working directory of its own under the build tree, so
# tests that write files cannot collide when ctest runs them in parallel; input data is
# found through FREEFORM_TEST_DATA_DIR (tests/data) and FREEFORM_SOURCE_DIR.
function(freeform_add_test topic)
  cmake_parse_arguments(PARSE_ARGV 1 arg "" "" "SOURCES;LIBRARIES")
  if(NOT arg_SOURCES)
    message(FATAL_ERROR "freeform_add_test(${topic}): no SOURCES given")
  endif()
  set(target test_${topic})
  add_executable(${target} ${arg_SOURCES})
  _freeform_setup_executable(${target})
  target_link_libraries(${target} PRIVATE freeform_doctest_main doctest::doctest ${arg_LIBRARIES})
  target_compile_definitions(${target} PRIVATE
    FREEFORM_TEST_DATA_DIR="${PROJECT_SOURCE_DIR}/tests/data"
    FREEFORM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  set_target_properties(${target} PROPERTIES FOLDER tests)

  set(workdir "${PROJECT_BINARY_DIR}/tests/work/${topic}")
  file(MAKE_DIRECTORY "${workdir}")
  add_test(NAME ${topic} COMMAND ${target} WORKING_DIRECTORY "${workdir}")
  set_tests_properties(${topic} PROPERTIES TIMEOUT 600 LABELS unit)
endfunction()

# freeform_add_example(<name> SOURCES <files>... [LIBRARIES <targets>...] [OUTPUT_NAME <file name>])
#
# Builds an example program into ${PROJECT_BINARY_DIR}/bin.
function(freeform_add_example name)
  cmake_parse_arguments(PARSE_ARGV 1 arg "" "OUTPUT_NAME" "SOURCES;LIBRARIES")
  if(NOT arg_SOURCES)
    message(FATAL_ERROR "freeform_add_example(${name}): no SOURCES given")
  endif()
  add_executable(${name} ${arg_SOURCES})
  _freeform_setup_executable(${name})
  target_link_libraries(${name} PRIVATE ${arg_LIBRARIES})
  _freeform_put_in_bin(${name} examples)
  if(arg_OUTPUT_NAME)
    set_target_properties(${name} PROPERTIES OUTPUT_NAME ${arg_OUTPUT_NAME})
  endif()
endfunction()

# freeform_add_benchmark(<name> SOURCES <files>... [LIBRARIES <targets>...] [STUDY])
#
# Without STUDY: a Google Benchmark micro-benchmark bench_<name> (with the library's
# main). With STUDY: a plain program study_<name> (speed/accuracy studies), which gets
# FREEFORM_HAVE_PAGMO / FREEFORM_HAVE_NLOPT when those optimisers were found. Both go to
# ${PROJECT_BINARY_DIR}/bin.
function(freeform_add_benchmark name)
  cmake_parse_arguments(PARSE_ARGV 1 arg "STUDY" "" "SOURCES;LIBRARIES")
  if(NOT arg_SOURCES)
    message(FATAL_ERROR "freeform_add_benchmark(${name}): no SOURCES given")
  endif()
  if(arg_STUDY)
    set(target study_${name})
  else()
    set(target bench_${name})
  endif()
  add_executable(${target} ${arg_SOURCES})
  _freeform_setup_executable(${target})
  target_link_libraries(${target} PRIVATE ${arg_LIBRARIES})
  if(arg_STUDY)
    if(TARGET Pagmo::pagmo)
      target_link_libraries(${target} PRIVATE Pagmo::pagmo)
      target_compile_definitions(${target} PRIVATE FREEFORM_HAVE_PAGMO=1)
    endif()
    if(FREEFORM_NLOPT_TARGET)
      target_link_libraries(${target} PRIVATE ${FREEFORM_NLOPT_TARGET})
      target_compile_definitions(${target} PRIVATE FREEFORM_HAVE_NLOPT=1)
    endif()
  else()
    # benchmark_main only supplies main() when the file has no BENCHMARK_MAIN() of its own.
    target_link_libraries(${target} PRIVATE benchmark::benchmark benchmark::benchmark_main)
  endif()
  _freeform_put_in_bin(${target} benchmarks)
endfunction()

function(_freeform_put_in_bin target folder)
  # $<1:...> keeps multi-config generators from adding a per-configuration subfolder,
  # so scripts and the Makefile always find the programs in bin/.
  set_target_properties(${target} PROPERTIES
    RUNTIME_OUTPUT_DIRECTORY "$<1:${PROJECT_BINARY_DIR}/bin>"
    FOLDER ${folder})
endfunction()
