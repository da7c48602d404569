"""Noise-aware excitation design on the Cepheus case: does minimising the predicted error pay?

Designs a trajectory for ``cepheus`` (tf = 5 s, Nf = 3, N = 35, h = 0.4934 N m s, the model's
joint limits) with the criteria ``cond`` (min cond(Y)), ``dopt`` (max log det of the Fisher
information) and ``crb`` (min trace of the relative Cramer-Rao bound), noise 1e-4 rad on the
joint angles and 1e-4 rad/s on the joint rates and the base rate, and prints for each design:
cond(Y), the predicted relative Cramer-Rao standard deviation of every parameter (the KCR bound
of the errors-in-variables model, ``spaceid.design.whitened_regressor``), its maximum and RMS
over the parameters [%], and the design's wall time. The paper's Table 2 trajectory is printed
beside them. Prints only; never fails on the figures.

    python benchmarks/bench_design_noise.py [--seeds 0 1 2] [--starts 64] [--jobs N]

Each seed's start points are the same for every criterion; the median over seeds is printed
last, as a single seed may find a poorer local optimum of the noise-aware criteria.
"""

import argparse
import os

import numpy as np

import spaceid
from spaceid.motion import design_excitation, whitened_regressor
from spaceid.estimation import Noise
from spaceid.dynamics import minimal_parameters
from spaceid.dynamics import excitation_regressor
from spaceid.motion import load_trajectory, sample_times

SETTING = dict(duration=5.0, harmonics=3, samples=35)
MOMENTUM = np.array([0.0, 0.0, 0.4934])  # [N m s], about the inertial z axis
NOISE = Noise(angle=1e-4, rate=1e-4, base_rate=1e-4)
CRITERIA = ("cond", "dopt", "crb")


def figures(param, traj):
    """cond(Y) and the predicted relative CRB standard deviations (k,) [%] of a trajectory."""
    q, qd, _ = traj.evaluate(sample_times(SETTING["duration"], SETTING["samples"]))
    Y = excitation_regressor(param, param.true_values, MOMENTUM)(q, qd)
    bound = whitened_regressor(param, param.true_values, MOMENTUM, NOISE)
    return np.linalg.cond(Y), 100 * np.sqrt(np.diag(bound.crb(q, qd)))


def row(label, param, traj, wall=None):
    c, rel = figures(param, traj)
    rms = np.sqrt(np.mean(rel**2))
    time = "" if wall is None else f"{wall:9.1f}"
    per = " ".join(f"{v:.4f}" for v in rel)
    print(f"{label:<14}{c:9.1f}{rel.max():9.4f}{rms:9.4f}{time:>9}  {per}")
    return rel.max(), rms


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--starts", type=int, default=64, help="local searches per design")
    parser.add_argument("--jobs", type=int, help="worker processes (default: all cores)")
    args = parser.parse_args()
    param = minimal_parameters(spaceid.load_model("cepheus"))
    print(f"Cepheus: tf = 5 s, Nf = 3, N = 35, h = 0.4934 N m s, model limits; noise "
          f"{NOISE.angle:g} rad (angles), {NOISE.rate:g} rad/s (joint rates), "
          f"{NOISE.base_rate:g} rad/s (base rate); {args.starts} starts, {os.cpu_count()} cores\n")
    print(f"{'design':<14}{'cond(Y)':>9}{'max %':>9}{'RMS %':>9}{'time s':>9}  "
          f"relative CRB std per parameter [%] ({', '.join(param.names)})")
    row("paper-table2", param, load_trajectory("paper-table2"))
    summary = {c: [] for c in CRITERIA}
    for seed in args.seeds:
        for criterion in CRITERIA:
            res = design_excitation(param, **SETTING, momentum=MOMENTUM, seed=seed, criterion=criterion,
                             noise=NOISE, n_starts=args.starts, jobs=args.jobs)  # fmt: skip
            label = f"{criterion} s{seed}"
            summary[criterion].append(row(label, param, res.trajectory, res.wall_time))
    if len(args.seeds) > 1:
        print("\nmedian over seeds (max %, RMS %): " + "; ".join(
            f"{c} {np.median([m for m, _ in v]):.4f}, {np.median([r for _, r in v]):.4f}"
            for c, v in summary.items()))  # fmt: skip


if __name__ == "__main__":
    main()
