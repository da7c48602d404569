"""Settings of the Cepheus twin: one frozen dataclass per part, each value with its unit, its
default and where the default comes from (published, measured, or assumed and why).

:class:`TwinSettings` gathers :class:`Controllers` (with :class:`PID` gains), :class:`Encoders`,
:class:`MotionCapture` and the optional effects :class:`BearingFriction`, :class:`JointFriction`,
:class:`TorqueLimits`, :class:`Thrusters` and :class:`Tank`, each with an ``enabled`` switch, and
the optional grasp of a free-floating payload, :class:`Capture`.
Every value is checked on construction (a :class:`~spaceid.SpaceidError` names the setting);
joint names are checked against the model when a run starts.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace

import numpy as np

from .._errors import SpaceidError
from ..models import Model, check_rigid_inertia, inertial_vector

__all__ = [
    "PID",
    "Controllers",
    "Encoders",
    "MotionCapture",
    "BearingFriction",
    "JointFriction",
    "TorqueLimits",
    "Thrusters",
    "Tank",
    "Capture",
    "TwinSettings",
    "JointControl",
    "JointEncoders",
    "StarTracker",
    "Gyro",
    "ServicerSettings",
]

G0 = 9.80665
"""Standard gravity [m/s^2] (specific impulse and table tilt)."""


# ------------------------------------------------------------------ validation helpers -------


def _probability(where, value) -> float:
    """``value`` as a probability in [0, 1), or a SpaceidError naming ``where``."""
    p = _number(where, value, low=0.0)
    if p >= 1:
        raise SpaceidError(f"{where} must be in [0, 1), got {p:g}")
    return p


def _number(where, value, *, low=None, strict=False, allow_inf=False):
    """``value`` as a float (at least, or with ``strict`` above, ``low``), or a SpaceidError naming ``where``."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise SpaceidError(f"{where} must be a number, got {value!r}") from None
    if math.isnan(x) or (math.isinf(x) and not allow_inf):
        raise SpaceidError(f"{where} must be a finite number, got {value!r}")
    if low is not None and (x <= low if strict else x < low):
        bound = f"greater than {low:g}" if strict else f"at least {low:g}"
        raise SpaceidError(f"{where} must be {bound}, got {x:g}")
    return x


def _per_joint(where, mapping, *, low=0.0, strict=False, allow_none=False):
    """A ``{joint: value}`` mapping with checked values (names are checked against a model later)."""
    if not isinstance(mapping, Mapping):
        raise SpaceidError(f"{where} must be a mapping from joint name to value, got {mapping!r}")
    out = {}
    for name, value in mapping.items():
        if value is None and allow_none:
            out[str(name)] = None
        else:
            out[str(name)] = _number(f"{where}['{name}']", value, low=low, strict=strict)
    return out


def _finite_tuple(value, n):
    """``value`` as a tuple of ``n`` finite floats, or None if it is not one."""
    try:
        out = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        return None
    return out if len(out) == n and all(math.isfinite(x) for x in out) else None


def _set(obj, name, value):
    """Set ``name`` of a frozen dataclass in its ``__post_init__`` (to the checked value)."""
    object.__setattr__(obj, name, value)


# ------------------------------------------------------------------ settings ------------------


@dataclass(frozen=True)
class PID:
    """Gains of one ros_control ``control_toolbox::Pid`` (effort output).

    Attributes
    ----------
    p : float
        Proportional gain: N m/rad for a position loop, N m s/rad for a velocity loop.
    i : float
        Integral gain: N m/(rad s) for a position loop, N m/rad for a velocity loop.
    d : float
        Derivative gain on the rate error, N m s/rad (position loops only).
    i_clamp : float
        Bound on the integral term ``|i_term| <= i_clamp`` [N m] (anti-windup, as ``i_clamp``).
    """

    p: float = 0.0
    i: float = 0.0
    d: float = 0.0
    i_clamp: float = math.inf

    def __post_init__(self):
        for name in ("p", "i", "d"):
            _set(self, name, _number(f"PID.{name}", getattr(self, name), low=0.0))
        _set(self, "i_clamp", _number("PID.i_clamp", self.i_clamp, low=0.0, allow_inf=True))


def _default_position_gains():
    # the robot's published controller configuration (shoulder and elbow PD)
    return {"left_shoulder": PID(p=0.1, d=0.04), "left_elbow": PID(p=0.1, d=0.02)}


def _default_velocity_gains():
    # PI on the wheel rate relative to the base: with I ~ 1.94e-3 kg m^2 (the rotor against the
    # rest of the system) I s^2 + p s + i has roots -4.3 and -6.1 rad/s (zeta ~ 1): a 100 rad/s^2
    # set-point ramp to 170 rad/s needs ~0.2 N m (limit 0.5), ends with a ~6 rad/s overshoot and
    # is within 0.5 rad/s ~1.1 s after the ramp; i_clamp = the effort limit.
    return {"reaction_wheel_joint": PID(p=0.02, i=0.05, i_clamp=0.5)}


