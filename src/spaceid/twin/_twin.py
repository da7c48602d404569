"""Torque-driven digital twin of the Cepheus air-bearing emulator.

The twin integrates the rigid-body dynamics of a planar model (default the ``cepheus-rw``
preset: base, reaction-wheel rotor, two-link arm) whose base floats on the granite table in x,
y and yaw, under the torques of ros_control-like effort controllers, and records what the
robot's sensors would publish: encoder joint states and the motion-capture pose of the base.

API
---
Everything is a free function or a frozen dataclass::

    settings = TwinSettings()                       # the realistic twin; every value overridable
    a = spin_up(170.0, settings=settings, seed=1)   # rest -> wheel at 170 rad/s relative to the base
    b = run_twin(load_trajectory("paper-table2"), duration=6.0, state=a.state,
                 settings=settings, seed=2)         # exciting trajectory (tf = 5 s), then hold
    run = join_runs(a, b)                           # one continuous recording
    run.recording      # spaceid.data.Recording: /joint_states (50 Hz) and mocap poses
    run.truth          # spaceid.data.Log at the control rate (planar, true q, qd, yaw, rate)
    run.base_position, run.base_velocity, run.effort, run.co2_mass   # more true histories
    run.state          # TwinState at the end: the start of the next phase

* :func:`run_twin` ``(reference=None, *, duration, wheel_speed=None, settings, state, seed)``
  runs one phase from ``state`` (default: at rest at the origin, full tank). ``reference``
  drives the position-controlled joints: a :class:`~spaceid.motion.FourierTrajectory`
  (joints matched by name, held at its end value after ``tf``), a callable
  ``reference(t) -> (q_ref, qd_ref[, qdd_ref])`` with ``t`` of shape (n,) [s] since the start of
  the phase and arrays of shape (n, n_position_joints) in model joint order, or None to hold
  the last commands. ``wheel_speed`` [rad/s] is the velocity set point of the velocity-controlled
  joints (a number or a callable of the phase time), None to hold the last command.
* :func:`spin_up` ramps the wheel set point to ``speed`` and lets it settle, arm holding.
* :func:`join_runs` concatenates consecutive phases into one run.
* :func:`planar_pinocchio` builds the Pinocchio model (root PX, PY, RZ) and
  :func:`drained_model` the :class:`~spaceid.models.Model` with a partly empty CO2 tank.

Dynamics
--------
Generalised coordinates ``q_pin = [x, y, yaw, q_1 .. q_n]`` ([m, m, rad, rad ...]): the base
origin position in the table (world) frame, the base yaw, then the joints in model order;
``v_pin`` is their time derivative (the base x, y rates are world-frame velocities, so
``d q_pin / dt = v_pin`` exactly). Accelerations come from Pinocchio's articulated-body algorithm
(``pin.aba``) with the base forces (air-bearing friction, thrusters) as an external force on the
base joint (``fext``, base frame). The equations are integrated with the classical fourth-order
Runge-Kutta method at the control period ``dt = 1 / Controllers.rate``. The efforts are held
over a step (zero-order hold, as the hardware applies them), and so are the friction forces and
the thrust, evaluated from the state at the start of the step: first order in the friction terms,
which is accurate where friction is sliding (``|qd|`` well above the tanh scale, an almost
constant force) and a stable, monotone approximation of the regularised stiction band as long as
``(c + F_c / s) dt / I_eff <= 1`` for every joint and base axis (checked at the start of a run; an
error names the setting otherwise). With friction and thrusters off the total angular and linear
momentum are conserved to ~2e-12 relative over 30 s at 1 kHz (tested to 1e-9): the local error is
O((lambda dt)^5), lambda the fastest closed-loop rate (~10 rad/s here).

Sensors and time stamps
-----------------------
The hardware loop runs at the control rate. At every tick the encoders are read (positions
quantised to ``2 pi / counts_per_rev``, rounded to the nearest count, zero at the joint zero: the
joints are homed), the hardware interface forms joint velocities as the finite difference of two
successive encoder readings (what a typical ros_control ``RobotHW`` reports), the controllers
compute efforts from these readings, and the efforts (saturated at the limits) are applied until
the next tick. ``/joint_states`` is published at ``Encoders.rate`` (50 Hz) from the tick at or
after each multiple of its period; its stamp is the tick time, its velocity the hardware finite
difference (or None, see ``Encoders.velocity``), its effort the applied effort. Motion capture
samples the true base pose at multiples of ``1 / MotionCapture.rate``, adds Gaussian noise, drops
frames with probability ``drop_probability`` and stamps each frame ``latency`` seconds *after*
its capture (the driver stamps on arrival): the pose stamped ``t`` was true at ``t - latency``.
Poses carry ``(x, y, 0)`` and the quaternion of the yaw, wrapped so that ``w >= 0``. Only the
motion capture is random; it draws from ``numpy.random.default_rng(seed)`` (noise and drops from
independent child streams), and the seed is recorded in ``meta``.

Simplifications
---------------
The arm motors sit on the base and drive the joints through belts: modelled as rigid
transmissions, an effort acting between parent and child, without motor rotor inertia or belt
compliance. The air bearings carry the base only through its planar motion (no tilt, no
out-of-plane dynamics). Thrust is constant while a valve is open (a regulated supply) and stops
when the tank is empty. The feed-forward term reads the true base velocity (on the robot it would
come from the motion capture).

Phases
------
A run covers ``[state.t, state.t + duration]``: the true history includes both ends, the sensor
streams are stamped on absolute time grids in ``[t0, t_end)`` (so consecutive phases continue the
same grids) and :func:`join_runs` drops the repeated boundary sample. The state carries the
controller memory (set points, integral terms, last encoder reading), so a phase split in two
gives the same true motion as one phase.

References
----------
Papadopoulos et al., identification of free-floating space robots from angular momentum
conservation, sections "The NTUA CSL emulator" and "Experiment results" (seed paper): three air
bearings fed with CO2 from an on-board tank (1.5 kg full, 60 bar) that also feeds three pairs of
opposed thrusters at 120 deg; a reaction wheel with I_rw = 0.00197372 kg m^2 spun to 170 rad/s;
arm joints under ros_control ``effort_controllers/JointPositionController`` (PD) and the wheel
under ``effort_controllers/JointVelocityController`` (PI); tf = 5 s. ``../shared/design/MATH.md``
section 5 (reaction wheel momentum).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, is_dataclass, replace

import numpy as np

from .._errors import SpaceidError, finite_array
from ..models import Model, inertial_vector, load_model, to_pinocchio
from ..data import JointStates, Poses, Recording
from ..motion import hermite_motion
from ..data import Log, yaw_to_quat
from ..motion import FourierTrajectory

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
    "TwinSettings",
    "TwinState",
    "TwinRun",
    "planar_pinocchio",
    "drained_model",
    "thruster_wrenches",
    "run_twin",
    "spin_up",
    "join_runs",
]

G0 = 9.80665
"""Standard gravity [m/s^2] (specific impulse and table tilt)."""

_BASE_JOINTS = ("base_x", "base_y", "base_yaw")


# ------------------------------------------------------------------ validation helpers -------


def _number(where, value, *, low=None, strict=False, allow_inf=False):
    """``value`` as a float, or a SpaceidError naming ``where``."""
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


def _check_names(where, names, model: Model):
    unknown = [n for n in names if n not in model.joints]
    if unknown:
        raise SpaceidError(
            f"{where} names joint '{unknown[0]}', which is not in model {model.name} "
            f"(joints: {', '.join(model.joints)}): use one of these names"
        )


def _set(obj, name, value):
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
        p = _number("mocap.drop_probability", self.drop_probability, low=0.0)
        if p >= 1:
            raise SpaceidError(f"mocap.drop_probability must be in [0, 1), got {p:g}")
        _set(self, "drop_probability", p)


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
        try:
            angles = tuple(float(a) for a in self.angles)
        except (TypeError, ValueError):
            angles = ()
        if len(angles) != 3 or not all(math.isfinite(a) for a in angles):
            raise SpaceidError(f"thrusters.angles must be 3 finite angles [rad], got {self.angles!r}")
        _set(self, "angles", angles)
        entries = []
        for i, entry in enumerate(self.schedule):
            where = f"thrusters.schedule[{i}]"
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
            entries.append((t_on, t_off, int(pair), int(sign)))
        _set(self, "schedule", tuple(entries))


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
        try:
            pos = tuple(float(p) for p in self.position)
        except (TypeError, ValueError):
            pos = ()
        if len(pos) != 2 or not all(math.isfinite(p) for p in pos):
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

    def without_effects(self) -> "TwinSettings":
        """The same settings with friction, torque limits, thrusters, tank drain and tilt off."""
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
                out["model"] = value.source or value.name if isinstance(value, Model) else str(value)
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
        Seeds, settings, model, CO2 mass at start and end, per-phase records.
    """

    recording: Recording
    truth: Log
    base_position: np.ndarray
    base_velocity: np.ndarray
    effort: np.ndarray
    co2_mass: np.ndarray
    state: TwinState
    meta: dict = field(default_factory=dict, compare=False)


