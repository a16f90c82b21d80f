#pragma once
// Umbrella header of the scene module: lights, the surface and receiver specs, the rays
// a light makes (docs/scene.md). The scene's JSON form is read and written at the file
// boundary, io/scene_json.hpp (in freeform/io.hpp).
#include "scene/light.hpp"
#include "scene/rays.hpp"
#include "scene/receiver.hpp"
#include "scene/scene.hpp"
