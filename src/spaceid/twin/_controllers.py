"""The controllers of the Cepheus twin: ros_control-like effort controllers and their set points.

Position-controlled joints (the arm) run ``effort_controllers/JointPositionController`` (PD on the
encoder reading, optional integral term), velocity-controlled joints (the reaction wheel)
``effort_controllers/JointVelocityController`` (PI on the finite-difference rate); the gains are
:class:`~spaceid.twin.Controllers`. Both follow ``control_toolbox::Pid``: the integral term is
updated first, clamped, then the effort formed. Set points come per control tick from a
reference (a :class:`~spaceid.motion.FourierTrajectory` or a callable of the phase time) and a
wheel speed, or hold the last command. The optional feed-forward
(``Controllers(feedforward=True)``) adds the free-floating inverse dynamics of the reference with
the twin's true model; it reads the true base velocity (on the robot it would come from the
motion capture). :func:`planned_feedforward` is what a lab can do instead: the same inverse
dynamics planned offline from its own model, the base velocity predicted from momentum
conservation, given to :func:`~spaceid.twin.run_twin` as ``effort``. :func:`computed_torque` is
a model-based state-feedback law for :func:`~spaceid.twin.run_twin`'s ``controller`` hook: joint
computed torque through the free-floating inertia ``H*`` and bias torque of any model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._errors import SpaceidError
from ..motion import FourierTrajectory
from ._plant import _planar_model, _symmetric, planar_pinocchio
from ._settings import PID, Controllers, _number

__all__ = ["planned_feedforward", "computed_torque"]


@dataclass(frozen=True)
class _Gains:
    """The controller of every joint, arrays of shape (n_joints,) in model joint order."""

    pos_mask: np.ndarray  # position-controlled
    vel_mask: np.ndarray  # velocity-controlled (neither: unactuated)
    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    i_clamp: np.ndarray


def _controller_gains(controllers: Controllers, joints) -> _Gains:
    """The :class:`_Gains` of ``controllers`` for the model's ``joints`` (zero gains where none)."""
    gains = {**controllers.position, **controllers.velocity}
    pid = [gains.get(j, PID()) for j in joints]
    return _Gains(
        pos_mask=np.array([j in controllers.position for j in joints]),
        vel_mask=np.array([j in controllers.velocity for j in joints]),
        kp=np.array([g.p for g in pid]),
        ki=np.array([g.i for g in pid]),
        kd=np.array([g.d for g in pid]),
        i_clamp=np.array([g.i_clamp for g in pid]),
    )


# ------------------------------------------------------------------ set points ----------------


def _setpoints(gains: _Gains, joints, reference, wheel_speed, tau, command0):
    """Set points at the phase times ``tau`` (n_t,) [s].

    Parameters
    ----------
    gains : _Gains
        Which joints are position- and velocity-controlled.
    joints : sequence of str
        The model joints.
    reference, wheel_speed
        As :func:`~spaceid.twin.run_twin`; None holds ``command0``.
    tau : ndarray of shape (n_t,)
        Time since the start of the phase [s].
    command0 : ndarray of shape (n,)
        The last commands before the phase.

    Returns
    -------
    command, rate, accel : ndarray of shape (n_t, n)
        Commands (position joints [rad], velocity joints [rad/s]), and the reference rate
        [rad/s] and acceleration [rad/s^2] of the position joints (zero elsewhere).
    """
    n_t, n = len(tau), len(joints)
    command = np.tile(command0, (n_t, 1))
    rate = np.zeros((n_t, n))
    accel = np.zeros((n_t, n))
    pos = np.flatnonzero(gains.pos_mask)
    if reference is not None:
        wanted = [joints[i] for i in pos]
        if isinstance(reference, FourierTrajectory):
            q_ref, qd_ref, qdd_ref = _trajectory_setpoints(reference, wanted, tau)
        elif callable(reference):
            q_ref, qd_ref, qdd_ref = _callable_setpoints(reference, wanted, tau)
        else:
            raise SpaceidError(
                "`reference` must be a FourierTrajectory, a callable t -> (q_ref, qd_ref) or None, "
                f"got {type(reference).__name__}"
            )
        if not (np.all(np.isfinite(q_ref)) and np.all(np.isfinite(qd_ref)) and np.all(np.isfinite(qdd_ref))):
            raise SpaceidError("`reference`: the set points contain NaN or infinite values")
        command[:, pos], rate[:, pos], accel[:, pos] = q_ref, qd_ref, qdd_ref
    vel = np.flatnonzero(gains.vel_mask)
    if wheel_speed is not None and len(vel):
        command[:, vel] = _velocity_setpoints(wheel_speed, tau, len(vel))
    return command, rate, accel


