#pragma once
// Umbrella header of the core module (docs/architecture.md §3): vectors and views, fixed
// point and histograms, counter-based random numbers, execution policies and the task
// pool, the deposit rule, frames and surface materials, errors and resource limits, the
// names of enumerations.
#include "core/deposit.hpp"
#include "core/enum_names.hpp"
#include "core/error.hpp"
#include "core/exec.hpp"
#include "core/fixed_point.hpp"
#include "core/frame.hpp"
#include "core/histogram.hpp"
#include "core/limits.hpp"
#include "core/material.hpp"
#include "core/math.hpp"
#include "core/rng.hpp"
#include "core/sparse_delta.hpp"
#include "core/task_pool.hpp"
#include "core/view.hpp"
