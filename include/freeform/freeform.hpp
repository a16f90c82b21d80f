#pragma once
// freeform in one include: design a surface from a scene in one call and write what it
// made (docs/architecture.md; README "Using the library").
//
//     const freeform::Scene scene = freeform::io::load_scene("letter-e.json");
//     const freeform::CompletedDesign d = freeform::design(scene, freeform::io::load_target_image(scene));
//     freeform::io::write_stl("letter-e.stl", d.exported.fabrication.mesh);
//
// Link freeform::freeform, or freeform::embree for the Embree tracer (the exported mesh's
// checks and error_physical need it). The modules' own umbrellas (core.hpp, scene.hpp,
// surface.hpp, trace.hpp, objective.hpp, propose.hpp, anneal.hpp, transport.hpp,
// design.hpp, io.hpp) give the parts.
#include "design.hpp"
#include "io.hpp"
