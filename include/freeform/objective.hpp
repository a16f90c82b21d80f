#pragma once
// Umbrella header of the objective module: targets, the image terms, the energy
// threshold, the penalties and their weighted sum.
#include "objective/image_terms.hpp"
#include "objective/objective.hpp"
#include "objective/penalty.hpp"
#include "objective/target.hpp"
#include "objective/trace_setup.hpp"
