"""Runs of the Cepheus twin: the hardware loop, its phases and their results.

The hardware loop runs at the control rate. At every tick it reads the encoders
(:mod:`~spaceid.twin._sensors`), runs the controllers on the readings
(:mod:`~spaceid.twin._controllers`), saturates the efforts, evaluates joint friction, thrust and
air-bearing friction from the state at the start of the step (:mod:`~spaceid.twin._effects`) and
takes one RK4 step of the plant with all of them held (:mod:`~spaceid.twin._plant`), then drains
the tank. After the loop the sensor streams are formed from the per-tick histories. A grasp
(:class:`~spaceid.twin.Capture`) splits the loop at its tick: the impact changes the rates
(:mod:`~spaceid.twin._capture`) and the loop goes on with the combined model.

A run covers ``[state.t, state.t + duration]``: the true history includes both ends, the sensor
streams are stamped on absolute time grids in ``[t0, t_end)`` (so consecutive phases continue the
same grids) and :func:`join_runs` drops the repeated boundary sample. The state carries the
controller memory (set points, integral terms, last encoder reading), so a phase split in two
gives the same true motion as one phase, also across a grasp: the true history holds the state
just before the grasp at its tick, the state after it starts the next step (and a phase that ends
at the grasp tick leaves the grasp to the next one).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from .._errors import SpaceidError, finite_array
from ..data import JointStates, Log, Poses, Recording, yaw_to_quat
from ..models import Model, attach_payload
from ._capture import _grasp, _grasp_link
from ._controllers import _controller_gains, _effort_setpoints, _feedforward_law, _Gains, _pid_law, _setpoints
from ._effects import (
    _bearing_friction_law,
    _check_dry_base,
    _check_friction_step,
    _effort_limits,
    _joint_friction_coefficients,
    _joint_friction_law,
    _saturation,
    _tank_drain,
    _thrust_per_tick,
    _tilt_table,
    _valves,
)
from ._plant import _base_force, _base_loader, _planar_model, _rk4_rows, _rk4_stepper, planar_pinocchio
from ._sensors import (
    _capture_poses,
    _check_publish_rate,
    _encoder_reader,
    _encoder_resolution,
    _hardware_rates,
    _publish_joint_states,
    _quantise,
)
from ._settings import TwinSettings, _check_joint_names, _number, _set

__all__ = ["TwinState", "TwinRun", "run_twin", "spin_up", "join_runs"]


# ------------------------------------------------------------------ state and result ----------


@dataclass(frozen=True, eq=False)
class TwinState:
    """State of the twin at one instant: the start of a phase.

    Attributes
    ----------
    t : float
        Time [s].
    base_xy : ndarray of shape (2,)
        Base origin in the world (table) frame [m].
    base_yaw : float
        Base yaw [rad] (unwrapped).
    base_vxy : ndarray of shape (2,)
        Base origin velocity, world axes [m/s].
    base_wz : float
        Base yaw rate [rad/s].
    q, qd : ndarray of shape (n_joints,) or None
        Joint positions [rad] and rates [rad/s], model joint order; None: zeros.
    co2_mass : float or None
        CO2 left in the tank [kg]; None: the full tank of the settings.
    command : ndarray of shape (n_joints,) or None
        Last controller set points (position joints [rad], velocity joints [rad/s], others
        ignored); None: hold the current q and qd.
    i_term : ndarray of shape (n_joints,) or None
        Integral terms of the controllers [N m]; None: zeros.
    encoder_prev : ndarray of shape (n_joints,) or None
        Encoder reading one control period before ``t`` [rad]; None: the current reading.
    grasp : dict or None
        The truth record of the grasp once a payload is held (``meta["capture"]`` of the run
        that grasped it; its ``link`` and ``payload["inertial"]`` make the plant the combined
        model); None: no payload held.
    """

    t: float = 0.0
    base_xy: np.ndarray = (0.0, 0.0)
    base_yaw: float = 0.0
    base_vxy: np.ndarray = (0.0, 0.0)
    base_wz: float = 0.0
    q: np.ndarray | None = None
    qd: np.ndarray | None = None
    co2_mass: float | None = None
    command: np.ndarray | None = None
    i_term: np.ndarray | None = None
    encoder_prev: np.ndarray | None = None
    grasp: dict | None = None

    def __post_init__(self):
        for name in ("t", "base_yaw", "base_wz"):
            _set(self, name, _number(f"state.{name}", getattr(self, name)))
        for name in ("base_xy", "base_vxy"):
            _set(self, name, _vector(f"state.{name}", getattr(self, name), 2))
        if self.co2_mass is not None:
            _set(self, "co2_mass", _number("state.co2_mass [kg]", self.co2_mass, low=0.0))

    @property
    def q_pin(self) -> np.ndarray:
        """``[x, y, yaw, q...]`` (requires ``q``)."""
        return np.r_[self.base_xy, self.base_yaw, self.q]

    @property
    def v_pin(self) -> np.ndarray:
        """``[vx, vy, wz, qd...]`` (requires ``qd``)."""
        return np.r_[self.base_vxy, self.base_wz, self.qd]


def _vector(where, value, n):
    """``value`` as a finite float array of shape (n,), or a SpaceidError naming ``where``."""
    return finite_array(value, (n,), where, "twin")


@dataclass(frozen=True, eq=False)
class TwinRun:
    """The outcome of one or more phases.

    Attributes
    ----------
    recording : Recording
        What the lab records: ``/joint_states`` (names in model order) and the mocap poses.
    truth : Log
        True motion at every control tick, planar (``base_w[:, 2]`` the yaw rate).
    base_position : ndarray of shape (n, 2)
        True base origin position, world frame [m].
    base_velocity : ndarray of shape (n, 2)
        True base origin velocity, world axes [m/s].
    effort : ndarray of shape (n, n_joints)
        Applied (saturated) efforts held from each tick to the next [N m]; the last row repeats.
    co2_mass : ndarray of shape (n,)
        CO2 left in the tank [kg].
    state : TwinState
        The final state (start of a next phase).
    meta : dict
        Seeds, settings, model, CO2 mass at start and end, per-phase records; ``capture``: the
        truth record of the grasp once a payload is held (docs/theory/capture.md).
    """

    recording: Recording
    truth: Log
    base_position: np.ndarray
    base_velocity: np.ndarray
    effort: np.ndarray
    co2_mass: np.ndarray
    state: TwinState
    meta: dict = field(default_factory=dict, compare=False)


# ------------------------------------------------------------------ set-up of a run -----------


@dataclass(frozen=True)
class _Setup:
    """Everything derived once from settings and model for a run."""

    model: Model
    pmodel: object  # planar pinocchio.Model, with the tilt's gravity; its base inertia follows the tank
    base_id: int
    n: int  # joints
    gains: _Gains
    resolution: np.ndarray  # encoder count [rad]; 0: exact
    limit: np.ndarray  # effort limit [N m]; inf: none
    viscous: np.ndarray  # joint friction [N m s/rad]
    coulomb: np.ndarray  # joint friction [N m]


def _setup(settings: TwinSettings, grasp: dict | None = None) -> _Setup:
    """The model and per-joint constants of ``settings``, checked against each other; with the
    payload of ``grasp`` (a :attr:`TwinState.grasp` record) held by its link."""
    model = _planar_model(settings.model)
    _check_joint_names(settings, model)
    if settings.capture is not None:
        _grasp_link(settings.capture, model)
    if grasp is not None:
        try:
            model = attach_payload(model, grasp["link"], grasp["payload"]["inertial"], where="state.grasp")
        except (KeyError, TypeError):
            raise SpaceidError("state.grasp must be the grasp record of a run (run.state.grasp)") from None
    c, jf = settings.controllers, settings.joint_friction
    _check_publish_rate(settings.encoders, c.rate)
    joints = model.joints
    limit = _effort_limits(settings.torque_limits, model)
    _check_dry_base(settings.tank, model)
    pmodel = planar_pinocchio(model)
    viscous, coulomb = _joint_friction_coefficients(jf, joints)
    _check_friction_step(pmodel, settings, joints, viscous + coulomb / jf.rate_scale, 1.0 / c.rate)
    _tilt_table(pmodel, settings)
    return _Setup(
        model=model,
        pmodel=pmodel,
        base_id=pmodel.getJointId("base_yaw"),
        n=len(joints),
        gains=_controller_gains(c, joints),
        resolution=_encoder_resolution(settings.encoders, joints),
        limit=limit,
        viscous=viscous,
        coulomb=coulomb,
    )


def _start_state(setup: _Setup, state: TwinState | None, settings: TwinSettings) -> TwinState:
    """``state`` with every None field resolved for ``setup``."""
    n = setup.n
    state = state if state is not None else TwinState()
    if not isinstance(state, TwinState):
        raise SpaceidError(f"`state` must be a TwinState (e.g. a previous run's .state), got {type(state).__name__}")
    q = np.zeros(n) if state.q is None else _vector("state.q", state.q, n)
    qd = np.zeros(n) if state.qd is None else _vector("state.qd", state.qd, n)
    hold = np.where(setup.gains.pos_mask, q, qd)
    command = hold if state.command is None else _vector("state.command", state.command, n)
    i_term = np.zeros(n) if state.i_term is None else _vector("state.i_term", state.i_term, n)
    if state.encoder_prev is None:
        prev = _quantise(q, setup.resolution)
    else:
        prev = _vector("state.encoder_prev", state.encoder_prev, n)
    co2 = settings.tank.co2_mass if state.co2_mass is None else state.co2_mass
    if settings.tank.enabled and co2 > settings.tank.co2_mass * (1 + 1e-12):
        raise SpaceidError(
            f"state.co2_mass = {co2:g} kg exceeds the full tank (tank.co2_mass = {settings.tank.co2_mass:g} kg)"
        )
    return replace(state, q=q, qd=qd, command=command, i_term=i_term, encoder_prev=prev, co2_mass=co2)


# ------------------------------------------------------------------ the hardware loop ---------


class _Laws(NamedTuple):
    """The per-tick functions of the hardware loop (None: the effect is off)."""

    read_encoders: object  # (q) -> readings, _sensors._encoder_reader
    control: object  # (qm, prev, command, rate, i_term) -> efforts, _controllers._pid_law
    feedforward: object  # (q_pin, v_pin, command, rate, accel) -> efforts or None
    saturate: object  # (efforts) -> efforts, _effects._saturation
    joint_friction: object  # (efforts, qd) -> efforts or None
    bearing_friction: object  # (yaw, vx, vy, wz) -> (Fx, Fy, Mz) or None


def _tick_laws(setup: _Setup, settings: TwinSettings, dt) -> _Laws:
    """The sensor, controller and effect laws of a run, built once from its set-up."""
    pos_mask = setup.gains.pos_mask
    feedforward = settings.controllers.feedforward and bool(pos_mask.any())
    return _Laws(
        read_encoders=_encoder_reader(setup.resolution),
        control=_pid_law(setup.gains, dt),
        feedforward=_feedforward_law(setup.pmodel, pos_mask) if feedforward else None,
        saturate=_saturation(setup.limit),
        joint_friction=_joint_friction_law(setup.viscous, setup.coulomb, settings.joint_friction.rate_scale),
        bearing_friction=_bearing_friction_law(settings.bearing_friction),
    )


def _integrate(setup: _Setup, settings: TwinSettings, state: TwinState, command, rate, accel, valves, dt,
               planned=None, feedback=None):
    """The hardware loop and RK4 integration over ``len(command) - 1`` steps.

    Per tick: read the encoders, run the controllers (plus the ``planned`` feed-forward efforts
    (n_steps + 1, n) [N m] of the tick, if any; a ``feedback`` law of :func:`run_twin` instead
    of both), saturate, evaluate friction and thrust at
    the start of the step, then one RK4 step of ``pin.aba`` with all of them held. The loop is
    scalar Python over the (few) joints, and the RK4 stages are small matrix products on the
    rows ``[q, v, a1..a4]``: ~25-35 us per step on one core (``benchmarks/bench_twin.py``).

    Returns
    -------
    Q, V : ndarray (n_steps + 1, 3 + n)
        True ``q_pin`` and ``v_pin`` at every tick.
    QM : ndarray (n_steps + 1, n)
        Encoder readings [rad].
    EFF : ndarray (n_steps + 1, n)
        Applied efforts [N m] (last row repeats).
    CO2 : ndarray (n_steps + 1,)
        CO2 in the tank [kg].
    i_term : ndarray (n,)
        Controller integral terms at the end.
    """
    pm, nj, n_steps = setup.pmodel, setup.n, len(command) - 1
    read_encoders, control, feedforward, saturate, joint_friction, bearing_friction = _tick_laws(setup, settings, dt)
    step = _rk4_stepper(pm, dt)
    fext, f_base = _base_force(pm, setup.base_id)
    thrust, n_open = _thrust_per_tick(settings.thrusters, valves)  # per tick [Fx, Fy, Mz], base frame
    tank = settings.tank
    load_base = _base_loader(pm, setup.base_id, setup.model, tank)
    drain = _tank_drain(tank, settings.thrusters, load_base, dt)
    co2 = float(state.co2_mass)
    if tank.enabled:
        load_base(co2)
    use_fext = bearing_friction is not None or any(n_open)
    drains = tank.enabled and (tank.bearing_flow > 0 or any(n_open))

    X, QM, EFF = [], [], []  # appended per tick (cheaper than row writes), stacked at the end
    CO2 = np.full(n_steps + 1, co2)
    W = _rk4_rows(state.q_pin, state.v_pin)
    tau = np.zeros(3 + nj)
    i_term, prev = state.i_term.tolist(), state.encoder_prev.tolist()
    commands, rates = command.tolist(), rate.tolist()  # Python floats: scalar code is faster on 3 joints
    planned = None if planned is None else planned.tolist()
    for k in range(n_steps + 1):
        ql, vl = W[:2].tolist()
        qm = read_encoders(ql[3:])
        X.append(W[:2].copy())
        QM.append(qm)
        if k == n_steps:
            EFF.append(EFF[-1] if k else [0.0] * nj)
            break
        if feedback is not None:  # the hook replaces the controllers and the feed-forward
            effort = _feedback_efforts(feedback, state.t + k * dt, qm, prev, dt, ql[2], vl[2], nj)
        else:
            effort = control(qm, prev, commands[k], rates[k], i_term)
            if feedforward:
                effort = [u + f for u, f in zip(effort, feedforward(W[0], W[1], command[k], rate[k], accel[k]))]
            if planned is not None:
                effort = [u + f for u, f in zip(effort, planned[k])]
        prev = qm
        effort = saturate(effort)
        EFF.append(effort)
        # joint friction (internal torques), held over the step like the effort
        tau[3:] = joint_friction(effort, vl[3:]) if joint_friction else effort
        firing = n_open[k] and (co2 > 0 or not tank.enabled)  # an empty tank gives no thrust
        if use_fext:
            # base wrench in the base frame: thrusters and air-bearing friction
            fx, fy, mz = thrust[k] if firing else (0.0, 0.0, 0.0)
            if bearing_friction:
                bx, by, bz = bearing_friction(ql[2], vl[0], vl[1], vl[2])
                fx, fy, mz = fx + bx, fy + by, mz + bz
            f_base[0], f_base[1], f_base[5] = fx, fy, mz
            step(W, tau, fext)
        else:
            step(W, tau)
        if drains:
            co2 = drain(co2, n_open[k] if firing else 0)
            CO2[k + 1] = co2
    X = np.array(X)
    return X[:, 0], X[:, 1], np.array(QM, float), np.array(EFF, float), CO2, np.array(i_term)


def _feedback_efforts(feedback, t, qm, prev, dt, yaw, wz, n) -> list:
    """Efforts (list of n) [N m] of a state-feedback law at tick time ``t`` [s]: ``feedback(t, q,
    qd, base_yaw, base_wz)`` with the encoder readings ``qm``, their finite difference from
    ``prev`` over ``dt`` and the true base yaw [rad] and yaw rate [rad/s]."""
    q = np.array(qm)
    out = feedback(t, q, (q - prev) * (1.0 / dt), yaw, wz)
    try:
        out = np.asarray(out, float).reshape(n)
    except (TypeError, ValueError):
        raise SpaceidError(f"`controller`(t, q, qd, base_yaw, base_wz) must return {n} efforts (one per joint, "
                           f"model order), got {np.shape(out)}") from None  # fmt: skip
    if not np.all(np.isfinite(out)):
        raise SpaceidError(f"`controller`: the efforts at t = {t:g} s contain NaN or infinite values")
    return out.tolist()


def _grasp_tick(capture, state: TwinState, times, dt) -> int | None:
    """The tick of the phase at which ``capture`` grasps: the first at or after its time (to
    within 1e-6 dt) that starts a step; None when there is none or a payload is already held."""
    if capture is None or state.grasp is not None:
        return None
    if capture.time < times[0] - 1e-6 * dt:
        raise SpaceidError(
            f"capture.time = {capture.time:g} s is before the phase's start (t = {times[0]:g} s) but the state "
            "holds no payload: start the phase from the state of the run that grasped it (run.state)"
        )
    k = int(np.searchsorted(times, capture.time - 1e-6 * dt))
    return k if k < len(times) - 1 else None


def _state_at(t, q_pin, v_pin, co2, command, i_term, encoder_prev, grasp) -> TwinState:
    """The :class:`TwinState` at a tick from the plant's coordinates and the controller memory."""
    return TwinState(t=float(t), base_xy=q_pin[:2], base_yaw=float(q_pin[2]), base_vxy=v_pin[:2],
                     base_wz=float(v_pin[2]), q=q_pin[3:], qd=v_pin[3:], co2_mass=float(co2), command=command,
                     i_term=i_term, encoder_prev=encoder_prev, grasp=grasp)  # fmt: skip


