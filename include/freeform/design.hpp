#pragma once
// Umbrella header of the design module: a whole design in one call (pipeline.hpp), a
// render in one call (render.hpp), and their parts — the problem the annealer solves,
// the designer's levels and stages, the start, held-out checks, the export, its cell
// means and the machinist's report.
#include "design/cell_means.hpp"
#include "design/designer.hpp"
#include "design/fabrication.hpp"
#include "design/held_out.hpp"
#include "design/initial.hpp"
#include "design/machining.hpp"
#include "design/options.hpp"
#include "design/pipeline.hpp"
#include "design/problem.hpp"
#include "design/render.hpp"
#include "design/replicas.hpp"
#include "design/resources.hpp"
#include "design/start.hpp"
#if defined(FREEFORM_WITH_EMBREE)
#include "design/embree_incremental.hpp"
#include "design/exported.hpp"
#endif
