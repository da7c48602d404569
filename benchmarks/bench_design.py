"""Excitation design on the Cepheus case: condition number reached against wall time.

Uses spaceid's own regressor of the ``cepheus`` preset (or, with ``--regressor closed-form``,
the closed form of docs/theory/cepheus.md in tests/cepheus_closed_form.py). Prints, for a few seeds,
the best condition number found by each wall time (the paper's Table 2 trajectory beside it),
the median over seeds, the time to come within 5 % of the best known value (about 36), and
the default run (64 starts, no budget). Prints only; never fails on timings.

    python benchmarks/bench_design.py [--seeds 5] [--budget 10] [--regressor spaceid|closed-form]
"""

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from cepheus_closed_form import cepheus_regressor  # noqa: E402

import spaceid  # noqa: E402
from spaceid.motion import optimize_excitation  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.dynamics import excitation_regressor  # noqa: E402
from spaceid.motion import load_trajectory, sample_times  # noqa: E402

CEPHEUS = dict(duration=5.0, harmonics=3, samples=35, q_max=1.5, qd_max=1.5, qdd_max=3.0)
JOINTS = ("left_shoulder", "left_elbow")
TARGET = 1.05 * 36  # within 5 % of the best known condition number
CHECKPOINTS = (0.25, 0.5, 1, 2, 5, 10, 20, 60)


def best_by(history, t):
    """Best value recorded by wall time ``t``, or NaN."""
    values = [v for time, v in history if time <= t]
    return min(values) if values else np.nan


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--budget", type=float, default=10.0, help="wall time per seed [s]")
    parser.add_argument("--regressor", choices=("spaceid", "closed-form"), default="spaceid")
    args = parser.parse_args()
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

    print("default run: 64 starts, no budget")
    defaults = [
        optimize_excitation(regressor, JOINTS, **CEPHEUS, seed=seed) for seed in seeds
    ]
    print("cond     " + "".join(f"{r.value:9.2f}" for r in defaults)
          + f"{np.median([r.value for r in defaults]):9.2f}")  # fmt: skip
    print("wall [s] " + "".join(f"{r.wall_time:9.2f}" for r in defaults)
          + f"{np.median([r.wall_time for r in defaults]):9.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