@dataclass(frozen=True)
class Controllers:
    """ros_control effort controllers, run at ``rate`` by the hardware loop.

    Attributes
    ----------
    rate : float
        Control (hardware loop) rate [Hz]; also the integration rate. Default 1000.
    position : dict of str to PID
        ``effort_controllers/JointPositionController`` per joint: ``effort = p e + d (qd_ref -
        qd_hw) + i_term``, ``e = q_ref - q_enc`` (the controller's form when the command carries a
        velocity; with position-only commands ros_control differentiates ``e`` instead, the same
        for a smooth reference up to quantisation noise). Default: the robot's published gains,
        shoulder p = 0.1 N m/rad, d = 0.04 N m s/rad; elbow p = 0.1, d = 0.02. These track the
        paper's trajectory with ~0.14 rad RMS error (see ``feedforward``).
    velocity : dict of str to PID
        ``effort_controllers/JointVelocityController`` per joint: ``effort = p e + i_term``,
        ``e = qd_ref - qd_hw``. Default: reaction wheel p = 0.02 N m s/rad, i = 0.05 N m/rad,
        i_clamp = 0.5 N m (critically damped at ~5 rad/s, chosen for this twin; the robot's
        wheel gains are not published). Joints in neither mapping are unactuated.
    feedforward : bool
        Add the free-floating inverse dynamics of the reference to the position loops
        (``pin.crba`` and ``pin.rnea`` at the reference joint state with the current base
        velocity, base accelerations solved so the base receives no actuation). Default False
        (the robot's controllers have none); on the paper's trajectory it brings the tracking
        error from ~0.14 to ~0.02 rad RMS with all effects on.
    """

    rate: float = 1000.0
    position: dict = field(default_factory=_default_position_gains)
    velocity: dict = field(default_factory=_default_velocity_gains)
    feedforward: bool = False

    def __post_init__(self):
        _set(self, "rate", _number("controllers.rate [Hz]", self.rate, low=0.0, strict=True))
        for kind in ("position", "velocity"):
            gains = getattr(self, kind)
            if not isinstance(gains, Mapping) or not all(isinstance(g, PID) for g in gains.values()):
                raise SpaceidError(f"controllers.{kind} must map joint names to PID(...) gains, got {gains!r}")
            _set(self, kind, {str(k): v for k, v in gains.items()})
        both = set(self.position) & set(self.velocity)
        if both:
            raise SpaceidError(
                f"controllers: joint '{sorted(both)[0]}' has both a position and a velocity "
                "controller: keep one of them"
            )
        for name, pid in self.velocity.items():
            if pid.d:
                raise SpaceidError(
                    f"controllers.velocity['{name}'].d = {pid.d:g}: derivative action on a velocity "
                    "loop is not modelled; set d=0"
                )


def _default_counts():
    # Assumed resolutions (not published): arm joints 20000 counts per joint revolution (a
    # 500-line encoder, x4 decoding, 10:1 reduction); wheel 4096 (1024 lines, x4, direct drive).
    return {"reaction_wheel_joint": 4096, "left_shoulder": 20000, "left_elbow": 20000}


@dataclass(frozen=True)
class Encoders:
    """Incremental joint encoders and the ``/joint_states`` publisher.

    Attributes
    ----------
    counts_per_rev : dict of str to int or None
        Counts per joint revolution after decoding; the reading is ``round(q / r) r`` with
        ``r = 2 pi / counts`` [rad] (None: no quantisation). Joints not listed read exactly.
        Default: arm joints 20000, wheel 4096 (assumed, not published).
    rate : float
        ``joint_state_controller`` publish rate [Hz]. Default 50 (the robot's configuration).
    velocity : {"difference", None}
        ``"difference"``: published velocities are the hardware interface's finite difference of
        successive encoder readings over one control period (noisy: one count per period is
        ``2 pi / counts * rate``); None: messages carry no velocities. The controllers always use
        the finite difference.
    """

    counts_per_rev: dict = field(default_factory=_default_counts)
    rate: float = 50.0
    velocity: str | None = "difference"

    def __post_init__(self):
        counts = _per_joint("encoders.counts_per_rev", self.counts_per_rev, low=1.0, allow_none=True)
        _set(self, "counts_per_rev", counts)
        _set(self, "rate", _number("encoders.rate [Hz]", self.rate, low=0.0, strict=True))
        if self.velocity not in ("difference", None):
            raise SpaceidError(f"encoders.velocity must be 'difference' or None, got {self.velocity!r}")


