"""Free-floating kinematics in base axes, batched over samples.

Every quantity is expressed in the base frame and measured relative to the base frame origin,
so neither the base attitude nor the base position is needed: the momentum equations in base
axes depend on ``q``, ``qd`` and the base angular velocity ``w0`` only.

Pinocchio evaluates one configuration per call; identification evaluates 10^4 samples at once,
so the tree recursion here runs over bodies with NumPy arrays over samples. Samples are the
last, contiguous axis (:func:`frame_table`): each NumPy call then runs one long inner loop or
one BLAS product, where a time-first layout of 3x3 blocks would run thousands of tiny ones.
:func:`body_states` gives the same quantities time-first. ``tests/test_regressor.py`` checks
them against Pinocchio's own kinematics.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..models import Model

__all__ = ["BodyStates", "FrameTable", "body_states", "frame_table", "skew"]


def skew(v):
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) @ b == a x b``."""
    v = np.asarray(v)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


def _cross(a, b, out=None):
    """Cross products over axis 1 (the component axis of the tables), broadcasting the rest.

    Basic slices only: NumPy broadcasts them with long inner loops over the samples.
    """
    out = np.empty(np.broadcast_shapes(a.shape, b.shape)) if out is None else out
    for r in range(3):
        i, j = (r + 1) % 3, (r + 2) % 3
        np.multiply(a[:, i], b[:, j], out=out[:, r])
        out[:, r] -= a[:, j] * b[:, i]
    return out


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


@dataclass(frozen=True)
class FrameTable:
    """The body frames of many samples, samples last, in blocks.

    Sample ``i * block + j`` sits at index ``[i, ..., j]``, so each block of samples is one
    contiguous slab. (The regressor asks for one long block, for long array operations in the
    recursion, and cuts the table it builds from it into short blocks that stay in cache.)

    Attributes
    ----------
    table : ndarray of shape (n_blocks, 3, 2, n_bodies, 4, block)
        Axis 1 is the vector component (base axes). ``table[:, :, 0, b]`` is the pose of body
        b as four vectors ``[p, R e_x, R e_y, R e_z]``: its origin relative to the base origin
        [m] and its axes. ``table[:, :, 1, b]`` is their inertial time derivative
        ``[v, w x R e_x, w x R e_y, w x R e_z]`` [m/s, 1/s], the base origin's own motion
        excluded. The base's origin row (``p`` and ``v`` of body 0) is zero by definition.
    omega : ndarray of shape (n_blocks, 3, n_bodies, block)
        Absolute angular velocities, base axes [rad/s].
    omega_body : ndarray of shape (n_blocks, 3, n_bodies, block)
        The same in each body's own axes, ``R^T w`` [rad/s].
    """

    table: np.ndarray
    omega: np.ndarray
    omega_body: np.ndarray


class _Geometry:
    """Hashable view of a model's geometry (everything but inertial values): what the
    kinematics constants and the minimal parameter set depend on."""

    def __init__(self, model: Model):
        self.model = model
        self.key = (model.planar, tuple(
            (b.parent, b.joint_type, b.joint, b.name, b.known_zero, b.axis.tobytes(), b.rotation.tobytes(), b.translation.tobytes())
            for b in model.bodies
        ))

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return self.key == other.key


@functools.lru_cache(maxsize=32)
def _constants(geometry: _Geometry):
    """Per-joint constants of the recursion and the tree's path matrix.

    Returns
    -------
    steps : list of (int, bool, ndarray of shape (11, 3))
        Per moving body: its parent, whether the joint is revolute, and the transposed 3x11
        matrix ``[C0, C1, C2, t, a]`` in parent axes, with ``C0 + cos(q) C1 + sin(q) C2`` the
        joint frame (fixed placement times Rodrigues' rotation), ``t`` the joint offset and
        ``a`` the joint axis.
    path : ndarray of shape (n_bodies, n_joints)
        ``path[j, k] = 1`` when the joint of moving body ``k + 1`` lies on the path to body j.
    """
    model = geometry.model
    steps = []
    for b in model.bodies[1:]:
        k = skew(b.axis)
        if b.joint_type == "revolute":
            c = [b.rotation @ (np.eye(3) + k @ k), -b.rotation @ k @ k, b.rotation @ k]
        else:  # prismatic: no rotation
            c = [b.rotation, np.zeros((3, 3)), np.zeros((3, 3))]
        steps.append((b.parent, b.joint_type == "revolute", np.column_stack([*c, b.translation, b.rotation @ b.axis]).T))
    path = np.zeros((len(model.bodies), len(steps)))
    for j in range(1, len(model.bodies)):
        k = j
        while k > 0:
            path[j, k - 1] = 1.0
            k = model.bodies[k].parent
    return steps, path