def _trajectory_setpoints(trajectory: FourierTrajectory, wanted, tau):
    """``q, qd, qdd`` (n_t, len(wanted)) of ``trajectory`` for the joints ``wanted`` (matched by
    name), held at the end value after its duration."""
    if set(trajectory.joints) != set(wanted):
        raise SpaceidError(
            f"`reference` drives joints ({', '.join(trajectory.joints)}) but the position-controlled "
            f"joints are ({', '.join(wanted)}): give a trajectory for these joints or change "
            "controllers.position"
        )
    order = [trajectory.joints.index(j) for j in wanted]
    q_ref, qd_ref, qdd_ref = (x[:, order] for x in trajectory.evaluate(np.minimum(tau, trajectory.duration)))
    after = tau > trajectory.duration
    qd_ref[after], qdd_ref[after] = 0.0, 0.0
    return q_ref, qd_ref, qdd_ref


def _callable_setpoints(reference, wanted, tau):
    """``q, qd, qdd`` (n_t, len(wanted)) from ``reference(tau) -> (q, qd[, qdd])``; without
    ``qdd`` the acceleration is the numerical derivative of ``qd``."""
    n_t = len(tau)
    out = reference(tau)
    if not isinstance(out, tuple) or len(out) not in (2, 3):
        raise SpaceidError("`reference`(t) must return (q_ref, qd_ref) or (q_ref, qd_ref, qdd_ref)")
    try:
        q_ref, qd_ref = (np.asarray(x, float).reshape(n_t, -1) for x in out[:2])
        qdd_ref = (
            np.asarray(out[2], float).reshape(n_t, -1)
            if len(out) == 3
            else (np.gradient(qd_ref, tau, axis=0) if n_t > 1 else np.zeros_like(qd_ref))
        )
    except (TypeError, ValueError):
        raise SpaceidError(
            f"`reference`(t) must return arrays of shape (len(t), n_position_joints) = ({n_t}, {len(wanted)})"
        ) from None
    if q_ref.shape[1] != len(wanted) or qd_ref.shape[1] != len(wanted):
        raise SpaceidError(
            f"`reference`(t) returned {q_ref.shape[1]} columns; expected one per position-controlled "
            f"joint ({', '.join(wanted)})"
        )
    return q_ref, qd_ref, qdd_ref


def _effort_setpoints(gains: _Gains, effort, tau) -> np.ndarray | None:
    """Feed-forward efforts (n_t, n) [N m] from ``effort(tau) -> (n_t, n_position_joints)``
    (zero on the other joints), or None without one."""
    if effort is None:
        return None
    if not callable(effort):
        raise SpaceidError(f"`effort` must be a callable t -> efforts (e.g. from planned_feedforward) or None, "
                           f"got {type(effort).__name__}")  # fmt: skip
    pos = np.flatnonzero(gains.pos_mask)
    values = effort(tau)
    try:
        values = np.asarray(values, float).reshape(len(tau), len(pos))
    except (TypeError, ValueError):
        raise SpaceidError(f"`effort`(t) must return an array of shape (len(t), n_position_joints) = "
                           f"({len(tau)}, {len(pos)})") from None  # fmt: skip
    if not np.all(np.isfinite(values)):
        raise SpaceidError("`effort`: the feed-forward efforts contain NaN or infinite values")
    out = np.zeros((len(tau), len(gains.pos_mask)))
    out[:, pos] = values
    return out


def _velocity_setpoints(wheel_speed, tau, n_vel):
    """Velocity commands (n_t, n_vel) [rad/s] from a number or a callable of the phase time."""
    n_t = len(tau)
    if callable(wheel_speed):
        w = np.asarray(wheel_speed(tau), float)
        w = np.broadcast_to(w.reshape(n_t, -1) if w.ndim else w, (n_t, n_vel))
    else:
        w = np.full((n_t, n_vel), _number("`wheel_speed` [rad/s]", wheel_speed))
    if not np.all(np.isfinite(w)):
        raise SpaceidError("`wheel_speed`: the set points contain NaN or infinite values")
    return w


# ------------------------------------------------------------------ control laws --------------