@dataclass(frozen=True)
class MotionCapture:
    """Motion capture of the base pose (PhaseSpace on the real table).

    Attributes
    ----------
    rate : float
        Frame rate [Hz]. Default 100.
    position_noise : float
        Standard deviation of the x and y position noise [m]. Default 5e-4.
    attitude_noise : float
        Standard deviation of the yaw noise [rad]. Default 1e-3.
    latency : float
        Delay between capture and stamp [s]: a pose stamped ``t`` was captured at ``t -
        latency``. Default 0.005.
    drop_probability : float
        Probability that a frame is lost (independently per frame), in [0, 1). Default 0.01.
    frame : str
        ``header.frame_id``. Default ``"world"``.
    """

    rate: float = 100.0
    position_noise: float = 5e-4
    attitude_noise: float = 1e-3
    latency: float = 0.005
    drop_probability: float = 0.01
    frame: str = "world"

    def __post_init__(self):
        _set(self, "rate", _number("mocap.rate [Hz]", self.rate, low=0.0, strict=True))
        for name in ("position_noise", "attitude_noise", "latency"):
            _set(self, name, _number(f"mocap.{name}", getattr(self, name), low=0.0))
        _set(self, "drop_probability", _probability("mocap.drop_probability", self.drop_probability))


@dataclass(frozen=True)
class BearingFriction:
    """Residual friction of the air bearings on the base.

    Force on the base origin ``F = -(c v + F_c tanh(|v| / v_s) v / |v|)`` (v the base origin
    velocity), yaw torque ``M = -(c_r w + M_c tanh(w / w_s))``. The viscous terms are the shear
    of the ~10 um CO2 film under the three 25 mm pads (mu ~ 1.5e-5 Pa s: c ~ mu A / h ~ 2.2e-3
    N s/m; pads at ~0.15 m from the centre: c_r ~ c 0.15^2 ~ 5e-5 N m s/rad); the Coulomb terms
    are an assumed residual (pad contact, surface defects), smoothed by tanh.

    Attributes
    ----------
    enabled : bool
        Default True.
    viscous_force : float
        c [N s/m]. Default 2.2e-3.
    coulomb_force : float
        F_c [N]. Default 1e-3.
    viscous_torque : float
        c_r [N m s/rad]. Default 5e-5.
    coulomb_torque : float
        M_c [N m]. Default 1e-4.
    speed_scale : float
        v_s [m/s] of the tanh. Default 1e-3.
    rate_scale : float
        w_s [rad/s] of the tanh. Default 1e-2.
    """

    enabled: bool = True
    viscous_force: float = 2.2e-3
    coulomb_force: float = 1e-3
    viscous_torque: float = 5e-5
    coulomb_torque: float = 1e-4
    speed_scale: float = 1e-3
    rate_scale: float = 1e-2

    def __post_init__(self):
        for name in ("viscous_force", "coulomb_force", "viscous_torque", "coulomb_torque"):
            _set(self, name, _number(f"bearing_friction.{name}", getattr(self, name), low=0.0))
        for name in ("speed_scale", "rate_scale"):
            _set(self, name, _number(f"bearing_friction.{name}", getattr(self, name), low=0.0, strict=True))


def _default_viscous():
    return {"reaction_wheel_joint": 1e-5, "left_shoulder": 5e-4, "left_elbow": 5e-4}


def _default_coulomb():
    return {"reaction_wheel_joint": 1e-3, "left_shoulder": 2e-3, "left_elbow": 2e-3}


@dataclass(frozen=True)
class JointFriction:
    """Friction in the joints (bearings, belts, motor): ``tau_f = -(c qd + tau_c tanh(qd / s))``.

    Internal torques: they act between parent and child and do not change the momentum.

    Attributes
    ----------
    enabled : bool
        Default True.
    viscous : dict of str to float
        c per joint [N m s/rad]. Default wheel 1e-5 (1.7 mN m at 170 rad/s), arm joints 5e-4.
    coulomb : dict of str to float
        tau_c per joint [N m]. Default wheel 1e-3, arm joints 2e-3 (assumed).
    rate_scale : float
        s [rad/s] of the tanh. Default 1e-2.
    """

    enabled: bool = True
    viscous: dict = field(default_factory=_default_viscous)
    coulomb: dict = field(default_factory=_default_coulomb)
    rate_scale: float = 1e-2

    def __post_init__(self):
        _set(self, "viscous", _per_joint("joint_friction.viscous", self.viscous))
        _set(self, "coulomb", _per_joint("joint_friction.coulomb", self.coulomb))
        _set(self, "rate_scale", _number("joint_friction.rate_scale", self.rate_scale, low=0.0, strict=True))


@dataclass(frozen=True)
class TorqueLimits:
    """Actuator saturation: ``|effort| <= limit`` per joint.

    Attributes
    ----------
    enabled : bool
        Default True.
    effort : dict of str to float or None
        Limits [N m]; None (default) takes the model joints' ``effort`` limits (cepheus-rw:
        wheel 0.5, arm joints 1.0). Joints without a limit are not saturated.
    """

    enabled: bool = True
    effort: dict | None = None

    def __post_init__(self):
        if self.effort is not None:
            _set(self, "effort", _per_joint("torque_limits.effort", self.effort, strict=True))


