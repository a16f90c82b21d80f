#pragma once
// Umbrella header of the io module: every file format freeform reads or writes.
// Consumers link libstb (pkg-config `stb`), which provides the stb implementations.
#include "io/file.hpp"
#include "io/font.hpp"
#include "io/image.hpp"
#include "io/mesh.hpp"
#include "io/pfm.hpp"