def _pid_law(gains: _Gains, dt):
    """The effort controllers as a function ``(qm, prev, command, rate, i_term) -> efforts``.

    ``qm`` and ``prev`` are this tick's and the previous tick's encoder readings [rad], ``command``
    and ``rate`` the set points of the tick, all lists of n Python floats; ``i_term`` (list of n,
    [N m]) is updated in place. Rates are the finite difference ``(qm - prev) / dt`` of the
    readings, as the hardware interface forms them. Unactuated joints get zero effort.
    """
    kind = [1 if p else (2 if w else 0) for p, w in zip(gains.pos_mask, gains.vel_mask)]
    kp, kd = gains.kp.tolist(), gains.kd.tolist()
    kidt = (gains.ki * dt).tolist()
    clamp = gains.i_clamp.tolist()
    inv_dt = 1.0 / dt
    joints_idx = range(len(kind))

    def efforts(qm, prev, cmd, rt, i_term):
        effort = [0.0] * len(kind)
        for j in joints_idx:
            kj = kind[j]
            if not kj:
                continue
            qdh = (qm[j] - prev[j]) * inv_dt
            # control_toolbox::Pid: integral term updated first, clamped, then the command
            e = cmd[j] - (qm[j] if kj == 1 else qdh)
            it = i_term[j] + kidt[j] * e
            it = -clamp[j] if it < -clamp[j] else (clamp[j] if it > clamp[j] else it)
            i_term[j] = it
            u = kp[j] * e + it
            if kj == 1:
                u += kd[j] * (rt[j] - qdh)
            effort[j] = u
        return effort

    return efforts


def _free_floating_efforts(pmodel, data, q, v, a_joints, M) -> np.ndarray:
    """Joint efforts (n,) [N m] that give the joints the accelerations ``a_joints`` (n,) at the
    state ``q`` (nq,), ``v`` (nv,) with the base unactuated: ``pin.rnea`` with the base
    accelerations solved so that the base receives no force; ``M`` (nv, nv) the joint-space
    inertia at ``q``. The base has ``nv - n`` coordinates (3 on the table, 6 for a free flyer)."""
    import pinocchio as pin

    nb = pmodel.nv - len(a_joints)
    af = np.zeros(pmodel.nv)
    af[nb:] = a_joints
    t_ff = pin.rnea(pmodel, data, q, v, af)
    a_base = -np.linalg.solve(M[:nb, :nb], t_ff[:nb])
    return t_ff[nb:] + M[nb:, :nb] @ a_base


def _feedforward_law(pmodel, pos_mask):
    """The inverse-dynamics feed-forward as a function ``(q_pin, v_pin, command, rate, accel) ->
    efforts`` (list of n [N m], zero on joints that are not position-controlled).

    ``q_pin``, ``v_pin`` (nq,) are the true state, ``command``, ``rate``, ``accel`` (n,) the set
    points: :func:`_free_floating_efforts` at the reference joint state with the current base
    velocity, the other joints' accelerations zero.
    """
    import pinocchio as pin

    data = pmodel.createData()
    pos_idx = 3 + np.flatnonzero(pos_mask)
    posf = pos_mask.astype(float)

    def efforts(q, v, cmd, rt, acc):
        qf, vf = q.copy(), v.copy()
        qf[pos_idx], vf[pos_idx] = cmd[pos_idx - 3], rt[pos_idx - 3]
        M = _symmetric(pin.crba(pmodel, data, qf))
        return (_free_floating_efforts(pmodel, data, qf, vf, acc * posf, M) * posf).tolist()

    return efforts


def planned_feedforward(reference, t, *, settings, model=None, wheel_speed: float = 0.0) -> np.ndarray:
    """Feed-forward efforts of the position-controlled joints planned offline from a model.

    What a lab computes before a run from its own model and the reference alone, reading no
    state of the robot: the free-floating inverse dynamics of the reference (the model's base
    unactuated and never measured), with the base velocity that keeps the total momentum zero
    (a system started at rest) and the velocity-controlled joints (the reaction wheel) at
    ``wheel_speed`` relative to the base. Pass it to :func:`~spaceid.twin.run_twin` as
    ``effort``.

    Parameters
    ----------
    reference : FourierTrajectory or callable
        As :func:`~spaceid.twin.run_twin`.
    t : array_like of shape (n_t,)
        Time since the start of the phase [s].
    settings : TwinSettings
        Which joints are position- and velocity-controlled, and the default model.
    model : Model or str, optional
        The lab's model (default ``settings.model``: the nominal preset, with a full tank and a
        level table, not the twin's state).
    wheel_speed : float
        Velocity-controlled joints' rate relative to the base [rad/s].

    Returns
    -------
    ndarray of shape (n_t, n_position_joints)
        Efforts [N m], position-controlled joints in model order.
    """
    import pinocchio as pin

    model = _planar_model(settings.model if model is None else model)
    joints = model.joints
    gains = _controller_gains(settings.controllers, joints)
    tau = np.atleast_1d(np.asarray(t, float))
    q, qd, qdd = _setpoints(gains, joints, reference, _number("`wheel_speed` [rad/s]", wheel_speed), tau,
                            np.zeros(len(joints)))  # fmt: skip
    q[:, gains.vel_mask] = 0.0  # commands of velocity joints are rates; the rotor angle does not matter
    qd[:, gains.vel_mask] = wheel_speed
    pmodel = planar_pinocchio(model)
    data = pmodel.createData()
    Q = np.concatenate([np.zeros((len(tau), 3)), q], axis=1)  # the base pose does not matter on a level table
    M = _symmetric(np.array([pin.crba(pmodel, data, x) for x in Q]))
    v_base = -np.linalg.solve(M[:, :3, :3], M[:, :3, 3:] @ qd[..., None])[..., 0]  # zero linear and angular momentum
    V = np.concatenate([v_base, qd], axis=1)
    efforts = np.array([_free_floating_efforts(pmodel, data, *row) for row in zip(Q, V, qdd, M)])
    return efforts[:, gains.pos_mask]



