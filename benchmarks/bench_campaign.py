"""Throughput of a Monte Carlo campaign on 1 and 2 workers, with each scheduler.

Runs the same Monte Carlo study (Cepheus, the paper's trajectory, 35 samples, ``ml`` and
``ols`` per run) with ``--scheduler processes`` and ``--scheduler dask`` (a LocalCluster started
by the call) on 1 and 2 workers, ``--repeats`` times each, the configurations interleaved repeat
by repeat so that a load change on a shared machine hits all of them. Prints per configuration
the medians of the wall time of the call, of the time to the first completed task (start-up:
simulation, worker processes, their imports) and of the steady throughput (runs per second
from the first completed task to the last, from the progress callback), and the parallel
efficiency ``throughput(2) / (2 throughput(1))`` of each scheduler, of the steady and of the
overall rates; checks that every configuration gave the same estimates bit for bit. Prints
only, never fails on timings.

    python benchmarks/bench_campaign.py [--runs 100] [--repeats 3]
"""

import argparse
import os
import time

import numpy as np

import spaceid
from spaceid.dynamics import minimal_parameters
from spaceid.studies import DEFAULT_NOISE, run_montecarlo

H = [0.0, 0.0, 0.4934]
CONFIGS = [("processes", 1), ("processes", 2), ("dask", 1), ("dask", 2)]


def campaign(param, runs, scheduler, jobs):
    """``(wall [s], time to the first completed task [s], steady runs/s, result)`` of one study."""
    stamps = []
    t = time.perf_counter()
    res = run_montecarlo(param, "paper-table2", samples=35, momentum=H, noise=DEFAULT_NOISE, runs=runs,
                         estimators=("ml", "ols"), seed=1, jobs=jobs, scheduler=scheduler,
                         progress=lambda done, total: stamps.append((time.perf_counter(), done)))  # fmt: skip
    wall = time.perf_counter() - t
    started = [(s, d) for s, d in stamps if d > 0]
    (t1, d1), (t2, d2) = started[0], started[-1]
    return wall, t1 - t, (d2 - d1) / (t2 - t1) if t2 > t1 else float("nan"), res


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    param = minimal_parameters(spaceid.load_model("cepheus"))
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"Monte Carlo campaign: cepheus, {args.runs} runs (ml + ols), {args.repeats} repeats, {cores} cores, "
          f"load average {os.getloadavg()[0]:.1f}", flush=True)
    times, reference, same = {c: [] for c in CONFIGS}, None, True
    for _ in range(args.repeats):
        for config in CONFIGS:
            wall, start, steady, res = campaign(param, args.runs, *config)
            times[config].append((wall, start, steady))
            print(f"  {config[0]}, {config[1]} worker{'s' * (config[1] > 1)}: {wall:.2f} s, first task after "
                  f"{start:.2f} s, then {steady:.1f} runs/s", flush=True)
            if reference is None:
                reference = res
            same &= all(np.array_equal(res.estimates[e], reference.estimates[e]) for e in res.estimators)
    median = {c: np.median(np.array(v), axis=0) for c, v in times.items()}
    print(f"{'scheduler':>10} {'workers':>7} {'wall [s]':>9} {'start [s]':>9} {'runs/s':>7} {'steady':>7} "
          f"{'eff.':>5} {'steady eff.':>11}")
    for scheduler, jobs in CONFIGS:
        wall, start, steady = median[scheduler, jobs]
        rate, one = args.runs / wall, median[scheduler, 1]
        eff = f"{rate / (jobs * args.runs / one[0]):.2f}" if jobs > 1 else "-"
        steady_eff = f"{steady / (jobs * one[2]):.2f}" if jobs > 1 else "-"
        print(f"{scheduler:>10} {jobs:>7} {wall:>9.2f} {start:>9.2f} {rate:>7.1f} {steady:>7.1f} {eff:>5} "
              f"{steady_eff:>11}")
    print(f"estimates bit-identical across the configurations: {same}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":  # the workers start by spawning: they import this file
    main()