# ------------------------------------------------------------------ models --------------------


def planar_pinocchio(model: Model):
    """A Pinocchio model of a planar ``model`` with the base on the table.

    The root is three joints ``base_x`` (prismatic x), ``base_y`` (prismatic y), ``base_yaw``
    (revolute z) carrying the base body, so ``q_pin = [x, y, yaw, joints...]`` and ``v_pin =
    dq_pin/dt``; the joints, their placements and the body inertias are those of
    :func:`spaceid.models.to_pinocchio` (same order). Gravity is zero (level table).

    Parameters
    ----------
    model : Model
        A planar model (``model.planar``).

    Returns
    -------
    pinocchio.Model
        ``nq = nv = 3 + n_joints``; ``getJointId("base_yaw")`` carries the base.
    """
    import pinocchio as pin

    if not model.planar:
        raise SpaceidError(
            f"model {model.name} is not planar: the twin moves on a table; load it with planar=True"
        )
    spatial = to_pinocchio(model)  # free-flyer root; joint 1 is the base
    pmodel = pin.Model()
    pmodel.name = model.name
    parent = 0
    for name, joint in zip(_BASE_JOINTS, (pin.JointModelPX(), pin.JointModelPY(), pin.JointModelRZ())):
        parent = pmodel.addJoint(parent, joint, pin.SE3.Identity(), name)
    ids = {1: parent}
    for j in range(1, spatial.njoints):
        if j > 1:
            ids[j] = pmodel.addJoint(ids[spatial.parents[j]], spatial.joints[j], spatial.jointPlacements[j], spatial.names[j])
        pmodel.appendBodyToJoint(ids[j], spatial.inertias[j], pin.SE3.Identity())
        pmodel.addBodyFrame(model.bodies[j - 1].name, ids[j], pin.SE3.Identity(), 0)
    pmodel.gravity = pin.Motion.Zero()
    return pmodel


