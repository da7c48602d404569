"""The time-series layout shared by simulation, logs, identification and validation.

Arrays are time-first. The base attitude is stored as a unit quaternion, scalar first
``[w, x, y, z]`` (base-to-inertial rotation), and the base angular velocity in base axes,
for planar and spatial systems alike; a planar log is one whose attitude is a pure yaw.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["Log", "yaw_to_quat", "quat_to_yaw", "quat_to_matrix", "quat_multiply", "first_unordered", "log_fingerprint"]


def first_unordered(t):
    """The first stamp of ``t (n,)`` that does not follow its predecessor: ``(i, count, kind)``
    with ``count`` such steps in all and ``kind`` "repeats" or "goes back from"; None when the
    stamps increase strictly. Callers word the error for their source (line, message, field)."""
    t = np.asarray(t)
    bad = np.flatnonzero(np.diff(t) <= 0)
    if not bad.size:
        return None
    i = int(bad[0]) + 1
    return i, bad.size, "repeats" if t[i] == t[i - 1] else "goes back from"


def yaw_to_quat(yaw):
    """Quaternions ``[w, x, y, z]`` of rotations by ``yaw`` [rad] about z; shape ``(..., 4)``."""
    yaw = np.asarray(yaw, dtype=float)
    out = np.zeros(yaw.shape + (4,))
    out[..., 0] = np.cos(yaw / 2)
    out[..., 3] = np.sin(yaw / 2)
    return out


def quat_to_yaw(quat):
    """Yaw angle [rad] of quaternions ``(..., 4)`` ``[w, x, y, z]`` (rotation about z)."""
    w, x, y, z = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def quat_to_matrix(quat):
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions ``(..., 4)`` ``[w, x, y, z]``."""
    w, x, y, z = np.moveaxis(np.asarray(quat, dtype=float), -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def quat_multiply(a, b):
    """Hamilton products ``a (x) b`` of quaternions ``(..., 4)`` ``[w, x, y, z]`` (broadcast)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    s, v, t, u = a[..., :1], a[..., 1:], b[..., :1], b[..., 1:]
    return np.concatenate([s * t - np.sum(v * u, -1, keepdims=True), s * u + t * v + np.cross(v, u)], -1)


@dataclass(frozen=True)
class Log:
    """Measured or simulated motion of a free-floating system.

    Attributes
    ----------
    t : ndarray of shape (n_samples,)
        Strictly increasing time stamps [s].
    joints : tuple of str
        Joint names (URDF names), the column order of ``q`` and ``qd``.
    q : ndarray of shape (n_samples, n_joints)
        Joint positions [rad or m].
    qd : ndarray of shape (n_samples, n_joints)
        Joint rates [rad/s or m/s].
    base_quat : ndarray of shape (n_samples, 4)
        Base attitude, scalar-first unit quaternion, base to inertial.
    base_w : ndarray of shape (n_samples, 3)
        Base angular velocity in base axes [rad/s].
    planar : bool
        True when the motion is planar (attitude a yaw about z); CSV files then carry
        ``base_yaw`` and ``base_wz`` instead of the quaternion and the 3-vector.
    meta : dict
        Provenance (source file, seed, noise levels, ...), carried into results.
    base_position : ndarray of shape (n_samples, 3) or None
        Base frame origin in the inertial frame [m] (z zero for planar logs), when measured
        (motion capture) or simulated; None otherwise.
    tau : ndarray of shape (n_samples, n_joints) or None
        Joint efforts [N m or N], when recorded; None otherwise.
    """

    t: np.ndarray
    joints: tuple
    q: np.ndarray
    qd: np.ndarray
    base_quat: np.ndarray
    base_w: np.ndarray
    planar: bool = True
    meta: dict = field(default_factory=dict, compare=False)
    base_position: np.ndarray | None = field(default=None, compare=False)
    tau: np.ndarray | None = field(default=None, compare=False)

    @property
    def n_samples(self) -> int:
        return len(self.t)

    @property
    def base_yaw(self):
        """Base yaw [rad], unwrapped, shape ``(n_samples,)`` (meaningful for planar logs)."""
        return np.unwrap(quat_to_yaw(self.base_quat))

    def select(self, index) -> "Log":
        """The log restricted to the samples ``index`` (a slice, mask or index array)."""
        return replace(
            self,
            t=self.t[index],
            q=self.q[index],
            qd=self.qd[index],
            base_quat=self.base_quat[index],
            base_w=self.base_w[index],
            base_position=None if self.base_position is None else self.base_position[index],
            tau=None if self.tau is None else self.tau[index],
        )


def log_fingerprint(log: Log) -> str:
    """A hash of the log's time stamps and joint angles (SHA-256, hex), equal for the same
    samples of the same motion however they were stored (a log CSV reads back bit for bit).

    Identification records it, so that validation can tell the log a model was fitted to."""
    digest = hashlib.sha256()
    for x in (log.t, log.q):
        x = np.ascontiguousarray(x, dtype="<f8")
        digest.update(str(x.shape).encode())
        digest.update(x.tobytes())
    return digest.hexdigest()