def _integrate_phase(setup: _Setup, settings: TwinSettings, state: TwinState, times, command, rate, accel, valves,
                     dt, planned, feedback=None):
    """:func:`_integrate` over a phase, split at the grasp tick if ``settings.capture`` grasps in it.

    Returns the histories of :func:`_integrate` (at the grasp tick the state just before the
    grasp, and the effort applied after it), then ``grasp``: the record of the payload held at the
    end (or None), and ``jump``: ``(k, v_after)``, the grasp tick and the rates after the impact
    (or None)."""
    k = _grasp_tick(settings.capture, state, times, dt)
    if k is None:
        return (*_integrate(setup, settings, state, command, rate, accel, valves, dt, planned, feedback), state.grasp,
                None)

    def inputs(ticks):
        return command[ticks], rate[ticks], accel[ticks], valves[ticks], None if planned is None else planned[ticks]

    c1, r1, a1, w1, p1 = inputs(slice(None, k + 1))
    Q1, V1, QM1, EFF1, CO21, i_term = _integrate(setup, settings, state, c1, r1, a1, w1, dt, p1, feedback)
    v_after, grasp = _grasp(setup.model, settings, Q1[-1], V1[-1], times[k], CO21[-1])
    prev = QM1[-2] if k else state.encoder_prev
    held = _state_at(times[k], Q1[-1], v_after, CO21[-1], command[k], i_term, prev, grasp)
    c2, r2, a2, w2, p2 = inputs(slice(k, None))
    Q2, V2, QM2, EFF2, CO22, i_term = _integrate(_setup(settings, grasp), settings, held, c2, r2, a2, w2, dt, p2,
                                           feedback)
    return (np.concatenate([Q1, Q2[1:]]), np.concatenate([V1, V2[1:]]), np.concatenate([QM1, QM2[1:]]),
            np.concatenate([EFF1[:-1], EFF2]), np.concatenate([CO21, CO22[1:]]), i_term, grasp, (k, v_after))


