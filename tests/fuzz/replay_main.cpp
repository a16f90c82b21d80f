// Runs saved inputs through a fuzz harness without libFuzzer, so that the corpora and
// the regressions are replayed by ctest in every build, with any compiler:
//   fuzz_replay_<reader> PATH...
// Each PATH is a file or a directory whose files (not subdirectories; names starting
// with '.' skipped, e.g. .gitkeep) are run in name order. Exit status 0 when every input
// ran; a finding aborts the program as it would abort libFuzzer, after the line that
// names the input. A missing PATH, or no input at all, is an error (status 1).
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <system_error>
#include <vector>

#include "fuzz_common.hpp"

namespace {

bool read_whole(const std::filesystem::path& file, std::string& bytes) {
    std::ifstream in(file, std::ios::binary);
    if (!in) return false;
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    return !in.bad();
}

}  // namespace

int main(int argc, char** argv) {
    namespace fs = std::filesystem;
    if (argc < 2) {
        std::fprintf(stderr, "usage: %s FILE_OR_DIRECTORY...\n", argv[0]);
        return 1;
    }
    std::vector<fs::path> inputs;
    for (int k = 1; k < argc; ++k) {
        const fs::path path = argv[k];
        std::error_code ec;
        if (fs::is_directory(path, ec)) {
            std::vector<fs::path> files;
            for (const fs::directory_entry& entry : fs::directory_iterator(path, ec))
                if (entry.is_regular_file() && entry.path().filename().string().rfind('.', 0) != 0)
                    files.push_back(entry.path());
            if (ec) {
                std::fprintf(stderr, "replay: cannot list %s: %s\n", path.string().c_str(), ec.message().c_str());
                return 1;
            }
            std::sort(files.begin(), files.end());
            inputs.insert(inputs.end(), files.begin(), files.end());
        } else if (fs::is_regular_file(path, ec)) {
            inputs.push_back(path);
        } else {
            std::fprintf(stderr, "replay: %s is neither a file nor a directory\n", path.string().c_str());
            return 1;
        }
    }
    if (inputs.empty()) {
        std::fprintf(stderr, "replay: no inputs in the paths given\n");
        return 1;
    }

    std::string bytes;
    for (const fs::path& file : inputs) {
        if (!read_whole(file, bytes)) {
            std::fprintf(stderr, "replay: cannot read %s\n", file.string().c_str());
            return 1;
        }
        std::fprintf(stderr, "replay: %s (%zu bytes)\n", file.string().c_str(), bytes.size());
        std::fflush(stderr);
        // A copy of exactly the input's size, so that AddressSanitizer sees a read past its end.
        const std::vector<std::uint8_t> copy(bytes.begin(), bytes.end());
        LLVMFuzzerTestOneInput(copy.data(), copy.size());
    }
    std::fprintf(stderr, "replay: %zu input(s) ran without a finding\n", inputs.size());
    return 0;
}
