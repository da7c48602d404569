"""Where an export's time goes: the statement of each convex program against Clarabel's work on it (issue 29,
item 3: the spatial presets' exports were over 2 s, most of it cvxpy's import and its compilation of each program,
until the programs were stated to Clarabel directly).

For each preset: a random smooth joint motion (three harmonics, seed 1) of ``--duration`` seconds simulated at
``--samples`` samples with 1e-4 rad and rad/s of noise on the joints (seed 1), identified with ``ml``, then
exported from the preset itself as the prior (as ``bench_cli.py``'s ``export`` line does) ``--repeats`` times in
this process, after one run that imports and warms everything. Per run: the wall time of ``export_model``, the
programs solved, the time inside the convex steps (``_Program.solve``: each program's statement and solve) and
inside Clarabel (its solver's set-up and solve); the medians, and whether the export was refused.

    python benchmarks/bench_export.py [--presets satellite-7dof servicer-dual] [--samples 500] [--duration 30]
                                      [--repeats 5]
"""

import argparse
import contextlib
import statistics
import time
import warnings

import numpy as np

from spaceid import SpaceidError
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.identified import export_model
from spaceid.models import load_model
from spaceid.motion import FourierTrajectory, add_noise, sample_times, simulate

MOMENTUM = {"cepheus": (0.0, 0.0, 0.4934), "satellite-7dof": (0.1, -0.2, 0.3), "servicer-dual": (0.1, -0.2, 0.3)}
NOISE = 1e-4


@contextlib.contextmanager
def timers():
    """While open, the seconds spent in the export's convex steps (``"step"``, counted in ``"programs"``) and in
    Clarabel's solver, its set-up and solve (``"solve"``), in the dict it gives."""
    import clarabel

    from spaceid.identified import _export

    totals = {"step": 0.0, "solve": 0.0, "programs": 0}
    real_solver, real_step = clarabel.DefaultSolver, _export._Program.solve

    def timed(function, key):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                totals[key] += time.perf_counter() - start
                totals["programs"] += key == "step"

        return wrapper

    class Solver:  # Clarabel's, timed
        def __init__(self, *args):
            self.solver = timed(real_solver, "solve")(*args)

        def solve(self):
            return timed(self.solver.solve, "solve")()

    try:
        clarabel.DefaultSolver, _export._Program.solve = Solver, timed(real_step, "step")
        yield totals
    finally:
        clarabel.DefaultSolver, _export._Program.solve = real_solver, real_step


def estimate(preset: str, samples: int, duration: float):
    """The preset's model and the ``ml`` identification of a noisy log of a random smooth motion."""
    model = load_model(preset)
    param = minimal_parameters(model)
    rng = np.random.default_rng(1)
    a, b = 0.2 * rng.standard_normal((2, model.n_joints, 3))
    motion = FourierTrajectory(model.joints, duration, a, b, meta={"source": "random:1"})
    h = np.array(MOMENTUM[preset])
    log = simulate(param, param.true_values, motion, sample_times(duration, samples), h, model=model)
    noise = Noise(angle=NOISE, rate=NOISE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return model, identify(param, add_noise(log, angle=NOISE, rate=NOISE, seed=1), h, noise=noise)


def export_once(result, prior) -> tuple:
    """``(wall, step, solve, programs, outcome)`` of one ``export_model``."""
    with timers() as spent, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        try:
            export = export_model(result, prior)
            outcome = "exact" if export.region is None else f"region {export.region:g}"
        except SpaceidError:
            outcome = "refused"
        wall = time.perf_counter() - start
    return wall, spent["step"], spent["solve"], spent["programs"], outcome


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--presets", nargs="+", default=["satellite-7dof", "servicer-dual"], choices=list(MOMENTUM))
    parser.add_argument("--samples", type=int, default=500)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print("| Preset | outcome | programs | export [s] | convex steps [s] | Clarabel [s] | statement [s] | "
          "statement / Clarabel |")
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for preset in args.presets:
        model, result = estimate(preset, args.samples, args.duration)
        export_once(result, model)  # imports, kernels, caches
        runs = [export_once(result, model) for _ in range(args.repeats)]
        wall, step, solve = (statistics.median(r[i] for r in runs) for i in range(3))
        stated = statistics.median(r[1] - r[2] for r in runs)
        print(f"| {preset} | {runs[-1][4]} | {runs[-1][3]} | {wall:.3f} | {step:.3f} | {solve:.3f} | {stated:.3f} | "
              f"{stated / solve:.2f} |", flush=True)


if __name__ == "__main__":
    main()