# ------------------------------------------------------------------ a phase -------------------


def run_twin(
    reference=None,
    *,
    duration: float,
    wheel_speed=None,
    settings: TwinSettings | None = None,
    state: TwinState | None = None,
    seed: int = 0,
    effort=None,
    controller=None,
) -> TwinRun:
    """Run the twin for one phase.

    Parameters
    ----------
    reference : FourierTrajectory or callable or None
        Set points of the position-controlled joints: a
        :class:`~spaceid.motion.FourierTrajectory` (joints matched by name, held at its end value
        after ``tf``), a callable ``reference(t) -> (q_ref, qd_ref[, qdd_ref])`` with ``t`` of
        shape (n,) [s] since the start of the phase and arrays of shape (n, n_position_joints) in
        model joint order (without ``qdd_ref`` the derivative of ``qd_ref``), or None to hold the
        last commands.
    duration : float
        Length of the phase [s]; rounded to a whole number of control periods.
    wheel_speed : float or callable or None
        Set point of the velocity-controlled joints [rad/s] (relative to the base), constant or
        ``f(t) -> (n,)`` of the phase time; None holds the last command.
    settings : TwinSettings, optional
        Default ``TwinSettings()``.
    state : TwinState, optional
        Start state; default at rest at the origin at t = 0, full tank.
    seed : int
        Seed of the motion-capture noise and dropped frames (recorded in ``meta``).
    effort : callable, optional
        Feed-forward efforts of the position-controlled joints, ``effort(t) -> (n,
        n_position_joints)`` [N m] of the phase time, added to the controllers' output before
        saturation (e.g. :func:`~spaceid.twin.planned_feedforward`, computed offline; unlike
        ``Controllers(feedforward=True)`` it reads no state of the twin).
    controller : callable, optional
        A state-feedback law in place of the twin's effort controllers (and of ``effort`` and
        the feed-forward), called at every control tick as ``controller(t, q, qd, base_yaw,
        base_wz) -> efforts``: ``t`` the absolute tick time [s], ``q`` (n_joints,) the encoder
        readings [rad] and ``qd`` (n_joints,) their finite difference over the last period
        [rad/s] (what the hardware interface gives the controllers), ``base_yaw`` [rad] and
        ``base_wz`` [rad/s] the true base attitude and rate (an ideal attitude sensor: the
        motion capture is slower and late); it returns the efforts of every joint (n_joints,)
        [N m] in model order, the reaction wheel's included, which the twin saturates at the
        torque limits and holds over the period like its own controllers' (e.g.
        :func:`~spaceid.twin.computed_torque`). ``reference`` and ``wheel_speed`` then only
        set the recorded commands and ``meta["tracking_rms"]``.

    Returns
    -------
    TwinRun
    """
    settings = TwinSettings() if settings is None else settings
    if not isinstance(settings, TwinSettings):
        raise SpaceidError(f"`settings` must be a TwinSettings(...), got {type(settings).__name__}")
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise SpaceidError(f"`seed` must be an integer, got {seed!r}") from None
    setup = _setup(settings, getattr(state, "grasp", None))  # the state is checked next
    state = _start_state(setup, state, settings)
    dt = 1.0 / settings.controllers.rate
    t0, joints = state.t, setup.model.joints
    times = t0 + dt * np.arange(_n_steps(duration, dt) + 1)
    command, rate, accel = _setpoints(setup.gains, joints, reference, wheel_speed, times - t0, state.command)
    planned = _effort_setpoints(setup.gains, effort, times - t0)
    valves = _valves(settings.thrusters, times, dt)
    if controller is not None and not callable(controller):
        raise SpaceidError(f"`controller` must be a callable (t, q, qd, base_yaw, base_wz) -> efforts (e.g. "
                           f"computed_torque) or None, got {type(controller).__name__}")  # fmt: skip
    Q, V, QM, EFF, CO2, i_term, grasp, jump = _integrate_phase(setup, settings, state, times, command, rate, accel,
                                                               valves, dt, planned, controller)
    rates = _hardware_rates(QM, state.encoder_prev, dt)
    joint_states = _publish_joint_states(settings.encoders, joints, times, dt, QM, rates, EFF)
    poses, n_frames, n_dropped = _capture_poses(settings.mocap, times, Q, V, seed, jump)
    final = _state_at(times[-1], Q[-1], V[-1], CO2[-1], command[-1], i_term, QM[-2], grasp)
    meta = _run_meta(setup, settings, seed, times, Q, command, CO2, n_frames, n_dropped)
    if grasp is not None:
        meta["capture"] = grasp
    return TwinRun(
        recording=Recording(joint_states, poses, meta),
        truth=_true_log(times, joints, Q, V, seed),
        base_position=Q[:, :2].copy(),
        base_velocity=V[:, :2].copy(),
        effort=EFF,
        co2_mass=CO2,
        state=final,
        meta=meta,
    )


