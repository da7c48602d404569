"""Maximum likelihood against least squares on the dual-arm servicer, side by side, in one run.

10,000 samples of the 14-DOF servicer (496 parameters) at random states that conserve the
momentum, 1e-3 noise on every joint angle, joint rate and base rate. Times, alternately repeat by
repeat so that a load change on a shared machine hits all of them: ``identify(ols)``, one
maximum-likelihood iteration (``_ml_step`` from the OLS estimate, with corrected signals that
differ from the measured ones, as in every iteration after the first), its parts (the stacked
equations, their directional derivatives, the signal Jacobian, the least-squares solve), and,
once, the whole ``identify(ml)``. Prints the medians and the ratio of one ML iteration to
``ols`` (target <= 3). Prints only, never fails on timings.

    python benchmarks/bench_ml.py [--samples 10000] [--repeats 3] [--no-full]
"""

import argparse
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
from spaceid.estimation._equations import _equations, _split

URDF = Path(spaceid.__file__).parent / "models" / "presets" / "servicer-dual.urdf"


def timed(fn):
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-full", action="store_true", help="skip the whole identify(ml) run")
    args = parser.parse_args()
    n, level = args.samples, 1e-3
    warnings.simplefilter("ignore")  # random states in time order trip the drift check; timings only

    model = spaceid.load_model(URDF)
    param = minimal_parameters(model)
    q, qd, _ = _random_states(model, n, seed=1)
    h = np.array([1.0, -2.0, 3.0])
    w = base_rate(param, param.true_values, q, qd, h)
    rng = np.random.default_rng(3)
    log = Log(np.arange(n) * 0.01, model.joints, q + level * rng.standard_normal(q.shape),
              qd + level * rng.standard_normal(qd.shape), np.tile([1.0, 0, 0, 0], (n, 1)),
              w + level * rng.standard_normal(w.shape), False)  # fmt: skip
    noise = Noise(angle=level, rate=level, base_rate=level)
    eq, _ = _equations(param, log, h, None, "bench")
    x, sigma = eq.signals(log), signal_sigma(param, noise)
    theta = identify(param, log, h, estimator="ols").values[eq.free]
    xh = estimate._ml_step(eq, x, x, theta, sigma)[4]  # the corrected signals of the first iteration
    phi = eq.phi(xh)
    A, b = _split(phi)

    parts = {
        "identify(ols)": lambda: identify(param, log, h, estimator="ols"),
        "ML iteration (_ml_step)": lambda: estimate._ml_step(eq, x, xh, theta, sigma),
        "  stacked equations (phi)": lambda: eq.phi(xh),
        "  linearised equations": lambda: eq.linearized(xh, x - xh),
        "  contracted derivative": lambda: eq.contracted_dphi(xh, x - xh, np.ones((n, 3))),
        "  signal Jacobian": lambda: eq.jacobian(xh, theta),
        "  least-squares solve": lambda: estimate._solve(A, b),
    }
    times = {k: [] for k in parts}
    for _ in range(args.repeats):
        for key, fn in parts.items():
            times[key].append(timed(fn))
    med = {k: float(np.median(v)) for k, v in times.items()}
    ratio = float(np.median(np.array(times["ML iteration (_ml_step)"]) / np.array(times["identify(ols)"])))
    print(f"dual-arm servicer: {model.n_joints} joints, {param.n_params} minimal parameters; {n} samples, "
          f"noise {level:g} on q, qd, w0; medians of {args.repeats} alternating repeats")
    for key, value in med.items():
        print(f"  {key:30s} {value:8.3f} s")
    print(f"  one ML iteration / ols         {ratio:8.2f}  (target <= 3; median of per-repeat ratios)")
    if args.no_full:
        return
    steps = []
    step = estimate._ml_step

    def counted(*a):
        steps.append(1)
        return step(*a)

    estimate._ml_step = counted
    try:
        start = time.perf_counter()
        r = identify(param, log, h, estimator="ml", noise=noise)
        t_ml = time.perf_counter() - start
    finally:
        estimate._ml_step = step
    t_ols = timed(parts["identify(ols)"])
    info = r.settings["estimator_info"]
    z = np.abs(r.values - param.true_values) / r.std
    print(f"  identify(ml)                   {t_ml:8.3f} s  (one run: {info['iterations']} iterations, {len(steps)} "
          f"steps with the line search, converged {info['converged']}; max |error| / std {z.max():.2f})")
    print(f"  identify(ml) / identify(ols)   {t_ml / t_ols:8.2f}  (ols {t_ols:.3f} s just after)")


if __name__ == "__main__":
    main()
