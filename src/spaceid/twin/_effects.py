"""The optional effects of the Cepheus twin: friction, torque limits, thrusters, the CO2 tank and
the table tilt (their settings and assumed values: :mod:`spaceid.twin._settings`).

Each effect is evaluated once per control tick from the state at the start of the step and held
over it (see :mod:`spaceid.twin._plant`). The per-tick laws are built once per run as functions of
Python floats (scalar code is faster than numpy on three joints); a law that would do nothing is
None, so the hardware loop skips it. Thrust is constant while a valve is open (a regulated
supply) and stops when the tank is empty; the gas leaves with the local base velocity.
"""

from __future__ import annotations

import math

import numpy as np

from .._errors import SpaceidError
from ..models import Model
from ._plant import _com_inertia, _symmetric
from ._settings import G0, BearingFriction, JointFriction, Tank, Thrusters, TorqueLimits, TwinSettings

__all__ = ["thruster_wrenches"]


# ------------------------------------------------------------------ thrusters and tank --------


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


def _valves(thrusters: Thrusters, times, dt) -> np.ndarray:
    """Open valves per tick, shape (n_t, 6) bool (rows of :func:`thruster_wrenches`): open from
    the first tick at or after ``t_on`` to the last one before ``t_off`` (to within 1e-6 dt)."""
    open_ = np.zeros((len(times), 6), bool)
    eps = 1e-6 * dt
    if thrusters.enabled:
        for t_on, t_off, pair, sign in thrusters.schedule:
            open_[(times >= t_on - eps) & (times < t_off - eps), 2 * pair + (0 if sign > 0 else 1)] = True
    return open_


def _thrust_per_tick(thrusters: Thrusters, valves):
    """Per tick: the wrench ``[Fx, Fy, Mz]`` of the open ``valves`` (n_t, 6) [N, N, N m], base
    frame, and their number; as lists of Python values."""
    return (valves.astype(float) @ thruster_wrenches(thrusters)).tolist(), valves.sum(axis=1).tolist()


def _tank_drain(tank: Tank, thrusters: Thrusters, load_base, dt):
    """One control period of CO2 use: a function ``(co2_mass, n_firing) -> co2_mass`` [kg] of the
    number of firing valves, which also updates the base inertia through ``load_base(co2_mass)``
    (:func:`spaceid.twin._plant._base_loader`) when the mass changes."""
    per_valve = thrusters.force / (tank.isp * G0)  # mass flow of one open valve [kg/s]
    bearing_flow = tank.bearing_flow

    def drain(co2, n_firing):
        flow = bearing_flow + (n_firing * per_valve if n_firing else 0.0)
        if flow > 0 and co2 > 0:
            co2 = max(co2 - flow * dt, 0.0)
            load_base(co2)
        return co2

    return drain


def _check_dry_base(tank: Tank, model: Model):
    """The base of ``model`` (full tank) less the tank's CO2 must keep a positive mass and inertia."""
    if not tank.enabled:
        return
    base_left = model.bodies[0].inertial - tank.co2_mass * tank.unit_inertial()
    dry = np.linalg.eigvalsh(_com_inertia(base_left)) if base_left[0] > 0 else [-1.0]
    if min(dry) <= 0:
        raise SpaceidError(
            f"tank.co2_mass = {tank.co2_mass:g} kg leaves the base (mass {model.bodies[0].mass:g} kg, "
            "inertia of the full base) without a physical dry mass and inertia: lower tank.co2_mass "
            "or move tank.position closer to the base origin"
        )


# ------------------------------------------------------------------ torque limits -------------


def _effort_limits(limits: TorqueLimits, model: Model) -> np.ndarray:
    """Saturation per joint (n_joints,) [N m], inf where there is none."""
    joints = model.joints
    if not limits.enabled:
        return np.full(len(joints), math.inf)
    source = limits.effort if limits.effort is not None else dict(zip(joints, model.joint_limits("effort")))
    limit = np.array([source.get(j, math.inf) for j in joints], float)
    limit[~np.isfinite(limit) | (limit <= 0)] = math.inf
    return limit


