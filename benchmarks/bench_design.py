"""Excitation design: condition number reached against wall time (Cepheus), the time budget
kept, the defaults on a 4-joint planar tree, and the 14-DOF servicer within 60 s.

Parts (``--parts``, all by default):

* ``cepheus``: spaceid's own regressor of the ``cepheus`` preset (or, with ``--regressor
  closed-form``, the closed form of docs/theory/cepheus.md in tests/cepheus_closed_form.py); for
  a few seeds, the best condition number found by each wall time (the paper's Table 2
  trajectory beside it), the median over seeds, the time to come within 5 % of the best known
  value (about 36), and the default run (no budget).
* ``budget``: budget against the measured wall time of the call (overrun %), Cepheus at 3500
  samples (SLSQP) and the servicer (trust region), with what ended the search.
* ``tree``: ``design_excitation`` with its defaults on a 4-joint planar tree
  (benchmarks/tree4-planar.yaml, 25 parameters, tf = 10 s, Nf = 5, N = 200): wall time, starts,
  cond, predicted relative Cramer-Rao std, stop reason.
* ``servicer``: servicer-dual (496 parameters; tf = 120 s, Nf = 12, N = 400, |qdd| <= 0.5),
  a 60 s budget, seed 0: this code against ``--baseline-src`` (a ``src`` folder of older
  spaceid code), each in a subprocess, alternating ``--repeats`` times in the same run: wall
  time, overrun, CPU time of the design's processes (about 2 x 60 s on a quiet 2-core machine;
  less on a loaded one), starts, cond and the predicted relative Cramer-Rao std (noise 1e-4 rad,
  rad/s, rad/s; median and worst over the parameters), stop reason; then the medians.

* ``steps``: the same servicer work free of the load: the two best screened starts searched 6
  trust-region steps each in one process, no budget, this code against ``--baseline-src``: CPU
  time and cond (a budgeted design on a loaded machine gets fewer steps, not worse ones).

Every row ends with the 1-minute load average when it finished (wall times on a loaded machine
are inflated, and a budgeted design then reaches less). Prints only; never fails on timings.

    python benchmarks/bench_design.py [--parts cepheus budget tree servicer steps] [--seeds 5] [--budget 10]
                                      [--regressor spaceid|closed-form] [--baseline-src DIR] [--repeats 1]
"""

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cepheus_closed_form import cepheus_regressor  # noqa: E402

import spaceid  # noqa: E402
from spaceid.estimation import Noise  # noqa: E402
from spaceid.motion import design_excitation, optimize_excitation, whitened_regressor  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.dynamics import excitation_regressor  # noqa: E402
from spaceid.motion import load_trajectory, sample_times  # noqa: E402

CEPHEUS = dict(duration=5.0, harmonics=3, samples=35, q_max=1.5, qd_max=1.5, qdd_max=3.0)
JOINTS = ("left_shoulder", "left_elbow")
TARGET = 1.05 * 36  # within 5 % of the best known condition number
CHECKPOINTS = (0.25, 0.5, 1, 2, 5, 10, 20, 60)
HERE = Path(__file__).resolve().parent
TREE = dict(duration=10.0, harmonics=5, samples=200, momentum=[0, 0, 0.5])
SERVICER = dict(duration=120.0, harmonics=12, samples=400, momentum=[1.0, -2.0, 3.0], qdd_max=0.5)
NOISE = Noise(angle=1e-4, rate=1e-4, base_rate=1e-4)


def best_by(history, t):
    """Best value recorded by wall time ``t``, or NaN."""
    values = [v for time, v in history if time <= t]
    return min(values) if values else np.nan


def servicer_param():
    urdf = Path(spaceid.__file__).parent / "models" / "presets" / "servicer-dual.urdf"
    return minimal_parameters(spaceid.load_model(str(urdf)))


def timed(function, *args, **kwargs):
    """``function(*args, **kwargs)`` and its wall time [s]."""
    t = time.perf_counter()
    out = function(*args, **kwargs)
    return out, time.perf_counter() - t


def load():
    """The 1-minute load average."""
    return os.getloadavg()[0]


def relative_crb(param, traj, settings):
    """Predicted relative Cramer-Rao std of ``param``'s nonzero parameters (noise ``NOISE``) on
    ``traj`` at the samples of ``settings``: (median, worst)."""
    bound = whitened_regressor(param, param.true_values, settings["momentum"], NOISE, relative=False)
    q, qd, _ = traj.evaluate(sample_times(settings["duration"], settings["samples"]))
    pi = np.abs(param.true_values)
    rel = np.sqrt(np.diag(bound.crb(q, qd)))[pi > 0] / pi[pi > 0]
    return np.median(rel), rel.max()


