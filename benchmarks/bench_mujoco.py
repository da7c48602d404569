"""spaceid against MuJoCo, an engine nobody on the project wrote: random spatial robots (1-4 arms
of 1-7 joints, prismatic joints, fixed links, rotated frames; tests/random_robots.py) flown with a
free joint in zero gravity (tests/mujoco_flight.py), their joints tracking a random motion by
computed torque with a 15 %-low inertia.

For each robot it prints MuJoCo's own momentum drift over the flight (RK4 at 1 ms) and the largest
difference, relative to the momentum, between MuJoCo's angular momentum and (a) spaceid's direct
rigid-body momentum, (b) the minimal regressor times the true minimal parameters, on MuJoCo's
states; then the medians and the worst. Prints only.

    python benchmarks/bench_mujoco.py [--robots 30] [--seed 0] [--duration 2]
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from mujoco_flight import fly  # noqa: E402
from random_robots import random_robot  # noqa: E402

import spaceid  # noqa: E402
from spaceid.data import quat_to_matrix  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.motion import FourierTrajectory  # noqa: E402

RATE = 50.0


def one(seed: int, duration: float, folder: Path) -> tuple:
    robot = random_robot(seed, planar=False)
    model = robot.load(folder)
    rng = np.random.default_rng(seed)
    shape = (len(model.joints), 3)
    motion = FourierTrajectory(model.joints, duration, 0.1 * rng.standard_normal(shape), 0.1 * rng.standard_normal(shape))
    times = np.arange(round(duration * RATE) + 1) / RATE
    flight = fly(folder / f"robot{seed}.urdf", motion, times, base_w=rng.normal(0.0, 0.05, 3))
    log, scale = flight.log, np.abs(flight.momentum).max()
    direct = spaceid.dynamics.angular_momentum(model, log.q, log.qd, log.base_w, log.base_quat)
    param = minimal_parameters(model)
    in_base = np.einsum("nji,nj->ni", quat_to_matrix(log.base_quat), flight.momentum)
    minimal = param.momentum(log.q, log.qd, log.base_w, param.true_values)
    return (robot.arms, param.n_params, flight.drift, np.abs(direct - flight.momentum).max() / scale,
            np.abs(minimal - in_base).max() / scale)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0, help="first robot seed")
    parser.add_argument("--duration", type=float, default=2.0, help="flight duration [s]")
    args = parser.parse_args()
    print(f"{'seed':>6} {'arms':<14} {'k':>5} {'drift':>9} {'direct':>9} {'regressor':>9} {'s':>6}")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seed, args.seed + args.robots):
            start = time.perf_counter()
            arms, k, drift, direct, minimal = one(seed, args.duration, Path(tmp))
            rows.append((drift, direct, minimal))
            print(f"{seed:>6} {str(arms):<14} {k:>5} {drift:>9.1e} {direct:>9.1e} {minimal:>9.1e} "
                  f"{time.perf_counter() - start:>6.1f}", flush=True)
    rows = np.array(rows)
    for label, f in (("median", np.median), ("worst", np.max)):
        print(f"{label:>6} {'':<14} {'':>5} " + " ".join(f"{v:>9.1e}" for v in f(rows, axis=0)))


if __name__ == "__main__":
    main()
