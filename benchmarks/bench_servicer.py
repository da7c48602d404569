"""The spatial goals on the dual-arm servicer flown in MuJoCo with the sensors a servicer has.

The servicer of the issue's report (``benchmarks/servicer-7dof.urdf``: 462.5 kg, a 3-joint and a
4-joint arm with mixed axes, one unaligned, a fixed tool, rotated inertial frames; 153 minimal
parameters) is flown in MuJoCo, an
engine nobody on the project wrote (tests/mujoco_flight.py): zero gravity, a free joint, the
joints tracking their reference by computed torque with a 15 %-low inertia (so the executed motion
is not the commanded one). The sensors: encoders 1e-4 rad, a star tracker 5e-5 rad, a gyro 1e-5
rad/s (optionally with a constant bias of 3e-4 rad/s, a MEMS-class gyro's), no joint-rate sensor;
logged at 50 Hz. The CAD prior is the servicer with its masses and inertias 15 % off.

Cases (``--cases``):

* ``designed``: ``design`` (120 s, 8 harmonics, 600 samples, |qdd| <= 0.3, the noise levels,
  ``--budget`` s), flown, identified;
* ``designed-bias``: the same flight with the gyro bias;
* ``undesigned``: 120 s of a random excitation (no design), identified without and with the CAD
  prior (``prior_std`` 0.15).

``designed-bias`` is identified without and with the bias estimated (``gyro_bias``).

Each identification is judged by the coverage of the large parameters (those whose contribution
to the momentum over the log is at least 1 % of the momentum's: the fraction within 2 standard
errors, the largest |z|, the root-mean-square z), their median relative error, chi2/dof, the
drift test's p-value, and the base attitude error over a held-out 60 s random motion flown in
MuJoCo, predicted from its true joint motion, against the CAD prior's. The flights are cached in
``--work``. Prints only.

    python benchmarks/bench_servicer.py [--cases designed designed-bias undesigned] [--budget 90]
                                        [--estimators wls ml] [--work DIR] [--seed 0]
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from mujoco_flight import Sensors, fly, sense  # noqa: E402
from random_robots import perturbed_prior  # noqa: E402

import spaceid  # noqa: E402
from spaceid.data import differentiate_log, read_log, write_log  # noqa: E402
from spaceid.dynamics import minimal_parameters  # noqa: E402
from spaceid.estimation import Noise  # noqa: E402
from spaceid.motion import FourierTrajectory, design_excitation, hermite_motion, load_trajectory, simulate  # noqa: E402
from spaceid.studies import attitude_error_angle, coverage  # noqa: E402

URDF = Path(__file__).with_name("servicer-7dof.urdf")
RATE = 50.0
NOISE = Noise(angle=1e-4, rate=0.0, base_rate=1e-5, attitude=5e-5)
BIAS = (3e-4, -3e-4, 3e-4)
BASE_W = (0.01, -0.02, 0.015)  # rad/s at the start: the momentum is not zero


def _times(duration: float) -> np.ndarray:
    return np.arange(round(duration * RATE) + 1) / RATE


def _random_motion(joints, duration, seed, amplitude=0.08, harmonics=6) -> FourierTrajectory:
    rng = np.random.default_rng(seed)
    shape = (len(joints), harmonics)
    return FourierTrajectory(joints, duration, amplitude * rng.standard_normal(shape),
                             amplitude * rng.standard_normal(shape), meta={"source": f"random:{seed}"})


def _designed(param, h, budget, seed, work: Path) -> FourierTrajectory:
    path = work / f"designed-{seed}-{budget:g}.json"
    if not path.exists():
        start = time.perf_counter()
        res = design_excitation(param, duration=120.0, harmonics=8, samples=600, momentum=h, seed=seed,
                                criterion="crb", noise=NOISE, qdd_max=0.3, time_budget=budget)
        res.trajectory.save(path)
        print(f"designed in {time.perf_counter() - start:.0f} s: crb trace {res.value:.4g}", flush=True)
    return load_trajectory(path)


def _flight(name, motion, duration, work: Path, model):
    """The true log of a MuJoCo flight (cached) and its momentum at the first sample."""
    path = work / f"{name}.csv"
    if not path.exists():
        start = time.perf_counter()
        flight = fly(URDF, motion, _times(duration), base_w=BASE_W)
        print(f"flew {name} ({duration:g} s) in {time.perf_counter() - start:.0f} s, MuJoCo's momentum drift "
              f"{flight.drift:.1e}", flush=True)
        write_log(path, flight.log)
        np.save(work / f"{name}-h.npy", flight.momentum[0])
    return read_log(path, joints=model.joints, planar=False), np.load(work / f"{name}-h.npy")


def _large(param, log, truth) -> np.ndarray:
    """Parameters whose contribution to the momentum over the log is >= 1 % of the momentum's."""
    y = param.regressor(log.q[::5], log.qd[::5], log.base_w[::5])
    contribution = np.sqrt(np.mean((y * truth) ** 2, axis=(0, 1)))
    return contribution >= 0.01 * np.sqrt(np.mean((y @ truth) ** 2))


def _held_out_error(param, values, held, h) -> float:
    """Largest base attitude error [rad] over the held-out flight, predicted from its joint motion
    (NaN when the model cannot be simulated: the message is printed)."""
    try:
        pred = simulate(param, values, hermite_motion(held.t, held.q, held.qd), held.t, h,
                        initial_quat=held.base_quat[0])
    except spaceid.SpaceidError as err:
        print(f"    held-out prediction: {err}")
        return float("nan")
    return float(attitude_error_angle(pred.base_quat, held.base_quat).max())