@dataclass(frozen=True)
class Thrusters:
    """The three pairs of opposed cold-gas thrusters, on/off valves on the base rim.

    Pair ``k`` sits at ``radius (cos a_k, sin a_k)`` in the base frame, ``a_k = angles[k]``; its
    ``+1`` thruster pushes along the counter-clockwise tangent ``(-sin a_k, cos a_k)`` (positive
    yaw torque ``force * radius``), its ``-1`` thruster the opposite way. Firing ``+1`` (or ``-1``)
    of all three pairs is a pure couple; one thruster gives a force and a torque. Layout and
    force are assumed (the paper gives 3 pairs at 120 deg, mid-height, on the rim).

    Attributes
    ----------
    enabled : bool
        Default True (with an empty schedule nothing fires).
    force : float
        Thrust of one open valve [N]. Default 0.2.
    radius : float
        Distance of the thrusters from the base origin [m]. Default 0.2.
    angles : tuple of 3 floats
        a_k [rad]. Default (pi, 5 pi / 3, pi / 3): pair 0 at the back, away from the arm.
    schedule : tuple of (t_on, t_off, pair, sign)
        Valve openings: thruster ``(pair, sign)`` open for the control ticks ``t_on <= t <
        t_off`` [s, absolute time], each valve state held for one control period; ``pair`` in
        {0, 1, 2}, ``sign`` in {+1, -1}. Default ().
    """

    enabled: bool = True
    force: float = 0.2
    radius: float = 0.2
    angles: tuple = (math.pi, 5 * math.pi / 3, math.pi / 3)
    schedule: tuple = ()

    def __post_init__(self):
        _set(self, "force", _number("thrusters.force [N]", self.force, low=0.0))
        _set(self, "radius", _number("thrusters.radius [m]", self.radius, low=0.0))
        angles = _finite_tuple(self.angles, 3)
        if angles is None:
            raise SpaceidError(f"thrusters.angles must be 3 finite angles [rad], got {self.angles!r}")
        _set(self, "angles", angles)
        openings = (_valve_opening(f"thrusters.schedule[{i}]", e) for i, e in enumerate(self.schedule))
        _set(self, "schedule", tuple(openings))


def _valve_opening(where, entry):
    """One checked ``(t_on, t_off, pair, sign)`` entry of :attr:`Thrusters.schedule`."""
    try:
        t_on, t_off, pair, sign = entry
    except (TypeError, ValueError):
        raise SpaceidError(f"{where} must be (t_on, t_off, pair, sign), got {entry!r}") from None
    t_on, t_off = _number(f"{where}.t_on", t_on), _number(f"{where}.t_off", t_off)
    if t_off <= t_on:
        raise SpaceidError(f"{where}: t_off = {t_off:g} s must be after t_on = {t_on:g} s")
    if pair not in (0, 1, 2):
        raise SpaceidError(f"{where}: pair must be 0, 1 or 2, got {pair!r}")
    if sign not in (1, -1):
        raise SpaceidError(f"{where}: sign must be +1 or -1, got {sign!r}")
    return (t_on, t_off, int(pair), int(sign))


@dataclass(frozen=True)
class Tank:
    """The on-board CO2 tank: its contents drain with thruster (and bearing) use.

    The model's base inertia is the base with ``co2_mass`` of CO2 in the tank (a full tank). The
    CO2 is a solid cylinder (vertical axis) at ``position`` in the base frame; with ``m`` left,
    the base inertial parameters are ``base - (co2_mass - m) * unit`` (``unit`` those of 1 kg of
    that cylinder), so the base mass, CoM and inertia drift as gas is used: the reason an
    identified model must be refreshed. Mass flow ``n_open * force / (isp * g0) + bearing_flow``;
    the gas leaves with the local base velocity (velocities are continuous, the thrust accounts
    for the exhaust). With the tank empty the thrusters give no force.

    Attributes
    ----------
    enabled : bool
        Default True; False keeps the mass constant (thrusters still push).
    co2_mass : float
        CO2 in the full tank [kg]. Default 0.5 (assumed: the tank weighs 1.5 kg full).
    position : tuple of 2 floats
        CO2 centre in the base frame [m]. Default (-0.05, 0.0): near the base CoM.
    radius, length : float
        Cylinder of the CO2 [m]. Default 0.03 and 0.25.
    isp : float
        Specific impulse of the thrusters [s]. Default 60 (CO2 cold gas).
    bearing_flow : float
        Constant CO2 consumption of the air bearings [kg/s]. Default 0.
    """

    enabled: bool = True
    co2_mass: float = 0.5
    position: tuple = (-0.05, 0.0)
    radius: float = 0.03
    length: float = 0.25
    isp: float = 60.0
    bearing_flow: float = 0.0

    def __post_init__(self):
        _set(self, "co2_mass", _number("tank.co2_mass [kg]", self.co2_mass, low=0.0))
        pos = _finite_tuple(self.position, 2)
        if pos is None:
            raise SpaceidError(f"tank.position must be 2 finite numbers (x, y) [m], got {self.position!r}")
        _set(self, "position", pos)
        for name in ("radius", "length", "bearing_flow"):
            _set(self, name, _number(f"tank.{name}", getattr(self, name), low=0.0))
        _set(self, "isp", _number("tank.isp [s]", self.isp, low=0.0, strict=True))

    def unit_inertial(self) -> np.ndarray:
        """Inertial parameters of 1 kg of CO2 about the base origin, shape (10,)."""
        r2, l2 = self.radius**2, self.length**2
        i_com = np.diag([(3 * r2 + l2) / 12, (3 * r2 + l2) / 12, r2 / 2])
        return inertial_vector(1.0, [*self.position, 0.0], i_com)


