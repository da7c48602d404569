"""Spatial regressor speed on the dual-arm servicer, next to Pinocchio and the memory floor, in one run.

Builds the minimal momentum regressor for 10,000 random states of the dual-arm servicer
(14 joints, 496 parameters) into a preallocated output, as identification does, and prints its
per-sample cost beside the per-sample cost of ``pinocchio.computeCentroidalMomentum`` on the same
model (called once per sample, as from Python) and beside the memory-bandwidth floor of writing
the regressor: its bytes a sample (3 x 496 doubles) over the write bandwidth measured by filling
the same output array. The regressor runs on the threads the library takes (``work_threads``:
both cores when they are idle) and on one thread; Pinocchio and the fill run on one.
``--baseline FILE`` times another ``_regressor.py`` (for example ``/work/main/src/spaceid/
dynamics/_regressor.py``, the code before a change; it runs on the ``_kinematics.py`` beside it when
there is one, else on this tree's) in the same repeats, and prints how far its regressor is from
this one. The first calls of a fresh process (regressor, momentum, linearised regressor) are timed
with an empty Numba cache (the kernels compiled) and again with the cache that run left (loaded),
in child processes.

Then the wall time of identification from 10,000 samples (regressor and solve):
least squares (``ols``, the target) on exact data, beside the same with the former factor
(Householder QR at any conditioning), the factorisation of ``[A | b]`` alone (Cholesky of the
Gram matrix with refinement, Householder QR, normal equations), and one run of the default
errors-in-variables maximum likelihood (``ml``) on data with 1e-3 noise on every signal.
Compared timings run alternately, repeat by repeat, so that a load change on a shared machine
hits all of them; medians of the repeats and the median of the per-repeat ratios. Prints only,
never fails on timings.

    python benchmarks/bench_regressor.py [--samples 10000] [--repeats 5] [--no-ml] [--baseline FILE]
"""

import argparse
import contextlib
import importlib.util
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.linalg import cho_factor, cho_solve

import spaceid
from spaceid.estimation import identify
from spaceid.estimation import Noise
from spaceid.dynamics import _kinematics, _regressor
from spaceid.dynamics._regressor import _random_states, minimal_parameters
from spaceid.dynamics import base_rate
from spaceid.data import Log
from spaceid.estimation._equations import _equations, _split
from spaceid.estimation import _linalg as linalg
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


def load_module(name, path):
    """The module of file ``path`` as ``spaceid.dynamics.<name>`` (its relative imports: this tree's)."""
    spec = importlib.util.spec_from_file_location(f"spaceid.dynamics.{name}", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def load_baseline(path):
    """The module of another ``_regressor.py``, with the names it took from this tree's kinematics
    bound to those of the ``_kinematics.py`` beside it, when there is one."""
    module = load_module("_regressor_baseline", path)
    if path.with_name("_kinematics.py").exists():
        kinematics = load_module("_kinematics_baseline", path.with_name("_kinematics.py"))
        for name, value in vars(_kinematics).items():
            if getattr(module, name, None) is value and hasattr(kinematics, name):
                setattr(module, name, getattr(kinematics, name))
    return module


FIRST_CALLS = """
import time
import numpy as np
import spaceid
from spaceid.dynamics._regressor import _random_states, minimal_parameters
param = minimal_parameters(spaceid.load_model({urdf!r}))
x = _random_states(param.model, 10, seed=1)
times = []
for call in (lambda: param.regressor(*x), lambda: param.momentum(*x, param.true_values),
             lambda: param.linearized_regressor(*x, x, step=1e-6)):
    start = time.perf_counter()
    call()
    times.append(time.perf_counter() - start)
print(*times)
"""


def first_calls():
    """Seconds of the first regressor, momentum and linearised-regressor calls of a fresh process,
    with an empty Numba cache and then with the cache that process left: ``(cold, warm)``."""
    with tempfile.TemporaryDirectory() as cache:
        env = os.environ | {"NUMBA_CACHE_DIR": cache}
        code = FIRST_CALLS.format(urdf=str(URDF))
        return [np.array(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                                        check=True).stdout.split(), float) for _ in range(2)]  # fmt: skip


