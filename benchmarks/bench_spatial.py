"""The spatial protocol on the servicer twin over many seeds (issue 27, item 8).

Each seed is one complete ``spaceid.studies.run_spatial_experiment`` with the default servicer
twin (servicer-dual; computed torque through a CAD model 15 % off; encoders 1e-4 rad with
2**18 counts, star tracker 5e-5 rad at 10 Hz with latency and lost frames, gyros 1e-5 rad/s with
a bias and a random walk; no joint-rate sensor): design with the CAD model, fly, read the
sensors, identify from all samples with the CAD model as the prior (``--no-prior``: the data
alone), predict a held-out motion with the identified model and with the CAD prior. Per seed and over the seeds: coverage of the large parameters (those whose
contribution to the momentum over the log is at least 1e-3 of the largest; fraction within 2
sigma, largest |z|, root-mean-square z); RMSE / median reported std per large parameter (no
Cramer-Rao bound exists on main for differentiated rates with a spatial base: the reported
standard errors are the reference, and RMS z says whether they are honest); the held-out
largest attitude error of the identified model and of the CAD prior, and their ratio; the
momentum drift of the twin.

    python benchmarks/bench_spatial.py [--seeds 20] [--first-seed 0] [--jobs 1] [--duration 120] [--budget 30]
                                       [--max-steps N] [--samples 600] [--estimator ml] [--no-prior]
                                       [--base-rate gyro]

A quick run: ``--seeds 2 --duration 60 --budget 10 --samples 300``.
"""

import argparse
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from spaceid.studies import run_spatial_experiment  # noqa: E402
from spaceid.studies import large_parameters  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.models import load_model  # noqa: E402


def one_run(seed, options):
    """The scores of one experiment."""
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = run_spatial_experiment(seed=seed, **options)
    m = r.metrics
    large = large_parameters(minimal_parameters(load_model("servicer-dual")), r.log, r.true)
    return {
        "seed": seed, "coverage": m["coverage"], "values": r.ident.values, "std": r.ident.std, "true": r.true,
        "large": large, "identified": (m["held-out attitude error, identified [rad]"] or {"max": np.nan})["max"],
        "prior": (m["held-out attitude error, CAD prior [rad]"] or {"max": np.nan})["max"],
        "drift": max(m["momentum drift relative to the joints' momentum"]),
        "cond": r.ident.condition_number, "seconds": time.perf_counter() - start,
        "by data": None if r.ident.prior is None else r.ident.prior.n_data,
    }  # fmt: skip


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--held-out", type=float, default=60.0)
    parser.add_argument("--budget", type=float, default=30.0, help="design time budget [s]")
    parser.add_argument("--max-steps", type=int, help="design budget in linearisations (then no time budget)")
    parser.add_argument("--samples", type=int, default=600, help="the design's N")
    parser.add_argument("--estimator", default="ml")
    parser.add_argument("--no-prior", action="store_true", help="identify from the data alone")
    parser.add_argument("--base-rate", default="gyro", choices=("gyro", "attitude"))
    args = parser.parse_args()
    options = {"duration": args.duration, "validation_duration": args.held_out,
               "time_budget": None if args.max_steps else args.budget, "max_steps": args.max_steps,
               "samples": args.samples, "estimator": args.estimator, "base_rate": args.base_rate,
               "prior": not args.no_prior}  # fmt: skip
    print(f"servicer-dual, {args.seeds} seeds from {args.first_seed}: {options}")
    print(f"{'seed':>4} {'n_large':>7} {'in 2 sigma':>10} {'max |z|':>8} {'RMS z':>7} {'whitened':>8} {'cond(Y)':>9} "
          f"{'att. err. id [rad]':>18} {'CAD prior [rad]':>15} {'prior/id':>8} {'momentum drift':>14} {'s':>5} "
          f"{'by data':>7}",
          flush=True)
    runs = []
    with ProcessPoolExecutor(args.jobs) as pool:
        seeds = range(args.first_seed, args.first_seed + args.seeds)
        for r in pool.map(one_run, seeds, [options] * args.seeds):  # each seed's row as it is done
            runs.append(r)
            c = r["coverage"]
            print(f"{r['seed']:>4} {c['n_large']:>7} {100 * c['within_2_sigma']:>9.1f}% {c['max_abs_z']:>8.3g} "
                  f"{c['rms_z']:>7.3g} {c['whitened_rms']:>8.3g} {r['cond']:>9.3g} {r['identified']:>18.3g} {r['prior']:>15.3g} "
                  f"{r['prior'] / r['identified']:>8.3g} {r['drift']:>14.2g} {r['seconds']:>5.0f} "
                  f"{r['by data'] if r['by data'] is not None else '-':>7}", flush=True)
    # over the seeds: the parameters large in every run, RMSE against the median reported std
    large = sorted(set.intersection(*(set(r["large"].tolist()) for r in runs)))
    err = np.array([r["values"][large] - r["true"][large] for r in runs])
    std = np.array([r["std"][large] for r in runs])
    z = err / std
    ratio = np.sqrt(np.mean(err**2, axis=0)) / np.median(std, axis=0)
    print(f"over the seeds, {len(large)} parameters large in every run: "
          f"{100 * np.mean(np.abs(z) <= 2):.1f} % of the z within 2, max |z| {np.abs(z).max():.3g}, "
          f"RMS z {np.sqrt(np.mean(z**2)):.3g}; RMSE / median std: median {np.median(ratio):.3g}, "
          f"largest {ratio.max():.3g}")
    gain = np.array([r["prior"] / r["identified"] for r in runs])  # NaN: a model not predicted (not rigid)
    print(f"held-out largest attitude error: identified median {np.nanmedian([r['identified'] for r in runs]):.3g} "
          f"rad ({np.sum(np.isnan(gain))} of {len(runs)} identified models not predicted: no rigid body has them), "
          f"CAD prior median {np.nanmedian([r['prior'] for r in runs]):.3g} rad; prior / identified median "
          f"{np.nanmedian(gain):.3g} (smallest {np.nanmin(gain):.3g}); identified better in {np.sum(gain > 1)} of "
          f"{len(runs)}, at most 1/20 of the prior's error in {np.sum(gain >= 20)}")
    whitened = [r["coverage"]["whitened_rms"] for r in runs]
    print(f"whitened RMS error of the large parameters per seed: median {np.median(whitened):.3g} (range "
          f"{min(whitened):.3g} to {max(whitened):.3g})")
    print(f"momentum drift of the twin (relative): largest {max(r['drift'] for r in runs):.2g}")


if __name__ == "__main__":
    main()
