"""Free-floating flights in MuJoCo, an engine nobody on the project wrote, with the sensors a
servicer has: the independent check of the spatial pipeline (tests and benchmarks).

MuJoCo reads the URDF itself (its own parser: kinematics, inertial frames, joint types), a free
joint is put on the root link, gravity and constraints are switched off, and the joints track
a reference by computed torque with a deliberately wrong (scaled) joint-space inertia, so the
executed motion is not the commanded one. The joint torques are internal forces: the angular
momentum is conserved up to the integrator's error, which :func:`fly` measures.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import mujoco
import numpy as np

from spaceid.data import Log

__all__ = ["Flight", "Sensors", "fly", "sense"]


@dataclass(frozen=True)
class Flight:
    """A flown motion, sampled at the log rate: the true states and MuJoCo's momentum.

    ``log`` has the true signals (base rate in base axes); ``momentum`` (n, 3) is MuJoCo's angular
    momentum about the system CoM in inertial axes [N m s], ``drift`` its largest deviation from
    the first sample relative to its norm (or to the system's momentum scale when it is zero).
    """

    log: Log
    momentum: np.ndarray
    drift: float


@dataclass(frozen=True)
class Sensors:
    """A servicer's sensors: encoders (white noise then quantised) [rad or m], a star tracker (a
    small rotation per base axis) [rad], a gyro (white noise per axis and a constant bias, base
    axes) [rad/s], and joint-rate sensors (None: the log has no rate columns) [rad/s or m/s]."""

    encoder: float = 1e-4
    quantum: float = 0.0
    star_tracker: float = 5e-5
    gyro: float = 1e-5
    gyro_bias: tuple = (0.0, 0.0, 0.0)
    joint_rate: float | None = None


def _model(path: Path, timestep: float):
    """MuJoCo's model of a URDF (a free joint added on its root link) or of an MJCF file that has
    its free joint already (spaceid's export)."""
    spec = mujoco.MjSpec.from_file(str(path))
    spec.compiler.fusestatic = False
    spec.option.gravity = [0.0, 0.0, 0.0]
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_RK4
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # no limits, no contacts
    root = spec.worldbody.first_body()
    if not any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in root.joints):
        root.add_freejoint()
    return spec.compile()


def _joints(m, names) -> tuple:
    """qpos and qvel addresses of the named joints."""
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name) for name in names]
    if min(ids) < 0:
        raise KeyError(
            f"joints missing in MuJoCo's model: {[n for n, i in zip(names, ids) if i < 0]}"
        )
    return np.array([m.jnt_qposadr[i] for i in ids]), np.array(
        [m.jnt_dofadr[i] for i in ids]
    )


def _momentum(m, d) -> np.ndarray:
    """Angular momentum about the system CoM, inertial axes (body 1 is the root)."""
    mujoco.mj_subtreeVel(m, d)
    return d.subtree_angmom[1].copy()


def _start(m, d, qa, va, q, qd, base_w) -> None:
    """The initial state: joints at the reference, the base rate given (base axes), the base's
    linear velocity the one that makes the system's linear momentum zero."""
    d.qpos[:] = m.qpos0
    d.qpos[3:7] = [1.0, 0.0, 0.0, 0.0]
    d.qpos[qa], d.qvel[:] = q, 0.0
    d.qvel[va], d.qvel[3:6] = qd, base_w
    mujoco.mj_forward(m, d)
    mujoco.mj_subtreeVel(m, d)
    d.qvel[0:3] = -d.subtree_linvel[1]  # a base translation moves every body alike
    mujoco.mj_forward(m, d)


def _torque(m, d, qa, va, ref, inertia_scale, wn) -> np.ndarray:
    """Computed torque with the joint-space inertia of the free-floating system scaled by
    ``inertia_scale``: a controller whose model is wrong, as a real one's is."""
    q_ref, qd_ref, qdd_ref = ref
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    base = np.arange(6)
    coupling = np.linalg.solve(full[np.ix_(base, base)], full[np.ix_(base, va)])
    inertia = full[np.ix_(va, va)] - full[np.ix_(va, base)] @ coupling
    bias = d.qfrc_bias[va] - coupling.T @ d.qfrc_bias[base]
    q, qd = d.qpos[qa], d.qvel[va]
    accel = qdd_ref + 2 * wn * (qd_ref - qd) + wn**2 * (q_ref - q)
    return inertia_scale * inertia @ accel + bias