def budget_part():
    print("time budget: budget against the measured wall time of the call")
    print(f"{'case':<28}{'budget [s]':>11}{'wall [s]':>10}{'overrun':>9}{'starts':>8}  {'stop':<10}{'load':>6}")
    param = minimal_parameters(spaceid.load_model("cepheus"))
    cases = [("cepheus N = 3500 (slsqp)", param, dict(duration=5.0, harmonics=3, samples=3500, momentum=[0, 0, 0.4934]),
              (5.0, 20.0)),
             ("servicer (trust region)", servicer_param(), SERVICER, (30.0,))]  # fmt: skip
    for name, p, settings, budgets in cases:
        for budget in budgets:
            res, wall = timed(design_excitation, p, **settings, seed=0, n_starts=64, time_budget=budget,
                              patience=10**9)  # the budget, not convergence, ends it
            print(f"{name:<28}{budget:11g}{wall:10.1f}{100 * (wall / budget - 1):8.1f}%{res.n_starts:8d}  "
                  f"{res.trajectory.meta.get('stop'):<10}{load():6.1f}")
    print()


def tree_part():
    param = minimal_parameters(spaceid.load_model(str(HERE / "tree4-planar.yaml")))
    res, wall = timed(design_excitation, param, **TREE, seed=0)
    median, worst = relative_crb(param, res.trajectory, TREE)
    print(f"4-joint planar tree ({len(param.names)} parameters, N = {TREE['samples']}, Nf = {TREE['harmonics']}), "
          f"defaults: wall {wall:.1f} s, {res.n_starts} starts, cond {res.value:.4g}, relative CRB std median "
          f"{median:.3g}, worst {worst:.3g}, stop {res.trajectory.meta['stop']}, load {load():.1f}\n")


def servicer_design(out, budget, steps=None):
    """Design the servicer within ``budget`` [s] (this process's spaceid), or, given ``steps``,
    without a budget in this process (the two best screened starts, ``steps`` trust-region steps
    each); write the trajectory to ``out`` and the wall and CPU time beside it (``out.wall``)."""
    options = {"time_budget": budget} if steps is None else {"n_starts": 2, "max_steps": steps, "jobs": 1}
    res, wall = timed(design_excitation, servicer_param(), **SERVICER, seed=0, **options)
    res.trajectory.save(out)
    # CPU time of this process and its (ended) worker processes: what the design got of the
    # machine, about cores x wall on a quiet one
    usage = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
    cpu = sum(u.ru_utime + u.ru_stime for u in usage)
    Path(f"{out}.wall").write_text(json.dumps({"wall": wall, "starts": res.n_starts, "cpu": cpu}))


def run_servicer(src, out, *options):
    """``servicer_design`` in a subprocess with the spaceid of ``src`` (None: this one): the
    trajectory, cond and relative CRB (median, worst) on it, and the ``.wall`` record."""
    env = {**os.environ, "PYTHONPATH": str(src or Path(spaceid.__file__).parents[1])}
    subprocess.run([sys.executable, __file__, "--servicer-run", str(out), *options], env=env, check=True)
    param = servicer_param()
    traj, info = load_trajectory(out), json.loads(Path(f"{out}.wall").read_text())
    q, qd, _ = traj.evaluate(sample_times(SERVICER["duration"], SERVICER["samples"]))
    cond = np.linalg.cond(excitation_regressor(param, param.true_values, SERVICER["momentum"])(q, qd))
    return traj, cond, *relative_crb(param, traj, SERVICER), info


def servicer_part(baseline_src, budget=60.0, repeats=1):
    print(f"servicer-dual, {budget:g} s budget, seed 0 (cond; predicted relative CRB std, noise 1e-4)")
    print(f"{'code':<10}{'wall [s]':>9}{'overrun':>9}{'cpu [s]':>8}{'starts':>7}{'cond':>11}{'median':>10}"
          f"{'worst':>10}  {'stop':<10}{'load':>6}")
    runs = [("new", None)] + ([("baseline", baseline_src)] if baseline_src else [])
    rows = {name: [] for name, _ in runs}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(repeats):
            for name, src in runs:  # alternating, so that both see the same load
                traj, cond, median, worst, info = run_servicer(src, Path(tmp) / f"{name}.json", "--budget", str(budget))
                rows[name].append((info["wall"], cond, median, worst))
                print(f"{name:<10}{info['wall']:9.1f}{100 * (info['wall'] / budget - 1):8.1f}%{info['cpu']:8.1f}"
                      f"{info['starts']:7d}{cond:11.3e}{median:10.3g}{worst:10.3g}  {traj.meta.get('stop', '-'):<10}"
                      f"{load():6.1f}")
    if repeats > 1:
        for name, values in rows.items():
            wall, cond, median, worst = np.median(values, axis=0)
            print(f"{name}, median of {repeats}: wall {wall:.1f} s, cond {cond:.3e}, relative CRB std median "
                  f"{median:.3g}, worst {worst:.3g}")
    print()


