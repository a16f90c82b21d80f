#pragma once
// Umbrella header of the transport module: the optimal-transport start (a grid transport
// map, the surface that realises it, its checks).
#include "transport/grid_ot.hpp"
#include "transport/morph.hpp"
#include "transport/start.hpp"