def _saturation(limit):
    """A function ``efforts (list of n) -> efforts clipped to +-limit`` [N m]."""
    lim = limit.tolist()

    def saturate(effort):
        return [-m if u < -m else (m if u > m else u) for u, m in zip(effort, lim)]

    return saturate


# ------------------------------------------------------------------ friction ------------------


def _joint_friction_coefficients(friction: JointFriction, joints):
    """Viscous [N m s/rad] and Coulomb [N m] coefficients per joint, shape (n,) each (zero when off)."""
    if not friction.enabled:
        return np.zeros(len(joints)), np.zeros(len(joints))
    return (np.array([friction.viscous.get(j, 0.0) for j in joints]),
            np.array([friction.coulomb.get(j, 0.0) for j in joints]))


def _joint_friction_law(viscous, coulomb, rate_scale):
    """A function ``(efforts, qd) -> efforts + friction`` (lists of n) [N m], ``qd`` the joint rates
    [rad/s], or None when every coefficient is zero. Internal torques: they act between parent and
    child and do not change the momentum."""
    visc, coul = viscous.tolist(), coulomb.tolist()
    if not (any(visc) or any(coul)):
        return None
    s_inv, tanh = 1.0 / rate_scale, math.tanh

    def with_friction(effort, qd):
        return [u - c * w - f * tanh(w * s_inv) for u, c, f, w in zip(effort, visc, coul, qd)]

    return with_friction


def _bearing_friction_law(bf: BearingFriction):
    """A function ``(yaw, vx, vy, wz) -> (Fx, Fy, Mz)``: the air-bearing friction on the base
    [N, N, N m], base frame, from the yaw [rad] and the base velocity (world axes [m/s], yaw rate
    [rad/s]); None when off or zero."""
    if not (bf.enabled and (bf.viscous_force or bf.coulomb_force or bf.viscous_torque or bf.coulomb_torque)):
        return None
    c_lin, fc_lin, vs_inv = bf.viscous_force, bf.coulomb_force, 1.0 / bf.speed_scale
    c_rot, fc_rot, ws_inv = bf.viscous_torque, bf.coulomb_torque, 1.0 / bf.rate_scale
    tanh, cos, sin, hypot = math.tanh, math.cos, math.sin, math.hypot

    def wrench(yaw, vx, vy, wz):
        cy, sy = cos(yaw), sin(yaw)
        bx, by = cy * vx + sy * vy, cy * vy - sy * vx
        speed = hypot(bx, by)
        kf = c_lin + (fc_lin * tanh(speed * vs_inv) / speed if speed > 0 else fc_lin * vs_inv)
        return -kf * bx, -kf * by, -(c_rot * wz + fc_rot * tanh(wz * ws_inv))

    return wrench


def _check_friction_step(pmodel, settings: TwinSettings, joints, joint_damping, dt):
    """Friction held over a step must not overshoot: ``damping dt / I_eff <= 1`` per axis.

    ``damping`` is the slope of the friction law at rest (``c + F_c / s``) and ``I_eff`` the
    effective (articulated) inertia ``1 / (M^-1)_ii`` at the zero configuration, where it is
    smallest for a stretched arm.
    """
    import pinocchio as pin

    minv = pin.computeMinverse(pmodel, pmodel.createData(), np.zeros(pmodel.nq))
    inertia = 1.0 / np.diag(_symmetric(minv))
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


# ------------------------------------------------------------------ table tilt ----------------


def _tilt_table(pmodel, settings: TwinSettings):
    """Set the gravity of ``pmodel`` to the in-plane component ``g0 sin(tilt)`` of a tilted table."""
    if not settings.table_tilt:
        return
    import pinocchio as pin

    g = G0 * math.sin(settings.table_tilt)
    azimuth = settings.tilt_azimuth
    pmodel.gravity = pin.Motion(np.array([g * math.cos(azimuth), g * math.sin(azimuth), 0.0]), np.zeros(3))