def drained_model(model: Model, tank: Tank, co2_mass: float) -> Model:
    """``model`` with ``co2_mass`` [kg] left in a tank that is full (``tank.co2_mass``) in it.

    Returns
    -------
    Model
        A copy whose base inertial parameters are ``base - (tank.co2_mass - co2_mass) * unit``.
    """
    used = tank.co2_mass - float(co2_mass)
    inertials = np.array([b.inertial for b in model.bodies])
    inertials[0] = inertials[0] - used * tank.unit_inertial()
    return model.with_inertials(inertials)


def thruster_wrenches(thrusters: Thrusters) -> np.ndarray:
    """Wrench of each open valve on the base, base frame.

    Returns
    -------
    ndarray of shape (6, 3)
        Row ``2 k`` thruster (k, +1), row ``2 k + 1`` thruster (k, -1); columns ``[Fx, Fy, Mz]``
        [N, N, N m] about the base origin.
    """
    rows = []
    for a in thrusters.angles:
        r = thrusters.radius * np.array([math.cos(a), math.sin(a)])
        f = thrusters.force * np.array([-math.sin(a), math.cos(a)])  # counter-clockwise tangent
        mz = r[0] * f[1] - r[1] * f[0]
        rows += [[f[0], f[1], mz], [-f[0], -f[1], -mz]]
    return np.array(rows)


# ------------------------------------------------------------------ the run -------------------


@dataclass(frozen=True)
class _Plant:
    """Everything derived once from settings and model for a run."""

    model: Model
    pmodel: object
    base_id: int
    n: int  # joints
    pos_mask: np.ndarray
    vel_mask: np.ndarray
    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    i_clamp: np.ndarray
    resolution: np.ndarray  # 0: exact
    limit: np.ndarray  # inf: none
    viscous: np.ndarray
    coulomb: np.ndarray


def _plant(settings: TwinSettings) -> _Plant:
    model = settings.model if isinstance(settings.model, Model) else load_model(settings.model)
    if not model.planar:
        raise SpaceidError(
            f"settings.model: model {model.name} is not planar: the twin needs a planar model "
            "(a YAML model with 'planar: true' or load_model(..., planar=True))"
        )
    c = settings.controllers
    _check_names("controllers.position", c.position, model)
    _check_names("controllers.velocity", c.velocity, model)
    _check_names("encoders.counts_per_rev", settings.encoders.counts_per_rev, model)
    _check_names("joint_friction.viscous", settings.joint_friction.viscous, model)
    _check_names("joint_friction.coulomb", settings.joint_friction.coulomb, model)
    if settings.torque_limits.effort is not None:
        _check_names("torque_limits.effort", settings.torque_limits.effort, model)
    if settings.encoders.rate > c.rate * (1 + 1e-12):
        raise SpaceidError(
            f"encoders.rate = {settings.encoders.rate:g} Hz exceeds controllers.rate = {c.rate:g} Hz: "
            "joint states cannot be published faster than the hardware loop; lower encoders.rate"
        )
    joints = model.joints
    gains = {**c.position, **c.velocity}
    pid = [gains.get(j, PID()) for j in joints]
    counts = settings.encoders.counts_per_rev
    resolution = np.array([2 * math.pi / counts[j] if counts.get(j) else 0.0 for j in joints])
    if settings.torque_limits.enabled:
        given = settings.torque_limits.effort
        source = given if given is not None else dict(zip(joints, model.joint_limits("effort")))
        limit = np.array([source.get(j, math.inf) for j in joints], float)
        limit[~np.isfinite(limit) | (limit <= 0)] = math.inf
    else:
        limit = np.full(len(joints), math.inf)
    jf = settings.joint_friction
    tank = settings.tank
    if tank.enabled:
        base_left = model.bodies[0].inertial - tank.co2_mass * tank.unit_inertial()
        dry = np.linalg.eigvalsh(_com_inertia(base_left)) if base_left[0] > 0 else [-1.0]
        if min(dry) <= 0:
            raise SpaceidError(
                f"tank.co2_mass = {tank.co2_mass:g} kg leaves the base (mass {model.bodies[0].mass:g} kg, "
                "inertia of the full base) without a physical dry mass and inertia: lower tank.co2_mass "
                "or move tank.position closer to the base origin"
            )
    pmodel = planar_pinocchio(model)
    viscous = np.array([jf.viscous.get(j, 0.0) for j in joints]) if jf.enabled else np.zeros(len(joints))
    coulomb = np.array([jf.coulomb.get(j, 0.0) for j in joints]) if jf.enabled else np.zeros(len(joints))
    _check_friction_step(pmodel, settings, joints, viscous + coulomb / jf.rate_scale, 1.0 / c.rate)
    if settings.table_tilt:
        import pinocchio as pin

        g = G0 * math.sin(settings.table_tilt)
        pmodel.gravity = pin.Motion(
            np.array([g * math.cos(settings.tilt_azimuth), g * math.sin(settings.tilt_azimuth), 0.0]), np.zeros(3)
        )
    return _Plant(
        model=model,
        pmodel=pmodel,
        base_id=pmodel.getJointId("base_yaw"),
        n=len(joints),
        pos_mask=np.array([j in c.position for j in joints]),
        vel_mask=np.array([j in c.velocity for j in joints]),
        kp=np.array([g.p for g in pid]),
        ki=np.array([g.i for g in pid]),
        kd=np.array([g.d for g in pid]),
        i_clamp=np.array([g.i_clamp for g in pid]),
        resolution=resolution,
        limit=limit,
        viscous=viscous,
        coulomb=coulomb,
    )


