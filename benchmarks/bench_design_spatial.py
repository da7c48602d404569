"""Excitation design on spatial systems: random feasible starts against the designed trajectory.

For the 7-DOF satellite (153 minimal parameters) and the 14-DOF dual-arm servicer (496), prints
the condition number of random feasible trajectories (each joint's random Fourier part scaled
onto its limits, and all joints scaled together by the tightest one, as a plain random start
would be), of the designed trajectory (``method="auto"`` picks the trust-region search), the
wall time, the seed, the largest |signal| / limit on 20001 times (at most 1: the limits hold
between the design grid's points too) and the best value by wall time. Limits: the URDF's
position and velocity limits, |qdd| <= 0.5 rad/s^2. Prints only; never fails on timings.

The servicer needs a richer motion than the satellite: with tf = 30 s, Nf = 6 its regressor is
rank deficient on random trajectories (cond ~ 1e17); tf = 120 s, Nf = 12, N = 400 excite it.
It runs twice from 2 of 16 screened starts: 4 steps a search (a quick look), then
``--servicer-steps`` (20: the convergence, ~1.5 min on 2 cores).

    python benchmarks/bench_design_spatial.py [--seeds 0 1] [--starts 8] [--steps 60]
                                              [--servicer-steps 20] [--budget S] [--no-servicer]
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

import spaceid
from spaceid.motion import design_excitation
from spaceid.dynamics import minimal_parameters
from spaceid.dynamics import excitation_regressor
from spaceid.motion import FourierTrajectory, sample_times

PRESETS = Path(spaceid.__file__).parent / "models" / "presets"
MOMENTUM = np.array([1.0, -2.0, 3.0])
QDD_MAX = 0.5
SYSTEMS = {
    "satellite-7dof": dict(duration=30.0, harmonics=6, samples=120),
    "servicer-dual": dict(duration=120.0, harmonics=12, samples=400),
}
CHECKPOINTS = (5, 10, 20, 30, 45, 60, 90, 120, 180, 240)


def limits_of(model):
    """(3, n_joints) limits as design_excitation takes them from the model, |qdd| <= QDD_MAX."""
    q = np.fmin(np.abs(model.joint_limits("lower")), np.abs(model.joint_limits("upper")))
    return np.array([q, model.joint_limits("velocity"), np.full(model.n_joints, QDD_MAX)])


def random_starts(model, regressor, settings, limits, seed, m=16):
    """cond of ``m`` random trajectories: each joint scaled onto its limits, and all scaled
    together by the tightest joint (zero boundary values, so scaling keeps them)."""
    rng = np.random.default_rng([seed, 999])
    T, nf, n = settings["duration"], settings["harmonics"], settings["samples"]
    grid, times = sample_times(T, 1001), sample_times(T, n)
    per_joint, together = [], []
    for _ in range(m):
        a, b = rng.standard_normal((2, model.n_joints, nf))
        peak = (np.abs(np.stack(FourierTrajectory(model.joints, T, a, b).evaluate(grid))).max(1).T
                / limits.T).max(1)  # fmt: skip
        for scale, out in ((peak, per_joint), (np.full_like(peak, peak.max()), together)):
            q, qd, _ = FourierTrajectory(model.joints, T, a / scale[:, None], b / scale[:, None]).evaluate(times)
            out.append(np.linalg.cond(regressor(q[None], qd[None])[0]))
    return np.array(per_joint), np.array(together)


def best_by(history, t):
    values = [v for time_, v in history if time_ <= t]
    return min(values) if values else np.nan


def run(name, seeds, options):
    model = spaceid.load_model(PRESETS / f"{name}.urdf")
    param = minimal_parameters(model)
    settings = SYSTEMS[name]
    regressor = excitation_regressor(param, param.true_values, MOMENTUM)
    limits = limits_of(model)
    print(f"== {name}: {model.n_joints} joints, {param.n_params} parameters; tf = {settings['duration']:g} s, "
          f"Nf = {settings['harmonics']}, N = {settings['samples']}; |qdd| <= {QDD_MAX}; "
          f"h = {MOMENTUM.tolist()} N m s")  # fmt: skip
    print(f"   options: {options}")
    for seed in seeds:
        per_joint, together = random_starts(model, regressor, settings, limits, seed)
        t0 = time.perf_counter()
        r = design_excitation(param, momentum=MOMENTUM, seed=seed, qdd_max=QDD_MAX, **settings, **options)
        wall = time.perf_counter() - t0
        q, qd, qdd = r.trajectory.evaluate(sample_times(settings["duration"], 20001))
        peak = max((np.abs(s).max(0) / lim).max() for s, lim in zip((q, qd, qdd), limits))
        print(f"   seed {seed}: random start cond (16, each joint on its limits): first {per_joint[0]:.3g}, "
              f"median {np.median(per_joint):.3g}, best {per_joint.min():.3g}; "
              f"scaled together: median {np.median(together):.3g}")  # fmt: skip
        print(f"           designed cond {r.value:.4g}  ({np.median(per_joint) / r.value:.0f} x better than "
              f"the median random start; the search started at {r.trajectory.meta['start_value']:.3g})")  # fmt: skip
        print(f"           method {r.trajectory.meta['method']}, starts {r.n_starts}, wall {wall:.1f} s, "
              f"peak |signal| / limit on 20001 times {peak:.9f}")  # fmt: skip
        marks = [t for t in CHECKPOINTS if t < wall] + [wall]
        print("           best by wall time: " + ", ".join(f"{t:.3g} s: {best_by(r.history, t):.3g}" for t in marks))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0])
    parser.add_argument("--starts", type=int, default=8, help="satellite: local searches")
    parser.add_argument("--steps", type=int, default=60, help="satellite: trust-region steps a search")
    parser.add_argument("--servicer-steps", type=int, default=20, help="servicer: trust-region steps a search, second run")
    parser.add_argument("--budget", type=float, default=None, help="time_budget [s] (machine-dependent result)")
    parser.add_argument("--no-servicer", action="store_true")
    args = parser.parse_args()
    print(f"{os.cpu_count()} cores; seeds {args.seeds}; no time budget unless --budget "
          "(then the result depends on the machine's speed)\n")
    budget = {} if args.budget is None else {"time_budget": args.budget}
    run("satellite-7dof", args.seeds, dict(n_starts=args.starts, max_steps=args.steps, **budget))
    print()
    print("the issue's script (design_excitation with n_starts=4, default max_steps):")
    run("satellite-7dof", args.seeds, dict(n_starts=4, **budget))
    if not args.no_servicer:
        print()
        for steps in (4, args.servicer_steps):
            run("servicer-dual", args.seeds, dict(n_starts=2, max_steps=steps, n_screen=16, **budget))


if __name__ == "__main__":
    main()