def _default_payload_inertia():
    # a solid cylinder of 0.5 kg, radius 0.05 m, height 0.1 m, axis vertical
    side = 0.5 * (3 * 0.05**2 + 0.1**2) / 12
    return ((side, 0.0, 0.0), (0.0, side, 0.0), (0.0, 0.0, 0.5 * 0.5 * 0.05**2))


@dataclass(frozen=True)
class Capture:
    """A free-floating payload on the table that the end effector grasps at ``time``.

    Before the grasp the payload floats on its own air bearings without friction: its CoM moves
    at the constant ``velocity`` and it turns at the constant ``rate``. At the first control tick
    at or after ``time`` it becomes rigidly attached to the body ``link`` where it then is (no
    contact or approach is modelled), in a plastic impact that conserves the total linear and
    angular momentum and applies no impulsive joint torque (:mod:`spaceid.twin._capture`); from
    then on the twin integrates the combined system, the payload's inertial parameters added to
    those of ``link``. The payload is a planar body: its CoM lies in the plane of the frame origin
    of ``link``, and its frame turns about the vertical only.

    Attributes
    ----------
    time : float
        Grasp instant [s] on the twin's clock (``TwinState.t``, 0 at the default start).
    link : str or None
        The body that grasps [model body name]; None (default): the model's last body (cepheus-rw:
        ``link2``, the arm's end link).
    mass : float
        Payload mass [kg]. Default 0.5.
    com : tuple of 2 floats
        Its CoM in the payload frame [m]. Default (0.02, 0.01).
    inertia : 3 x 3 nested tuples or 3 floats
        Inertia about the CoM, payload axes [kg m^2] (3 floats: the principal moments along the
        payload axes); it must be one a rigid body has. Default a solid cylinder of 0.5 kg, radius
        0.05 m and height 0.1 m with a vertical axis (Izz = 6.25e-4).
    position : tuple of 2 floats
        Payload frame origin in the world (table) frame at t = 0 [m]. Default (0.5, 0.1).
    yaw : float
        Payload frame yaw at t = 0 [rad]. Default 0.
    velocity : tuple of 2 floats
        Velocity of its CoM, world axes [m/s]. Default (0, 0).
    rate : float
        Its yaw rate [rad/s]. Default 0.
    """

    time: float
    link: str | None = None
    mass: float = 0.5
    com: tuple = (0.02, 0.01)
    inertia: tuple = field(default_factory=_default_payload_inertia)
    position: tuple = (0.5, 0.1)
    yaw: float = 0.0
    velocity: tuple = (0.0, 0.0)
    rate: float = 0.0

    def __post_init__(self):
        _set(self, "time", _number("capture.time [s]", self.time, low=0.0))
        if self.link is not None and (not isinstance(self.link, str) or not self.link):
            raise SpaceidError(
                f"capture.link must be a body name of the model or None (the last body), got {self.link!r}"
            )
        _set(self, "mass", _number("capture.mass [kg]", self.mass, low=0.0, strict=True))
        for name in ("com", "position", "velocity"):
            pair = _finite_tuple(getattr(self, name), 2)
            if pair is None:
                raise SpaceidError(f"capture.{name} must be 2 finite numbers (x, y), got {getattr(self, name)!r}")
            _set(self, name, pair)
        for name in ("yaw", "rate"):
            _set(self, name, _number(f"capture.{name}", getattr(self, name)))
        _set(self, "inertia", _payload_inertia(self.inertia))

    def inertia_matrix(self) -> np.ndarray:
        """The inertia about the CoM (3, 3) [kg m^2], payload axes."""
        return np.array(self.inertia)