def _com_inertia(inertial) -> np.ndarray:
    """Inertia about the CoM (3, 3) [kg m^2] of standard inertial parameters (10,)."""
    import pinocchio as pin

    return np.array(pin.Inertia.FromDynamicParameters(np.asarray(inertial, float)).inertia)


def _check_friction_step(pmodel, settings, joints, joint_damping, dt):
    """Friction held over a step must not overshoot: ``damping dt / I_eff <= 1`` per axis.

    ``damping`` is the slope of the friction law at rest (``c + F_c / s``) and ``I_eff`` the
    effective (articulated) inertia ``1 / (M^-1)_ii`` at the zero configuration, where it is
    smallest for a stretched arm.
    """
    import pinocchio as pin

    minv = pin.computeMinverse(pmodel, pmodel.createData(), np.zeros(pmodel.nq))
    inertia = 1.0 / np.diag(np.triu(minv) + np.triu(minv, 1).T)
    bf = settings.bearing_friction
    damping = np.zeros(pmodel.nv)
    if bf.enabled:
        damping[:2] = bf.viscous_force + bf.coulomb_force / bf.speed_scale
        damping[2] = bf.viscous_torque + bf.coulomb_torque / bf.rate_scale
    damping[3:] = joint_damping
    ratio = damping * dt / inertia
    worst = int(np.argmax(ratio))
    if ratio[worst] > 1.0:
        if worst < 2:
            what, axis = "bearing_friction.speed_scale (or lower coulomb_force)", ("base x", "base y")[worst]
        elif worst == 2:
            what, axis = "bearing_friction.rate_scale (or lower coulomb_torque)", "base yaw"
        else:
            what, axis = "joint_friction.rate_scale (or its coulomb/viscous values)", f"joint '{joints[worst - 3]}'"
        raise SpaceidError(
            f"friction on {axis} is too stiff for the control period: slope x dt / inertia = "
            f"{ratio[worst]:.3g} > 1 (slope {damping[worst]:.3g}, inertia {inertia[worst]:.3g}): "
            f"raise {what} or controllers.rate"
        )


def _quantise(q, resolution):
    """Encoder readings: ``round(q / r) r`` where ``r > 0``; exact where ``r == 0`` (the same
    arithmetic as the hardware loop of :func:`_integrate`)."""
    r = np.where(resolution > 0, resolution, 1.0)
    return np.where(resolution > 0, np.round(q * (1.0 / r)) * r, q)


def _joint_state(plant: _Plant, state: TwinState | None, settings: TwinSettings) -> TwinState:
    """``state`` with every None field resolved for ``plant``."""
    n = plant.n
    state = state if state is not None else TwinState()
    if not isinstance(state, TwinState):
        raise SpaceidError(f"state must be a TwinState (e.g. a previous run's .state), got {type(state).__name__}")
    q = np.zeros(n) if state.q is None else _vector("state.q", state.q, n)
    qd = np.zeros(n) if state.qd is None else _vector("state.qd", state.qd, n)
    command = np.where(plant.pos_mask, q, qd) if state.command is None else _vector("state.command", state.command, n)
    i_term = np.zeros(n) if state.i_term is None else _vector("state.i_term", state.i_term, n)
    prev = _quantise(q, plant.resolution) if state.encoder_prev is None else _vector("state.encoder_prev", state.encoder_prev, n)
    co2 = settings.tank.co2_mass if state.co2_mass is None else state.co2_mass
    if settings.tank.enabled and co2 > settings.tank.co2_mass * (1 + 1e-12):
        raise SpaceidError(
            f"state.co2_mass = {co2:g} kg exceeds the full tank (tank.co2_mass = {settings.tank.co2_mass:g} kg)"
        )
    return replace(state, q=q, qd=qd, command=command, i_term=i_term, encoder_prev=prev, co2_mass=co2)


