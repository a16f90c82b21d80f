#pragma once
// Exceptions thrown at API boundaries (scene loading, file I/O, parameter checks).
// Their messages always name the offending key, value or file so that a user can fix
// the input without reading the source.
#include <stdexcept>
#include <string>

namespace freeform {

// Bad user input: a scene key, a parameter, or a file that cannot be read or parsed.
// The CLI maps it to exit code 2.
class InputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

// A file could not be read or written (missing, unreadable, corrupt, disk full).
class IoError : public InputError {
public:
    using InputError::InputError;
};

}  // namespace freeform
