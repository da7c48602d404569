"""The paper's Cepheus experiment on the realistic twin, over many seeds (issue 11, item 9).

Each seed is one complete ``spaceid.run_experiment`` with the default twin (every effect on:
air-bearing and joint friction, torque limits, thrusters, CO2 tank, encoder quantisation,
motion-capture noise and latency): design, spin-up, excitation, ROS bag, reading back,
identification (N samples and all samples), held-out validation. Per parameter over the seeds:
bias and RMSE relative to the truth [%], RMSE / median predicted std, fraction within 2 sigma,
largest |z|; per configuration: cond(Y) as designed and as executed (medians). Configurations
(``--drift``, one per argument): ``none``, ``default`` (the experiment's default: ``viscous``
while the table's friction acts) or drift kinds (on this protocol the base turns one way at a
steady rate, so the terms are nearly collinear and one of them is what the data can carry).

    python benchmarks/bench_experiment.py [--seeds 20] [--jobs 2] [--drift none default [torque,viscous ...]]
"""

import argparse
import os
import warnings
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import spaceid  # noqa: E402


def one_run(seed, drift):
    """Estimates, standard errors and condition numbers of one experiment (all samples)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = spaceid.run_experiment(seed=seed, drift=drift)
    ident = r.ident_all
    return {
        "values": ident.values, "std": ident.std, "true": r.true, "names": ident.names,
        "cond_designed": r.settings["cond(Y) designed / executed, all samples"][0],
        "cond_executed": r.settings["cond(Y) designed / executed, all samples"][1],
        "validation": r.metrics.get("base_w_nrms"),
    }  # fmt: skip


def summarise(label, runs):
    """Print the per-parameter table of one configuration and return its worst figures."""
    names = runs[0]["names"]
    est = np.array([r["values"] for r in runs])
    std = np.array([r["std"] for r in runs])
    true = runs[0]["true"]
    free = std.max(axis=0) > 0  # anchored parameters (the wheel's rotor inertia) have no error bar
    err = est - true
    rel = 100 * err / np.abs(true)
    z = np.where(std > 0, err / np.where(std > 0, std, 1), 0.0)
    rmse = np.sqrt((err**2).mean(axis=0))
    ratio = rmse / np.median(std, axis=0)
    print(f"\n{label}: {len(runs)} seeds; cond designed {np.median([r['cond_designed'] or np.nan for r in runs]):.1f}, "
          f"executed {np.median([r['cond_executed'] or np.nan for r in runs]):.1f} (medians); "
          f"held-out base-rate NRMS {100 * np.median([r['validation'] or np.nan for r in runs]):.2f} %")
    print(f"  {'parameter':<10}{'bias %':>9}{'RMSE %':>9}{'RMSE/std':>10}{'|z|<=2':>8}{'max|z|':>8}")
    for i in np.flatnonzero(free):
        print(f"  {names[i]:<10}{rel[:, i].mean():>9.2f}{np.sqrt((rel[:, i] ** 2).mean()):>9.2f}{ratio[i]:>10.2f}"
              f"{np.mean(np.abs(z[:, i]) <= 2):>8.2f}{np.abs(z[:, i]).max():>8.1f}")
    worst = np.sqrt((rel[:, free] ** 2).mean(axis=0)).max()
    within = np.mean(np.abs(z[:, free]) <= 2)
    print(f"  worst relative RMSE {worst:.2f} %, worst RMSE/std {ratio[free].max():.2f}, "
          f"within 2 sigma {100 * within:.0f} %, beyond 4 sigma {int((np.abs(z[:, free]) > 4).sum())}")
    return worst, ratio[free].max(), within


def _kinds(drift):
    """The ``drift`` argument of :func:`spaceid.run_experiment` for one ``--drift`` argument."""
    return {"none": (), "default": None}.get(drift, tuple(drift.split(",")))


def _label(drift):
    return {"none": "--drift none", "default": "default drift terms"}.get(drift, f"--drift {drift}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--jobs", type=int, default=os.cpu_count())
    parser.add_argument("--drift", nargs="+", default=["none", "default"], help="drift terms, one configuration per "
                        "argument: none, default (the experiment's default) or kinds (e.g. viscous torque,viscous)")
    args = parser.parse_args()
    configs = {_label(d): _kinds(d) for d in args.drift}
    seeds = range(args.seeds)
    with ProcessPoolExecutor(args.jobs) as pool:
        results = {label: list(pool.map(one_run, seeds, [drift] * len(seeds))) for label, drift in configs.items()}
    print("Cepheus experiment on the realistic twin (all samples of the excitation, default estimator)")
    for label, runs in results.items():
        summarise(label, runs)


if __name__ == "__main__":
    main()
