// Fuzz target: scene files (io::parse_scene, the JSON reader and its validation).
//
// On a scene that parses, more must hold:
//   - scene_to_json(scene), dumped as text, parses again, and the second scene writes the
//     same JSON (the round trip that makes an effective scene reproducible);
//   - plan_resources for a design and check_resources for a render finish, either with a
//     plan or with an InputError.
#include <cstddef>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <optional>
#include <string>

#include <freeform/core/error.hpp>
#include <freeform/design/resources.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/scene_json.hpp>
#include <nlohmann/json.hpp>

#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    using namespace freeform;
    const Limits limits = fuzz::fuzz_limits();
    // An absolute directory that need not exist: parse_job resolves names but opens nothing.
    const std::filesystem::path base_dir = "/fuzz/scenes";

    std::optional<DesignJob> scene;
    try {
        scene.emplace(io::parse_job(fuzz::bytes_of(data, size), "fuzz.json", base_dir, limits));
    } catch (const InputError&) {
        return 0;
    }

    // The round trip: any exception here, InputError included, is a finding.
    std::string written;
    try {
        const nlohmann::json first = job_to_json(*scene);
        written = first.dump(2);
        const DesignJob again = io::parse_job(written, "roundtrip.json", base_dir, limits);
        const nlohmann::json second = job_to_json(again);
        if (second != first)
            fuzz::property_failed("fuzz_scene", "the re-read scene writes different JSON",
                                  written + "\n----- written again:\n" + second.dump(2));
    } catch (const std::exception& e) {
        fuzz::property_failed("fuzz_scene", std::string("the written scene does not read back: ") + e.what(), written);
    }

    // Planning only computes sizes; it must neither crash nor hang on any valid scene.
    try {
        (void)plan_resources(*scene, RunKind::design, 2);
    } catch (const InputError&) {
    }
    try {
        (void)check_resources(*scene, RunKind::render, 2, Limits{});
    } catch (const InputError&) {
    }
    return 0;
}
