"""Free-floating kinematics in base axes, batched over samples.

Every quantity is expressed in the base frame and measured relative to the base frame origin,
so neither the base attitude nor the base position is needed: the momentum equations in base
axes depend on ``q``, ``qd`` and the base angular velocity ``w0`` only.

Pinocchio evaluates one configuration per call; identification evaluates 10^4 samples at once,
so the tree recursion here runs over bodies with NumPy arrays over samples (leading axes).
``tests/test_regressor.py`` checks the result against Pinocchio's own kinematics.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .model import Model

__all__ = ["BodyStates", "body_states", "skew"]


def skew(v):
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) @ b == a x b``."""
    v = np.asarray(v)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def _axis_rotation(axis, angle):
    """Rotations ``(..., 3, 3)`` by ``angle (...,)`` about the unit ``axis (3,)`` (Rodrigues)."""
    k = skew(axis)
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


@dataclass(frozen=True)
class BodyStates:
    """Poses and velocities of every body frame, in base axes, relative to the base origin.

    Attributes
    ----------
    rotation : ndarray of shape (..., n_bodies, 3, 3)
        Body-to-base rotations.
    position : ndarray of shape (..., n_bodies, 3)
        Body frame origins [m].
    omega : ndarray of shape (..., n_bodies, 3)
        Absolute angular velocities (base rate included) [rad/s].
    velocity : ndarray of shape (..., n_bodies, 3)
        Inertial time derivative of ``position`` (the base origin's own motion excluded) [m/s].
    """

    rotation: np.ndarray
    position: np.ndarray
    omega: np.ndarray
    velocity: np.ndarray


def body_states(model: Model, q, qd, w0) -> BodyStates:
    """Forward kinematics of the whole tree for many samples at once.

    Parameters
    ----------
    model : Model
    q, qd : array_like of shape (..., n_joints)
        Joint positions [rad or m] and rates [rad/s or m/s], in ``model.joints`` order.
    w0 : array_like of shape (..., 3)
        Base angular velocity in base axes [rad/s].

    Returns
    -------
    BodyStates
    """
    q, qd, w0 = (np.asarray(a, dtype=float) for a in (q, qd, w0))
    lead = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1], w0.shape[:-1])
    rot = [np.broadcast_to(np.eye(3), lead + (3, 3))]
    pos = [np.zeros(lead + (3,))]
    omg = [np.broadcast_to(w0, lead + (3,))]
    vel = [np.zeros(lead + (3,))]
    for j, body in enumerate(model.bodies[1:]):
        a = body.parent
        r_joint = rot[a] @ body.rotation  # joint frame at zero position, in base axes
        axis = r_joint @ body.axis
        offset = rot[a] @ body.translation
        p = pos[a] + offset
        v = vel[a] + np.cross(omg[a], offset)
        if body.joint_type == "revolute":
            r = r_joint @ _axis_rotation(body.axis, q[..., j])
            w = omg[a] + axis * qd[..., j, None]
        else:  # prismatic: slide along the axis
            r = r_joint
            w = omg[a]
            slide = axis * q[..., j, None]
            p = p + slide
            v = v + np.cross(omg[a], slide) + axis * qd[..., j, None]
        rot.append(r)
        pos.append(p)
        omg.append(w)
        vel.append(v)
    return BodyStates(np.stack(rot, -3), np.stack(pos, -2), np.stack(omg, -2), np.stack(vel, -2))
