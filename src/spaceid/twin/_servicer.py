"""The servicer twin: a spatial free-floating robot under computed-torque joint control, with the
sensors a servicer has (docs/theory/twin-spatial.md).

The plant is Pinocchio's model of the robot with a free-flyer root (:func:`spaceid.models.to_pinocchio`),
in zero gravity, integrated by the classical RK4 on the embedded coordinates (base position,
unit quaternion, joints; :func:`~spaceid.twin._plant._rk4_stepper` with
:func:`~spaceid.twin.free_flyer_rate`) at ``control.substeps`` steps per control period. At every
control tick the encoders are read (white noise, quantised), the computed-torque law of the
lab's model (:class:`~spaceid.twin.JointControl`, off by 15 % by default) gives the efforts from
the readings and their one-period difference, the efforts are saturated at the torque limits
and held over the period. The joint torques are internal: the angular and linear momentum stay
what they were, which the run checks with :func:`spaceid.dynamics.angular_momentum` on the true
states (an independent formula) and records (``meta["momentum_drift"]``).

After the loop the sensor streams are formed from the true history: joint states at the
encoders' rate (no velocities: no joint-rate sensor), star-tracker frames (noise, latency, lost
frames) and gyro samples (bias, random walk, noise) on the joint-state stamps.
:func:`servicer_log` reads them as a lab reads a recording (:func:`spaceid.data.to_log`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from .._errors import SpaceidError, finite_array
from ..data import JointStates, Log, Recording, quat_to_matrix, to_log
from ..dynamics import angular_momentum
from ..models import Model, load_model, perturbed_model, to_pinocchio
from ._controllers import _controller_gains, _free_floating_efforts, _setpoints
from ._effects import _effort_limits
from ._plant import _rk4_rows, _rk4_stepper, _symmetric, free_flyer_rate
from ._run import _n_steps
from ._sensors import _every, _gyro_samples, _quantise, _star_tracker_frames
from ._settings import PID, Controllers, ServicerSettings

__all__ = ["ServicerState", "ServicerRun", "servicer_model", "cad_model", "run_servicer", "servicer_log"]


@dataclass(frozen=True, eq=False)
class ServicerState:
    """State of the servicer twin at one instant: the start of a phase.

    Attributes
    ----------
    t : float
        Time [s].
    base_quat : array_like of shape (4,)
        Base attitude ``[w, x, y, z]``, base to inertial. Default identity.
    q, qd : ndarray of shape (n_joints,) or None
        Joint positions [rad] and rates [rad/s]; None: the reference's at the phase start.
    momentum : array_like of shape (3,)
        Angular momentum of the system, inertial axes [N m s]; with zero linear momentum it sets
        the base velocity (unless ``base_w`` and ``base_v`` are given). Default zero: at rest.
    base_w, base_v : array_like of shape (3,) or None
        Base angular velocity [rad/s] and origin velocity [m/s], base axes: given together (a
        previous run's ``state``), they replace ``momentum``.
    base_position : array_like of shape (3,)
        Base origin in the inertial frame [m]. Default zero.
    gyro_walk : array_like of shape (3,)
        The gyro bias's random walk so far [rad/s]. Default zero.
    encoder_prev : ndarray of shape (n_joints,) or None
        The controllers' count one period before ``t`` [rad]; None: the current one.
    """

    t: float = 0.0
    base_quat: np.ndarray = (1.0, 0.0, 0.0, 0.0)
    q: np.ndarray | None = None
    qd: np.ndarray | None = None
    momentum: np.ndarray = (0.0, 0.0, 0.0)
    base_w: np.ndarray | None = None
    base_v: np.ndarray | None = None
    base_position: np.ndarray = (0.0, 0.0, 0.0)
    gyro_walk: np.ndarray = (0.0, 0.0, 0.0)
    encoder_prev: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class ServicerRun:
    """The outcome of one phase of the servicer twin.

    Attributes
    ----------
    recording : Recording
        What the servicer logs: joint states at the encoders' rate (readings, no velocities, the
        applied efforts) and the star tracker's frames (stamped on arrival, positions zero).
    gyro : ndarray of shape (n, 3)
        Gyro samples at the joint-state stamps, base axes [rad/s].
    truth : Log
        The true motion at every control tick (spatial; base rate in base axes), with
        ``base_position`` [m].
    base_velocity : ndarray of shape (n_ticks, 3)
        True base origin velocity, base axes [m/s].
    momentum : ndarray of shape (n_ticks, 3)
        :func:`spaceid.dynamics.angular_momentum` of the true states, inertial axes [N m s].
    effort : ndarray of shape (n_ticks, n_joints)
        Applied (saturated) efforts from each tick to the next [N m]; the last row repeats.
    state : ServicerState
        The final state (the start of a next phase).
    meta : dict
        Seeds, settings, the CAD model's record, frames and drops, the tracking error, the gyro
        bias walk at the end, and ``momentum_drift``: the largest change of the momentum [N m s]
        and that change relative to ``momentum_scale`` (the largest momentum of the joint
        motion alone, which the base's motion cancels).
    """

    recording: Recording
    gyro: np.ndarray
    truth: Log
    base_velocity: np.ndarray
    momentum: np.ndarray
    effort: np.ndarray
    state: ServicerState
    meta: dict = field(default_factory=dict, compare=False)


# ------------------------------------------------------------------ models --------------------


def servicer_model(spec) -> Model:
    """The twin's spatial model from ``ServicerSettings.model`` (a Model, a preset name or a path)."""
    model = spec if isinstance(spec, Model) else load_model(spec)
    if model.planar:
        raise SpaceidError(f"settings.model: model {model.name} is planar: the servicer twin needs a spatial model "
                           "(a URDF, or a YAML model without 'planar: true'); planar models fly on TwinSettings")
    return model


def cad_model(settings: ServicerSettings) -> Model:
    """The lab's model that the controllers use (and the experiment's CAD prior):
    ``settings.control.model``, or the twin's model with every mass and principal moment off by
    ``control.model_error`` (:func:`spaceid.models.perturbed_model`, ``exact``, seeded
    ``control.model_seed``)."""
    model, control = servicer_model(settings.model), settings.control
    if control.model is not None:
        cad = servicer_model(control.model)
        if cad.joints != model.joints:
            raise SpaceidError(f"settings.control.model: its joints ({', '.join(cad.joints)}) are not the twin's "
                               f"({', '.join(model.joints)}): give a model of the same robot")  # fmt: skip
        return cad
    return perturbed_model(model, control.model_seed, mass=control.model_error, moments=control.model_error,
                           exact=True)  # fmt: skip


# ------------------------------------------------------------------ the start state -----------


def _start(pmodel, state: ServicerState, q_ref, qd_ref, n) -> tuple:
    """``(q_pin, v_pin, encoder_prev)`` at the start of a phase from ``state`` (joints default to
    the reference's ``q_ref``, ``qd_ref``)."""
    import pinocchio as pin

    if not isinstance(state, ServicerState):
        raise SpaceidError(f"`state` must be a ServicerState (e.g. a previous run's .state), got "
                           f"{type(state).__name__}")  # fmt: skip
    q = q_ref if state.q is None else finite_array(state.q, (n,), "state.q", "twin")
    qd = qd_ref if state.qd is None else finite_array(state.qd, (n,), "state.qd", "twin")
    quat = finite_array(state.base_quat, (4,), "state.base_quat", "twin")
    if abs(np.linalg.norm(quat) - 1) > 1e-6:
        raise SpaceidError(f"state.base_quat must be a unit quaternion [w, x, y, z], got norm {np.linalg.norm(quat):g}")
    q_pin = np.r_[finite_array(state.base_position, (3,), "state.base_position", "twin"), quat[1:], quat[0], q]
    v_pin = np.r_[np.zeros(6), qd]
    if (state.base_w is None) != (state.base_v is None):
        raise SpaceidError("state.base_w and state.base_v go together (a previous run's state): give both, or "
                           "neither and `momentum`")  # fmt: skip
    if state.base_w is not None:
        v_pin[:3] = finite_array(state.base_v, (3,), "state.base_v", "twin")
        v_pin[3:6] = finite_array(state.base_w, (3,), "state.base_w", "twin")
    else:  # the base rows of M v are the momentum about the base origin in base axes (linear zero)
        h = finite_array(state.momentum, (3,), "state.momentum", "twin")
        M = _symmetric(pin.crba(pmodel, pmodel.createData(), q_pin))
        wanted = np.r_[np.zeros(3), quat_to_matrix(quat).T @ h]
        v_pin[:6] = np.linalg.solve(M[:6, :6], wanted - M[:6, 6:] @ qd)
    prev = None if state.encoder_prev is None else finite_array(state.encoder_prev, (n,), "state.encoder_prev",
                                                                 "twin")  # fmt: skip
    return q_pin, v_pin, prev


# ------------------------------------------------------------------ the control loop ----------


def _control_law(cad_pmodel, control, limit):
    """The computed-torque law of :class:`~spaceid.twin.JointControl` through the lab's model:
    ``law(q_pin, v_pin, qm, qdm, q_r, qd_r, qdd_r) -> efforts`` (n,) [N m], saturated; the base
    coordinates of ``q_pin``, ``v_pin`` are the true ones, the joints' the measured ``qm``, ``qdm``."""
    import pinocchio as pin

    data = cad_pmodel.createData()
    kp, kd = control.kp, control.kd

    def law(q_pin, v_pin, qm, qdm, q_r, qd_r, qdd_r):
        qc, vc = q_pin.copy(), v_pin.copy()
        qc[7:], vc[6:] = qm, qdm
        M = _symmetric(pin.crba(cad_pmodel, data, qc))
        tau = _free_floating_efforts(cad_pmodel, data, qc, vc, qdd_r + kd * (qd_r - qdm) + kp * (q_r - qm), M)
        return np.clip(tau, -limit, limit)

    return law


def _fly(pmodel, law, q_pin, v_pin, prev, command, rate, accel, enc_noise, resolution, dt, substeps):
    """The control loop over ``len(command) - 1`` periods: returns ``Q (n_t, nq)``, ``V (n_t, nv)``
    (the true state at the ticks), ``QM (n_t, n)`` (the logged encoder readings: noise, then
    quantised) and ``EFF (n_t, n)``. The controllers read the servo's own count (quantised, without
    the logged readings' white noise) and its difference over the period (``prev``: the count
    one period before the start, None: the first one)."""
    step = _rk4_stepper(pmodel, dt / substeps, free_flyer_rate)
    W = _rk4_rows(q_pin, v_pin)
    tau = np.zeros(pmodel.nv)
    Q, V, QM, EFF = [], [], [], []
    for k in range(len(command)):
        Q.append(W[0].copy())
        V.append(W[1].copy())
        QM.append(_quantise(W[0][7:] + enc_noise[k], resolution))  # the logged joint encoders
        if k == len(command) - 1:
            EFF.append(EFF[-1] if k else np.zeros(len(QM[-1])))
            break
        qc = _quantise(W[0][7:], resolution)  # the servo's own (motor-side) reading: counts, no white noise
        prev = qc if prev is None else prev
        tau[6:] = law(W[0], W[1], qc, (qc - prev) / dt, command[k], rate[k], accel[k])
        EFF.append(tau[6:].copy())
        for _ in range(substeps):
            step(W, tau)
        prev = qc
    return np.array(Q), np.array(V), np.array(QM), np.array(EFF)


def _quat_wxyz(Q) -> np.ndarray:
    """Base quaternions ``[w, x, y, z]`` (n, 4) from Pinocchio configurations (n, nq)."""
    return np.column_stack([Q[:, 6], Q[:, 3:6]])


def _momentum_record(model: Model, truth: Log) -> tuple:
    """``(h (n, 3), record)``: the angular momentum of the true states (inertial axes) and its
    largest change, absolute [N m s] and relative to the momentum of the joint motion alone."""
    h = angular_momentum(model, truth.q, truth.qd, truth.base_w, truth.base_quat)
    joints_only = angular_momentum(model, truth.q, truth.qd, np.zeros_like(truth.base_w))
    change = float(np.abs(h - h[0]).max())
    scale = float(max(np.linalg.norm(joints_only, axis=1).max(), np.linalg.norm(h[0]), 1e-300))
    return h, {"momentum_start": h[0].tolist(), "momentum_drift": change, "momentum_scale": scale,
               "momentum_drift_relative": change / scale}  # fmt: skip


# ------------------------------------------------------------------ a phase -------------------


def run_servicer(reference, *, duration: float, settings: ServicerSettings | None = None,
                 state: ServicerState | None = None, seed: int = 0) -> ServicerRun:
    """Fly the servicer twin for one phase.

    Parameters
    ----------
    reference : FourierTrajectory or callable or None
        The joints' reference: a :class:`~spaceid.motion.FourierTrajectory` of every joint
        (matched by name, held at its end value after its duration), a callable ``reference(t)
        -> (q_ref, qd_ref[, qdd_ref])`` of the phase time ``t`` (n,) [s] with arrays of shape (n,
        n_joints) in model order, or None to hold the joints where they are.
    duration : float
        Length of the phase [s]; rounded to a whole number of control periods.
    settings : ServicerSettings, optional
        Default ``ServicerSettings()`` (the dual-arm servicer).
    state : ServicerState, optional
        Start state; default at rest (zero momentum), the joints on the reference.
    seed : int
        Seed of the sensors: the encoder noise, the star tracker's noise and lost frames and the
        gyro's walk and noise draw from independent children of ``SeedSequence(seed)``
        (recorded in ``meta``).

    Returns
    -------
    ServicerRun
    """
    import pinocchio as pin

    settings = ServicerSettings() if settings is None else settings
    if not isinstance(settings, ServicerSettings):
        raise SpaceidError(f"`settings` must be a ServicerSettings(...), got {type(settings).__name__}")
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise SpaceidError(f"`seed` must be an integer, got {seed!r}") from None
    model, control = servicer_model(settings.model), settings.control
    cad, joints, n = cad_model(settings), model.joints, len(model.joints)
    state = ServicerState() if state is None else state
    dt = 1.0 / control.rate
    times = float(state.t) + dt * np.arange(_n_steps(duration, dt) + 1)
    gains = _controller_gains(Controllers(position={j: PID() for j in joints}, velocity={}), joints)
    q0 = np.zeros(n) if state.q is None else state.q
    command, rate, accel = _setpoints(gains, joints, reference, None, times - times[0], np.asarray(q0, float))
    pmodel = to_pinocchio(model)
    pmodel.gravity = pin.Motion.Zero()
    cad_pmodel = to_pinocchio(cad)
    cad_pmodel.gravity = pin.Motion.Zero()
    q_pin, v_pin, prev = _start(pmodel, state, command[0], rate[0], n)
    enc_rng, tracker_seed, gyro_seed = np.random.SeedSequence(seed).spawn(3)
    enc_noise = settings.encoders.noise * np.random.default_rng(enc_rng).standard_normal((len(times), n))
    resolution = np.full(n, settings.encoders.resolution)
    law = _control_law(cad_pmodel, control, _effort_limits(settings.torque_limits, model))
    Q, V, QM, EFF = _fly(pmodel, law, q_pin, v_pin, prev, command, rate, accel, enc_noise, resolution, dt,
                         control.substeps)  # fmt: skip
    truth = Log(times, joints, Q[:, 7:], V[:, 6:], _quat_wxyz(Q), V[:, 3:6], False,
                {"source": "spaceid.twin servicer (truth)", "seed": seed}, base_position=Q[:, :3])  # fmt: skip
    momentum, drift = _momentum_record(model, truth)
    ticks = _every(times, settings.encoders.rate, "encoders.rate")
    ticks = ticks[times[ticks] < times[-1] - 1e-9 * dt]  # [t0, t_end): the next phase continues the grid
    frames, n_frames, n_dropped = _star_tracker_frames(settings.star_tracker, times, truth.base_quat,
                                                       tracker_seed.generate_state(1)[0])  # fmt: skip
    gyro, walk = _gyro_samples(settings.gyro, times[ticks], truth.base_w[ticks], gyro_seed.generate_state(1)[0],
                               state.gyro_walk)  # fmt: skip
    meta = {
        "source": "spaceid.twin servicer", "model": model.source or model.name, "seed": seed,
        "sensor seeds": "encoders, star tracker, gyro: SeedSequence(seed).spawn(3)",
        "settings": settings.to_dict(), "cad model": cad.source or f"{model.name} perturbed",
        "t_start": float(times[0]), "t_end": float(times[-1]),
        "star_tracker_frames": n_frames, "star_tracker_dropped": n_dropped,
        "gyro_walk_end": walk[-1].tolist() if len(walk) else list(state.gyro_walk),
        "tracking_rms": dict(zip(joints, np.sqrt(np.mean((Q[:-1, 7:] - command[:-1]) ** 2, axis=0)).tolist())),
        **drift,
    }  # fmt: skip
    joint_states = JointStates(t=times[ticks], names=tuple(joints), position=QM[ticks], velocity=None,
                               effort=EFF[ticks])  # fmt: skip
    final = ServicerState(t=float(times[-1]), base_quat=truth.base_quat[-1], q=Q[-1, 7:], qd=V[-1, 6:],
                          momentum=momentum[-1], base_w=truth.base_w[-1], base_v=V[-1, :3], base_position=Q[-1, :3],
                          gyro_walk=meta["gyro_walk_end"],
                          encoder_prev=_quantise(Q[-2, 7:], resolution))  # fmt: skip
    return ServicerRun(Recording(joint_states, frames, meta), gyro, truth, V[:, :3], momentum, EFF, final, meta)


# ------------------------------------------------------------------ the lab's reading ---------


def servicer_log(run: ServicerRun, settings: ServicerSettings | None = None, *, base_rate: str = "gyro",
                 max_gap: float | None = None) -> Log:
    """A run's sensor streams read as a lab reads its recording.

    The joint states and star-tracker frames go through :func:`spaceid.data.to_log` (the time
    base: the joint-state stamps; the frames' stamps moved back by the known latency; the
    attitude smoothed, differentiated and interpolated; the joint rates differentiated from the
    encoder readings, with the encoder count as ``quantum``); the base rate is then the gyro's
    (default) or the differentiated attitude's.

    Parameters
    ----------
    run : ServicerRun
    settings : ServicerSettings, optional
        The settings the run was flown with, for what the lab knows of its sensors (the
        star tracker's latency, the encoder count); default ``ServicerSettings()``.
    base_rate : {"gyro", "attitude"}
        The base rate's source.
    max_gap : float, optional
        Longest time without a frame that is bridged [s]; default ten star-tracker periods.

    Returns
    -------
    Log
        Spatial, joint rates and (with ``attitude``) the base rate differentiated; ``meta``:
        ``base_rate``, ``differentiation`` (the joints', and the base's with ``attitude``) and the
        recording's provenance.
    """
    settings = ServicerSettings() if settings is None else settings
    if base_rate not in ("gyro", "attitude"):
        raise SpaceidError(f"`base_rate` must be 'gyro' or 'attitude', got {base_rate!r}")
    model = servicer_model(settings.model)
    tracker = settings.star_tracker
    log = to_log(run.recording, joints=model.joints, planar=False, pose_latency=tracker.latency,
                 max_gap=10.0 / tracker.rate if max_gap is None else max_gap,
                 quantum=settings.encoders.resolution or None)  # fmt: skip
    meta = dict(log.meta, base_rate=base_rate)
    if base_rate == "attitude":
        return replace(log, meta=meta)
    t = run.recording.joints.t  # the gyro is sampled at the joint-state stamps
    gyro = np.column_stack([np.interp(log.t, t, run.gyro[:, i]) for i in range(3)])
    # the base rate is measured now, not differentiated: only the joints' record stays, so that
    # identification models the gyro's own noise (and may estimate its bias), not the attitude's
    # derivative
    meta["differentiation"] = {k: v for k, v in meta["differentiation"].items() if k != "base"}
    return replace(log, base_w=gyro, meta=meta)
