"""Spatial regressor speed on the dual-arm servicer, next to Pinocchio, in one run.

Builds the minimal momentum regressor for 10,000 random states of the dual-arm servicer
(14 joints, 496 parameters) and prints its per-sample cost beside the per-sample cost of
``pinocchio.computeCentroidalMomentum`` on the same model (called once per sample, as from
Python), then the wall time of identification from 10,000 samples (regressor and solve):
least squares (``ols``, the target) on exact data, beside the same with the former factor
(Householder QR at any conditioning), the factorisation of ``[A | b]`` alone (Cholesky of the
Gram matrix with refinement, Householder QR, normal equations), and one run of the default
errors-in-variables maximum likelihood (``ml``) on data with 1e-3 noise on every signal.
The two are timed alternately, repeat by repeat, so that a load change on a shared machine
hits both; medians of the repeats and the median of the per-repeat ratios. Prints only,
never fails on timings.

    python benchmarks/bench_regressor.py [--samples 10000] [--repeats 5] [--no-ml]
"""

import argparse
import contextlib
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.linalg import cho_factor, cho_solve

import spaceid
from spaceid.estimation import identify
from spaceid.estimation import Noise
from spaceid.dynamics._regressor import _random_states, minimal_parameters
from spaceid.dynamics import base_rate
from spaceid.data import Log
from spaceid.estimation._equations import _equations, _split
from spaceid.estimation import _estimators as estimate
from spaceid._threads import one_blas_thread

URDF = Path(spaceid.__file__).parent / "models" / "presets" / "servicer-dual.urdf"


def normal_equations(A, b):
    """The former least-squares step, for comparison: Cholesky of the column-scaled normal
    equations with one refinement step (squares the condition number)."""
    scale = np.linalg.norm(A, axis=0)
    with one_blas_thread():
        factor = cho_factor((A.T @ A) / np.outer(scale, scale))
        rhs = (A.T @ b) / scale
        x = cho_solve(factor, rhs)
        x += cho_solve(factor, rhs - (A.T @ (A @ (x / scale))) / scale)
        return x / scale, cho_solve(factor, np.eye(len(scale))) / np.outer(scale, scale)


@contextlib.contextmanager
def patched(module, name, value):
    """``module.name`` set to ``value`` meanwhile."""
    original = getattr(module, name)
    setattr(module, name, value)
    try:
        yield
    finally:
        setattr(module, name, original)


def median_time(fn, repeats):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-ml", action="store_true", help="skip the (slow) maximum-likelihood run")
    args = parser.parse_args()
    n = args.samples

    model = spaceid.load_model(URDF)
    start = time.perf_counter()
    param = minimal_parameters(model)
    derive = time.perf_counter() - start
    q, qd, w0 = _random_states(model, n, seed=1)

    pmodel = pin.buildModelFromUrdf(str(URDF), pin.JointModelFreeFlyer())
    data = pmodel.createData()
    rng = np.random.default_rng(2)
    configs = [pin.randomConfiguration(pmodel, -np.ones(pmodel.nq), np.ones(pmodel.nq)) for _ in range(n)]
    velocities = rng.standard_normal((n, pmodel.nv))

    def pinocchio_loop():
        for c, v in zip(configs, velocities):
            pin.computeCentroidalMomentum(pmodel, data, c, v)

    def regressor():
        param.regressor(q, qd, w0)

    regressor(), pinocchio_loop()  # untimed: caches and lazy initialisation
    pairs = [(median_time(regressor, 1), median_time(pinocchio_loop, 1)) for _ in range(args.repeats)]
    t_reg, t_pin = np.median(pairs, axis=0)
    ratio = float(np.median([a / b for a, b in pairs]))

    # identification from n samples: states that satisfy momentum conservation sample by sample
    # (random joint states, base rate from h = [1, -2, 3] N m s at identity attitude)
    h = np.array([1.0, -2.0, 3.0])
    w_cons = base_rate(param, param.true_values, q, qd, h)
    log = Log(np.arange(n) * 0.01, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (n, 1)), w_cons, False)
    result, former = [], []

    def householder_only(*args):  # the former factor: blocked Householder QR at any conditioning
        return None

    def identify_householder():
        with patched(estimate, "_gram_factor", householder_only):
            former.append(identify(param, log, h, estimator="ols"))

    def identify_now():
        result.append(identify(param, log, h, estimator="ols"))

    t_id, t_id_hh = np.median([(median_time(identify_now, 1), median_time(identify_householder, 1))
                               for _ in range(args.repeats)], axis=0)  # fmt: skip
    err, err_hh = (np.abs(r[-1].values - param.true_values).max() / np.abs(param.true_values).max()
                   for r in (result, former))  # fmt: skip
    # the least-squares step alone: the factor now (Cholesky of the Gram matrix, refined), the
    # blocked Householder QR before it, and the normal equations before that
    eq, _ = _equations(param, log, h, None, "bench")
    A, b = _split(eq.phi(eq.signals(log)))
    scale = estimate._column_scale(A)

    def householder():
        estimate._blockwise(A, b, scale, estimate._accumulate_factor, estimate._accumulate_factor)

    t_ls, t_qr, t_ne = np.median([(median_time(lambda: estimate._triangular_factor(A, b, scale), 1),
                                   median_time(householder, 1), median_time(lambda: normal_equations(A, b), 1))
                                  for _ in range(args.repeats)], axis=0)  # fmt: skip

    print(f"dual-arm servicer: {model.n_joints} joints, {len(model.bodies)} bodies, {param.n_params} minimal parameters "
          f"(derived in {derive:.2f} s)")
    print(f"{n} samples, median of {args.repeats} runs")
    print(f"  spaceid minimal regressor      {t_reg / n * 1e6:8.2f} us/sample  ({t_reg:.3f} s)")
    print(f"  pinocchio computeCentroidal... {t_pin / n * 1e6:8.2f} us/sample  ({t_pin:.3f} s)")
    print(f"  ratio                          {ratio:8.1f}  (target <= 10; median of per-repeat ratios)")
    print(f"  identify(ols) from {n} samples {t_id:8.3f} s  (target < 1 s); max error {err:.1e} of max |pi|")
    print(f"    with Householder QR only     {t_id_hh:8.3f} s  (the former factor); max error {err_hh:.1e}")
    print(f"  factor of [A | b]              {t_ls:8.3f} s  (Cholesky of the Gram matrix, refined; blocked "
          f"Householder QR {t_qr:.3f} s, normal equations {t_ne:.3f} s)")
    if args.no_ml:
        return
    level = 1e-3
    rng = np.random.default_rng(3)
    noisy = Log(log.t, model.joints, *(a + level * rng.standard_normal(a.shape) for a in (q, qd)), log.base_quat,
                w_cons + level * rng.standard_normal(w_cons.shape), False)
    start = time.perf_counter()
    r = identify(param, noisy, h, estimator="ml", noise=Noise(angle=level, rate=level, base_rate=level))
    t_ml = time.perf_counter() - start
    z = np.abs(r.values - param.true_values) / r.std
    print(f"  identify(ml) from {n} samples  {t_ml:8.3f} s  (one run, noise {level:g} on q, qd, w0; "
          f"{r.settings['estimator_info']['iterations']} iterations; max |error| / std {z.max():.2f})")


if __name__ == "__main__":
    main()
