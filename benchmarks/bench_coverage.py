"""Honest standard errors and the drift test's level on spatial robots, designed and undesigned motions.

For each case (robot, designed or undesigned motion, rates measured or differentiated from the angles,
estimator) the same noise-free log is given ``--seeds`` noise draws (encoders 1e-4 rad, joint-rate
sensors 1e-4 rad/s, gyro 1e-5 rad/s, star tracker 5e-5 rad, per axis; the momentum conserved to
round-off) and identified with the levels given (measured rates) or estimated from the log
(differentiated, as the CLI does; ``encoders``: the joint rates differentiated from the encoders, the
gyro's rate kept, a servicer's sensors). Printed per case, over the large parameters (|pi| at least 1e-3
of the largest): the fraction of errors within 2 reported standard errors, the largest |z|, the
root-mean-square z, the median number of directions the data do not determine
(``diagnostics.undetermined``), and the drift test's false alarms on these conserved logs against
its level (``alpha`` times the logs: the expected count).

    python benchmarks/bench_coverage.py [--seeds 10] [--robots satellite 3] [--estimators ols wls ml]
                                        [--rates measured differentiated encoders] [--gyro 1e-5]
                                        [--duration 20] [--rate 100] [--budget 20]

Designed motions: ``design_excitation`` (cond criterion, 5 harmonics, 200 samples, |qdd| <= 0.5, the
URDF's position and velocity limits, 1 rad and 1 rad/s where it has none, ``--budget`` s);
undesigned: a random Fourier motion (5 harmonics, coefficients 0.05 rad/s, seed 123).
"""

import argparse
import dataclasses
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import spaceid
from spaceid.data import differentiate_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.motion import FourierTrajectory, design_excitation, simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from random_robots import random_robot  # noqa: E402

H = np.array([1.0, -2.0, 3.0])
LEVELS = Noise(angle=1e-4, rate=1e-4, base_rate=1e-5, attitude=5e-5, source="given")
PRESETS = Path(spaceid.__file__).parent / "models" / "presets"


def quat_product(a, b):
    """Hamilton products of scalar-first quaternions ``(n, 4)``."""
    w0, x0, y0, z0 = a.T
    w1, x1, y1, z1 = b.T
    return np.stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                     w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1], -1)  # fmt: skip


def with_noise(log, noise: Noise, seed: int):
    """``log`` with white noise of each sensor's level: joint angles and rates, the gyro per axis and
    a small rotation of the attitude per base axis (``q_meas = q_true (x) exp(tilt / 2)``)."""
    rng = np.random.default_rng(seed)
    n, nj = log.q.shape
    tilt = noise.attitude * rng.standard_normal((n, 3))
    half = np.linalg.norm(tilt, axis=1, keepdims=True) / 2
    dq = np.hstack([np.cos(half), np.sinc(half / np.pi) * tilt / 2])
    return dataclasses.replace(log, q=log.q + noise.angle * rng.standard_normal((n, nj)),
                               qd=log.qd + noise.rate * rng.standard_normal((n, nj)),
                               base_w=log.base_w + noise.base_rate * rng.standard_normal((n, 3)),
                               base_quat=quat_product(log.base_quat, dq))  # fmt: skip


def robot(name: str, folder: Path):
    if name == "satellite":
        return spaceid.load_model(PRESETS / "satellite-7dof.urdf")
    return random_robot(int(name), planar=False, max_arms=2, max_joints=4).load(folder)


def motion(param, kind: str, duration: float, budget: float):
    if kind == "designed":
        lower, upper = param.model.joint_limits("lower"), param.model.joint_limits("upper")
        q_max = np.nan_to_num(np.fmin(np.abs(lower), np.abs(upper)), nan=1.0)  # continuous joints: 1 rad
        qd_max = np.nan_to_num(param.model.joint_limits("velocity"), nan=1.0)
        return design_excitation(param, duration=duration, harmonics=5, samples=200, momentum=H, seed=0,
                                 time_budget=budget, q_max=q_max, qd_max=qd_max, qdd_max=0.5).trajectory  # fmt: skip
    a, b = 0.05 * np.random.default_rng(123).standard_normal((2, param.model.n_joints, 5))
    return FourierTrajectory(param.model.joints, duration, a, b)


def case(param, log, rates: str, estimator: str, seeds: int, levels: Noise = LEVELS) -> dict:
    large = np.abs(param.true_values) >= 1e-3 * np.abs(param.true_values).max()
    z, alarms, weak, elapsed = [], 0, [], time.perf_counter()
    for seed in range(seeds):
        noisy = with_noise(log, levels, seed)
        if rates != "measured":
            noisy = differentiate_log(noisy, base=rates == "differentiated")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = identify(param, noisy, H, estimator=estimator, noise=levels if rates == "measured" else None)
        z.append(((result.values - param.true_values) / result.std)[large])
        alarms += bool(result.diagnostics.drift_test.drift)
        weak.append(len(result.diagnostics.undetermined))
    z = np.abs(np.array(z))
    return {"within2": float(np.mean(z <= 2)), "max": float(z.max()), "rms": float(np.sqrt(np.mean(z**2))),
            "undetermined": float(np.median(weak)), "alarms": alarms, "seconds": time.perf_counter() - elapsed}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--robots", nargs="+", default=["satellite", "3"])
    parser.add_argument("--estimators", nargs="+", default=["ols", "wls", "ml"])
    parser.add_argument("--kinds", nargs="+", default=["designed", "undesigned"])
    parser.add_argument("--rates", nargs="+", default=["measured", "differentiated"],
                        choices=["measured", "differentiated", "encoders"])
    parser.add_argument("--gyro", type=float, default=LEVELS.base_rate, help="the gyro's white noise [rad/s]")
    parser.add_argument("--duration", type=float, default=20.0)
    parser.add_argument("--rate", type=float, default=100.0)
    parser.add_argument("--budget", type=float, default=20.0)
    parser.add_argument("--folder", type=Path, default=Path("/tmp"))
    args = parser.parse_args()
    alpha = 1e-3
    levels = dataclasses.replace(LEVELS, base_rate=args.gyro)
    print(f"noise {levels.to_dict()}, h = {H.tolist()} N m s, {args.duration:g} s at {args.rate:g} Hz, "
          f"{args.seeds} noise seeds per case; drift test level {alpha:g}: {alpha * args.seeds:.2g} alarms expected")
    print(f"{'robot':>10} {'motion':>10} {'rates':>14} {'est':>4} {'p':>4} {'cond':>8} {'within2':>8} {'max|z|':>8} "
          f"{'rms z':>7} {'undet':>6} {'alarms':>7} {'s/fit':>6}")
    t = np.arange(0.0, args.duration + 0.5 / args.rate, 1 / args.rate)
    for name in args.robots:
        model = robot(name, args.folder)
        param = minimal_parameters(model)
        for kind in args.kinds:
            log = simulate(param, param.true_values, motion(param, kind, args.duration, args.budget), t, H, model=model)
            cond = identify(param, log, H, estimator="ols").diagnostics.condition_number_scaled
            for rates in args.rates:
                for estimator in args.estimators:
                    r = case(param, log, rates, estimator, args.seeds, levels)
                    print(f"{name:>10} {kind:>10} {rates:>14} {estimator:>4} {param.n_params:>4} {cond:>8.2g} "
                          f"{r['within2']:>8.3f} {r['max']:>8.3g} {r['rms']:>7.3g} {r['undetermined']:>6g} "
                          f"{r['alarms']:>3}/{args.seeds:<3} {r['seconds'] / args.seeds:>6.2f}", flush=True)


if __name__ == "__main__":
    main()
