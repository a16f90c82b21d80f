#pragma once
// Umbrella header of the Embree module: the Embree 3 tracer (extra meshes, imported
// surface meshes, refit after height changes). Link freeform::embree (Embree 3).
#include "trace/embree.hpp"
#include "trace/setup.hpp"