def _references(plant, reference, wheel_speed, times, t0, state):
    """Set points over ``times``: command (n_t, n) [rad or rad/s], rate and acceleration (n_t, n)."""
    n_t, n = len(times), plant.n
    tau = times - t0
    command = np.tile(state.command, (n_t, 1))
    rate = np.zeros((n_t, n))
    accel = np.zeros((n_t, n))
    pos = np.flatnonzero(plant.pos_mask)
    joints = plant.model.joints
    if reference is not None:
        if isinstance(reference, FourierTrajectory):
            wanted = [joints[i] for i in pos]
            if set(reference.joints) != set(wanted):
                raise SpaceidError(
                    f"reference drives joints ({', '.join(reference.joints)}) but the position-controlled "
                    f"joints are ({', '.join(wanted)}): give a trajectory for these joints or change "
                    "controllers.position"
                )
            order = [reference.joints.index(j) for j in wanted]
            clipped = np.minimum(tau, reference.duration)
            q_ref, qd_ref, qdd_ref = (x[:, order] for x in reference.evaluate(clipped))
            after = tau > reference.duration
            qd_ref[after], qdd_ref[after] = 0.0, 0.0
        elif callable(reference):
            out = reference(tau)
            if not isinstance(out, tuple) or len(out) not in (2, 3):
                raise SpaceidError("reference(t) must return (q_ref, qd_ref) or (q_ref, qd_ref, qdd_ref)")
            try:
                q_ref, qd_ref = (np.asarray(x, float).reshape(n_t, -1) for x in out[:2])
                qdd_ref = (
                    np.asarray(out[2], float).reshape(n_t, -1)
                    if len(out) == 3
                    else (np.gradient(qd_ref, tau, axis=0) if n_t > 1 else np.zeros_like(qd_ref))
                )
            except (TypeError, ValueError):
                raise SpaceidError(
                    f"reference(t) must return arrays of shape (len(t), n_position_joints) = ({n_t}, {len(pos)})"
                ) from None
            if q_ref.shape[1] != len(pos) or qd_ref.shape[1] != len(pos):
                raise SpaceidError(
                    f"reference(t) returned {q_ref.shape[1]} columns; expected one per position-controlled "
                    f"joint ({', '.join(joints[i] for i in pos)})"
                )
        else:
            raise SpaceidError(
                f"reference must be a FourierTrajectory, a callable t -> (q_ref, qd_ref) or None, got {type(reference).__name__}"
            )
        if not (np.all(np.isfinite(q_ref)) and np.all(np.isfinite(qd_ref)) and np.all(np.isfinite(qdd_ref))):
            raise SpaceidError("reference: the set points contain NaN or infinite values")
        command[:, pos], rate[:, pos], accel[:, pos] = q_ref, qd_ref, qdd_ref
    vel = np.flatnonzero(plant.vel_mask)
    if wheel_speed is not None and len(vel):
        if callable(wheel_speed):
            w = np.asarray(wheel_speed(tau), float)
            w = np.broadcast_to(w.reshape(n_t, -1) if w.ndim else w, (n_t, len(vel)))
        else:
            w = np.full((n_t, len(vel)), _number("wheel_speed [rad/s]", wheel_speed))
        if not np.all(np.isfinite(w)):
            raise SpaceidError("wheel_speed: the set points contain NaN or infinite values")
        command[:, vel] = w
    return command, rate, accel


def _valves(thrusters: Thrusters, times, dt) -> np.ndarray:
    """Open valves per tick, shape (n_t, 6) bool (rows of :func:`thruster_wrenches`): open from
    the first tick at or after ``t_on`` to the last one before ``t_off`` (to within 1e-6 dt)."""
    open_ = np.zeros((len(times), 6), bool)
    eps = 1e-6 * dt
    if thrusters.enabled:
        for t_on, t_off, pair, sign in thrusters.schedule:
            open_[(times >= t_on - eps) & (times < t_off - eps), 2 * pair + (0 if sign > 0 else 1)] = True
    return open_


