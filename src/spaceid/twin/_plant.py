"""The plant of the Cepheus twin: the planar rigid-body model on the table and its dynamics step.

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

The arm motors sit on the base and drive the joints through belts: modelled as rigid
transmissions, an effort acting between parent and child, without motor rotor inertia or belt
compliance. The air bearings carry the base only through its planar motion (no tilt, no
out-of-plane dynamics). The base inertia follows the CO2 left in the tank (:func:`drained_model`).
"""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError
from ..models import Model, load_model, to_pinocchio
from ._settings import Tank

__all__ = ["planar_pinocchio", "drained_model", "free_flyer_rate"]

_BASE_JOINTS = ("base_x", "base_y", "base_yaw")


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
            ids[j] = pmodel.addJoint(
                ids[spatial.parents[j]], spatial.joints[j], spatial.jointPlacements[j], spatial.names[j]
            )
        pmodel.appendBodyToJoint(ids[j], spatial.inertias[j], pin.SE3.Identity())
        pmodel.addBodyFrame(model.bodies[j - 1].name, ids[j], pin.SE3.Identity(), 0)
    pmodel.gravity = pin.Motion.Zero()
    return pmodel


def _planar_model(spec) -> Model:
    """The twin's model from ``TwinSettings.model`` (a Model, a preset name or a path)."""
    model = spec if isinstance(spec, Model) else load_model(spec)
    if not model.planar:
        raise SpaceidError(
            f"settings.model: model {model.name} is not planar: the twin needs a planar model "
            "(a YAML model with 'planar: true' or load_model(..., planar=True))"
        )
    return model


def drained_model(model: Model, tank: Tank, co2_mass: float) -> Model:
    """``model`` with ``co2_mass`` [kg] left in a tank that is full (``tank.co2_mass``) in it.

    Parameters
    ----------
    model : Model
        The model with a full tank (its base includes ``tank.co2_mass`` of CO2).
    tank : Tank
        The tank: its full mass, position and cylinder.
    co2_mass : float
        CO2 left [kg].

    Returns
    -------
    Model
        A copy whose base inertial parameters are ``base - (tank.co2_mass - co2_mass) * unit``.
    """
    inertials = np.array([b.inertial for b in model.bodies])
    inertials[0] = _drained_base(inertials[0], tank, co2_mass, tank.unit_inertial())
    return model.with_inertials(inertials)


def _drained_base(full, tank: Tank, co2_mass, unit) -> np.ndarray:
    """Base inertial parameters (10,) with ``co2_mass`` [kg] left; ``full`` with a full tank,
    ``unit`` those of 1 kg of CO2 (``tank.unit_inertial()``)."""
    return full - (tank.co2_mass - float(co2_mass)) * unit


def _base_loader(pmodel, base_id, model: Model, tank: Tank):
    """A function ``co2_mass -> None`` that sets the base inertia of ``pmodel`` to the base of
    ``model`` with ``co2_mass`` [kg] left in ``tank``."""
    import pinocchio as pin

    full, unit = model.bodies[0].inertial, tank.unit_inertial()

    def load(co2_mass):
        pmodel.inertias[base_id] = pin.Inertia.FromDynamicParameters(_drained_base(full, tank, co2_mass, unit))

    return load


def _com_inertia(inertial) -> np.ndarray:
    """Inertia about the CoM (3, 3) [kg m^2] of standard inertial parameters (10,)."""
    import pinocchio as pin

    return np.array(pin.Inertia.FromDynamicParameters(np.asarray(inertial, float)).inertia)


def _symmetric(upper) -> np.ndarray:
    """The symmetric matrices (..., n, n) of which Pinocchio filled the upper triangle (``crba``,
    ``computeMinverse``)."""
    return np.triu(upper) + np.triu(upper, 1).swapaxes(-1, -2)


# ------------------------------------------------------------------ the dynamics step ---------


def _base_force(pmodel, base_id):
    """External forces for ``pin.aba``: ``(fext, f_base)``, ``f_base`` a view of the base joint's
    ``[force; torque]`` (6,) in the base frame, to be written before each step."""
    import pinocchio as pin

    fext = pin.StdVec_Force()
    for _ in range(pmodel.njoints):
        fext.append(pin.Force.Zero())
    return fext, fext[base_id].vector


def _rk4_rows(q_pin, v_pin) -> np.ndarray:
    """The integrator's working rows ``W = [q, v, a1, a2, a3, a4]``, shape (6, nq): rows 0 and 1
    hold the state (``q_pin``, ``v_pin``), the others the stage accelerations. With a free-flyer
    root (``nq = nv + 1``) only ``[q, v]``, a list of the two arrays, for :func:`_rk4_stepper`'s
    general form."""
    if len(q_pin) != len(v_pin):
        return [np.array(q_pin, float), np.array(v_pin, float)]
    W = np.zeros((6, len(q_pin)))
    W[0], W[1] = q_pin, v_pin
    return W


