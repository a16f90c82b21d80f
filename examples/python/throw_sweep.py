#!/usr/bin/env python3
"""The letter E mirror with its screen at four throw distances (docs/python.md).

    PYTHONPATH=build/release/python /usr/bin/python3 examples/python/throw_sweep.py [SCENE] [SECONDS]
"""
import sys

import freeform

scene = freeform.Scene.load(sys.argv[1] if len(sys.argv) > 1 else "examples/scenes/letter-e.json").to_json()
seconds = float(sys.argv[2]) if len(sys.argv) > 2 else 10
for throw in (0.25, 0.5, 1.0, 2.0):
    scene["receiver"]["center"][2] = throw  # the screen faces the mirror from `throw` metres above it
    d = freeform.design(freeform.Scene.from_json(scene), time_budget=seconds, seed=1)
    m = d.metrics
    print(f"throw {throw:4.2f} m: error_physical {m['error_physical']:.4f}, energy {m['energy']:.3f}, "
          f"sag {m['fabrication']['sag']['range'] * 1e3:.2f} mm, steepest {m['fabrication']['max_slope_degrees']:.1f} deg")