def _n_steps(duration, dt) -> int:
    """The number of control periods ``dt`` [s] in ``duration`` [s] (at least one)."""
    duration = _number("`duration` [s]", duration, low=0.0, strict=True)
    n_steps = int(round(duration / dt))
    if n_steps < 1:
        raise SpaceidError(
            f"`duration` = {duration:g} s is shorter than one control period ({dt:g} s): give a longer duration"
        )
    return n_steps


def _true_log(times, joints, Q, V, seed) -> Log:
    """The true motion at every tick as a planar :class:`~spaceid.data.Log`."""
    base_w = np.zeros((len(times), 3))
    base_w[:, 2] = V[:, 2]
    return Log(times, joints, Q[:, 3:].copy(), V[:, 3:].copy(), yaw_to_quat(Q[:, 2]), base_w, True,
               {"source": "spaceid.twin (truth)", "seed": seed})


def _run_meta(setup: _Setup, settings: TwinSettings, seed, times, Q, command, CO2, n_frames, n_dropped) -> dict:
    """Provenance of a phase: seed, settings, CO2 and base mass at both ends, frames, tracking."""
    joints, tank = setup.model.joints, settings.tank
    pos = setup.gains.pos_mask
    track = Q[:-1, 3:][:, pos] - command[:-1][:, pos]  # true tracking error
    t0, t_end = float(times[0]), float(times[-1])
    base_mass = setup.model.bodies[0].mass
    rms = {joints[i]: float(np.sqrt(np.mean(track[:, c] ** 2))) for c, i in enumerate(np.flatnonzero(pos))}
    return {
        "source": "spaceid.twin",
        "model": setup.model.source or setup.model.name,
        "seed": seed,
        "settings": settings.to_dict(),
        "t_start": t0,
        "t_end": t_end,
        "co2_mass_start": float(CO2[0]),
        "co2_mass_end": float(CO2[-1]),
        "base_mass_start": float(base_mass - (tank.co2_mass - CO2[0]) * tank.enabled),
        "base_mass_end": float(base_mass - (tank.co2_mass - CO2[-1]) * tank.enabled),
        "mocap_frames": n_frames,
        "mocap_dropped": n_dropped,
        "tracking_rms": rms,
        "phases": [{"t_start": t0, "t_end": t_end, "seed": seed}],
    }


