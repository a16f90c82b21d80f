#pragma once
// Umbrella header of the scene module: lights, the surface and receiver specs, the rays
// a light makes, and the scene's JSON form (docs/scene.md).
#include "scene/json.hpp"
#include "scene/light.hpp"
#include "scene/rays.hpp"
#include "scene/receiver.hpp"
#include "scene/scene.hpp"
