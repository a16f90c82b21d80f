// Fuzz target: the argument layer of the `freeform` command line (CLI11 parsing, then
// the checks of option values that read no file: --limit, --material, --tracer,
// --time-budget). The input is split at NUL bytes into arguments after argv[0]; no
// command is ever run.
//
// apps/freeform/main.cpp is included whole, with its main() left out; its functions
// are in an anonymous namespace, so this translation unit can call them directly.
#define FREEFORM_CLI_NO_MAIN
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "../../apps/freeform/main.cpp"
#include "fuzz_common.hpp"

namespace {

// More arguments do not reach new code; the cap keeps inputs of many NULs cheap.
constexpr std::size_t max_arguments = 64;

// cli_main would run the command. It is only referenced here, so that the compiler does
// not report it as an unused function of the included file.
[[maybe_unused]] int (*const never_called)(int, char**) = &cli_main;

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
    const std::string_view input = freeform::fuzz::bytes_of(data, size);
    std::vector<std::string> arguments{"freeform"};
    std::size_t start = 0;
    while (arguments.size() < max_arguments && start <= input.size()) {
        const std::size_t nul = input.find('\0', start);
        const std::size_t end = nul == std::string_view::npos ? input.size() : nul;
        arguments.emplace_back(input.substr(start, end - start));
        if (nul == std::string_view::npos) break;
        start = nul + 1;
    }
    if (input.empty()) arguments.pop_back();  // no input: "freeform" alone
    std::vector<const char*> argv;
    for (const std::string& a : arguments) argv.push_back(a.c_str());
    argv.push_back(nullptr);

    CommandLine cl;
    if (parse_command_line(int(arguments.size()), argv.data(), cl)) return 0;  // help, version or usage error
    try {
        check_arguments(cl);
    } catch (const freeform::InputError&) {
    }
    return 0;
}