def free_flyer_rate(q_pin, v_pin) -> np.ndarray:
    """``d q_pin / dt`` (nq,) of a Pinocchio model with a free-flyer root.

    ``q_pin = [p, quat, joints]`` (the base origin in the world [m], the base attitude as
    Pinocchio's unit quaternion ``[x, y, z, w]``, then the joints), ``v_pin = [v, w, qd]`` (the
    base origin velocity and angular velocity in base axes, then the joint rates):
    ``dp/dt = R v``, ``d quat/dt = quat (x) [w, 0] / 2``, ``d joints/dt = qd`` (revolute and
    prismatic joints).
    """
    # scalar arithmetic: called four times per RK4 step, where numpy's batched quaternion helpers
    # (spaceid.data.quat_to_matrix, quat_multiply) cost ten times the step's four pin.aba
    x, y, z, s = q_pin[3:7].tolist()
    wx, wy, wz = v_pin[3:6].tolist()
    vx, vy, vz = v_pin[0:3].tolist()
    out = np.empty(len(q_pin))
    out[0] = (1 - 2 * (y * y + z * z)) * vx + 2 * (x * y - z * s) * vy + 2 * (x * z + y * s) * vz
    out[1] = 2 * (x * y + z * s) * vx + (1 - 2 * (x * x + z * z)) * vy + 2 * (y * z - x * s) * vz
    out[2] = 2 * (x * z - y * s) * vx + 2 * (y * z + x * s) * vy + (1 - 2 * (x * x + y * y)) * vz
    out[3:7] = (0.5 * (s * wx + y * wz - z * wy), 0.5 * (s * wy + z * wx - x * wz), 0.5 * (s * wz + x * wy - y * wx),
                -0.5 * (x * wx + y * wy + z * wz))  # fmt: skip
    out[7:] = v_pin[6:]
    return out


def _rk4_stepper(pmodel, dt, rate=None):
    """One classical RK4 step of ``d q_pin / dt = rate(q, v)``, ``d v_pin / dt = aba(q, v, tau[, fext])``.

    Returns a function ``step(W, tau[, fext])`` that advances rows 0 and 1 of ``W``
    (:func:`_rk4_rows`) by ``dt`` [s] in place, with ``tau`` (nv,) and ``fext`` held over the step.
    Without ``rate`` (``d q_pin / dt = v_pin``: the planar twin) every stage input and the update
    are fixed linear combinations of the rows of ``W``, one small matrix product each (the
    Butcher tableau of the classical RK4 in Runge-Kutta-Nystrom form). With ``rate`` (a
    free-flyer root, :func:`free_flyer_rate`) the same tableau on the embedded coordinates, the
    quaternion renormalised at every stage and after the step (the projection keeps the order).
    """
    import pinocchio as pin

    aba, data = pin.aba, pmodel.createData()
    if rate is not None:
        return _rk4_general(pmodel, data, rate, dt)
    h2, h6, hh2, hh4, hh6 = dt / 2, dt / 6, dt * dt / 2, dt * dt / 4, dt * dt / 6
    stage2 = np.array([[1, h2, 0, 0, 0, 0], [0, 1, h2, 0, 0, 0]])  # q + dt/2 v, v + dt/2 a1
    stage3 = np.array([[1, h2, hh4, 0, 0, 0], [0, 1, 0, h2, 0, 0]])  # q + dt/2 v2, v + dt/2 a2
    stage4 = np.array([[1, dt, 0, hh2, 0, 0], [0, 1, 0, 0, dt, 0]])  # q + dt v3, v + dt a3
    update = np.array([[1, dt, hh6, hh6, hh6, 0], [0, 1, h6, 2 * h6, 2 * h6, h6]])

    def step(W, *forces):
        W[2] = aba(pmodel, data, W[0], W[1], *forces)
        s = stage2 @ W
        W[3] = aba(pmodel, data, s[0], s[1], *forces)
        s = stage3 @ W
        W[4] = aba(pmodel, data, s[0], s[1], *forces)
        s = stage4 @ W
        W[5] = aba(pmodel, data, s[0], s[1], *forces)
        W[:2] = update @ W

    return step


def _rk4_general(pmodel, data, rate, dt):
    """:func:`_rk4_stepper` with ``d q_pin / dt = rate(q, v)``, on ``W = [q, v]`` (a list)."""
    import pinocchio as pin

    aba = pin.aba

    def unit(q):  # the base quaternion renormalised
        q[3:7] /= np.sqrt(q[3:7] @ q[3:7])
        return q

    def step(W, *forces):
        q, v = W
        k1q, k1v = rate(q, v), aba(pmodel, data, q, v, *forces).copy()
        q2, v2 = unit(q + dt / 2 * k1q), v + dt / 2 * k1v
        k2q, k2v = rate(q2, v2), aba(pmodel, data, q2, v2, *forces).copy()
        q3, v3 = unit(q + dt / 2 * k2q), v + dt / 2 * k2v
        k3q, k3v = rate(q3, v3), aba(pmodel, data, q3, v3, *forces).copy()
        q4, v4 = unit(q + dt * k3q), v + dt * k3v
        k4q, k4v = rate(q4, v4), aba(pmodel, data, q4, v4, *forces).copy()
        q[:] = unit(q + dt / 6 * (k1q + 2 * k2q + 2 * k3q + k4q))
        v[:] = v + dt / 6 * (k1v + 2 * k2v + 2 * k3v + k4v)

    return step