def regressor_speed(args, model, param, states, pinocchio_loop, derive):
    """Print the regressor's cost a sample beside Pinocchio's and the write floor, timed alternately."""
    n = len(states[0])
    out = np.empty((n, 3, param.n_params))
    written = out[0].nbytes  # bytes of regressor a sample

    def on_threads(count, module, call):
        def run():
            with patched(module, "work_threads", lambda: count):
                call()
        return run

    def into_out(p):
        return lambda: p.regressor(*states, out=out)

    def others(p):  # the other evaluations of the columns: the momentum and the linearised regressor
        return (lambda: p.momentum(*states, p.true_values),
                lambda: p.linearized_regressor(*states, states, step=1e-6, out=out))

    timed = {"regressor": into_out(param), "one thread": on_threads(1, _regressor, into_out(param)),
             "two threads": on_threads(2, _regressor, into_out(param)),
             "kinematics": lambda: _kinematics.frame_table(model, *states, 256),
             "allocating": lambda: param.regressor(*states), "pinocchio": pinocchio_loop,
             "floor": lambda: out.fill(1.0)}  # fmt: skip
    timed |= dict(zip(("momentum", "linearised"), others(param)))
    if args.baseline:
        base = load_baseline(args.baseline)
        base_param = base.minimal_parameters(model)
        y = param.regressor(*states)
        gap = np.abs(base_param.regressor(*states) - y).max() / np.abs(y).max()
        timed |= {"baseline": into_out(base_param), "baseline one thread": on_threads(1, base, into_out(base_param)),
                  "baseline two threads": on_threads(2, base, into_out(base_param))}
        timed |= dict(zip(("baseline momentum", "baseline linearised"), others(base_param)))
    for fn in timed.values():  # untimed: caches and lazy initialisation
        fn()
    times, cpu = {k: [] for k in timed}, {k: [] for k in timed}
    for _ in range(args.repeats):
        for k, fn in timed.items():
            start, start_cpu = time.perf_counter(), time.process_time()
            fn()
            times[k].append(time.perf_counter() - start)
            cpu[k].append(time.process_time() - start_cpu)  # all threads': the load distorts it less
    times = {k: np.array(v) for k, v in times.items()}

    def per_sample(k):
        return float(np.median(times[k])) / n * 1e6

    def cpu_per_sample(k):
        return f"CPU {float(np.median(cpu[k])) / n * 1e6:5.2f} us"

    def ratio(k, to):
        return float(np.median(times[k] / times[to]))

    print(f"dual-arm servicer: {model.n_joints} joints, {len(model.bodies)} bodies, {param.n_params} minimal "
          f"parameters (derived in {derive:.2f} s)")
    print(f"{n} samples, medians of {args.repeats} alternating runs and of the per-run ratios; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    threads = _regressor.work_threads()

    def row(label, k, note):
        print(f"  {label:<31}{per_sample(k):8.2f} us/sample  ({cpu_per_sample(k)}) {note}")

    row("spaceid minimal regressor", "regressor", f"{threads} thread{'s' if threads > 1 else ''} now = "
        f"{ratio('regressor', 'pinocchio'):.2f} x pinocchio (target <= 3), "
        f"{ratio('regressor', 'floor'):.1f} x the floor")
    for k in ("one thread", "two threads"):
        row(f"  on {k}", k, f"= {ratio(k, 'pinocchio'):.2f} x pinocchio, {ratio(k, 'floor'):.1f} x the floor")
    row("  allocating its output", "allocating", f"= {ratio('allocating', 'pinocchio'):.2f} x pinocchio")
    row("  its kinematics alone", "kinematics", "(frame_table, blocks of 256)")
    row("  momentum (Y pi, summed)", "momentum", "")
    row("  linearised regressor", "linearised", "(Y + dY along a direction, as maximum likelihood)")
    row("pinocchio computeCentroidal...", "pinocchio", "")
    row("memory floor", "floor", f"{written} bytes a sample over {written / per_sample('floor') / 1e3:.1f} GB/s, "
        "the rate of filling the output")
    cold, warm = first_calls()
    print(f"  first calls of a process       regressor {cold[0]:.2f} s, momentum {cold[1]:.2f} s, linearised "
          f"{cold[2]:.2f} s compiling (empty Numba cache); {warm[0]:.2f} s, {warm[1]:.2f} s, {warm[2]:.2f} s cached")
    if args.baseline:
        print(f"  baseline {args.baseline}: max |difference| {gap:.1e} of max |Y|")
        for k, mine in (("", "regressor"), (" one thread", "one thread"), (" two threads", "two threads")):
            row(f"  its regressor{k}", f"baseline{k}", f"this one {ratio(mine, 'baseline' + k):.2f} x it")
        for k in ("momentum", "linearised"):
            row(f"  its {k}", f"baseline {k}", f"this one {ratio(k, 'baseline ' + k):.2f} x it")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--no-ml", action="store_true", help="skip the (slow) maximum-likelihood run")
    parser.add_argument("--baseline", type=Path, help="another _regressor.py to time beside this one")
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

    regressor_speed(args, model, param, (q, qd, w0), pinocchio_loop, derive)

    # identification from n samples: states that satisfy momentum conservation sample by sample
    # (random joint states, base rate from h = [1, -2, 3] N m s at identity attitude)
    h = np.array([1.0, -2.0, 3.0])
    w_cons = base_rate(param, param.true_values, q, qd, h)
    log = Log(np.arange(n) * 0.01, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (n, 1)), w_cons, False)
    result, former = [], []

    def householder_only(*args):  # the former factor: blocked Householder QR at any conditioning
        return None

    def identify_householder():
        with patched(linalg, "_gram_factor", householder_only):
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
    scale = linalg._column_scale(A)

    def householder():
        linalg._factor_of_rows(A, b, scale)

    t_ls, t_qr, t_ne = np.median([(median_time(lambda: linalg._triangular_factor(A, b, scale), 1),
                                   median_time(householder, 1), median_time(lambda: normal_equations(A, b), 1))
                                  for _ in range(args.repeats)], axis=0)  # fmt: skip

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
          f"{r.diagnostics.estimator_info['iterations']} iterations; max |error| / std {z.max():.2f})")


if __name__ == "__main__":
    main()
