"""The grasp of a free-floating payload by the Cepheus twin (settings: :class:`~spaceid.twin.Capture`).

Before the grasp the payload floats freely: its CoM moves in a straight line at constant speed
and it turns at a constant rate. At the grasp instant it becomes part of the grasping link, in the
pose it has then, and the twin goes on with the combined model (:func:`spaceid.models.attach_payload`).

The grasp is a plastic impact: the link and the payload reach a common velocity within an
instant, through an impulse between them; the joints transmit impulses, but the motors (finite
efforts) and the table (no impulsive force in the plane) do not. With ``M`` and ``M_c`` the joint-
space inertia matrices of the robot and of the combined system at the grasp configuration ``q``,
``J`` the grasping link's Jacobian (body frame) and ``I_p V_p`` the payload's spatial momentum in
that frame, the generalised momentum is conserved through the impact:

    M_c v+ = M v- + J^T I_p V_p

(``M_c = M + J^T I_p J``). Its first three rows (base x, y, yaw) are the total linear momentum and
the angular momentum about the base origin, payload included: so the total momentum about any
fixed point is conserved; the joint rows say that no impulsive torque acts in the joints. The
kinetic energy lost is that of the relative motion that the impulse stops.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from ..dynamics import minimal_parameters
from ..models import Model, attach_payload, body_index, inertial_vector
from ._plant import _planar_model, _symmetric, drained_model, planar_pinocchio
from ._settings import Capture, TwinSettings

__all__ = ["payload_pose", "place_payload", "table_momentum"]


def payload_pose(capture: Capture, t: float):
    """The free-floating payload of ``capture`` at time ``t`` [s] (as if not grasped).

    Returns
    -------
    com : ndarray of shape (2,)
        Its CoM in the world (table) frame [m].
    yaw : float
        Its frame's yaw [rad].
    """
    c0 = np.asarray(capture.position) + _rotation(capture.yaw)[:2, :2] @ np.asarray(capture.com)
    return c0 + np.asarray(capture.velocity) * t, capture.yaw + capture.rate * t


def place_payload(capture: Capture, model, state, *, offset=(0.0, 0.0), yaw: float = 0.0) -> Capture:
    """``capture`` set to grasp at ``state.t`` with the payload frame at ``offset`` in the link.

    The payload keeps its velocity and rate; its pose at t = 0 is set back along them so that at
    the grasp its frame origin is at ``offset`` (2,) [m] in the grasping link's frame (in the plane
    of its origin) and turned by ``yaw`` [rad] from the link's axes: a grasp at the gripper.

    Parameters
    ----------
    capture : Capture
        The payload (mass, CoM, inertia, velocity, rate, link); its time and pose are replaced.
    model : str or Model
        The twin's model (``TwinSettings.model``).
    state : TwinState
        Where the robot is at the grasp, e.g. the ``state`` of the run that ends there.
    offset : tuple of 2 floats
    yaw : float

    Returns
    -------
    Capture
    """
    import pinocchio as pin

    model = _planar_model(model)
    pm = planar_pinocchio(model)
    data = pm.createData()
    q = np.zeros(model.n_joints) if state.q is None else state.q
    pin.framesForwardKinematics(pm, data, np.r_[state.base_xy, state.base_yaw, q])
    link = data.oMf[pm.getFrameId(_grasp_link(capture, model))]
    at = np.array(link.translation)[:2] + np.array(link.rotation)[:2, :2] @ np.asarray(offset, float)
    heading = math.atan2(link.rotation[1, 0], link.rotation[0, 0]) + float(yaw)
    com = at + _rotation(heading)[:2, :2] @ np.asarray(capture.com)
    t = state.t
    start_yaw = heading - capture.rate * t
    com0 = com - np.asarray(capture.velocity) * t
    return replace(capture, time=t, yaw=start_yaw,
                   position=tuple(com0 - _rotation(start_yaw)[:2, :2] @ np.asarray(capture.com)))


def table_momentum(model: Model, q_pin, v_pin) -> np.ndarray:
    """Total momentum of the planar ``model`` on the table: ``[p_x, p_y, L_z]`` [N s, N s, N m s],
    the linear momentum and the angular momentum about the world origin, world axes.

    ``q_pin``, ``v_pin`` of shape (3 + n_joints,) are the twin's coordinates ``[x, y, yaw, q]``
    and their rates (:mod:`spaceid.twin._plant`).
    """
    pm = planar_pinocchio(model)
    return _momentum_about_origin(pm, pm.createData(), q_pin, v_pin)


def _momentum_about_origin(pm, data, q_pin, v_pin) -> np.ndarray:
    import pinocchio as pin

    h = pin.computeCentroidalMomentum(pm, data, np.asarray(q_pin, float), np.asarray(v_pin, float))
    c = data.com[0]
    return np.array([h.linear[0], h.linear[1], h.angular[2] + c[0] * h.linear[1] - c[1] * h.linear[0]])


def _rotation(yaw) -> np.ndarray:
    """The rotation (3, 3) about the vertical by ``yaw`` [rad]."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _grasp_link(capture: Capture, model: Model) -> str:
    """The name of the grasping body (``capture.link``, or the last body), checked against ``model``."""
    link = capture.link if capture.link is not None else model.bodies[-1].name
    body_index(model, link, "capture.link")
    return link


