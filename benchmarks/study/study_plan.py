"""What the study runs: cases, methods and the experiment plans (quick and full).

A run is (case, method, seed, time budget). Cases are public scenes, some with a JSON merge
patch that turns them into a stress case; methods are an engine of study_run with a patch
of the scene's "optimise"/"surface"/"light" keys and a few driver options. Every variant
of ours is the library's freeform::design() with such a patch (engine "design"). Everything
the report says about a method's settings comes from here and from the result files.

The start. Since commit 66d6687 a design starts from the transport surface (surface.initial
"transport", the default for a scene with a target): "ours" is that default, transport start
+ annealing, and "transport-only" is the start alone (study_run --start-only). Every other
variant of ours (the ablation ladder, the bandits, the stress, model and evaluation
variants) was measured with the flat start that was the default before, and keeps it
explicitly: its patch includes {"surface": {"initial": "flat"}} (FLAT_START), so running it
again reproduces what is committed; "ours-flat-start" is the former "ours". The baselines
(SPSA, pagmo2, NLopt) never went through design()'s start: they start from the scene's
initial heights, which are flat for every case (control_grid.hpp), and are unchanged.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Case:
    name: str
    scene: str                      # relative to the repository root
    budget: float                   # seconds per run, full mode
    quick_budget: float = 0.0       # seconds per run, quick mode (0: not in quick mode)
    case_patch: dict = field(default_factory=dict)
    stress: str = ""                # why this is a stress case ("" for the public cases)
    title: str = ""
    reference: dict = field(default_factory=dict)  # the reference's figures for this case


@dataclass(frozen=True)
class Method:
    name: str
    engine: str
    title: str
    patch: dict = field(default_factory=dict)
    options: tuple = ()             # extra study_run arguments
    family: str = "ours"            # ours | ablation | baseline | stress | model | evaluation
    judged_with_check: bool = False  # also judged on 4x rays (--check-render)
    # Methods stopped by an iteration cap (optimise.max_iterations) rather than by time: their
    # time budget is only a safety cap, far above what they need, so that no stage is cut
    # short; `expected` (case -> seconds, measured on the 2-core development machine) is what
    # the plan's estimate counts for them.
    time_cap: float = 0.0
    expected: dict = field(default_factory=dict)
    # Per-case iteration cap (case -> optimise.max_iterations), merged into the patch of
    # each run (run_study.run_command): for iteration budgets that differ between cases.
    iterations: dict = field(default_factory=dict)

    def patch_for(self, case: str) -> dict:
        if case in self.iterations:
            return merged(self.patch, {"optimise": {"max_iterations": self.iterations[case]}})
        return self.patch


# --- cases -------------------------------------------------------------------------------

# The lens example before commit 33929ba: a 1 cm thick lens with +-5 mm height bounds. Its
# transport surface needs about 20 mm of sag range, so the example now allows +-12 mm (and
# is 1.5 cm thick); the runs of the earlier study were made on this one and are kept as the
# case "lens-5mm".
LENS_5MM_PATCH = {"surface": {"material": {"refractive": 1.49, "thickness": 0.01}, "height_bounds": [-0.005, 0.005]}}

# Grazing light on the E case: collimated light at 70 degrees from the mirror's normal,
# the receiver moved onto the specular direction (0.5 m away, facing the mirror). Rays
# cross ~27 surface cells inside the height slab, and the reflected beam is 3x narrower.
_SIN70, _COS70 = 0.9396926, 0.3420201
GRAZING_PATCH = {
    "light": {"type": "collimated", "direction": [0, -_SIN70, -_COS70], "rays_per_cell": 16},
    "receiver": {"center": [0, -0.5 * _SIN70, 0.5 * _COS70], "normal": [0, _SIN70, -_COS70], "up": [0, 0, 1]},
}

# A point light close to the mirror: a flat mirror spreads its light over ~4x the
# receiver, so the start has about a quarter of the energy on the receiver.
POINT_LOW_PATCH = {"light": {"type": "point", "position": [0, 0, 0.12], "rays_per_cell": 16}}

CASES = {c.name: c for c in [
    Case("E", "examples/scenes/letter-e.json", 12, 6, title="letter E (collimated, mirror, 101² mesh, 200² px)",
         reference={"error": 0.083, "energy": 0.976, "iterations": 5.3e5, "seconds": 337}),
    Case("V", "examples/scenes/letter-v.json", 12, title="letter V (collimated, mirror, 101², 200²)",
         reference={"error": 0.087, "energy": 0.988, "iterations": 3.7e5, "seconds": 239}),
    Case("at", "examples/scenes/letter-at.json", 12, title="symbol @ (collimated, mirror, 101², 200²)",
         reference={"error": 0.086, "energy": 0.965, "iterations": 9.2e5, "seconds": 548}),
    Case("headlight", "examples/scenes/headlight.json", 5, 3,
         title="headlight low beam (collimated, mirror, mesh auto: 53², 27² before issue 11; 50² px)",
         reference={"error": 0.096, "energy": 1.0, "iterations": 1.3e5, "seconds": 75,
                    "runs": [0.096, 0.092, 0.103, 0.089]}),
    Case("point", "examples/scenes/point-light.json", 12,
         title="letter F, point light 0.3 m from an elliptical 12 x 8 cm mirror (121 x 81 mesh, 240 x 160 px)",
         reference={"energy_threshold": 0.95}),
    Case("lens", "examples/scenes/lens.json", 12,
         title="letter L through a PMMA lens (IOR 1.49, 1.5 cm thick, ±12 mm height bounds, 101², 200²)"),
    Case("lens-5mm", "examples/scenes/lens.json", 12, case_patch=LENS_5MM_PATCH,
         title="the lens example as it was before 33929ba (1 cm thick, ±5 mm height bounds)",
         stress="the lens with ±5 mm height bounds: the transport surface needs about 20 mm of sag range "
                "(the runs of earlier passes on 'lens' were made on this scene)"),
    Case("camera", "examples/scenes/camera.json", 40,
         title="grey photograph 'camera' (collimated, mirror, 401² mesh, 200² px)",
         stress="photographic target: every pixel matters, 401² mesh",
         reference={"error": 0.104, "energy": 0.948, "iterations": 5.6e6, "seconds": 4980,
                    "note": "the reference's photo case is Lenna, not this image"}),
    Case("point-low", "examples/scenes/point-light.json", 12, case_patch=POINT_LOW_PATCH,
         title="point light 0.12 m from the mirror: low initial energy",
         stress="point light with low initial energy (~0.25 of the light on the receiver at the start)"),
    Case("grazing", "examples/scenes/letter-e.json", 12, case_patch=GRAZING_PATCH,
         title="letter E under grazing light (70° from the normal)",
         stress="grazing light: long paths through the height slab, foreshortened beam"),
]}

# Targets the earlier passes never used (issue 11, part 4: the "auto" mesh rule checked off
# the example targets), each on the setup of an example scene (light, surface, receiver,
# budget), only the target replaced. The images are drawn by benchmarks/study/make_targets.py;
# paths in a patch resolve against the scene file's directory (examples/scenes/).
_STUDY_TARGETS = "../../benchmarks/study/targets/"


def _image_target(name: str) -> dict:
    return {"target": {"text": None, "font": None, "margin": None, "image": _STUDY_TARGETS + name}}


NEW_TARGET_CASES = ["R", "amp", "ring", "checker", "gradient"]
CASES.update({c.name: c for c in [
    Case("R", "examples/scenes/letter-e.json", 12, case_patch={"target": {"text": "R"}},
         title="letter R on the letter-E setup (collimated, mirror, 200² px)"),
    Case("amp", "examples/scenes/point-light.json", 12, case_patch={"target": {"text": "&"}},
         title="symbol & on the point-light setup (point light 0.3 m, elliptical 12 x 8 cm mirror, 240 x 160 px)"),
    Case("ring", "examples/scenes/headlight.json", 5, case_patch=_image_target("ring.png"),
         title="a bright ring on the headlight setup (collimated, mirror, 50² px)"),
    Case("checker", "examples/scenes/lens.json", 12, case_patch=_image_target("checker.png"),
         title="a 4 x 4 checkerboard through the lens setup (PMMA, 1.5 cm, ±12 mm bounds, 200² px)"),
    Case("gradient", "examples/scenes/camera.json", 40, case_patch=_image_target("gradient.png"),
         title="a smooth grey landscape (photographic: 65 % grey pixels) on the camera setup (200² px)"),
]})

PUBLIC_CASES = ["E", "V", "at", "headlight", "point", "lens", "camera"]
# Where the flat-start runs of the earlier passes were made: the lens case then was lens-5mm.
LEGACY_CASES = [c if c != "lens" else "lens-5mm" for c in PUBLIC_CASES]
SIMPLE_CASES = ["E", "V", "at", "headlight", "point", "lens"]  # failure rate 0 expected

# --- methods -----------------------------------------------------------------------------

# The evaluation pairs (ours-fixed / ours-full-eval-fixed): iterations over the whole design
# (the history bandit's 1000-move pre-process included) and the safety time cap (seconds).
PAIR_ITERATIONS = 2000
PAIR_CAP = 3600.0

# Issue 11, part 3: the fixed iteration count of each simple case, the median iterations of
# ours' time-budget runs in benchmarks/results/model13 (12 s, headlight 5 s, 2 threads, the
# 1000-move pre-process included) rounded to 500; the safety cap (seconds) that no run
# reaches; and the seconds a run takes on one thread of the 2-core machine (estimate only).
FIXED_ITERATIONS = {"E": 13000, "V": 12500, "at": 12500, "headlight": 13000, "point": 7000, "lens": 9000}
FIXED_CAP = 3600.0
FIXED_EXPECTED = {"E": 14.0, "V": 14.0, "at": 14.0, "headlight": 6.0, "point": 15.0, "lens": 15.0}

# Issue 11, part 4: the mesh rule's comparison, at one budget for every case.
MESH_AUTO = {"surface": {"mesh": "auto"}}
MESH_RULE_BUDGET = 20.0

_NO_PENALTIES = {"energy_threshold": 0, "sobel_weight": 0, "lost_light_weight": 0}

# The start every variant of ours had before the transport start became the default.
FLAT_START = {"surface": {"initial": "flat"}}


def merged(patch: dict, extra: dict) -> dict:
    """patch with extra merged in (nested objects merged, extra's keys appended after patch's)."""
    out = dict(patch)
    for k, v in extra.items():
        out[k] = merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def flat(patch: dict | None = None) -> dict:
    return merged(patch or {}, FLAT_START)

METHODS = {m.name: m for m in [
    Method("ours", "design", "ours, the default: transport start (optimal transport surface, surface.initial "
           "\"transport\"), then annealing (multi-level from the start's error, 7 kernel shapes + history bandit, "
           "Phong, energy/Sobel/lost-light terms, incremental evaluation)", judged_with_check=True),
    Method("ours-flat-start", "design", "ours from a flat mirror (surface.initial \"flat\"; the default before "
           "66d6687, \"ours\" of the earlier passes)", patch=flat(), judged_with_check=True),
    Method("transport-only", "design", "the transport start alone, no annealing (make_design_start with the run's "
           "seed)", options=("--start-only",), family="transport", judged_with_check=True, expected={"camera": 4.0}),
    # The ablation ladder, from the reference's chapter-3 baseline up to ours.
    Method("sa-plain", "design", "plain SA (reference ch. 3): single-vertex moves, flat triangles, no penalties, "
           "one level", patch=flat({"optimise": {"single_vertex": True, "multilevel": False, **_NO_PENALTIES},
                                     "surface": {"phong_alpha": 0}}), family="ablation"),
    Method("sa+kernels", "design", "+ Gaussian kernels (7 shapes, picked uniformly at random)",
           patch=flat({"optimise": {"multilevel": False, "bandit": "uniform", **_NO_PENALTIES},
                       "surface": {"phong_alpha": 0}}), family="ablation"),
    Method("sa+kernels+phong", "design", "+ Phong correction (α = 0.75)",
           patch=flat({"optimise": {"multilevel": False, "bandit": "uniform", **_NO_PENALTIES}}), family="ablation"),
    Method("sa+kernels+phong+terms", "design", "+ energy threshold 0.95, Sobel term 0.1, lost-light term 1",
           patch=flat({"optimise": {"multilevel": False, "bandit": "uniform"}}), family="ablation"),
    Method("ours-uniform", "design", "+ multi-level (kernel shape still uniform at random)",
           patch=flat({"optimise": {"bandit": "uniform"}})),
    Method("ours-ucb1", "design", "ours with the UCB1 bandit", patch=flat({"optimise": {"bandit": "ucb1"}})),
    Method("ours-ducb", "design", "ours with the discounted-UCB bandit",
           patch=flat({"optimise": {"bandit": "discounted-ucb"}})),
    Method("ours-one-kernel", "design", "ours with one kernel shape (isotropic σ = support/4, no pre-process)",
           patch=flat({"optimise": {"kernel_shapes": "isotropic"}})),
    # Full retraces are slow: sample the trace every 20 moves, not every 200.
    Method("ours-full-eval", "design", "ours judging every proposal by a full retrace of every ray "
           "(optimise.evaluation \"full\"), same time budget", patch=flat({"optimise": {"evaluation": "full"}}),
           options=("--progress-every", "20")),
    Method("ours-no-lost-light", "design", "ours with the reference's objective: no lost-light term "
           "(optimise.lost_light_weight 0; the energy threshold stays)",
           patch=flat({"optimise": {"lost_light_weight": 0}}), family="ablation"),
    Method("ours-error-guided", "design", "ours with error-guided kernel centres (optimise.error_guided)",
           patch=flat({"optimise": {"error_guided": True}}), family="ablation"),
    Method("ours-single-level", "design", "ours without the multi-level schedule",
           patch=flat({"optimise": {"multilevel": False}})),
    Method("ours-flat", "design", "ours with flat triangles (Phong α = 0)", patch=flat({"surface": {"phong_alpha": 0}})),
    # Stress variants of ours.
    Method("ours-tiny-kernels", "design", "ours with 3 x 3 kernels only, on every level",
           patch=flat(), options=("--kernel-supports", "3"), family="stress"),
    Method("ours-no-energy", "design", "ours without energy terms (no eq. 4.4 threshold, no lost-light term)",
           patch=flat({"optimise": {"energy_threshold": 0, "lost_light_weight": 0}}), family="stress"),
    # "No more than a scene needs": larger models than the scene chose.
    Method("ours-mesh2x", "design", "ours on a final mesh with twice the vertices per side",
           patch=flat(), options=("--mesh-scale", "2"), family="model", judged_with_check=True),
    Method("ours-rays4x", "design", "ours with 4x the rays on the final level",
           patch=flat(), options=("--rays-scale", "4"), family="model", judged_with_check=True),
    # Full against incremental evaluation at a fixed iteration count, same seed: the two must
    # end with the same heights bit for bit (the incremental objective is exact), so the
    # ratio of their speeds is the speed-up of incremental evaluation at equal work. The
    # repeat runs the incremental design again: a fixed iteration count must make a design
    # reproducible, or the comparison means nothing.
    Method("ours-fixed", "design", f"ours stopped after {PAIR_ITERATIONS} iterations, incremental evaluation",
           patch=flat({"optimise": {"max_iterations": PAIR_ITERATIONS}}), options=("--progress-every", "20"),
           family="evaluation", time_cap=PAIR_CAP, expected={"headlight": 3.5, "E": 6.5}),
    Method("ours-fixed-repeat", "design", "ours-fixed again (same seed): is the design reproducible?",
           patch=flat({"optimise": {"max_iterations": PAIR_ITERATIONS}}), options=("--progress-every", "20"),
           family="evaluation", time_cap=PAIR_CAP, expected={"headlight": 3.5, "E": 6.5}),
    Method("ours-full-eval-fixed", "design", f"ours stopped after {PAIR_ITERATIONS} iterations, every proposal "
           "judged by a full retrace", patch=flat({"optimise": {"max_iterations": PAIR_ITERATIONS, "evaluation": "full"}}),
           options=("--progress-every", "20"), family="evaluation", time_cap=PAIR_CAP,
           expected={"headlight": 8.5, "E": 115}),
    # Issue 11, part 3: ours (transport start and all) stopped at a fixed iteration count per
    # case, no time limit (the time budget is only a safety cap): no clock decides anything,
    # so the spread over seeds is the method's own, whatever the machine's load. The repeat
    # runs the first seed again: the two must end with the same heights bit for bit.
    Method("ours-iters", "design", "ours stopped at a fixed iteration count per case (FIXED_ITERATIONS: the median "
           "iterations of the time-budget runs of benchmarks/results/model13), no time limit",
           iterations=FIXED_ITERATIONS, family="stability", time_cap=FIXED_CAP, expected=FIXED_EXPECTED),
    Method("ours-iters-repeat", "design", "ours-iters again (same seed): is the design reproducible?",
           iterations=FIXED_ITERATIONS, family="stability", time_cap=FIXED_CAP, expected=FIXED_EXPECTED),
    # Issue 11, part 4: the "auto" mesh rule against a mesh twice as fine, at equal time, from
    # the transport start (ours-mesh2x above is from a flat start, earlier passes).
    # The committed runs (benchmarks/results/mesh_rule) were made at a1ad4d9, when "auto" gave a binary target
    # r/2 + 1 vertices (made odd); they led to the rule's 2m - 1 since. Run again, ours-mesh-auto is the current
    # rule and its x2 arm twice that: use --fresh or another --out (a run's command does not name the rule).
    Method("ours-mesh-auto", "design", "ours with surface.mesh \"auto\" (the rule of plan_levels; at a1ad4d9, when "
           "the committed runs were made, r/2 + 1 vertices along the longer side for a binary target, made odd, and "
           "2r + 1 for a photograph: the example scenes' explicit meshes)",
           patch=MESH_AUTO, family="mesh-rule"),
    Method("ours-mesh-auto-x2", "design", "ours on twice the auto mesh per side ((n - 1)·2 + 1 vertices)",
           patch=MESH_AUTO, options=("--mesh-scale", "2"), family="mesh-rule"),
    # Baselines on the same tracer and objective (control grid, see control_grid.hpp).
    Method("spsa", "spsa", "SPSA (Spall gains a_k = a/(k+1+A)^0.602, c_k = c/(k+1)^0.101), 13² control grid",
           family="baseline"),
    Method("spsa-fullmesh", "spsa", "SPSA on every vertex of the final mesh", options=("--control", "0"),
           family="baseline"),
    Method("spsa-few-rays", "spsa", "SPSA with 1 ray per receiver cell while optimising",
           patch={"light": {"rays_per_cell": 1}}, family="stress"),
    Method("pagmo-sa", "pagmo-sa", "pagmo2 simulated annealing (Corana), 13² control grid", family="baseline"),
    Method("pagmo-cmaes", "pagmo-cmaes", "pagmo2 CMA-ES, 13² control grid", family="baseline"),
    Method("pagmo-xnes", "pagmo-xnes", "pagmo2 xNES, 13² control grid", family="baseline"),
    Method("pagmo-sade", "pagmo-sade", "pagmo2 self-adaptive DE, 13² control grid", family="baseline"),
    Method("nlopt-bobyqa", "nlopt-bobyqa", "NLopt BOBYQA, 13² control grid", family="baseline"),
    Method("nlopt-crs2", "nlopt-crs2", "NLopt CRS2-LM, 13² control grid", family="baseline"),
]}

ABLATION_LADDER = ["sa-plain", "sa+kernels", "sa+kernels+phong", "sa+kernels+phong+terms", "ours-uniform",
                   "ours-flat-start", "ours"]
# "Our best method" on a case, for the failure threshold: the best of these.
OURS_FAMILY = ["ours", "ours-flat-start", "ours-uniform", "ours-ucb1", "ours-ducb", "ours-one-kernel",
               "ours-single-level"]
# What the variants of ours (all from a flat start) are compared with in the report.
FLAT_REFERENCE = "ours-flat-start"
# The start, with and without annealing, shown next to each other everywhere.
START_METHODS = ["ours", "ours-flat-start", "transport-only"]

# Issue 9's goals (measured at exactly its budgets, the "goals" runs): case -> (seconds,
# method, error at most, energy at least or None).
ISSUE9_GOALS = [
    ("E", 20.0, "ours", 0.06, 0.97),
    ("E", None, "transport-only", 0.15, None),
    ("headlight", 5.0, "ours", 0.04, None),
    ("camera", 60.0, "ours", 0.10, None),
    ("point", 20.0, "ours", 0.15, None),
    ("lens", 20.0, "ours", 0.15, None),
]
MAIN_BASELINES = ["sa-plain", "spsa", "pagmo-sa", "pagmo-cmaes", "nlopt-bobyqa"]


@dataclass(frozen=True)
class Run:
    case: str
    method: str
    seed: int
    budget: float
    purpose: str          # main | ablation | extra | stress | ladder | model | evaluation | quick
    save_images: bool = False

    @property
    def key(self) -> str:
        return f"{self.case}/{self.method}/b{self.budget:g}-s{self.seed}"


def _grid(cases, methods, seeds, purpose, budget_scale=1.0, quick=False, save_first=False):
    runs = []
    for c in cases:
        case = CASES[c]
        b = (case.quick_budget if quick else case.budget) * budget_scale
        for m in methods:
            cap = METHODS[m].time_cap
            for i, s in enumerate(seeds):
                runs.append(Run(c, m, s, round(cap or b, 3), purpose, save_images=save_first and i == 0))
    return runs


def expected_seconds(run: Run) -> float:
    """The optimisation time a run is expected to take (start-up and renders not included)."""
    m = METHODS[run.method]
    if m.family == "transport":  # the start alone: no budget to spend (about 1 s; the camera's 401² fit more)
        return m.expected.get(run.case, 1.0)
    return m.expected.get(run.case, run.budget) if m.time_cap else run.budget


def evaluation_pairs(cases, seeds, purpose):
    """Full against incremental evaluation at a fixed iteration count, and one repeat."""
    return (_grid(cases, ["ours-fixed", "ours-full-eval-fixed"], seeds, purpose)
            + _grid(cases, ["ours-fixed-repeat"], seeds[:1], purpose))


SEEDS = list(range(101, 111))   # never the cases' own seed (1), which judges every run


def full_plan() -> list[Run]:
    runs = []
    # The default (transport start + annealing) and the start alone on every case.
    runs += _grid(PUBLIC_CASES, ["ours", "transport-only"], SEEDS, "main", save_first=True)
    # Flat starts: ours as it was, and the baselines. On the lens, the earlier passes ran on
    # lens-5mm (the example's former bounds): there they are complete, and ours and the
    # transport start are added; on the current lens they are planned again.
    runs += _grid(PUBLIC_CASES, ["ours-flat-start"] + MAIN_BASELINES, SEEDS, "main", save_first=True)
    runs += _grid(["lens-5mm"], ["ours-flat-start"] + MAIN_BASELINES + ["ours", "transport-only"], SEEDS, "main",
                  save_first=True)
    runs += _grid(["E", "headlight"], ["sa+kernels", "sa+kernels+phong", "sa+kernels+phong+terms", "ours-uniform",
                                       "ours-ucb1", "ours-ducb", "ours-one-kernel", "ours-full-eval",
                                       "ours-single-level", "ours-flat", "ours-no-lost-light", "ours-error-guided"], SEEDS,
                  "ablation")
    runs += evaluation_pairs(["headlight", "E"], SEEDS[:3], "evaluation")
    runs += _grid(["headlight"], ["pagmo-xnes", "pagmo-sade", "nlopt-crs2"], SEEDS, "extra")
    runs += _grid(["E"], ["spsa-fullmesh"], SEEDS, "extra")
    runs += _grid(["point-low"], ["ours-flat-start", "ours", "transport-only", "ours-no-energy", "ours-no-lost-light", "sa-plain", "spsa", "pagmo-cmaes", "nlopt-bobyqa"], SEEDS,
                  "stress")
    runs += _grid(["grazing"], ["ours-flat-start", "ours", "transport-only", "sa-plain", "spsa", "pagmo-cmaes", "nlopt-bobyqa"], SEEDS, "stress")
    runs += _grid(["E", "headlight", "point"], ["ours-tiny-kernels"], SEEDS, "stress")
    runs += _grid(["E", "point"], ["ours-no-energy"], SEEDS, "stress")
    runs += _grid(["point"], ["ours-no-lost-light"], SEEDS, "stress")
    runs += _grid(["E", "headlight"], ["spsa-few-rays"], SEEDS, "stress")
    # Our error against time budget (flat start, earlier passes): final errors at B/4, B/2
    # (B: 10 seeds above) and 4 B.
    for scale in (0.25, 0.5, 4.0):
        runs += _grid(LEGACY_CASES, ["ours-flat-start"], SEEDS[:3], "ladder", budget_scale=scale)
    runs += _grid([c for c in LEGACY_CASES if c != "camera"], ["ours-mesh2x"], SEEDS[:5], "model")
    runs += _grid(LEGACY_CASES, ["ours-rays4x"], SEEDS[:5], "model")
    runs += goal_runs(SEEDS)
    return _unique(runs)


# Plans that are not part of the full study (make bench): run only when --purposes names them.
SEPARATE_PURPOSES = ("stability-fixed", "mesh-rule")


def separate_plan(purposes) -> list[Run]:
    runs = []
    if "stability-fixed" in purposes:
        runs += _grid(SIMPLE_CASES, ["ours-iters"], SEEDS, "stability-fixed")
        runs += _grid(SIMPLE_CASES, ["ours-iters-repeat"], SEEDS[:1], "stability-fixed")
    if "mesh-rule" in purposes:
        # Interleaved by seed (auto, x2, auto, x2, ...), so that a change in the machine's
        # load meets both arms alike.
        for c in SIMPLE_CASES + NEW_TARGET_CASES:
            for s in SEEDS:
                for m in ("ours-mesh-auto", "ours-mesh-auto-x2"):
                    runs.append(Run(c, m, s, MESH_RULE_BUDGET, "mesh-rule"))
    return _unique(runs)


def goal_runs(seeds) -> list[Run]:
    """Issue 9's goals at exactly its budgets (ours; the transport start has no budget)."""
    runs = []
    for case, budget, method, _, _ in ISSUE9_GOALS:
        if budget is not None:
            runs += [Run(case, method, s, budget, "goals") for s in seeds]
    return runs


def quick_plan() -> list[Run]:
    seeds = SEEDS[:3]
    runs = _grid(["E", "headlight"], ["ours", "ours-flat-start", "transport-only", "sa-plain", "spsa", "pagmo-cmaes",
                                      "nlopt-bobyqa"], seeds, "quick", quick=True, save_first=True)
    runs += _grid(["E", "headlight"], ["ours-no-lost-light"], seeds, "quick", quick=True)
    runs += _grid(["headlight"], ["ours-one-kernel", "ours-full-eval", "pagmo-sa"], seeds, "quick", quick=True)
    # The full-retrace pair on E takes two minutes: only in the full plan.
    runs += evaluation_pairs(["headlight"], seeds, "evaluation")
    return _unique(runs)


def _unique(runs):
    seen, out = set(), []
    for r in runs:
        if r.key not in seen:
            seen.add(r.key)
            out.append(r)
    return out