def spin_up(
    speed: float = 170.0,
    *,
    ramp: float = 100.0,
    settle: float = 2.0,
    settings: TwinSettings | None = None,
    state: TwinState | None = None,
    seed: int = 0,
) -> TwinRun:
    """Spin the velocity-controlled joints (the reaction wheel) up to ``speed``, arm holding.

    The set point ramps linearly from the current command at ``ramp`` [rad/s^2] to ``speed``
    [rad/s] (relative to the base), then holds for ``settle`` [s]. With the default PI gains and
    ramp the wheel overshoots by ~6 rad/s (3.5 %) at the end of the ramp, is within 0.5 rad/s
    of 170 rad/s ~1.1 s and within 0.05 rad/s ~2 s after it, using at most ~0.25 N m (limit
    0.5). The momentum of the rest of the system is then ``h - I_rw (w0 + w_rw)`` (docs/theory/scale.md),
    with ``h`` the total (zero when starting at rest).

    Returns
    -------
    TwinRun
        Its ``state`` starts the next phase.
    """
    speed = _number("spin_up speed [rad/s]", speed)
    ramp = _number("spin_up ramp [rad/s^2]", ramp, low=0.0, strict=True)
    settle = _number("spin_up settle [s]", settle, low=0.0)
    settings = TwinSettings() if settings is None else settings
    setup = _setup(settings)
    start = _start_state(setup, state, settings)
    w0 = start.command[setup.gains.vel_mask]
    w0 = float(w0[0]) if len(w0) else 0.0
    ramp_time = abs(speed - w0) / ramp

    def setpoint(t):
        return w0 + np.sign(speed - w0) * np.minimum(ramp * np.asarray(t), abs(speed - w0))

    run = run_twin(None, duration=max(ramp_time + settle, 1.0 / settings.controllers.rate),
                   wheel_speed=setpoint, settings=settings, state=start, seed=seed)
    meta = dict(run.meta, spin_up={"speed": speed, "ramp": ramp, "settle": settle})
    return replace(run, meta=meta, recording=replace(run.recording, meta=meta))