def fly(path, trajectory, times, *, base_w=(0.0, 0.0, 0.0), inertia_error=0.15, bandwidth=20.0,
        timestep=1e-3) -> Flight:
    """Fly ``trajectory`` (anything with ``joints`` and ``evaluate(t) -> (q, qd, qdd)``) in MuJoCo.

    Parameters
    ----------
    path : path
        A URDF (a free joint is added on its root link) or a free-floating MJCF file.
    trajectory : FourierTrajectory
        The joints' reference; the joints start on it.
    times : array_like of shape (n,)
        Log time stamps [s], multiples of ``timestep`` from 0.
    base_w : array_like of shape (3,)
        Initial base angular velocity, base axes [rad/s] (sets the momentum).
    inertia_error : float
        The controller's joint-space inertia is ``1 - inertia_error`` times the true one.
    bandwidth : float
        Tracking bandwidth [rad/s] (critically damped).
    timestep : float
        MuJoCo's RK4 step [s].
    """
    m = _model(Path(path), timestep)
    d = mujoco.MjData(m)
    names = tuple(trajectory.joints)
    qa, va = _joints(m, names)
    times = np.asarray(times, float)
    steps = np.rint(times / timestep).astype(int)
    q0, qd0, _ = (x[0] for x in trajectory.evaluate(times[:1]))
    _start(m, d, qa, va, q0, qd0, np.asarray(base_w, float))
    rows, step = [], 0
    for target in steps:
        while step < target:
            ref = (x[0] for x in trajectory.evaluate(np.array([d.time])))
            d.qfrc_applied[:] = 0.0
            d.qfrc_applied[va] = _torque(
                m, d, qa, va, tuple(ref), 1.0 - inertia_error, bandwidth
            )
            mujoco.mj_step(m, d)
            step += 1
        rows.append(
            (
                d.qpos[qa].copy(),
                d.qvel[va].copy(),
                d.qpos[3:7].copy(),
                d.qvel[3:6].copy(),
                _momentum(m, d),
            )
        )
    q, qd, quat, w, h = (np.array(x) for x in zip(*rows))
    scale = max(np.linalg.norm(h[0]), np.abs(h).max(), 1e-300)
    drift = float(np.abs(h - h[0]).max() / scale)
    log = Log(
        times,
        names,
        q,
        qd,
        quat,
        w,
        False,
        {"source": f"mujoco:{Path(path).name}", "engine": "mujoco"},
    )
    return Flight(log, h, drift)


def sense(log: Log, sensors: Sensors, seed: int) -> Log:
    """The log as a servicer's sensors see it (seeded; the levels and seed recorded in ``meta``)."""
    rng = np.random.default_rng(seed)
    n, nj = log.q.shape
    q = log.q + sensors.encoder * rng.standard_normal((n, nj))
    if sensors.quantum:
        q = sensors.quantum * np.round(q / sensors.quantum)
    if sensors.joint_rate is None:
        qd = np.full_like(log.qd, np.nan)
    else:
        qd = log.qd + sensors.joint_rate * rng.standard_normal((n, nj))
    w = (
        log.base_w
        + np.asarray(sensors.gyro_bias, float)
        + sensors.gyro * rng.standard_normal((n, 3))
    )
    tilt = sensors.star_tracker * rng.standard_normal((n, 3))
    quat = _times(log.base_quat, _rotation_quat(tilt))
    meta = dict(
        log.meta,
        sensors={k: getattr(sensors, k) for k in sensors.__dataclass_fields__},
        sensor_seed=seed,
    )
    if sensors.joint_rate is None:
        meta.update(rates="missing", missing_rates=[f"qd_{j}" for j in log.joints])
    return replace(log, q=q, qd=qd, base_quat=quat, base_w=w, meta=meta)


def _rotation_quat(v) -> np.ndarray:
    angle = np.linalg.norm(v, axis=1, keepdims=True)
    return np.hstack([np.cos(angle / 2), np.sinc(angle / (2 * np.pi)) * v / 2])


def _times(a, b) -> np.ndarray:
    """Quaternion products ``a b`` (scalar first), row by row."""
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        -1,
    )