def _payload_inertia(value) -> tuple:
    """:attr:`Capture.inertia` as a checked, symmetric 3 x 3 nested tuple [kg m^2]."""
    diagonal = _finite_tuple(value, 3) if np.ndim(value) == 1 else None
    try:
        matrix = np.diag(diagonal) if diagonal is not None else np.array(value, dtype=float)
    except (TypeError, ValueError):
        matrix = None
    if matrix is None or matrix.shape != (3, 3) or not np.all(np.isfinite(matrix)):
        raise SpaceidError(
            f"capture.inertia must be a 3 x 3 matrix or 3 principal moments [kg m^2], got {value!r}"
        )
    if not np.allclose(matrix, matrix.T, rtol=0, atol=1e-12 * np.abs(matrix).max()):
        raise SpaceidError(f"capture.inertia must be symmetric, got {matrix.tolist()}")
    check_rigid_inertia("capture.inertia: the payload", matrix)
    return tuple(tuple(row) for row in (matrix + matrix.T) / 2)


@dataclass(frozen=True)
class TwinSettings:
    """Everything the twin needs, with units; ``to_dict()`` for provenance.

    Attributes
    ----------
    model : str or Model
        Planar model (preset name or path, or a Model). Default ``"cepheus-rw"``.
    controllers, encoders, mocap : Controllers, Encoders, MotionCapture
    bearing_friction, joint_friction, torque_limits, thrusters, tank :
        The optional effects, each with an ``enabled`` switch.
    table_tilt : float
        Inclination of the table [rad] (gravity component ``g0 sin(tilt)`` in the plane, towards
        azimuth ``tilt_azimuth`` [rad] in the world frame). Default 0 (level; the real table is
        within 0.01 deg = 1.7e-4 rad).
    tilt_azimuth : float
        Default 0.
    capture : Capture or None
        A payload the end effector grasps during the run; None (default): none.
    """

    model: str | Model = "cepheus-rw"
    controllers: Controllers = field(default_factory=Controllers)
    encoders: Encoders = field(default_factory=Encoders)
    mocap: MotionCapture = field(default_factory=MotionCapture)
    bearing_friction: BearingFriction = field(default_factory=BearingFriction)
    joint_friction: JointFriction = field(default_factory=JointFriction)
    torque_limits: TorqueLimits = field(default_factory=TorqueLimits)
    thrusters: Thrusters = field(default_factory=Thrusters)
    tank: Tank = field(default_factory=Tank)
    table_tilt: float = 0.0
    tilt_azimuth: float = 0.0
    capture: Capture | None = None

    def __post_init__(self):
        for f in fields(self):
            expected = {
                "controllers": Controllers, "encoders": Encoders, "mocap": MotionCapture,
                "bearing_friction": BearingFriction, "joint_friction": JointFriction,
                "torque_limits": TorqueLimits, "thrusters": Thrusters, "tank": Tank,
            }.get(f.name)
            if expected and not isinstance(getattr(self, f.name), expected):
                raise SpaceidError(
                    f"settings.{f.name} must be a {expected.__name__}(...), got {getattr(self, f.name)!r}"
                )
        _set(self, "table_tilt", _number("settings.table_tilt [rad]", self.table_tilt, low=0.0))
        if self.table_tilt >= math.pi / 2:
            raise SpaceidError(f"settings.table_tilt must be below pi/2 rad, got {self.table_tilt:g}")
        _set(self, "tilt_azimuth", _number("settings.tilt_azimuth [rad]", self.tilt_azimuth))
        if self.capture is not None and not isinstance(self.capture, Capture):
            raise SpaceidError(f"settings.capture must be a Capture(time=...) or None, got {self.capture!r}")

    def without_effects(self) -> "TwinSettings":
        """The same settings with friction, torque limits, thrusters, tank drain and tilt off (a
        capture stays)."""
        return replace(
            self,
            bearing_friction=replace(self.bearing_friction, enabled=False),
            joint_friction=replace(self.joint_friction, enabled=False),
            torque_limits=replace(self.torque_limits, enabled=False),
            thrusters=replace(self.thrusters, enabled=False),
            tank=replace(self.tank, enabled=False),
            table_tilt=0.0,
        )

    def to_dict(self) -> dict:
        """JSON-ready dictionary of every value (the model by name or source)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "model":
                out["model"] = _model_name(value)
            else:
                out[f.name] = _plain(value)
        return out


def _plain(value):
    """Dataclasses, tuples, dicts and numpy values as plain JSON types (inf as a string)."""
    if is_dataclass(value):
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _check_joint_names(settings: TwinSettings, model: Model):
    """Every joint a per-joint setting names is in ``model``, or a SpaceidError naming the setting."""
    c, jf = settings.controllers, settings.joint_friction
    named = [
        ("controllers.position", c.position),
        ("controllers.velocity", c.velocity),
        ("encoders.counts_per_rev", settings.encoders.counts_per_rev),
        ("joint_friction.viscous", jf.viscous),
        ("joint_friction.coulomb", jf.coulomb),
    ]
    if settings.torque_limits.effort is not None:
        named.append(("torque_limits.effort", settings.torque_limits.effort))
    for where, names in named:
        unknown = [n for n in names if n not in model.joints]
        if unknown:
            raise SpaceidError(
                f"{where} names joint '{unknown[0]}', which is not in model {model.name} "
                f"(joints: {', '.join(model.joints)}): use one of these names"
            )


# ------------------------------------------------------------------ the servicer twin ---------


def _vector3(where, value) -> tuple:
    """``value`` as 3 finite floats, or a SpaceidError naming ``where``."""
    out = _finite_tuple(value, 3)
    if out is None:
        raise SpaceidError(f"{where} must be 3 finite numbers (x, y, z), got {value!r}")
    return out


@dataclass(frozen=True)
class JointControl:
    """The servicer's joint controllers: computed torque through the lab's (CAD) model.

    At every control tick ``tau = H*_cad (qdd_r + kd (qd_r - qd_m) + kp (q_r - q_m)) + b_cad``:
    ``H*_cad`` and ``b_cad`` the free-floating joint-space inertia and bias torque of the lab's
    model (Pinocchio's ``crba`` and ``rnea`` with the base unactuated), ``q_m`` the servo's
    reading (the encoder count, without the logged readings' white noise: a motor-side encoder
    seen through the gear) and ``qd_m`` its difference over the last control period, the base
    attitude and rate the true ones (an attitude estimator's). The efforts
    are saturated and held over the period. With the model off by ``e`` the joints follow the
    reference with errors of about ``e |qdd_r| / kp``: the executed motion is not the designed one.

    Attributes
    ----------
    rate : float
        Control rate [Hz]. Default 100 (a flight computer's joint loop).
    kp : float
        Position gain [1/s^2] (an acceleration per unit error). Default 25 (5 rad/s).
    kd : float
        Rate gain [1/s]. Default 10 (critical damping with ``kp``).
    model : Model or str or None
        The lab's model the law uses; None (default): the twin's model with every mass and
        principal moment ``model_error`` off (:func:`spaceid.models.perturbed_model`, ``exact``,
        seeded ``model_seed``): a CAD model.
    model_error : float
        Relative error of that CAD model's masses and moments, in [0, 1). Default 0.15.
    model_seed : int
        Seed of the CAD model's errors. Default 0.
    substeps : int
        RK4 steps of the plant per control period. Default 5 (2 ms at 100 Hz).
    """

    rate: float = 100.0
    kp: float = 25.0
    kd: float = 10.0
    model: object = None
    model_error: float = 0.15
    model_seed: int = 0
    substeps: int = 5

    def __post_init__(self):
        _set(self, "rate", _number("control.rate [Hz]", self.rate, low=0.0, strict=True))
        _set(self, "kp", _number("control.kp [1/s^2]", self.kp, low=0.0))
        _set(self, "kd", _number("control.kd [1/s]", self.kd, low=0.0))
        error = _number("control.model_error", self.model_error, low=0.0)
        if error >= 1:
            raise SpaceidError(f"control.model_error must be in [0, 1), got {error:g}")
        _set(self, "model_error", error)
        for name in ("model_seed", "substeps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < (name == "substeps"):
                raise SpaceidError(f"control.{name} must be an integer{' >= 1' if name == 'substeps' else ''}, "
                                   f"got {value!r}")  # fmt: skip
            _set(self, name, int(value))


@dataclass(frozen=True)
class JointEncoders:
    """Absolute joint encoders: white noise, then quantised.

    The logged reading is ``round((q + n) / r) r`` with ``n ~ N(0, noise^2)`` independent per
    tick and joint and ``r = 2 pi / counts_per_rev``, at ``rate``, stamped at the tick (the
    controllers read the count ``round(q / r) r`` at every tick). No joint-rate sensor: the log
    has no joint rates.

    Attributes
    ----------
    noise : float
        Standard deviation of the white noise [rad]. Default 1e-4.
    counts_per_rev : int or None
        Counts per revolution (None: no quantisation). Default 2**18 (r = 2.4e-5 rad).
    rate : float
        Log rate [Hz]; divides the control rate. Default 50.
    """

    noise: float = 1e-4
    counts_per_rev: int | None = 2**18
    rate: float = 50.0

    def __post_init__(self):
        _set(self, "noise", _number("encoders.noise [rad]", self.noise, low=0.0))
        if self.counts_per_rev is not None:
            _set(self, "counts_per_rev", int(_number("encoders.counts_per_rev", self.counts_per_rev, low=1.0)))
        _set(self, "rate", _number("encoders.rate [Hz]", self.rate, low=0.0, strict=True))

    @property
    def resolution(self) -> float:
        """The count [rad]; 0 without quantisation."""
        return 0.0 if self.counts_per_rev is None else 2 * math.pi / self.counts_per_rev


@dataclass(frozen=True)
class StarTracker:
    """A star tracker: the base attitude with noise, latency and lost frames.

    A frame captured at ``t`` (a multiple of ``1 / rate``) holds the true attitude at ``t`` turned
    by a small rotation ``exp([n]x)``, ``n ~ N(0, noise^2)`` per base axis, and is stamped
    ``t + latency`` (on arrival); each frame is lost with probability ``drop_probability``.

    Attributes
    ----------
    rate : float
        Frame rate [Hz]; divides the control rate. Default 10.
    noise : float
        Standard deviation of the rotation per base axis [rad]. Default 5e-5 (10 arcsec).
    latency : float
        Stamp minus capture time [s]; the lab knows it (the log is read with it). Default 0.02.
    drop_probability : float
        Probability that a frame is lost, in [0, 1). Default 0.02.
    """

    rate: float = 10.0
    noise: float = 5e-5
    latency: float = 0.02
    drop_probability: float = 0.02

    def __post_init__(self):
        _set(self, "rate", _number("star_tracker.rate [Hz]", self.rate, low=0.0, strict=True))
        for name in ("noise", "latency"):
            _set(self, name, _number(f"star_tracker.{name}", getattr(self, name), low=0.0))
        _set(self, "drop_probability", _probability("star_tracker.drop_probability", self.drop_probability))


@dataclass(frozen=True)
class Gyro:
    """Rate gyros on the base: the true rate (base axes) plus a constant bias, a random walk of
    the bias and white noise, sampled with the encoders (at :attr:`JointEncoders.rate`).

    ``w_m(t_k) = w(t_k) + bias + b_k + n_k``, ``b_0 = 0``, ``b_k = b_{k-1} + walk sqrt(dt) N(0, 1)``,
    ``n_k ~ N(0, noise^2)``, per axis.

    Attributes
    ----------
    noise : float
        Standard deviation of the white noise [rad/s]. Default 1e-5.
    bias : tuple of 3 floats
        Constant bias, base axes [rad/s]. Default (2e-6, -1e-6, 1.5e-6) (about 0.5 deg/h, a
        navigation-grade gyro after calibration; a MEMS gyro's is ~3e-4).
    walk : float
        Rate random walk of the bias [rad/s/sqrt(s)]. Default 1e-8.
    """

    noise: float = 1e-5
    bias: tuple = (2e-6, -1e-6, 1.5e-6)
    walk: float = 1e-8

    def __post_init__(self):
        _set(self, "noise", _number("gyro.noise [rad/s]", self.noise, low=0.0))
        _set(self, "bias", _vector3("gyro.bias [rad/s]", self.bias))
        _set(self, "walk", _number("gyro.walk [rad/s/sqrt(s)]", self.walk, low=0.0))


@dataclass(frozen=True)
class ServicerSettings:
    """Everything the servicer twin needs, with units; ``to_dict()`` for provenance.

    Attributes
    ----------
    model : str or Model
        A spatial model (preset name, URDF or YAML path, or a Model). Default ``"servicer-dual"``.
    control : JointControl
    encoders : JointEncoders
    star_tracker : StarTracker
    gyro : Gyro
    torque_limits : TorqueLimits
        Default: the model's joint effort limits (servicer-dual: 250 and 150 N m).
    """

    model: str | Model = "servicer-dual"
    control: JointControl = field(default_factory=JointControl)
    encoders: JointEncoders = field(default_factory=JointEncoders)
    star_tracker: StarTracker = field(default_factory=StarTracker)
    gyro: Gyro = field(default_factory=Gyro)
    torque_limits: TorqueLimits = field(default_factory=TorqueLimits)

    def __post_init__(self):
        for name, kind in (("control", JointControl), ("encoders", JointEncoders), ("star_tracker", StarTracker),
                           ("gyro", Gyro), ("torque_limits", TorqueLimits)):  # fmt: skip
            if not isinstance(getattr(self, name), kind):
                raise SpaceidError(f"settings.{name} must be a {kind.__name__}(...), got {getattr(self, name)!r}")

    def without_noise(self) -> "ServicerSettings":
        """The same settings with exact sensors (no noise, quantisation, bias, latency or lost
        frames); the controllers and their model unchanged."""
        return replace(
            self,
            encoders=replace(self.encoders, noise=0.0, counts_per_rev=None),
            star_tracker=replace(self.star_tracker, noise=0.0, latency=0.0, drop_probability=0.0),
            gyro=Gyro(noise=0.0, bias=(0.0, 0.0, 0.0), walk=0.0),
        )

    def to_dict(self) -> dict:
        """JSON-ready dictionary of every value (models by name or source)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            out[f.name] = _model_name(value) if f.name == "model" else _plain(value)
        if self.control.model is not None:
            out["control"]["model"] = _model_name(self.control.model)
        return out


def _model_name(value) -> str:
    """A model as provenance records it: its source or name (a Model), else the string given."""
    return value.source or value.name if isinstance(value, Model) else str(value)