# ------------------------------------------------------------------ joined phases -------------


def join_runs(*runs: TwinRun) -> TwinRun:
    """Concatenate consecutive phases (each starting from the previous one's ``state``).

    The repeated boundary sample of the true history is dropped; sensor streams are simply
    concatenated (they are stamped in half-open intervals).
    """
    if not runs:
        raise SpaceidError("join_runs needs at least one TwinRun")
    for a, b in zip(runs, runs[1:]):
        if abs(a.truth.t[-1] - b.truth.t[0]) > 1e-9 or a.truth.joints != b.truth.joints:
            raise SpaceidError(
                f"join_runs: a phase starts at t = {b.truth.t[0]:g} s but the previous one ends at "
                f"{a.truth.t[-1]:g} s: start each phase from the previous run's .state"
            )
    first = runs[0]
    truth = Log(
        _cat_phases(runs, lambda r: r.truth.t), first.truth.joints, _cat_phases(runs, lambda r: r.truth.q),
        _cat_phases(runs, lambda r: r.truth.qd), _cat_phases(runs, lambda r: r.truth.base_quat),
        _cat_phases(runs, lambda r: r.truth.base_w), True, dict(first.truth.meta),
    )
    # effort: the boundary sample of the later phase is the one applied from then on
    effort = np.concatenate([r.effort[:-1] for r in runs] + [runs[-1].effort[-1:]])
    meta = _joined_meta(runs)
    recording = Recording(
        _join_joint_states([r.recording.joints for r in runs]), _join_poses([r.recording.base for r in runs]), meta
    )
    return TwinRun(
        recording=recording,
        truth=truth,
        base_position=_cat_phases(runs, lambda r: r.base_position),
        base_velocity=_cat_phases(runs, lambda r: r.base_velocity),
        effort=effort,
        co2_mass=_cat_phases(runs, lambda r: r.co2_mass),
        state=runs[-1].state,
        meta=meta,
    )