def computed_torque(model, reference, times, *, kp=100.0, kd=20.0, momentum=(0.0, 0.0, 0.0), stride: int = 5):
    """A joint computed-torque law through a model's free-floating dynamics, for
    ``run_twin(..., controller=computed_torque(...))``.

    At the tick ``t_k`` the law gives ``tau = H*_k (qdd_r + kd (qd_r - qd) + kp (q_r - q)) + b_k``
    with the measured ``q``, ``qd`` and the reference at ``t_k``; ``H*_k`` and ``b_k`` are the
    model's reduced inertia and bias torque (:meth:`~spaceid.identified.IdentifiedModel.reduced_inertia`,
    ``bias_torque``) along the reference, evaluated in one batched call on every ``stride``-th
    tick and linear between them (a call per control tick would cost ~1 ms): with an exact model
    the joint errors obey ``e'' + kd e' + kp e = 0`` to first order in the errors. The gains are
    accelerations per unit error, so the same gains suit every model and a model's errors show
    as tracking errors (``H*`` off by a fraction ``d`` gives errors of about ``d |qdd_r| / kp``).

    Parameters
    ----------
    model : IdentifiedModel
        Anything with ``reduced_inertia(q)`` and ``bias_torque(q, qd, momentum)``: the
        :class:`~spaceid.identified.IdentifiedModel` of an identification, or the same with the
        true or a CAD prior's minimal parameters (:meth:`~spaceid.identified.IdentifiedModel.with_values`).
    reference : callable
        ``reference(t) -> (q_r, qd_r, qdd_r)``: every joint's reference at the times ``t`` (n_t,)
        [s], arrays of shape (n_t, n_joints) in model order [rad, rad/s, rad/s^2].
    times : array_like of shape (n_t,)
        The control ticks of the run [s], evenly spaced (``state.t + arange(n_steps + 1) /
        controllers.rate``); the law uses the nearest one (the first or last outside).
    kp : float or array_like of shape (n_joints,)
        Position gains [1/s^2]; default 100 (a natural frequency of 10 rad/s). Zero on a
        reaction wheel: only its rate matters.
    kd : float or array_like of shape (n_joints,)
        Rate gains [1/s]; default 20 (critical damping with ``kp = 100``).
    momentum : array_like of shape (3,)
        Total angular momentum of the system [N m s]; default zero (started at rest).
    stride : int
        Ticks between evaluations of ``H*`` and ``b``; default 5 (5 ms at 1 kHz).

    Returns
    -------
    callable
        ``law(t, q, qd, base_yaw, base_wz) -> efforts`` (n_joints,) [N m].
    """
    times = np.asarray(times, float)
    if times.ndim != 1 or len(times) < 2 or not np.all(np.diff(times) > 0):
        raise SpaceidError("computed_torque: `times` must be increasing control ticks, shape (n_t,) with n_t >= 2")
    if int(stride) < 1:
        raise SpaceidError(f"computed_torque: `stride` must be a positive number of ticks, got {stride!r}")
    q_r, qd_r, qdd_r = (np.asarray(x, float) for x in reference(times))
    coarse = np.r_[np.arange(0, len(times) - 1, int(stride)), len(times) - 1]
    reduced_c = model.reduced_inertia(q_r[coarse])
    bias_c = model.bias_torque(q_r[coarse], qd_r[coarse], momentum=np.asarray(momentum, float))
    w = np.interp(np.arange(len(times)), coarse, np.arange(len(coarse)))  # fractional coarse index per tick
    i = np.minimum(w.astype(int), len(coarse) - 2)
    f = (w - i)[:, None]
    bias = (1 - f) * bias_c[i] + f * bias_c[i + 1]
    reduced = (1 - f[..., None]) * reduced_c[i] + f[..., None] * reduced_c[i + 1]
    kp, kd = np.asarray(kp, float), np.asarray(kd, float)
    t0, dt, last = times[0], times[1] - times[0], len(times) - 1

    def law(t, q, qd, base_yaw, base_wz):
        k = min(max(int(round((t - t0) / dt)), 0), last)
        return reduced[k] @ (qdd_r[k] + kd * (qd_r[k] - qd) + kp * (q_r[k] - q)) + bias[k]

    return law
