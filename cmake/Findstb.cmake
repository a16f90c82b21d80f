# Findstb
# -------
# Finds the stb single-file libraries as packaged by Debian/Ubuntu (libstb-dev): headers
# in <prefix>/include/stb and the implementations compiled into libstb. Code includes
# <stb_image.h>, <stb_image_write.h> and <stb_truetype.h> and never defines the
# *_IMPLEMENTATION macros itself, so the library must be linked.
#
# Result: the imported target stb::stb, and stb_FOUND, stb_INCLUDE_DIR, stb_LIBRARY.
# This module is installed next to freeformConfig.cmake so that consumers recreate the
# same target on their machine instead of inheriting this machine's absolute paths.

find_path(stb_INCLUDE_DIR
  NAMES stb_image.h
  PATH_SUFFIXES stb
  DOC "Directory holding stb_image.h")
find_library(stb_LIBRARY
  NAMES stb
  DOC "The compiled stb implementations (libstb)")
mark_as_advanced(stb_INCLUDE_DIR stb_LIBRARY)

# The three headers the io module needs must all be there, not just stb_image.h.
set(_stb_missing_headers "")
if(stb_INCLUDE_DIR)
  foreach(_stb_header IN ITEMS stb_image.h stb_image_write.h stb_truetype.h)
    if(NOT EXISTS "${stb_INCLUDE_DIR}/${_stb_header}")
      list(APPEND _stb_missing_headers "${_stb_header}")
    endif()
  endforeach()
endif()
if(_stb_missing_headers)
  set(stb_INCLUDE_DIR "stb_INCLUDE_DIR-NOTFOUND"
      CACHE PATH "Directory holding stb_image.h" FORCE)
  if(NOT stb_FIND_QUIETLY)
    message(STATUS "stb: ${_stb_missing_headers} missing next to stb_image.h")
  endif()
endif()
unset(_stb_missing_headers)

include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(stb
  REQUIRED_VARS stb_LIBRARY stb_INCLUDE_DIR)

if(stb_FOUND AND NOT TARGET stb::stb)
  add_library(stb::stb UNKNOWN IMPORTED)
  set_target_properties(stb::stb PROPERTIES
    IMPORTED_LOCATION "${stb_LIBRARY}"
    INTERFACE_INCLUDE_DIRECTORIES "${stb_INCLUDE_DIR}")
endif()