def frame_table(model: Model, q, qd, w0, block: int) -> FrameTable:
    """Forward kinematics of the whole tree for many samples, in blocks.

    Parameters
    ----------
    model : Model
    q, qd : array_like of shape (n_samples, n_joints)
        Joint positions [rad or m] and rates [rad/s or m/s], in ``model.joints`` order.
    w0 : array_like of shape (n_samples, 3)
        Base angular velocity in base axes [rad/s].
    block : int
        Samples per block. The last block is padded with zero states.

    Returns
    -------
    FrameTable
        ``ceil(n_samples / block)`` blocks.
    """
    steps, path = _constants(_Geometry(model))
    nb, nj = len(model.bodies), len(steps)
    n = -(-len(q) // block)
    inputs = np.zeros((n * block, 2 * nj + 3))
    inputs[: len(q)] = np.concatenate([q, qd, w0], -1)
    inputs = np.ascontiguousarray(inputs.reshape(n, block, 2 * nj + 3).transpose(0, 2, 1))
    q, qd, w0 = inputs[:, :nj], inputs[:, nj : 2 * nj], inputs[:, 2 * nj :]
    rodrigues = np.stack([np.ones_like(q), np.cos(q), np.sin(q)], 2)  # (n, nj, 3, block): 1, cos, sin
    table = np.empty((n, 3, 2, nb, 4, block))
    rot, pos, vel, rate = table[:, :, 0, :, 1:], table[:, :, 0, :, 0], table[:, :, 1, :, 0], table[:, :, 1, :, 1:]
    rot[:, :, 0] = np.eye(3)[None, :, :, None]
    joint = np.empty((n, 3, 2, nj, block))  # offset from the parent's origin and axis, base axes
    # the recursion over the tree runs on rotations only (one BLAS product and a few array
    # operations per joint); positions and velocities are path sums over all joints at once
    for j, (parent, _, c) in enumerate(steps):
        g = np.matmul(c, rot[:, :, parent])  # (n, 3, 11, block): R_parent [C0, C1, C2, t, a]
        # R_parent (C0 + cos C1 + sin C2) in one pass (C1 = C2 = 0 for a prismatic joint)
        np.einsum("nrcab,ncb->nrab", g[:, :, :9].reshape(n, 3, 3, 3, block), rodrigues[:, j], out=rot[:, :, j + 1])
        joint[:, :, :, j] = g[:, :, 9:]
    offset, axis = joint[:, :, 0], joint[:, :, 1]
    rates = axis * qd[:, None]  # joint velocity directions times rates
    revolute = np.array([s[1] for s in steps])[:, None]
    omega = w0[:, :, None] + np.matmul(path, rates * revolute)
    # v_j = v_parent + w_parent x (p_j - p_parent) (+ slide rate), summed along the path
    if not revolute.all():  # prismatic joints slide along their axes
        offset += axis * (q * ~revolute)[:, None]
    step_vel = _cross(omega[:, :, [s[0] for s in steps]], offset)
    if not revolute.all():
        step_vel += rates * ~revolute
    np.matmul(path, offset, out=pos)
    np.matmul(path, step_vel, out=vel)
    _cross(omega[:, :, :, None], rot, out=rate)
    omega_body = np.einsum("nrbkc,nrbc->nkbc", rot, omega)
    return FrameTable(table, omega, omega_body)


def _flatten_states(q, qd, w0):
    """Broadcast ``q, qd, w0`` over their leading shape and flatten it: ``(lead, [q, qd, w0])``
    with each array of shape ``(prod(lead), m)``."""
    q, qd, w0 = (np.asarray(a, dtype=float) for a in (q, qd, w0))
    lead = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1], w0.shape[:-1])
    n = int(np.prod(lead))
    return lead, [np.broadcast_to(a, lead + a.shape[-1:]).reshape(n, a.shape[-1]) for a in (q, qd, w0)]


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
    lead, flat = _flatten_states(q, qd, w0)
    n = len(flat[0])
    ft = frame_table(model, *flat, block=max(n, 1))
    t = np.moveaxis(ft.table, -1, 1).reshape((-1,) + ft.table.shape[1:-1])[:n]  # (n, 3, 2, nb, 4)
    rot = t[:, :, 0, :, 1:].transpose(0, 2, 1, 3)
    pos, vel = t[:, :, 0, :, 0].transpose(0, 2, 1), t[:, :, 1, :, 0].transpose(0, 2, 1)
    omega = np.moveaxis(ft.omega, -1, 1).reshape(-1, 3, len(model.bodies))[:n].transpose(0, 2, 1)
    return BodyStates(*(np.ascontiguousarray(a).reshape(lead + a.shape[1:]) for a in (rot, pos, omega, vel)))