def _integrate(plant, settings, state, command, rate, accel, valves, dt):
    """The hardware loop and RK4 integration over ``len(command) - 1`` steps.

    Per tick: read the encoders, run the controllers, saturate, evaluate friction and thrust at
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
    import pinocchio as pin

    n_steps = len(command) - 1
    nj = plant.n
    nq = 3 + nj
    pm = plant.pmodel
    data = pm.createData()
    aba = pin.aba
    base_id = plant.base_id
    fext = pin.StdVec_Force()
    for _ in range(pm.njoints):
        fext.append(pin.Force.Zero())
    f_base = fext[base_id].vector  # a view of the base force in fext [f; torque], base frame

    bf = settings.bearing_friction
    bearing = bool(bf.enabled and (bf.viscous_force or bf.coulomb_force or bf.viscous_torque or bf.coulomb_torque))
    c_lin, fc_lin, vs_inv = bf.viscous_force, bf.coulomb_force, 1.0 / bf.speed_scale
    c_rot, fc_rot, ws_inv = bf.viscous_torque, bf.coulomb_torque, 1.0 / bf.rate_scale

    tank = settings.tank
    wrench = thruster_wrenches(settings.thrusters)  # (6, 3) base frame
    flow_per_valve = settings.thrusters.force / (tank.isp * G0)
    unit = tank.unit_inertial()
    base_full = plant.model.bodies[0].inertial
    co2 = float(state.co2_mass)
    if tank.enabled:
        pm.inertias[base_id] = pin.Inertia.FromDynamicParameters(base_full - (tank.co2_mass - co2) * unit)
    thrust_steps = valves.any(axis=1).tolist()
    n_open = valves.sum(axis=1).tolist()
    thrust_b = (valves.astype(float) @ wrench).tolist()  # per tick [Fx, Fy, Mz], base frame
    use_fext = bearing or any(thrust_steps)
    drains = tank.enabled and (tank.bearing_flow > 0 or any(thrust_steps))
    bearing_flow = tank.bearing_flow

    X, QM, EFF = [], [], []  # appended per tick (cheaper than row writes), stacked at the end
    CO2 = np.full(n_steps + 1, co2)
    # RK4 works on W = [q, v, a1, a2, a3, a4] (rows): every stage input and the update are fixed
    # linear combinations of these rows, one small matrix product each (Butcher tableau of the
    # classical RK4 with d q / dt = v, written in Runge-Kutta-Nystrom form)
    W = np.zeros((6, nq))
    W[0], W[1] = state.q_pin, state.v_pin
    q, v = W[0], W[1]  # views

    # per-joint constants as Python floats (scalar code is faster than numpy on 3 joints)
    kind = [1 if p else (2 if w else 0) for p, w in zip(plant.pos_mask, plant.vel_mask)]
    res = plant.resolution.tolist()
    inv_r = [1.0 / r if r > 0 else 0.0 for r in res]
    kp, kd = plant.kp.tolist(), plant.kd.tolist()
    kidt = (plant.ki * dt).tolist()
    clamp, lim = plant.i_clamp.tolist(), plant.limit.tolist()
    visc, coul = plant.viscous.tolist(), plant.coulomb.tolist()
    s_inv = 1.0 / settings.joint_friction.rate_scale
    joint_friction = any(visc) or any(coul)
    joints_idx = range(nj)
    i_term = state.i_term.tolist()
    prev = state.encoder_prev.tolist()
    commands, rates = command.tolist(), rate.tolist()
    inv_dt = 1.0 / dt
    h2, h6, hh2, hh4, hh6 = dt / 2, dt / 6, dt * dt / 2, dt * dt / 4, dt * dt / 6
    stage2 = np.array([[1, h2, 0, 0, 0, 0], [0, 1, h2, 0, 0, 0]])  # q + dt/2 v, v + dt/2 a1
    stage3 = np.array([[1, h2, hh4, 0, 0, 0], [0, 1, 0, h2, 0, 0]])  # q + dt/2 v2, v + dt/2 a2
    stage4 = np.array([[1, dt, 0, hh2, 0, 0], [0, 1, 0, 0, dt, 0]])  # q + dt v3, v + dt a3
    update = np.array([[1, dt, hh6, hh6, hh6, 0], [0, 1, h6, 2 * h6, 2 * h6, h6]])
    tau = np.zeros(nq)
    tanh, cos, sin, hypot = math.tanh, math.cos, math.sin, math.hypot

    ff = settings.controllers.feedforward and bool(plant.pos_mask.any())
    if ff:
        data_ff = pm.createData()
        pos_idx = 3 + np.flatnonzero(plant.pos_mask)
        posf = plant.pos_mask.astype(float)

    for k in range(n_steps + 1):
        ql, vl = W[:2].tolist()
        # hardware read: encoders (round to the nearest count) and finite-difference rates
        qm = [round(ql[3 + j] * inv_r[j]) * res[j] if inv_r[j] else ql[3 + j] for j in joints_idx]
        X.append(W[:2].copy())
        QM.append(qm)
        if k == n_steps:
            EFF.append(EFF[-1] if k else [0.0] * nj)
            break
        cmd, rt = commands[k], rates[k]
        effort = [0.0] * nj
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
        prev = qm
        if ff:
            qf, vf = q.copy(), v.copy()
            qf[pos_idx], vf[pos_idx] = np.asarray(cmd)[pos_idx - 3], np.asarray(rt)[pos_idx - 3]
            af = np.zeros(nq)
            af[pos_idx] = accel[k][pos_idx - 3]
            M = pin.crba(pm, data_ff, qf)
            M = np.triu(M) + np.triu(M, 1).T
            t_ff = pin.rnea(pm, data_ff, qf, vf, af)
            a_base = -np.linalg.solve(M[:3, :3], t_ff[:3])
            extra = ((t_ff[3:] + M[3:, :3] @ a_base) * posf).tolist()
            effort = [u + f for u, f in zip(effort, extra)]
        for j in joints_idx:
            u = effort[j]
            effort[j] = -lim[j] if u < -lim[j] else (lim[j] if u > lim[j] else u)
        EFF.append(effort)
        # joint friction (internal torques), held over the step like the effort
        tj = effort
        if joint_friction:
            tj = [u - visc[j] * vl[3 + j] - coul[j] * tanh(vl[3 + j] * s_inv) for j, u in zip(joints_idx, effort)]
        tau[3:] = tj
        # base wrench in the base frame: thrusters (gas permitting) and air-bearing friction
        firing = thrust_steps[k] and (co2 > 0 or not tank.enabled)
        if use_fext:
            fx, fy, mz = thrust_b[k] if firing else (0.0, 0.0, 0.0)
            if bearing:
                cy, sy = cos(ql[2]), sin(ql[2])
                vx, vy, wz = vl[0], vl[1], vl[2]
                bx, by = cy * vx + sy * vy, cy * vy - sy * vx
                speed = hypot(bx, by)
                kf = c_lin + (fc_lin * tanh(speed * vs_inv) / speed if speed > 0 else fc_lin * vs_inv)
                fx -= kf * bx
                fy -= kf * by
                mz -= c_rot * wz + fc_rot * tanh(wz * ws_inv)
            f_base[0], f_base[1], f_base[5] = fx, fy, mz
            args = (tau, fext)
        else:
            args = (tau,)
        # classical RK4 on (q_pin, v_pin), d q_pin / dt = v_pin
        W[2] = aba(pm, data, q, v, *args)
        s = stage2 @ W
        W[3] = aba(pm, data, s[0], s[1], *args)
        s = stage3 @ W
        W[4] = aba(pm, data, s[0], s[1], *args)
        s = stage4 @ W
        W[5] = aba(pm, data, s[0], s[1], *args)
        W[:2] = update @ W
        if drains:
            flow = bearing_flow + (n_open[k] * flow_per_valve if firing else 0.0)
            if flow > 0 and co2 > 0:
                co2 = max(co2 - flow * dt, 0.0)
                pm.inertias[base_id] = pin.Inertia.FromDynamicParameters(base_full - (tank.co2_mass - co2) * unit)
            CO2[k + 1] = co2
    X = np.array(X)
    return X[:, 0], X[:, 1], np.array(QM, float), np.array(EFF, float), CO2, np.array(i_term)


def _grid(t0, t_end, period):
    """Multiples of ``period`` in ``[t0, t_end)`` (tolerant to round-off at the ends)."""
    eps = 1e-9 * period
    first = math.ceil((t0 - eps) / period)
    last = math.ceil((t_end - eps) / period) - 1
    return np.arange(first, last + 1) * period


def run_twin(
    reference=None,
    *,
    duration: float,
    wheel_speed=None,
    settings: TwinSettings | None = None,
    state: TwinState | None = None,
    seed: int = 0,
) -> TwinRun:
    """Run the twin for one phase.

    Parameters
    ----------
    reference : FourierTrajectory or callable or None
        Set points of the position-controlled joints (see the module docstring); the time
        argument is the time since the start of the phase [s]. None holds the last commands.
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

    Returns
    -------
    TwinRun
    """
    settings = TwinSettings() if settings is None else settings
    if not isinstance(settings, TwinSettings):
        raise SpaceidError(f"settings must be a TwinSettings(...), got {type(settings).__name__}")
    try:
        seed = int(seed)
    except (TypeError, ValueError):
        raise SpaceidError(f"seed must be an integer, got {seed!r}") from None
    plant = _plant(settings)
    state = _joint_state(plant, state, settings)
    dt = 1.0 / settings.controllers.rate
    duration = _number("duration [s]", duration, low=0.0, strict=True)
    n_steps = int(round(duration / dt))
    if n_steps < 1:
        raise SpaceidError(
            f"duration = {duration:g} s is shorter than one control period ({dt:g} s): give a longer duration"
        )
    t0 = state.t
    times = t0 + dt * np.arange(n_steps + 1)
    command, rate, accel = _references(plant, reference, wheel_speed, times, t0, state)
    valves = _valves(settings.thrusters, times, dt)
    Q, V, QM, EFF, CO2, i_term = _integrate(plant, settings, state, command, rate, accel, valves, dt)
    QDH = (QM - np.vstack([state.encoder_prev, QM[:-1]])) * (1.0 / dt)  # as the hardware interface
    enc_prev = QM[-2]

    joints = plant.model.joints
    yaw, wz = Q[:, 2], V[:, 2]
    base_w = np.zeros((len(times), 3))
    base_w[:, 2] = wz
    seed_info = {"seed": seed}
    truth = Log(times, joints, Q[:, 3:].copy(), V[:, 3:].copy(), yaw_to_quat(yaw), base_w, True,
                {"source": "spaceid.twin (truth)", **seed_info})

    # /joint_states: tick k publishes when a multiple of the publish period falls in
    # (t_k - dt, t_k] (absolute time, so phases continue the grid); stamped with the tick time
    t_end = times[-1]
    count = np.floor(np.r_[t0 - dt, times[:-1]] * settings.encoders.rate + 1e-6)
    ticks = np.flatnonzero(np.diff(count) > 0)
    joint_states = JointStates(
        t=times[ticks],
        names=tuple(joints),
        position=QM[ticks],
        velocity=QDH[ticks] if settings.encoders.velocity == "difference" else None,
        effort=EFF[ticks],
    )

    # motion capture: true pose at the capture instants (cubic Hermite between ticks)
    mc = settings.mocap
    capture = _grid(t0, t_end, 1.0 / mc.rate)
    pose, _ = hermite_motion(times, Q[:, :3], V[:, :3])(capture)
    noise_rng, drop_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    noise = noise_rng.standard_normal((len(capture), 3)) * [mc.position_noise, mc.position_noise, mc.attitude_noise]
    keep = drop_rng.random(len(capture)) >= mc.drop_probability
    measured = (pose + noise)[keep]
    quat = yaw_to_quat(measured[:, 2])
    quat[quat[:, 0] < 0] *= -1  # a yaw in (-pi, pi], as a motion-capture system reports it
    poses = Poses(
        t=capture[keep] + mc.latency,
        position=np.column_stack([measured[:, :2], np.zeros(len(measured))]),
        quat=quat,
        frame=mc.frame,
    )

    final = TwinState(
        t=float(t_end),
        base_xy=Q[-1, :2],
        base_yaw=float(Q[-1, 2]),
        base_vxy=V[-1, :2],
        base_wz=float(V[-1, 2]),
        q=Q[-1, 3:],
        qd=V[-1, 3:],
        co2_mass=float(CO2[-1]),
        command=command[-1],
        i_term=i_term,
        encoder_prev=enc_prev,
    )
    pos = plant.pos_mask
    track = Q[:-1, 3:][:, pos] - command[:-1][:, pos]  # true tracking error
    meta = {
        "source": "spaceid.twin",
        "model": plant.model.source or plant.model.name,
        "seed": seed,
        "settings": settings.to_dict(),
        "t_start": float(t0),
        "t_end": float(t_end),
        "co2_mass_start": float(CO2[0]),
        "co2_mass_end": float(CO2[-1]),
        "base_mass_start": float(plant.model.bodies[0].mass - (settings.tank.co2_mass - CO2[0]) * settings.tank.enabled),
        "base_mass_end": float(plant.model.bodies[0].mass - (settings.tank.co2_mass - CO2[-1]) * settings.tank.enabled),
        "mocap_frames": int(len(capture)),
        "mocap_dropped": int((~keep).sum()),
        "tracking_rms": {joints[i]: float(np.sqrt(np.mean(track[:, c] ** 2))) for c, i in enumerate(np.flatnonzero(pos))},
        "phases": [{"t_start": float(t0), "t_end": float(t_end), "seed": seed}],
    }
    return TwinRun(
        recording=Recording(joint_states, poses, meta),
        truth=truth,
        base_position=Q[:, :2].copy(),
        base_velocity=V[:, :2].copy(),
        effort=EFF,
        co2_mass=CO2,
        state=final,
        meta=meta,
    )


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
    0.5). The momentum of the rest of the system is then ``h - I_rw (w0 + w_rw)`` (MATH.md
    sec. 5), with ``h`` the total (zero when starting at rest).

    Returns
    -------
    TwinRun
        Its ``state`` starts the next phase.
    """
    speed = _number("spin_up speed [rad/s]", speed)
    ramp = _number("spin_up ramp [rad/s^2]", ramp, low=0.0, strict=True)
    settle = _number("spin_up settle [s]", settle, low=0.0)
    settings = TwinSettings() if settings is None else settings
    plant = _plant(settings)
    start = _joint_state(plant, state, settings)
    w0 = start.command[plant.vel_mask]
    w0 = float(w0[0]) if len(w0) else 0.0
    ramp_time = abs(speed - w0) / ramp

    def setpoint(t):
        return w0 + np.sign(speed - w0) * np.minimum(ramp * np.asarray(t), abs(speed - w0))

    run = run_twin(None, duration=max(ramp_time + settle, 1.0 / settings.controllers.rate),
                   wheel_speed=setpoint, settings=settings, state=start, seed=seed)
    meta = dict(run.meta, spin_up={"speed": speed, "ramp": ramp, "settle": settle})
    return replace(run, meta=meta, recording=replace(run.recording, meta=meta))


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

    def cat(get, skip):
        return np.concatenate([get(r)[1:] if (skip and i) else get(r) for i, r in enumerate(runs)])

    truth = Log(
        cat(lambda r: r.truth.t, True), first.truth.joints, cat(lambda r: r.truth.q, True),
        cat(lambda r: r.truth.qd, True), cat(lambda r: r.truth.base_quat, True),
        cat(lambda r: r.truth.base_w, True), True, dict(first.truth.meta),
    )
    js = [r.recording.joints for r in runs]
    joints = JointStates(
        t=np.concatenate([j.t for j in js]),
        names=js[0].names,
        position=np.concatenate([j.position for j in js]),
        velocity=None if any(j.velocity is None for j in js) else np.concatenate([j.velocity for j in js]),
        effort=None if any(j.effort is None for j in js) else np.concatenate([j.effort for j in js]),
    )
    ps = [r.recording.base for r in runs]
    base = Poses(
        t=np.concatenate([p.t for p in ps]),
        position=np.concatenate([p.position for p in ps]),
        quat=np.concatenate([p.quat for p in ps]),
        frame=ps[0].frame,
    )
    # effort: the boundary sample of the later phase is the one applied from then on
    effort = np.concatenate([r.effort[:-1] for r in runs] + [runs[-1].effort[-1:]])
    meta = dict(
        first.meta,
        t_end=runs[-1].meta["t_end"],
        co2_mass_end=runs[-1].meta["co2_mass_end"],
        base_mass_end=runs[-1].meta["base_mass_end"],
        mocap_frames=sum(r.meta["mocap_frames"] for r in runs),
        mocap_dropped=sum(r.meta["mocap_dropped"] for r in runs),
        phases=[p for r in runs for p in r.meta["phases"]],
        seed=[r.meta["seed"] for r in runs],
    )
    meta.pop("tracking_rms", None)
    return TwinRun(
        recording=Recording(joints, base, meta),
        truth=truth,
        base_position=cat(lambda r: r.base_position, True),
        base_velocity=cat(lambda r: r.base_velocity, True),
        effort=effort,
        co2_mass=cat(lambda r: r.co2_mass, True),
        state=runs[-1].state,
        meta=meta,
    )
