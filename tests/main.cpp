// The one doctest main shared by every test executable (built once as an object library).
//
// FREEFORM_TEST_SUITE_EXCLUDE (a comma-separated list of doctest test suites) leaves those
// suites out, as doctest's --test-suite-exclude would: ctest's presets cannot pass
// arguments to a test, but they can set its environment. The ThreadSanitizer preset
// (CMakePresets.json) sets it to "serial": cases that run on one thread only, whose
// races ThreadSanitizer cannot see and whose time it multiplies (docs/cli.md, "The make targets").
// Arguments on the command line still apply after it.
#define DOCTEST_CONFIG_IMPLEMENT
#include <doctest/doctest.h>

#include <cstdlib>

int main(int argc, char** argv) {
    doctest::Context context;
    if (const char* suites = std::getenv("FREEFORM_TEST_SUITE_EXCLUDE"); suites != nullptr && *suites != '\0')
        context.addFilter("test-suite-exclude", suites);
    context.applyCommandLine(argc, argv);
    return context.run();
}
