#pragma once
// Umbrella header of the surface module: the height map, the overlay a move is judged on,
// refinement between levels, smoothing, the tool's cut and the export meshes.
#include "surface/export.hpp"
#include "surface/heightmap.hpp"
#include "surface/overlay.hpp"
#include "surface/phong.hpp"
#include "surface/refine.hpp"
#include "surface/smooth.hpp"
#include "surface/tool.hpp"
#include "surface/triangle_mesh.hpp"
