#pragma once
// Umbrella header of the io module: every file freeform reads or writes — scene files,
// target images and fonts, PNG/PFM images, height maps, OBJ/STL meshes, grid sag tables, the JSON of a design's
// report — and the staged writing of a result folder.
// Consumers link libstb (pkg-config `stb`), which provides the stb implementations.
#include "io/file.hpp"
#include "io/font.hpp"
#include "io/form_check.hpp"
#include "io/heightmap.hpp"
#include "io/image.hpp"
#include "io/mesh.hpp"
#include "io/pfm.hpp"
#include "io/sag.hpp"
#include "io/report_json.hpp"
#include "io/scene_file.hpp"
#include "io/scene_json.hpp"
#include "io/staged_output.hpp"
#include "io/target.hpp"
// Not included here, because with freeform::step they bring in Open CASCADE's headers
// (seconds of compile time per file): io/step.hpp (STEP parts) and io/forms.hpp (the
// smooth forms written, read back and judged). Include them where they are used.
