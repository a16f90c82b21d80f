#pragma once
// Pieces shared by the fuzz harnesses in tests/fuzz: the input as a string_view, the
// limits a fuzz run uses, and the report of a broken property.
//
// Each harness defines LLVMFuzzerTestOneInput. Built with clang's -fsanitize=fuzzer it
// is a libFuzzer target (fuzz_<reader>); linked with replay_main.cpp it is a plain
// program that runs saved inputs (fuzz_replay_<reader>, part of every test build).
// A harness catches freeform::InputError only: any other exception, a crash, a
// sanitizer report or a failed property check is a finding.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include <freeform/core/limits.hpp>

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size);

namespace freeform::fuzz {

// The input bytes, without a copy (libFuzzer passes a null pointer for the empty input).
inline std::string_view bytes_of(const std::uint8_t* data, std::size_t size) {
    if (size == 0) return {};
    return {reinterpret_cast<const char*>(data), size};
}

// Limits for fuzzing. The defaults accept 8192 x 8192 images and 2^26 triangles, which
// a few header bytes can ask for and which would, correctly, be allocated; libFuzzer's
// -rss_limit_mb would then stop the run for an input that is no bug. Lower values keep
// every code path (the over-limit refusal included) and the memory small.
inline Limits fuzz_limits() {
    Limits limits;
    limits.pixels = std::uint64_t(1) << 22;
    limits.triangles = std::uint64_t(1) << 18;
    return limits;
}

// A property of a successful read does not hold: print what and why, then abort so that
// libFuzzer (or the replay) reports the input as a crash. Under `make fuzz` the target's
// stderr is closed (-close_fd_mask=3); run the saved input again to see this message.
[[noreturn]] inline void property_failed(const char* harness, const std::string& what, std::string_view detail = {}) {
    std::fprintf(stderr, "%s: property violated: %s\n", harness, what.c_str());
    if (!detail.empty()) std::fprintf(stderr, "-----\n%.*s\n-----\n", int(detail.size()), detail.data());
    std::fflush(stderr);
    std::abort();
}

}  // namespace freeform::fuzz
