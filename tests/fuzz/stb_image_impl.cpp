// stb_image's implementation, compiled into fuzz_image and fuzz_replay_image. The
// library links Debian's precompiled libstb, which has no coverage instrumentation and
// no sanitizer checks, so a fuzzer could neither steer into its decoders nor see their
// memory errors. This copy comes from the same header (libstb-dev) and is compiled with
// the flags of the build that includes it: the libFuzzer build, or the sanitize preset
// when the replay runs there. Its definitions take precedence over the shared library's
// in these two programs only.
#define STB_IMAGE_IMPLEMENTATION
#include <stb_image.h>
