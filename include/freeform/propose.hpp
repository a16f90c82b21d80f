#pragma once
// Umbrella header of the propose module: the moves of the annealer (Gaussian kernels of
// a bank, the single-vertex baseline) and the bandits that choose among the kernels.
#include "propose/bandit.hpp"
#include "propose/kernel.hpp"
#include "propose/options.hpp"
#include "propose/single_vertex.hpp"
