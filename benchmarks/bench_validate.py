"""``spaceid validate`` against ``spaceid identify`` on the same kind of log, and the accuracy of
the re-simulation (issue 29, item 1).

For each preset (cepheus, satellite-7dof, servicer-dual): two random smooth joint motions (three
harmonics, seeds 1 and 2) of ``--duration`` seconds are simulated at ``--samples`` samples with a
little sensor noise; the first is identified, the second validated on, both through the CLI in
fresh processes (imports, reading, writing and figures included), ``--repeats`` times each,
alternating; the medians and the ratio validate / identify are printed. Then, in this process:
the time of ``spaceid.studies.validate`` alone, and the largest attitude error of its
re-simulation against SciPy's DOP853 at rtol 1e-13, restarted at every sample, with the base rate
solved from the momentum at every evaluation (the old solver's route, tightened; spatial only).

``--drift``: the logs drift under a constant torque and viscous friction of the base, identified
with the parameters (``--drift torque,viscous``) and re-simulated with the identified terms; the
reference then carries the momentum as a state too (planar presets included). ``--drift coulomb``:
under Coulomb friction instead, whose sign the planar reference flips at the zero crossings of the
base rate (the solver's events).

    python benchmarks/bench_validate.py [--samples 900] [--duration 30] [--repeats 3] [--presets ...]
                                        [--trajectory DESIGN.json] [--drift [coulomb]]

Run it with ``PYTHONPATH`` set to another source tree to time that version (the CLI runs
``python -m spaceid.cli`` of whatever ``spaceid`` imports).
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

import spaceid
from spaceid.data import quat_to_matrix, write_log
from spaceid.dynamics import base_rate, minimal_parameters
from spaceid.models import load_model
from spaceid.motion import FourierTrajectory, add_noise, load_trajectory, simulate

SETTINGS = {  # momentum [N m s], noise (angles and rates) of the logs
    "cepheus": ("0.05", 1e-5),
    "satellite-7dof": ("1,-2,3", 1e-7),
    "servicer-dual": ("1,-2,3", 1e-10),  # 496 parameters on an undesigned motion: noise kept tiny
}


DRIFT = {"torque": (2e-3, -1e-3, 5e-4), "viscous": 0.02, "coulomb": 2e-4}
"""The drift of ``--drift``: torque [N m] (inertial axes; planar: about z) and viscous friction [N m s/rad];
of ``--drift coulomb``: Coulomb friction [N m]."""


COULOMB_MOMENTUM = "0.001"
"""A planar preset's momentum [N m s] under ``--drift coulomb``: small, so that the base turns back and forth
(Cepheus: 6 and 9 sign changes of the base rate in the two logs)."""


def _drift(model, kind) -> dict | None:
    if kind is None:
        return None
    if kind == "coulomb":
        return {"coulomb": DRIFT["coulomb"]}
    return {"torque": DRIFT["torque"][2] if model.planar else list(DRIFT["torque"]), "viscous": DRIFT["viscous"]}


def _log(model, param, momentum, seed, samples, duration, noise, trajectory=None, drift=None):
    rng = np.random.default_rng(seed)
    shape = (model.n_joints, 3)
    motion = FourierTrajectory(model.joints, duration, rng.uniform(-0.3, 0.3, shape), rng.uniform(-0.3, 0.3, shape))
    if trajectory is not None:
        motion = load_trajectory(trajectory, joints=model.joints)
        duration = motion.duration
    log = simulate(param, param.true_values, motion, np.linspace(0.0, duration, samples), momentum, model=model,
                   drift=drift)
    return add_noise(log, angle=noise, rate=noise, seed=seed)


def _cli_seconds(args):
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "spaceid.cli", *args], capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"spaceid {' '.join(args)} failed:\n{done.stderr}")
    return time.perf_counter() - start


def _reference_error(param, pi, log, momentum, predicted, drift=None):
    """Largest attitude error angle [rad] of ``predicted`` against DOP853 at rtol 1e-13 on the
    same (Hermite) joint motion, restarted at every sample (where the motion is only once
    differentiable); with ``drift`` the inertial momentum is a state too, a planar Coulomb torque's sign
    flipped at the zero crossings of the base rate (events, each restarting the interval's integration)."""
    from scipy.integrate import solve_ivp

    from spaceid.motion import hermite_motion
    from spaceid.studies import attitude_error_angle

    motion = hermite_motion(log.t, log.q, log.qd)
    tau = np.zeros(3) if not drift else np.asarray(drift.get("torque", np.zeros(3)), float) * np.ones(3)
    if param.model.planar:
        tau[:2] = 0.0  # a number about z
    c, mu = (drift.get(k, 0.0) if drift else 0.0 for k in ("viscous", "coulomb"))

    def rate(t, y):
        q, qd = motion(np.array([t]))
        rot = quat_to_matrix(y[:4] / np.linalg.norm(y[:4]))
        return rot, base_rate(param, pi, q, qd, (rot.T @ y[4:])[None])[0]

    def rhs(t, y, s):
        rot, w = rate(t, y)
        wi, x, v = rot @ w, y[0], y[1:4]
        friction = mu * (np.array([0.0, 0.0, s]) if param.model.planar else wi / np.linalg.norm(wi))
        return np.r_[0.5 * np.r_[-v @ w, x * w + np.cross(v, w)], tau - c * wi - friction]

    def crossing(t, y, s):  # the planar base rate's zero, where a Coulomb torque turns
        return s * rate(t, y)[1][2]

    crossing.terminal, crossing.direction = True, -1
    ref = [np.r_[log.base_quat[0], momentum]]  # interval by interval: the Hermite motion is smooth between samples only
    s = np.sign(rate(log.t[0], ref[0])[1][2])
    for t0, t1 in zip(log.t[:-1], log.t[1:]):
        y = ref[-1]
        while True:
            sol = solve_ivp(rhs, (t0, t1), y, method="DOP853", rtol=1e-13, atol=1e-15, args=(s,),
                            events=crossing if mu and param.model.planar else None)
            y = sol.y[:, -1]
            if sol.status != 1:
                break
            t0, y, s = sol.t_events[0][0], sol.y_events[0][0], -s
        ref.append(np.r_[y[:4] / np.linalg.norm(y[:4]), y[4:]])
    ref = np.array(ref)
    return float(attitude_error_angle(ref[:, :4], predicted.base_quat).max())


def run(name, args, folder):
    model = load_model(name)
    param = minimal_parameters(model)
    momentum_text, noise = SETTINGS[name]
    if args.drift == "coulomb" and model.planar:
        momentum_text = COULOMB_MOMENTUM  # the base turns back and forth: the torque changes sign
    momentum = np.array([0.0, 0.0, float(momentum_text)]) if model.planar else np.array(momentum_text.split(","), float)
    fit, held = (folder / f"{name}-{s}.csv" for s in (1, 2))
    drift = _drift(model, args.drift)
    for seed, path in ((1, fit), (2, held)):
        write_log(path, _log(model, param, momentum, seed, args.samples, args.duration, noise, args.trajectory, drift))
    result, out = folder / f"{name}.json", folder / f"{name}-validation"
    noise_options = ["--noise-angle", f"{noise:g}", "--noise-rate", f"{noise:g}"]
    identify = ["identify", name, str(fit), "--momentum", momentum_text, *noise_options, "-o", str(result),
                *(["--drift", ",".join(drift)] if drift else [])]
    validate = ["validate", str(result), str(held), "--momentum", momentum_text, "--out", str(out), "--overwrite"]
    times = {"identify": [], "validate": []}
    for _ in range(args.repeats):
        times["identify"].append(_cli_seconds(identify))
        times["validate"].append(_cli_seconds(validate))
    med = {k: statistics.median(v) for k, v in times.items()}

    from spaceid.data import read_log
    from spaceid.studies import predictor, validate as run_validate

    source = predictor(result)
    log = read_log(held, joints=model.joints, planar=model.planar)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_validate(source, log, momentum=momentum)  # compiled kernels warm
        start = time.perf_counter()
        check = run_validate(source, log, momentum=momentum)
        inside = time.perf_counter() - start
    error = "-" if model.planar and not drift else \
        f"{_reference_error(source.param, source.values, log, momentum, check.predicted, source.drift):.1e}"
    print(f"{name:15s} {args.samples:6d} {med['identify']:9.2f} {med['validate']:9.2f} "
          f"{med['validate'] / med['identify']:6.2f} {inside:10.3f} {error:>12s}", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=900)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--presets", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--trajectory", help="A 'spaceid design' output to fly instead of the random motions (both "
                        "logs then differ by their noise only; servicer-dual needs one: a random motion leaves "
                        "parameters unexcited)")
    parser.add_argument("--drift", nargs="?", const="torque,viscous", choices=["torque,viscous", "coulomb"],
                        help="logs that drift under a torque and viscous friction (or Coulomb friction: "
                        "--drift coulomb), identified and re-simulated with them")
    args = parser.parse_args()
    print(f"spaceid from {Path(spaceid.__file__).parent}; {os.cpu_count()} cores; medians of {args.repeats} CLI runs [s]")
    print(f"{'preset':15s} {'N':>6s} {'identify':>9s} {'validate':>9s} {'ratio':>6s} {'validate()':>10s} "
          f"{'att. error':>12s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.presets:
            run(name, args, Path(tmp))


if __name__ == "__main__":
    main()
