"""The drift test's false alarms on conserved spatial logs flown in MuJoCo (issue 27, item 5).

Every log conserves the momentum (MuJoCo, an engine nobody on the project wrote; zero gravity, a
free joint, the joints tracking their reference by computed torque with a 15 %-low inertia;
tests/mujoco_flight.py), so every drift warning is a false alarm. The robots: random spatial
robots (tests/random_robots.py, at most ``--arms`` arms of ``--joints`` joints) with a heavy base
(mass and moments ``--base-scale`` times the drawn ones: 10 to 316 kg times that), and every
``--servicer-every``-th log the 462.5 kg dual-arm servicer (``benchmarks/servicer-7dof.urdf``).
The motions: a random Fourier excitation (not designed), and every ``--designed-every``-th log
(random robots only) a ``design`` (criterion ``cond``, 2 starts, at most 20 linearisations a local
search: the same on any machine). The sensors: encoders 1e-4 rad with a 2**18-count quantum, a
star tracker 5e-5 rad, a gyro 1e-5 rad/s, no joint-rate sensor, at 50 Hz; the joint rates
differentiated from the encoders, the gyro kept for the base rate (as ``identify`` on the CLI
does with a gyro), identified with the default estimator (``ml``) and these noise levels, the
momentum MuJoCo's at the first sample.

Prints per log the robot, its minimal parameters, MuJoCo's momentum drift, the drift test's
p-value, the share of its drift coefficients' variance from directions the data do not determine
(``DriftTest.confounded``: at 0.01 or more the test stays silent, whatever its p-value) and whether
it warned; then the count of warnings against the stated level (``DriftTest.alpha``), its binomial
tail probability, the logs the test was silent on, and the p-values' calibration at wider levels (the fraction below 0.01, 0.05 and 0.1, a Kolmogorov-Smirnov test of their uniformity):
with 50 logs a level of 1e-3 expects 0.05 warnings, so the wider levels are what measures the
rate. A log whose motion does not excite every parameter is refused by ``identify`` (no test) and
replaced by the next. Prints only.

    python benchmarks/bench_false_alarms.py [--logs 50] [--seed 0] [--duration 30] [--base-scale 10]
                                            [--servicer-every 10] [--designed-every 5] [--first 0] [--record FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from mujoco_flight import Sensors, fly, sense  # noqa: E402
from random_robots import random_robot  # noqa: E402

import spaceid  # noqa: E402
from spaceid.data import differentiate_log  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.estimation import Noise  # noqa: E402
from spaceid.estimation._residuals import CONFOUNDED  # noqa: E402
from spaceid.motion import FourierTrajectory, design_excitation  # noqa: E402

SERVICER = Path(__file__).with_name("servicer-7dof.urdf")
RATE = 50.0
QUANTUM = 2 * np.pi / 2**18
SENSORS = Sensors(encoder=1e-4, quantum=QUANTUM, star_tracker=5e-5, gyro=1e-5)
NOISE = Noise(angle=float(np.hypot(1e-4, QUANTUM / np.sqrt(12))), rate=0.0, base_rate=1e-5, attitude=5e-5)


def _random_motion(joints, duration, seed, amplitude=0.08, harmonics=6) -> FourierTrajectory:
    rng = np.random.default_rng(seed)
    shape = (len(joints), harmonics)
    return FourierTrajectory(joints, duration, amplitude * rng.standard_normal(shape),
                             amplitude * rng.standard_normal(shape), meta={"source": f"random:{seed}"})


def _case(i, args) -> dict:
    """Robot and motion of log ``i``: the servicer every ``servicer_every``-th, designed motions every
    ``designed_every``-th of the others."""
    servicer = args.servicer_every > 0 and i % args.servicer_every == args.servicer_every - 1
    designed = not servicer and args.designed_every > 0 and i % args.designed_every == 0
    return {"seed": args.seed + i, "servicer": servicer, "designed": designed}


def one_log(i, args) -> dict:
    """Fly, sense, differentiate and identify log ``i``; the drift test's record."""
    case, start = _case(i, args), time.perf_counter()
    seed = case["seed"]
    rng = np.random.default_rng([seed, 1])
    base_w = rng.normal(0.0, 0.02, 3)  # rad/s at the start: the momentum is not zero
    with tempfile.TemporaryDirectory() as tmp:
        if case["servicer"]:
            path, name = SERVICER, "servicer-7dof"
        else:
            robot = random_robot(seed, planar=False, max_arms=args.arms, max_joints=args.joints,
                                 base_scale=args.base_scale)
            robot.load(Path(tmp))
            path, name = Path(tmp) / f"robot{seed}.urdf", f"random{robot.arms}"
        model = spaceid.load_model(path)
        param = minimal_parameters(model)
        if case["designed"]:
            h = spaceid.dynamics.angular_momentum(model, np.zeros(len(model.joints)), np.zeros(len(model.joints)),
                                                  base_w)
            motion = design_excitation(param, duration=args.duration, harmonics=4, samples=200, momentum=h,
                                       seed=seed, n_starts=2, max_steps=20, jobs=1, q_max=1.0, qd_max=0.5,
                                       qdd_max=0.3).trajectory
        else:
            motion = _random_motion(model.joints, args.duration, seed)
        times = np.arange(round(args.duration * RATE) + 1) / RATE
        flight = fly(path, motion, times, base_w=base_w)
    log = differentiate_log(sense(flight.log, SENSORS, seed), base=False, quantum=QUANTUM)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        try:
            result = spaceid.identify(param, log, flight.momentum[0], noise=NOISE)
        except spaceid.SpaceidError as err:  # a motion that does not excite every parameter: no test
            return {**case, "robot": name, "k": param.n_params, "refused": str(err)}
    test = result.diagnostics.drift_test
    return {**case, "robot": name, "k": param.n_params, "engine_drift": flight.drift, "p": test.p_value,
            "alpha": test.alpha, "warned": bool(test.drift), "confounded": test.confounded,
            "estimator": result.estimator, "cond": result.condition_number,
            "drift_warning": any("trend with time" in str(w.message) for w in seen),
            "seconds": time.perf_counter() - start}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0, help="log i's seed: this plus i")
    parser.add_argument("--first", type=int, default=0, help="the first log's index i (a share of a longer run)")
    parser.add_argument("--duration", type=float, default=30.0, help="flight duration [s]")
    parser.add_argument("--arms", type=int, default=2, help="random robots: most arms")
    parser.add_argument("--joints", type=int, default=4, help="random robots: most joints an arm")
    parser.add_argument("--base-scale", type=float, default=10.0, help="random robots: base mass factor")
    parser.add_argument("--servicer-every", type=int, default=10, help="every n-th log the servicer (0: never)")
    parser.add_argument("--designed-every", type=int, default=5, help="every n-th random robot's motion "
                        "designed (0: never)")
    parser.add_argument("--record", type=Path, help="JSON lines of the logs done: read first (those logs are "
                        "not flown again), appended to as logs are done")
    args = parser.parse_args()
    print(f"{args.logs} conserved logs: {vars(args)}")
    print(f"{'log':>4} {'robot':<22} {'motion':<10} {'k':>4} {'cond':>8} {'est.':>4} {'engine drift':>12} "
          f"{'drift p':>9} {'confounded':>10} {'warned':>6} {'s':>5}", flush=True)
    done = [json.loads(line) for line in args.record.read_text().splitlines()] if args.record and \
        args.record.exists() else []  # fmt: skip
    rows, i = [], args.first
    while len(rows) < args.logs:  # logs refused (a motion that does not excite every parameter) replaced
        r = next((d for d in done if d["seed"] == args.seed + i), None) or one_log(i, args)
        if args.record and r not in done:
            with args.record.open("a") as f:
                f.write(json.dumps(r) + "\n")
        if "refused" in r:
            print(f"{i:>4} {r['robot']:<22} {'designed' if r['designed'] else 'random':<10} {r['k']:>4} "
                  f"refused: {r['refused'][:80]}", flush=True)
        else:
            rows.append(r)
            print(f"{i:>4} {r['robot']:<22} {'designed' if r['designed'] else 'random':<10} {r['k']:>4} "
                  f"{r['cond']:>8.2g} {r['estimator']:>4} {r['engine_drift']:>12.1e} {r['p']:>9.3g} "
                  f"{'-' if r['confounded'] is None else format(r['confounded'], '.2g'):>10} {'yes' if r['warned'] else 'no':>6} {r['seconds']:>5.0f}", flush=True)
        i += 1
    alpha, n = rows[0]["alpha"], len(rows)
    warned = sum(r["warned"] for r in rows)
    print(f"warnings: {warned} of {n} at the stated level {alpha:g} (rate {warned / n:.3g}, twice the level "
          f"{2 * alpha:g}; P(>= {warned} | level) = {stats.binom.sf(warned - 1, n, alpha):.3g}); "
          f"the warning text seen {sum(r['drift_warning'] for r in rows)} times")
    silent = [r for r in rows if (r["confounded"] or 0.0) >= CONFOUNDED]
    unknown = sum(r["confounded"] is None for r in rows)  # a record without it (counted as deciding)
    print(f"the test silent on {len(silent)} of {n} logs (a drift confounded with directions the data do not "
          f"determine: share >= {CONFOUNDED:g}; {sum(r['servicer'] for r in silent)} of them the servicer's)"
          + (f"; the share not recorded for {unknown}" if unknown else ""))
    for label, group in (("all logs", rows), ("logs it decides on", [r for r in rows if r not in silent])):
        p = np.array([r["p"] for r in group])
        calibration = ", ".join(f"{int(np.sum(p < level))} below {level:g} (P(>=) {stats.binom.sf(np.sum(p < level) - 1, len(p), level):.2g})"
                                for level in (0.01, 0.05, 0.1))  # fmt: skip
        print(f"p-values, {label} ({len(p)}): {calibration}; Kolmogorov-Smirnov against uniform p = "
              f"{stats.kstest(p, 'uniform').pvalue:.3g}; median {np.median(p):.3g}, smallest {p.min():.3g}")


if __name__ == "__main__":
    main()
