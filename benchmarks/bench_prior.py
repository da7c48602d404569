"""A CAD prior on a motion that was not designed: the dual-arm servicer, one run.

The servicer (``servicer-dual``) flies an undesigned random motion (a few random harmonics per
joint, small amplitudes) with joint encoders and a star tracker at ``--angle`` and gyros and
joint rates at ``--rate``, its momentum known. It is identified three ways: from the data alone
(``--estimator``; on such a motion the data often do not determine the parameters and identify
refuses, which is printed), from the CAD prior alone (masses and principal moments off by
``--off``, each by a random sign), and the maximum a posteriori with that prior
(``identify(..., prior=...)``). Each model then predicts the base attitude of a held-out random
motion (``spaceid.studies.predict``) and the largest attitude error over it is printed, with the
directions that the data and the prior set. Prints only.

    python benchmarks/bench_prior.py [--seed 0] [--duration 60] [--held-out 60] [--off 0.15]
"""

import argparse
import time
import warnings

import numpy as np

import spaceid
from spaceid import SpaceidError
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify
from spaceid.models import inertial_vector
from spaceid.models.internal import pseudo_inertia
from spaceid.motion import FourierTrajectory, add_noise, simulate
from spaceid.studies import attitude_error_angle, predict


def random_motion(joints, duration, seed, amplitude=0.05, harmonics=3):
    """An undesigned motion: random Fourier coefficients of the joint rates [rad/s], rest at both ends."""
    rng = np.random.default_rng(seed)
    a, b = (rng.normal(0, amplitude, (len(joints), harmonics)) for _ in range(2))
    return FourierTrajectory(joints, duration, a, b, meta={"source": f"random seed {seed}"})


def cad_prior(model, off, seed):
    """The model with every mass and principal moment about the CoM off by ``off`` (relative), each
    by a random sign; the CoMs and principal axes kept (a CAD model of the right shape, wrong mass)."""
    rng = np.random.default_rng(seed)
    rows = []
    for b in model.bodies:
        i_c = pseudo_inertia(b.inertial)[:3, :3] - b.mass * np.outer(b.com, b.com)
        w, v = np.linalg.eigh(np.trace(i_c) * np.eye(3) - i_c)
        f = 1 + off * rng.choice([-1.0, 1.0])  # one factor per body keeps the triangle inequalities
        rows.append(inertial_vector(b.mass * (1 + off * rng.choice([-1.0, 1.0])), b.com, v @ np.diag(w * f) @ v.T))
    return model.with_inertials(rows)


def coverage(values, std, true):
    """Share of the large minimal parameters (|true| above 1e-3 of the largest) within 2 standard
    deviations of the truth, and the largest |z| among them."""
    big = np.abs(true) > 1e-3 * np.abs(true).max()
    z = np.abs(values - true)[big] / np.where(std[big] > 0, std[big], np.nan)
    return f"{100 * np.mean(z < 2):.0f} % of {big.sum()} large parameters within 2 std, max |z| {np.nanmax(z):.3g}"


def held_out_error(result, truth_log, t, motion):
    q, qd, _ = motion.evaluate(t)
    try:
        pred = predict(result, t, q, qd, initial_quat=truth_log.base_quat[0])
    except SpaceidError as exc:
        return f"prediction failed ({exc})"
    return float(attitude_error_angle(pred.base_quat, truth_log.base_quat).max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--held-out", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=10.0)
    parser.add_argument("--off", type=float, default=0.15)
    parser.add_argument("--angle", type=float, default=1e-4)
    parser.add_argument("--rate", type=float, default=1e-5)
    parser.add_argument("--estimator", default="wls")
    args = parser.parse_args()
    true = spaceid.load_model("servicer-dual")
    param = minimal_parameters(true)
    h = np.array([0.5, -0.3, 0.8])
    motion = random_motion(true.joints, args.duration, args.seed)
    t = np.linspace(0, args.duration, int(args.duration * args.rate_hz) + 1)
    log = add_noise(simulate(param, param.true_values, motion, t, h, model=true), angle=args.angle, rate=args.rate,
                    seed=args.seed + 1)
    held = random_motion(true.joints, args.held_out, args.seed + 100)
    t_held = np.linspace(0, args.held_out, int(args.held_out * args.rate_hz) + 1)
    truth = simulate(param, param.true_values, held, t_held, h, model=true)
    prior = cad_prior(true, args.off, args.seed + 2)
    print(f"servicer-dual: {param.n_params} minimal parameters, {len(true.bodies) * 10} standard; undesigned motion "
          f"{args.duration:g} s at {args.rate_hz:g} Hz (seed {args.seed}), noise {args.angle:g} rad / {args.rate:g} "
          f"rad/s; prior {100 * args.off:g} % off; held-out {args.held_out:g} s")
    from spaceid.estimation import Identification

    prior_pi = param.projection @ spaceid.dynamics.full_values(prior)
    as_prior = Identification(param.names, param.definitions, prior_pi, np.zeros_like(prior_pi),
                              np.zeros((len(prior_pi),) * 2), 1.0, np.ones(1), 0.0, 0, "prior", h, "servicer-dual",
                              False, {"parameterization": param.to_dict()})
    rows = [("CAD prior", held_out_error(as_prior, truth, t_held, held))]
    notes = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        try:
            data = identify(param, log, h, estimator=args.estimator)
            rows.append((f"data alone ({args.estimator})", held_out_error(data, truth, t_held, held)))
            notes.append(f"data alone: {coverage(data.values, data.std, param.true_values)}")
        except SpaceidError as exc:
            rows.append((f"data alone ({args.estimator})", f"refused: {str(exc)[:110]}..."))
        mid = time.perf_counter()
        map_ = identify(param, log, h, estimator=args.estimator, prior=prior)
        end = time.perf_counter()
    rows.append((f"MAP with the prior ({args.estimator})", held_out_error(map_, truth, t_held, held)))
    for name, err in rows:
        print(f"  {name:28s} max held-out attitude error: " + (f"{err:.3g} rad" if isinstance(err, float) else err))
    notes += [f"prior: {coverage(map_.prior.prior_values, map_.prior.prior_std_values, param.true_values)}",
              f"MAP: {coverage(map_.values, map_.std, param.true_values)}"]
    for note in notes:
        print(f"  {note}")
    print(f"  {map_.prior.summary()}")
    print(f"  time: data alone {mid - start:.1f} s, MAP {end - mid:.1f} s ({map_.prior.steps} convex steps)")


if __name__ == "__main__":
    main()
