// stb_image, stb_image_write and stb_truetype, compiled in: run.sh builds the benchmark
// where Debian's libstb (which the CMake build links) is not installed.
#define STB_IMAGE_IMPLEMENTATION
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STB_TRUETYPE_IMPLEMENTATION
#include <stb_image.h>
#include <stb_image_write.h>
#include <stb_truetype.h>
