"""What the study runs: cases, methods and the plans (quick and full).

A run is (case, method, seed, time budget). Cases are public scenes, some with a JSON merge
patch that turns them into a stress case; methods are an engine of study_run with a patch
of the scene and a few driver options. Every variant of ours is the library's
freeform::design() with such a patch (engine "design"), so what the study measures is what a
user gets. Every run is judged by `error_physical` (docs/measures.md): the cell means of the
exported mesh, nearest deposit, at the receiver's resolution.

The plan since issue 22 (the study re-run in the physical measure, one build, every run
fresh) asks four questions, one purpose each:
  main       ours (the defaults: transport start, then annealing) and every baseline at the
             case's budget B: the one-screen table
  ladder     ours at B/2 and 2B: error_physical against time (with B from "main")
  stability  ours at a fixed iteration count (the median of its B runs), 10 seeds, and one
             seed repeated: the spread without the clock, and reproducibility
  stress     cases built to fail (too tight a lens, a point light losing most of its light,
             grazing light): where methods fail and why
The flat-start variants, the ablation ladder and the bandit comparisons of the earlier passes
(err measure) are in git history (commit 628f878, benchmarks/results/REPORT.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Case:
    name: str
    scene: str                      # relative to the repository root
    budget: float                   # seconds per run, full mode (B)
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
    family: str = "ours"            # ours | transport | baseline | stability
    # Methods stopped by an iteration cap (optimise.max_iterations) rather than by time: their
    # time budget is only a safety cap, far above what they need; `expected` (case -> seconds
    # on the 2-core development machine) is what the plan's estimate counts for them.
    time_cap: float = 0.0
    expected: dict = field(default_factory=dict)
    # Per-case iteration cap (case -> optimise.max_iterations), merged into the patch of
    # each run (run_study.run_command). Filled by run_study.py before the stability runs.
    iterations: dict = field(default_factory=dict)

    def patch_for(self, case: str) -> dict:
        if case in self.iterations:
            return merged(self.patch, {"optimise": {"max_iterations": self.iterations[case]}})
        return self.patch


def merged(patch: dict, extra: dict) -> dict:
    """patch with extra merged in (nested objects merged, extra's keys appended after patch's)."""
    out = dict(patch)
    for k, v in extra.items():
        out[k] = merged(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


# --- cases -------------------------------------------------------------------------------

# The lens example with +-5 mm height bounds and 1 cm thickness (its form before commit
# 33929ba): the transport surface needs about 20 mm of sag range, so no design fits.
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
# receiver, so a flat start has about a quarter of the energy on the receiver.
POINT_LOW_PATCH = {"light": {"type": "point", "position": [0, 0, 0.12], "rays_per_cell": 16}}

CASES = {c.name: c for c in [
    Case("E", "examples/scenes/letter-e.json", 10, 6, title="letter E (collimated mirror, mesh auto 201², 200² px)",
         reference={"error": 0.083, "energy": 0.976, "iterations": 5.3e5, "seconds": 337}),
    Case("V", "examples/scenes/letter-v.json", 10, title="letter V (collimated mirror, auto 201², 200² px)",
         reference={"error": 0.087, "energy": 0.988, "iterations": 3.7e5, "seconds": 239}),
    Case("at", "examples/scenes/letter-at.json", 10, title="symbol @ (collimated mirror, auto 201², 200² px)",
         reference={"error": 0.086, "energy": 0.965, "iterations": 9.2e5, "seconds": 548}),
    Case("headlight", "examples/scenes/headlight.json", 5, 3,
         title="headlight low beam (collimated mirror, auto 53², 50² px)",
         reference={"error": 0.096, "energy": 1.0, "iterations": 1.3e5, "seconds": 75}),
    Case("point", "examples/scenes/point-light.json", 10,
         title="letter F, point light 0.3 m from an elliptical 12 x 8 cm mirror (121 x 81 mesh, 240 x 160 px)"),
    Case("lens", "examples/scenes/lens.json", 10,
         title="letter L through a PMMA lens (IOR 1.49, 1.5 cm thick, ±12 mm bounds, 101², 200² px)"),
    Case("camera", "examples/scenes/camera.json", 30,
         title="grey photograph 'camera' (collimated mirror, auto 201², 200² px)",
         reference={"error": 0.104, "energy": 0.948, "iterations": 5.6e6, "seconds": 4980,
                    "note": "the reference's photograph is Lenna, not this image"}),
    Case("lens-5mm", "examples/scenes/lens.json", 10, case_patch=LENS_5MM_PATCH,
         title="the lens with ±5 mm height bounds, 1 cm thick",
         stress="too tight a lens: the transport surface needs about 20 mm of sag range, the bounds allow 10"),
    Case("point-low", "examples/scenes/point-light.json", 10, case_patch=POINT_LOW_PATCH,
         title="point light 0.12 m from the mirror",
         stress="low initial energy: a flat mirror puts about a quarter of the light on the receiver"),
    Case("grazing", "examples/scenes/letter-e.json", 10, case_patch=GRAZING_PATCH,
         title="letter E under grazing light (70° from the normal)",
         stress="grazing light: long paths through the height slab, a foreshortened beam"),
]}

PUBLIC_CASES = ["E", "V", "at", "headlight", "point", "lens", "camera"]
STRESS_CASES = ["lens-5mm", "point-low", "grazing"]

# --- methods -----------------------------------------------------------------------------

_NO_PENALTIES = {"energy_threshold": 0, "sobel_weight": 0, "lost_light_weight": 0}
FIXED_CAP = 3600.0
# Case -> optimise.max_iterations of the stability methods; filled by run_study.py (the
# median iterations of ours' "main" runs on disk) or by its --fixed-iterations.
FIXED_ITERATIONS: dict = {}

METHODS = {m.name: m for m in [
    Method("ours", "design", "ours, the defaults: transport start (optimal transport on a grid 3x finer than the "
           "pixels, heights by a Poisson solve, judged by the exact tracer), then annealing (multi-level from the "
           "start's error, 7 kernel shapes + history bandit, Phong, energy/Sobel/lost-light terms, incremental "
           "evaluation)"),
    Method("transport-only", "design", "the transport start alone, no annealing (make_design_start with the run's "
           "seed)", options=("--start-only",), family="transport", expected={"camera": 5.0}),
    Method("sa-plain", "design", "plain SA as in the reference's chapter 3: flat start, single-vertex moves, flat "
           "triangles, no penalties, one level",
           patch={"surface": {"initial": "flat", "phong_alpha": 0},
                  "optimise": {"single_vertex": True, "multilevel": False, **_NO_PENALTIES}}, family="baseline"),
    Method("spsa", "spsa", "SPSA (Spall's gains a_k = a/(k+1+A)^0.602, c_k = c/(k+1)^0.101) on a 13² control grid, "
           "flat start", family="baseline"),
    Method("pagmo-sa", "pagmo-sa", "pagmo2 simulated annealing (Corana), 13² control grid, flat start",
           family="baseline"),
    Method("pagmo-cmaes", "pagmo-cmaes", "pagmo2 CMA-ES, 13² control grid, flat start", family="baseline"),
    Method("nlopt-bobyqa", "nlopt-bobyqa", "NLopt BOBYQA, 13² control grid, flat start", family="baseline"),
    # Ours stopped at a fixed iteration count per case, no time limit (the time budget is
    # only a safety cap): no clock decides anything, so the spread over seeds is the
    # method's own, whatever the machine's load. The count is the median iterations of the
    # case's "main" runs of ours (run_study.py fills `iterations` from them before these
    # runs, and records it in each run's command). The repeat runs the first seed again:
    # the two must end with the same heights bit for bit.
    Method("ours-iters", "design", "ours stopped at a fixed iteration count per case (the median iterations of its "
           "runs at the case's budget B), no time limit", family="stability", time_cap=FIXED_CAP,
           iterations=FIXED_ITERATIONS),
    Method("ours-iters-repeat", "design", "ours-iters again, same seed: is the design reproducible?",
           family="stability", time_cap=FIXED_CAP, iterations=FIXED_ITERATIONS),
]}
ITERATION_METHODS = ("ours-iters", "ours-iters-repeat")

BASELINES = ["sa-plain", "spsa", "pagmo-sa", "pagmo-cmaes", "nlopt-bobyqa"]
MAIN_METHODS = ["ours", "transport-only"] + BASELINES
LADDER_SCALES = (0.5, 2.0)


@dataclass(frozen=True)
class Run:
    case: str
    method: str
    seed: int
    budget: float
    purpose: str          # main | ladder | stability | stress | quick
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
    if m.family == "transport":  # the start alone: no budget to spend (a few seconds: two OT grids)
        return m.expected.get(run.case, 3.0)
    if m.time_cap:               # stopped by iterations: about the case's budget
        return m.expected.get(run.case, CASES[run.case].budget)
    return run.budget


SEEDS = list(range(101, 111))   # never the cases' own seed (1), which judges every run
BASELINE_SEEDS = SEEDS[:2]
LADDER_SEEDS = SEEDS[:2]
TRANSPORT_SEEDS = SEEDS[:3]
STRESS_SEEDS = SEEDS[:2]


def full_plan() -> list[Run]:
    """The order matters: ours' B runs come first (the stability runs' iteration counts are
    their median), the cheap questions before the long ones."""
    runs = _grid(PUBLIC_CASES, ["ours"], SEEDS, "main", save_first=True)
    runs += _grid(PUBLIC_CASES, ["transport-only"], TRANSPORT_SEEDS, "main")
    runs += _grid(PUBLIC_CASES, BASELINES, BASELINE_SEEDS, "main", save_first=True)
    for scale in LADDER_SCALES:
        runs += _grid(PUBLIC_CASES, ["ours"], LADDER_SEEDS, "ladder", budget_scale=scale)
    runs += _grid(PUBLIC_CASES, ["ours-iters"], SEEDS, "stability")
    runs += _grid(PUBLIC_CASES, ["ours-iters-repeat"], SEEDS[:1], "stability")
    runs += _grid(STRESS_CASES, ["ours", "transport-only", "sa-plain"], STRESS_SEEDS, "stress")
    return _unique(runs)


def quick_plan() -> list[Run]:
    seeds = SEEDS[:2]
    runs = _grid(["E", "headlight"], ["ours", "transport-only", "sa-plain", "spsa", "pagmo-cmaes", "nlopt-bobyqa"],
                 seeds, "quick", quick=True, save_first=True)
    runs += _grid(["E", "headlight"], ["ours"], seeds, "quick", quick=True, budget_scale=2.0)
    return _unique(runs)


def _unique(runs):
    seen, out = set(), []
    for r in runs:
        if r.key not in seen:
            seen.add(r.key)
            out.append(r)
    return out


# What study_run is compiled from, as git pathspecs: two commits (or a commit and the working
# tree) that agree on these build the same binary; the study's scripts and documents are not in it.
COMPILED_SOURCES = ["include", "apps", "benchmarks/study", "benchmarks/CMakeLists.txt", "CMakeLists.txt", "cmake",
                    ":(exclude)*.py", ":(exclude)*.md"]
