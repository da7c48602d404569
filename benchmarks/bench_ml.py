"""Maximum likelihood against least squares on the dual-arm servicer, side by side, in one run.

10,000 samples of the 14-DOF servicer (496 parameters) at random states that conserve the
momentum, 1e-3 noise on every joint angle, joint rate and base rate. Times the whole
``identify(ml)`` and ``identify(ols)`` calls, both given the noise levels (as the CLI benchmark's
commands are: least squares judges the directions the data do not determine by them, and levels
estimated from a log of independent random states would be those states' spread), alternately,
repeat by repeat, so that a load change
on a shared machine hits both, and prints their medians and the median of the per-repeat ratios
(target <= 3), in wall and in processor time (every thread's). Then, once each, the parts of the ML
call: one evaluation of the iteration (:func:`~spaceid.estimation._estimators._ml_evaluate`: the
signal Jacobian, the residuals, the
weights' derivative, the gradient), the signal Jacobian and the weights' derivative alone, and the
factorisation of the whitened equations (three times per call: two preconditioners, in single precision where
that pays and the condition allows, and the covariance's, in double).
Prints only, never fails on timings.

    python benchmarks/bench_ml.py [--samples 10000] [--repeats 3] [--no-parts]
"""

import argparse
import os
import time
import warnings
from pathlib import Path

import numpy as np

import spaceid
from spaceid.data import Log
from spaceid.dynamics import base_rate
from spaceid.dynamics._regressor import _random_states, minimal_parameters
from spaceid.estimation import Noise, identify, signal_sigma
from spaceid.estimation import _estimators as estimate
from spaceid.estimation import _linalg as linalg
from spaceid.estimation._equations import _equations, _split

URDF = Path(spaceid.__file__).parent / "models" / "presets" / "servicer-dual.urdf"


def timed(fn):
    """``(wall, cpu, out)``: the wall and processor time [s] of ``fn()`` (the processor time of every thread
    of the process: steadier than the wall time on a loaded machine) and its value."""
    start, cpu = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - start, time.process_time() - cpu, out


def servicer_log(n, level):
    """``(param, log, h, noise)``: ``n`` noisy servicer samples whose base rate conserves ``h``."""
    model = spaceid.load_model(URDF)
    param = minimal_parameters(model)
    q, qd, _ = _random_states(model, n, seed=1)
    h = np.array([1.0, -2.0, 3.0])
    w = base_rate(param, param.true_values, q, qd, h)
    rng = np.random.default_rng(3)
    log = Log(np.arange(n) * 0.01, model.joints, q + level * rng.standard_normal(q.shape),
              qd + level * rng.standard_normal(qd.shape), np.tile([1.0, 0, 0, 0], (n, 1)),
              w + level * rng.standard_normal(w.shape), False)  # fmt: skip
    return param, log, h, Noise(angle=level, rate=level, base_rate=level)


def parts(param, log, h, noise):
    """Times of the parts of one ML call, each once."""
    eq, _ = _equations(param, log, h, None, "bench")
    x, sigma = eq.signals(log), signal_sigma(param, noise)
    phi = eq.phi(x)
    theta = linalg._solve(*_split(phi))[0]
    equations = lambda rows, e, xe: phi[rows]  # noqa: E731
    first = estimate._ml_evaluate(eq, x, theta, sigma, estimate.ML_PART, equations)
    previous = (theta, first["xh"], first["r"], first["L"], first["J"])
    xh, n = first["xh"], len(x)
    out = {
        "ML evaluation (_ml_evaluate)": lambda: estimate._ml_evaluate(eq, x, theta, sigma, estimate.ML_PART, equations,
                                                                     previous),  # fmt: skip
        "  signal Jacobian": lambda: eq.jacobian(xh, theta),
        "  weights' derivative (contracted)": lambda: eq.contracted_dphi(xh, x - xh, np.ones((n, param.rows))),
        "whitened factorisation": lambda: linalg._gram_matrix_factor(linalg._whitened_gram(first["L"], phi)),
        "  in single precision (preconditioners)": lambda: linalg._gram_matrix_factor(
            linalg._whitened_gram(first["L"], phi, single=True), limit=linalg.SINGLE_COND),
    }
    return {key: timed(fn)[:2] for key, fn in out.items()}


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-parts", action="store_true", help="skip the timing of the ML call's parts")
    args = parser.parse_args()
    level = 1e-3
    warnings.simplefilter("ignore")  # random states in time order trip the drift check; timings only
    param, log, h, noise = servicer_log(args.samples, level)
    identify(param, log, h, estimator="ols", noise=noise)  # warm-up: caches, imports
    times, result = {"identify(ols)": [], "identify(ml)": []}, None  # (wall, cpu) per repeat
    for _ in range(args.repeats):  # both given the noise levels, as the CLI benchmark's commands
        times["identify(ols)"].append(timed(lambda: identify(param, log, h, estimator="ols", noise=noise))[:2])
        *elapsed, result = timed(lambda: identify(param, log, h, estimator="ml", noise=noise))
        times["identify(ml)"].append(elapsed)
    ratios = np.median(np.array(times["identify(ml)"]) / np.array(times["identify(ols)"]), axis=0)
    info = result.diagnostics.estimator_info
    z = np.abs(result.values - param.true_values) / result.std
    print(f"dual-arm servicer: {param.model.n_joints} joints, {param.n_params} minimal parameters; {args.samples} "
          f"samples, noise {level:g} on q, qd, w0; medians of {args.repeats} alternating repeats; load "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")  # fmt: skip
    print(f"  {'':36s} {'wall':>8s}   {'CPU':>8s}")
    for key, values in times.items():
        wall, cpu = np.median(values, axis=0)
        print(f"  {key:36s} {wall:8.3f} s {cpu:8.3f} s")
    print(f"  identify(ml) / identify(ols)         {ratios[0]:8.2f}   {ratios[1]:8.2f}    (target <= 3; median of the "
          "per-repeat ratios)")
    print(f"  ML: {info['iterations']} iterations after the start, converged {info['converged']}, fallback "
          f"{info['fallback']}; max |error| / std {z.max():.2f}")
    if not args.no_parts:
        for key, (wall, cpu) in parts(param, log, h, noise).items():
            print(f"  {key:36s} {wall:8.3f} s {cpu:8.3f} s")


if __name__ == "__main__":
    main()