def _payload_momentum(capture: Capture, com) -> np.ndarray:
    """``[p_x, p_y, L_z]`` of the free payload with its CoM at ``com`` (2,) [m], about the world
    origin."""
    p = capture.mass * np.asarray(capture.velocity)
    return np.array([p[0], p[1], capture.inertia[2][2] * capture.rate + com[0] * p[1] - com[1] * p[0]])


def _grasp(model: Model, settings: TwinSettings, q_pin, v_pin, t: float, co2_mass: float):
    """The plastic impact of the grasp at time ``t`` [s] in the configuration ``q_pin`` with the
    rates ``v_pin`` just before it, ``co2_mass`` [kg] left in the tank.

    Returns
    -------
    v_after : ndarray of shape (3 + n_joints,)
        The rates just after the grasp (the module docstring).
    record : dict
        The truth of the grasp, JSON-ready; the state carries it (``TwinState.grasp``) and the
        run's ``meta["capture"]`` (docs/theory/capture.md lists its keys).
    """
    import pinocchio as pin

    capture = settings.capture
    link = _grasp_link(capture, model)
    robot = drained_model(model, settings.tank, co2_mass) if settings.tank.enabled else model
    pm = planar_pinocchio(robot)
    data = pm.createData()
    frame = pm.getFrameId(link)
    pin.framesForwardKinematics(pm, data, q_pin)
    rot, origin = np.array(data.oMf[frame].rotation), np.array(data.oMf[frame].translation)
    com, yaw = payload_pose(capture, t)
    com_link = rot.T @ (np.r_[com, origin[2]] - origin)  # the payload's CoM in the plane of the link origin
    turn = rot.T @ _rotation(yaw)
    inertia_link = turn @ capture.inertia_matrix() @ turn.T
    inertial = inertial_vector(capture.mass, com_link, inertia_link)
    combined = attach_payload(robot, link, inertial, where="capture.link")
    # the payload's spatial velocity at the link origin, link axes, and its momentum there
    spin = np.array([0.0, 0.0, capture.rate])
    v_origin = np.r_[capture.velocity, 0.0] + np.cross(spin, origin - np.r_[com, origin[2]])
    twist = pin.Motion(rot.T @ v_origin, rot.T @ spin)
    momentum = (pin.Inertia.FromDynamicParameters(inertial) * twist).vector
    jac = pin.computeFrameJacobian(pm, data, q_pin, frame, pin.LOCAL)
    pc = planar_pinocchio(combined)
    pc_data = pc.createData()
    mass_matrix = _symmetric(pin.crba(pm, data, q_pin))
    v_after = np.linalg.solve(_symmetric(pin.crba(pc, pc_data, q_pin)), mass_matrix @ v_pin + jac.T @ momentum)
    before, after = (minimal_parameters(m) for m in (robot, combined))
    record = {
        "time": float(t),
        "time_requested": capture.time,
        "link": link,
        "payload": {"mass": capture.mass, "com": com_link.tolist(), "inertia": inertia_link.tolist(),
                    "inertial": inertial.tolist()},
        "payload_at_grasp": {"com": com.tolist(), "yaw": float(yaw), "velocity": list(capture.velocity),
                             "rate": capture.rate},
        "velocity_before": np.asarray(v_pin, float).tolist(),
        "velocity_after": v_after.tolist(),
        "momentum_before": (_momentum_about_origin(pm, data, q_pin, v_pin) + _payload_momentum(capture, com)).tolist(),
        "momentum_after": _momentum_about_origin(pc, pc_data, q_pin, v_after).tolist(),
        "co2_mass": float(co2_mass),
        "minimal_parameters": {
            "before": {"names": list(before.names), "values": before.true_values.tolist()},
            "after": {"names": list(after.names), "values": after.true_values.tolist()},
        },
    }  # fmt: skip
    return v_after, record