def steps_part(baseline_src, steps=6):
    """The work behind the budgeted figure, free of the load: the servicer's two best screened
    starts searched ``steps`` trust-region steps each in one process, and the CPU time taken."""
    print(f"servicer-dual, 2 screened starts, {steps} trust-region steps each, one process, no budget")
    print(f"{'code':<10}{'cpu [s]':>8}{'wall [s]':>9}{'cond':>11}{'median':>10}{'worst':>10}{'load':>6}")
    runs = [("new", None)] + ([("baseline", baseline_src)] if baseline_src else [])
    with tempfile.TemporaryDirectory() as tmp:
        for name, src in runs:
            _, cond, median, worst, info = run_servicer(src, Path(tmp) / f"{name}.json", "--steps", str(steps))
            print(f"{name:<10}{info['cpu']:8.1f}{info['wall']:9.1f}{cond:11.3e}{median:10.3g}{worst:10.3g}"
                  f"{load():6.1f}")
    print()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", nargs="+", choices=("cepheus", "budget", "tree", "servicer", "steps"),
                        default=["cepheus", "budget", "tree", "servicer", "steps"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--budget", type=float, default=10.0, help="wall time per seed [s]")
    parser.add_argument("--regressor", choices=("spaceid", "closed-form"), default="spaceid")
    parser.add_argument("--baseline-src", help="src folder of the spaceid to compare on the servicer")
    parser.add_argument("--repeats", type=int, default=1, help="servicer: runs of each code, alternating")
    parser.add_argument("--steps", type=int, default=None, help=argparse.SUPPRESS)
    parser.add_argument("--servicer-run", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.servicer_run:
        return servicer_design(args.servicer_run, args.budget, args.steps)
    print(f"{os.cpu_count()} cores\n")
    if "budget" in args.parts:
        budget_part()
    if "tree" in args.parts:
        tree_part()
    if "servicer" in args.parts:
        servicer_part(args.baseline_src, repeats=args.repeats)
    if "steps" in args.parts:
        steps_part(args.baseline_src)
    if "cepheus" in args.parts:
        cepheus_part(args)


def cepheus_part(args):
    if args.regressor == "spaceid":
        param = minimal_parameters(spaceid.load_model("cepheus"))
        regressor = excitation_regressor(param, param.true_values, [0, 0, 0.4934])
    else:
        regressor = cepheus_regressor

    q, qd, _ = load_trajectory("paper-table2").evaluate(sample_times(5.0, 35))
    paper = np.linalg.cond(cepheus_regressor(q, qd))
    print(f"Cepheus: tf = 5 s, Nf = 3, N = 35, |q| <= 1.5, |qd| <= 1.5, |qdd| <= 3; "
          f"{os.cpu_count()} cores; regressor: {args.regressor}")  # fmt: skip
    print(f"paper-table2: cond = {paper:.1f}; target <= {TARGET:.1f}\n")

    seeds = range(args.seeds)
    runs = [
        optimize_excitation(
            regressor,
            JOINTS,
            **CEPHEUS,
            seed=seed,
            n_starts=100_000,
            time_budget=args.budget,
            patience=10**9,  # every start until the budget: the best by wall time
        )
        for seed in seeds
    ]
    checkpoints = [t for t in CHECKPOINTS if t < args.budget] + [args.budget]
    print(f"best cond by wall time, budget {args.budget:g} s")
    print("time [s] " + "".join(f"{f'seed {s}':>9}" for s in seeds) + f"{'median':>9}")
    for t in checkpoints:
        row = [best_by(r.history, t) for r in runs]
        print(f"{t:>8g} " + "".join(f"{v:9.2f}" for v in row) + f"{np.median(row):9.2f}")
    reach = [next((t for t, v in r.history if v <= TARGET), np.nan) for r in runs]
    print("final    " + "".join(f"{r.value:9.2f}" for r in runs)
          + f"{np.median([r.value for r in runs]):9.2f}")  # fmt: skip
    print("starts   " + "".join(f"{r.n_starts:9d}" for r in runs))
    print("wall [s] " + "".join(f"{r.wall_time:9.2f}" for r in runs))
    print(f"to <= {TARGET:.1f} " + "".join(f"{t:9.2f}" for t in reach)
          + f"{np.median(reach):9.2f}  [s]")  # fmt: skip
    print(f"paper / final (median): {paper / np.median([r.value for r in runs]):.1f}\n")

    print("default run: default starts (64) and patience, no budget")
    defaults = [
        optimize_excitation(regressor, JOINTS, **CEPHEUS, seed=seed) for seed in seeds
    ]
    print("cond     " + "".join(f"{r.value:9.2f}" for r in defaults)
          + f"{np.median([r.value for r in defaults]):9.2f}")  # fmt: skip
    print("wall [s] " + "".join(f"{r.wall_time:9.2f}" for r in defaults)
          + f"{np.median([r.wall_time for r in defaults]):9.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