def _z(result, truth) -> np.ndarray:
    return (result.values - truth) / np.where(result.std > 0, result.std, np.inf)


def _pooled(label, runs) -> str:
    """One row over the noise seeds: the large parameters' z of every run pooled."""
    z = np.abs(np.concatenate([r[0] for r in runs]))
    return (f"{label + ' (pooled)':<34} {np.mean(z <= 2):>6.3f} {z.max():>7.2f} {np.sqrt(np.mean(z**2)):>6.2f}  "
            f"whitened rms {np.median([r[1] for r in runs]):.2f} (median over {len(runs)} noise seeds)")


def _row(label, result, param, truth, large, held, h_held, prior_error) -> str:
    zl = np.abs(_z(result, truth)[large])
    rel = np.abs(result.values - truth)[large] / np.abs(truth[large])
    error = _held_out_error(param, result.values, held, h_held)
    d = result.diagnostics
    p = d.drift_test.p_value if d.drift_test is not None and d.drift_test.run else float("nan")
    return (f"{label:<34} {np.mean(zl <= 2):>6.2f} {zl.max():>7.2f} {np.sqrt(np.mean(zl**2)):>6.2f} "
            f"{100 * np.median(rel):>8.3g} {d.chi2_dof or float('nan'):>9.3g} {p:>8.2g} {error:>9.2e} "
            f"{error / prior_error:>7.3f}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", default=["designed", "designed-bias", "undesigned"])
    parser.add_argument("--estimators", nargs="+", default=["wls"])
    parser.add_argument("--budget", type=float, default=90.0, help="design budget [s]")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--noise-seeds", type=int, default=1,
                        help="sensor-noise draws per flight (seeds --seed, --seed + 1, ...): a pooled row each")
    parser.add_argument("--work", type=Path, default=Path("/tmp/spaceid-bench-servicer-7dof"))
    args = parser.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    model = spaceid.load_model(URDF)
    param = minimal_parameters(model)
    truth = param.true_values
    prior_model = perturbed_prior(model, args.seed + 7, mass=0.15, moments=0.15, com=0.0)
    prior = minimal_parameters(prior_model).true_values
    held, h_held = _flight(f"held-{args.seed}", _random_motion(model.joints, 60.0, 1000 + args.seed), 60.0,
                           args.work, model)
    prior_error = _held_out_error(param, prior, held, h_held)
    print(f"CAD prior (15 % off): held-out attitude error {prior_error:.3e} rad over 60 s")
    print(f"{'case / estimator':<34} {'in2s':>6} {'max|z|':>7} {'rms z':>6} {'med err%':>8} {'chi2/dof':>9} "
          f"{'drift p':>8} {'held-out':>9} {'/prior':>7}")
    for case in args.cases:
        if case.startswith("designed"):
            h0 = np.asarray(BASE_W)  # the design's momentum: the nominal model's for that base rate
            h_design = spaceid.dynamics.angular_momentum(model, np.zeros(len(model.joints)),
                                                         np.zeros(len(model.joints)), h0)
            motion = _designed(param, h_design, args.budget, args.seed, args.work)
            true, h = _flight(f"designed-{args.seed}-{args.budget:g}", motion, 120.0, args.work, model)
        else:
            true, h = _flight(f"undesigned-{args.seed}", _random_motion(model.joints, 120.0, args.seed), 120.0,
                              args.work, model)
        bias = BIAS if case.endswith("bias") else (0.0, 0.0, 0.0)
        large = _large(param, true, truth)
        pooled = {}
        for noise_seed in range(args.seed, args.seed + args.noise_seeds):
            sensed = sense(true, Sensors(encoder=1e-4, star_tracker=5e-5, gyro=1e-5, gyro_bias=bias), seed=noise_seed)
            log = differentiate_log(sensed, base=False)  # the joint rates from the encoders; the gyro's kept
            if args.noise_seeds > 1:
                print(f"  noise seed {noise_seed}")
            _identified(args, case, param, log, h, truth, large, held, h_held, prior_error, prior_model, pooled)
        if args.noise_seeds > 1:
            for label, runs in pooled.items():
                print(_pooled(label, runs))


def _identified(args, case, param, log, h, truth, large, held, h_held, prior_error, prior_model, pooled):
    """Each estimator and variant of ``case`` on ``log``: a row each, its z's kept in ``pooled``."""
    variants = {"": {}}
    if case.endswith("bias"):
        variants["+bias"] = {"gyro_bias": True}
    if case == "undesigned":
        variants["+prior"] = {"prior": prior_model, "prior_std": 0.15}
    for estimator in args.estimators:
        for name, options in variants.items():
            label = f"{case}{name} / {estimator}"
            start = time.perf_counter()
            with warnings.catch_warnings(record=True) as seen:
                warnings.simplefilter("always")
                try:
                    result = spaceid.identify(param, log, h, estimator=estimator, cond_limit=1e14, **options)
                except spaceid.SpaceidError as err:
                    print(f"{label:<34} error: {err}")
                    continue
            print(_row(label, result, param, truth, large, held, h_held, prior_error)
                  + f"  ({large.sum()} large, {time.perf_counter() - start:.0f} s, {len(seen)} warnings)",
                  flush=True)
            pooled.setdefault(label, []).append((_z(result, truth)[large], coverage(result, truth, np.arange(len(truth)))["whitened_rms"]))
            for w in seen:
                print(f"    warning: {str(w.message)[:200]}")


if __name__ == "__main__":
    main()
