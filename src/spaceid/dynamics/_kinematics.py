"""Free-floating kinematics in base axes, batched over samples.

Every quantity is expressed in the base frame and measured relative to the base frame origin,
so neither the base attitude nor the base position is needed: the momentum equations in base
axes depend on ``q``, ``qd`` and the base angular velocity ``w0`` only.

Pinocchio evaluates one configuration per call; identification evaluates 10^4 samples at once,
so the tree recursion here is a compiled kernel run sample by sample, its per-sample results
kept in cache (:func:`spaceid.dynamics._kernels._sample_frames`). :func:`frame_table` lays them out
samples last, in blocks, for the NumPy work that follows (each operation one long loop over
samples); :func:`body_states` gives them time-first. ``tests/test_regressor.py`` checks them
against Pinocchio's own kinematics.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..models import Model
from ._kernels import _frame_blocks

__all__ = ["BodyStates", "FrameTable", "body_states", "frame_table", "skew"]


def skew(v):
    """Cross-product matrices ``(..., 3, 3)`` of vectors ``(..., 3)``: ``skew(a) @ b == a x b``."""
    v = np.asarray(v)
    z = np.zeros(v.shape[:-1])
    x, y, w = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([z, -w, y], -1), np.stack([w, z, -x], -1), np.stack([-y, x, z], -1)], -2)


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
            (b.parent, b.joint_type, b.joint, b.name, b.known_zero,
             b.axis.tobytes(), b.rotation.tobytes(), b.translation.tobytes())
            for b in model.bodies
        ))

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return self.key == other.key


@functools.lru_cache(maxsize=32)
def _joint_arrays(geometry: _Geometry):
    """Per-joint constants of the compiled recursion: parents ``(n_joints,)``, revolute flags ``(n_joints,)``
    and the matrices ``[C0, C1, C2, t, a]`` ``(n_joints, 3, 11)`` in parent axes, with ``C0 + cos(q) C1 + sin(q)
    C2`` the joint frame (fixed placement times Rodrigues' rotation), ``t`` the joint offset and ``a`` the joint
    axis (joint ``j`` moves body ``j + 1``)."""
    bodies = geometry.model.bodies[1:]
    matrices = []
    for b in bodies:
        k = skew(b.axis)
        if b.joint_type == "revolute":
            c = [b.rotation @ (np.eye(3) + k @ k), -b.rotation @ k @ k, b.rotation @ k]
        else:  # prismatic: no rotation
            c = [b.rotation, np.zeros((3, 3)), np.zeros((3, 3))]
        matrices.append(np.column_stack([*c, b.translation, b.rotation @ b.axis]))
    return (np.array([b.parent for b in bodies], dtype=np.int64),
            np.array([b.joint_type == "revolute" for b in bodies], dtype=bool),
            np.array(matrices).reshape(-1, 3, 11))  # fmt: skip


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
    nb = len(model.bodies)
    n = -(-len(q) // block)
    states = [np.zeros((n * block, np.shape(a)[-1])) for a in (q, qd, w0)]
    for padded, a in zip(states, (q, qd, w0)):
        padded[: len(a)] = a
    table, omega, spin = np.empty((n, 3, 2, nb, 4, block)), np.empty((n, 3, nb, block)), np.empty((n, 3, nb, block))
    _frame_blocks(*_joint_arrays(_Geometry(model)), *states, table.reshape(n, 3, 8 * nb, block), omega, spin)
    return FrameTable(table, omega, spin)


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