def _cat_phases(runs, get) -> np.ndarray:
    """``get(run)`` of consecutive runs concatenated, without the repeated first sample of each later run."""
    return np.concatenate([get(r)[1:] if i else get(r) for i, r in enumerate(runs)])


def _join_joint_states(js) -> JointStates:
    """Consecutive ``/joint_states`` streams as one (velocity and effort only if all have them)."""
    return JointStates(
        t=np.concatenate([j.t for j in js]),
        names=js[0].names,
        position=np.concatenate([j.position for j in js]),
        velocity=None if any(j.velocity is None for j in js) else np.concatenate([j.velocity for j in js]),
        effort=None if any(j.effort is None for j in js) else np.concatenate([j.effort for j in js]),
    )


def _join_poses(ps) -> Poses:
    """Consecutive motion-capture streams as one."""
    return Poses(
        t=np.concatenate([p.t for p in ps]),
        position=np.concatenate([p.position for p in ps]),
        quat=np.concatenate([p.quat for p in ps]),
        frame=ps[0].frame,
    )


def _joined_meta(runs) -> dict:
    """The first run's ``meta`` with the end values of the last, totals and every phase and seed."""
    meta = dict(
        runs[0].meta,
        t_end=runs[-1].meta["t_end"],
        co2_mass_end=runs[-1].meta["co2_mass_end"],
        base_mass_end=runs[-1].meta["base_mass_end"],
        mocap_frames=sum(r.meta["mocap_frames"] for r in runs),
        mocap_dropped=sum(r.meta["mocap_dropped"] for r in runs),
        phases=[p for r in runs for p in r.meta["phases"]],
        seed=[r.meta["seed"] for r in runs],
    )
    meta.pop("tracking_rms", None)  # of one phase only
    if "capture" in runs[-1].meta:  # the payload held at the end, whichever phase grasped it
        meta["capture"] = runs[-1].meta["capture"]
    return meta
