"""Exciting joint trajectories: a finite Fourier series plus a quintic (paper Eq. 12).

For joint i, with ``wf = 2 pi / tf``,

    q_i(t) = sum_{l=1..Nf} [a_il/(wf l) sin(wf l t) - b_il/(wf l) cos(wf l t)]
             + sum_{j=0..5} c_ij t^j,

so that ``qd_i`` has the Fourier coefficients ``a_il`` (cosine) and ``b_il`` (sine), in rad/s. The
quintic is not free: it makes q, qd and qdd take prescribed values at t = 0 and t = tf. For fixed
boundary values, q, qd and qdd are therefore affine in the free coefficients ``X = [a | b]``:

    [q, qd, qdd](t)[:, i] = B(t) @ X[i] + P(t)[:, i]

with the boundary-corrected basis ``B`` of :func:`fourier_basis` (every basis function has zero
q, qd, qdd at both ends) and the quintic ``P`` of :func:`boundary_quintic` through the boundary
values. The designer uses this form for linear limit constraints and batched evaluation.

References
----------
The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md):
Eq. 12 and Table 2 (as read in docs/theory/excitation.md).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._errors import SpaceidError, finite_array, shown
from ..data import read_json

__all__ = [
    "FourierTrajectory",
    "BOUNDARY_FIELDS",
    "NAMED_TRAJECTORIES",
    "fourier_basis",
    "boundary_quintic",
    "sample_times",
    "load_trajectory",
]

BOUNDARY_FIELDS = ("q0", "qd0", "qdd0", "qf", "qdf", "qddf")
"""Boundary values, in the order ``[q, qd, qdd](0)`` then ``[q, qd, qdd](tf)``."""

MIN_DURATION = 1e-3
"""[s] The shortest trajectory accepted: no robot's joint motion, nor any sensor's log, is shorter."""
MAX_JOINT_RATE = 1e4
"""[rad/s or m/s] The largest joint rate a trajectory may reach (about 95,000 rpm): beyond it the
coefficients are not rad/s of a robot's joint (a unit error, a corrupted file)."""
_FORMAT = "spaceid.motion"
_VERSION = 1

# Quintic p(s) = sum_j d_j s^j on s = t / tf in [0, 1]: rows give p, p', p'' at s = 0 and s = 1,
# so _QUINTIC maps those six values to d (normalised time keeps the solve well conditioned).
_QUINTIC = np.linalg.inv(
    np.array(
        [
            [1, 0, 0, 0, 0, 0],
            [0, 1, 0, 0, 0, 0],
            [0, 0, 2, 0, 0, 0],
            [1, 1, 1, 1, 1, 1],
            [0, 1, 2, 3, 4, 5],
            [0, 0, 2, 6, 12, 20],
        ],
        dtype=float,
    )
)


def sample_times(duration, n):
    """``n`` equally spaced times over ``[0, duration]``, both ends included; shape (n,) [s]."""
    return np.linspace(0.0, float(duration), int(n))


def _hermite(t, duration):
    """Quintic Hermite basis: ``(3, n_t, 6)`` map from the boundary values to [p, p', p''](t).

    The six boundary values are ordered as :data:`BOUNDARY_FIELDS`, in SI units.
    """
    T = float(duration)
    s = np.asarray(t, dtype=float)[:, None] / T
    j = np.arange(6)
    powers = [s ** np.maximum(j - k, 0) for k in range(3)]
    falling = [np.ones(6), j, j * (j - 1)]  # d^k/ds^k s^j = j (j-1) .. s^(j-k)
    rows = np.stack([falling[k] * powers[k] / T**k for k in range(3)])
    return rows @ _QUINTIC * np.array([1, T, T * T, 1, T, T * T])


def _raw_fourier(t, duration, harmonics):
    """Fourier part of Eq. 12: q, qd, qdd (3, n_t, 2 harmonics), columns ``[a_1.., b_1..]``."""
    wl = 2 * np.pi / float(duration) * np.arange(1, harmonics + 1)
    phase = np.asarray(t, dtype=float)[:, None] * wl
    s, c = np.sin(phase), np.cos(phase)
    return np.stack([np.hstack([s / wl, -c / wl]), np.hstack([c, s]), np.hstack([-wl * s, wl * c])])


def fourier_basis(t, *, duration, harmonics):
    """Boundary-corrected Fourier basis of Eq. 12.

    Parameters
    ----------
    t : array_like of shape (n_t,)
        Times [s].
    duration : float
        Trajectory duration tf [s].
    harmonics : int
        Number of harmonics Nf.

    Returns
    -------
    ndarray of shape (3, n_t, 2 * harmonics)
        ``B[0]``, ``B[1]``, ``B[2]``: the q [rad], qd [rad/s], qdd [rad/s^2] responses to a unit
        coefficient, columns ``[a_1..a_Nf, b_1..b_Nf]`` [per rad/s]. Each column is a Fourier
        term minus the quintic through its own boundary values, so it vanishes (with its first
        two derivatives) at t = 0 and t = tf.
    """
    ends = _raw_fourier([0.0, duration], duration, harmonics)  # (3, 2, K)
    at_ends = np.concatenate([ends[:, 0], ends[:, 1]])  # (6, K), BOUNDARY_FIELDS order
    return _raw_fourier(t, duration, harmonics) - _hermite(t, duration) @ at_ends


def boundary_quintic(t, *, duration, boundary):
    """The quintic through given boundary values.

    Parameters
    ----------
    t : array_like of shape (n_t,)
        Times [s].
    duration : float
        Trajectory duration tf [s].
    boundary : array_like of shape (6, n_joints)
        ``q0, qd0, qdd0, qf, qdf, qddf`` [rad, rad/s, rad/s^2].

    Returns
    -------
    ndarray of shape (3, n_t, n_joints)
        q, qd, qdd of the quintic.
    """
    return _hermite(t, duration) @ np.asarray(boundary, dtype=float)


@dataclass(frozen=True, eq=False)
class FourierTrajectory:
    """A Fourier-plus-quintic joint trajectory (paper Eq. 12).

    Attributes
    ----------
    joints : tuple of str
        Joint names, the column order of q.
    duration : float
        Duration tf [s]; the base frequency is ``wf = 2 pi / tf``.
    a, b : ndarray of shape (n_joints, n_harmonics)
        Cosine and sine coefficients of qd [rad/s].
    q0, qd0, qdd0, qf, qdf, qddf : ndarray of shape (n_joints,)
        q [rad], qd [rad/s], qdd [rad/s^2] at t = 0 and t = tf; zeros when omitted.
    meta : dict
        Provenance (source, criterion, seed, ...); not compared.

    Notes
    -----
    The quintic coefficients are derived, see :attr:`c`. Instances compare equal when all
    fields but ``meta`` are equal.
    """

    joints: tuple
    duration: float
    a: np.ndarray
    b: np.ndarray
    q0: np.ndarray = None
    qd0: np.ndarray = None
    qdd0: np.ndarray = None
    qf: np.ndarray = None
    qdf: np.ndarray = None
    qddf: np.ndarray = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        src = self.meta.get("source", "trajectory")
        joints = tuple(str(j) for j in self.joints)
        try:  # true is not one second
            duration = math.nan if isinstance(self.duration, (bool, np.bool_)) else float(self.duration)
        except (TypeError, ValueError):
            duration = math.nan
        if not (math.isfinite(duration) and duration > 0):
            raise SpaceidError(
                f"{src}: field 'duration' must be a positive number of seconds, got {shown(self.duration)}"
            )
        if duration < MIN_DURATION:
            raise SpaceidError(f"{src}: field 'duration' is {duration:g} s, shorter than {MIN_DURATION:g} s: give the "
                               "motion's duration in seconds")
        a = finite_array(self.a, 2, "a", src)
        if a.shape[0] != len(joints) or a.shape[1] < 1:
            raise SpaceidError(
                f"{src}: field 'a' must have shape (n_joints={len(joints)}, n_harmonics), "
                f"got {a.shape}"
            )
        set_ = object.__setattr__
        set_(self, "joints", joints)
        set_(self, "duration", duration)
        set_(self, "a", a)
        set_(self, "b", finite_array(self.b, a.shape, "b", src))
        for name in BOUNDARY_FIELDS:
            value = getattr(self, name)
            value = np.zeros(len(joints)) if value is None else value
            set_(self, name, finite_array(value, (len(joints),), name, src))
        self._check_rates(src)

    def _check_rates(self, src):
        """A SpaceidError naming the fields when the joint rates, on a grid of 8 points a harmonic,
        overflow or exceed :data:`MAX_JOINT_RATE` (huge coefficients: a unit error, a corrupted file)."""
        with np.errstate(all="ignore"):
            _, qd, _ = self.evaluate(np.linspace(0.0, self.duration, 8 * self.n_harmonics + 2))
            peak = float(np.max(np.abs(qd))) if np.all(np.isfinite(qd)) else math.inf
        if peak > MAX_JOINT_RATE:
            raise SpaceidError(f"{src}: fields 'a', 'b' and the boundary values give joint rates up to {peak:.3g} "
                               f"rad/s, above {MAX_JOINT_RATE:g}: give the Fourier coefficients in rad/s of a robot's "
                               "motion")

    def __eq__(self, other):
        if not isinstance(other, FourierTrajectory):
            return NotImplemented
        return (
            self.joints == other.joints
            and self.duration == other.duration
            and all(
                np.array_equal(getattr(self, k), getattr(other, k))
                for k in ("a", "b") + BOUNDARY_FIELDS
            )
        )

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_harmonics(self) -> int:
        return self.a.shape[1]

    @property
    def coefficients(self):
        """Free coefficients ``X = [a | b]``, shape (n_joints, 2 n_harmonics) [rad/s]."""
        return np.hstack([self.a, self.b])

    @property
    def boundary(self):
        """Boundary values, shape (6, n_joints), rows in :data:`BOUNDARY_FIELDS` order."""
        return np.stack([getattr(self, k) for k in BOUNDARY_FIELDS])

    @property
    def c(self):
        """Quintic coefficients ``c_ij`` of ``t^j``, shape (n_joints, 6) [rad/s^j]."""
        T = self.duration
        ends = _raw_fourier([0.0, T], T, self.n_harmonics)
        fourier_ends = np.concatenate([ends[:, 0], ends[:, 1]]) @ self.coefficients.T
        scale = np.array([1, T, T * T, 1, T, T * T])[:, None]
        d = _QUINTIC @ ((self.boundary - fourier_ends) * scale)  # coefficients of s^j
        return (d / T ** np.arange(6)[:, None]).T

    def evaluate(self, t):
        """Joint positions, rates and accelerations.

        Parameters
        ----------
        t : array_like of shape (n_t,)
            Times [s].

        Returns
        -------
        q, qd, qdd : ndarray of shape (n_t, n_joints)
            [rad], [rad/s], [rad/s^2].
        """
        t = np.atleast_1d(np.asarray(t, dtype=float))
        B = fourier_basis(t, duration=self.duration, harmonics=self.n_harmonics)
        P = boundary_quintic(t, duration=self.duration, boundary=self.boundary)
        q, qd, qdd = B @ self.coefficients.T + P
        return q, qd, qdd

    def to_dict(self) -> dict:
        """JSON-ready dictionary; :meth:`from_dict` inverts it."""
        return {
            "format": _FORMAT,
            "version": _VERSION,
            "joints": list(self.joints),
            "duration": self.duration,
            "a": self.a.tolist(),
            "b": self.b.tolist(),
            "boundary": {k: getattr(self, k).tolist() for k in BOUNDARY_FIELDS},
            "meta": _jsonable(self.meta),
        }

    @classmethod
    def from_dict(cls, data, *, source="trajectory"):
        """Build from :meth:`to_dict` output; ``source`` names the origin in error messages."""
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise SpaceidError(
                f"{source}: not a spaceid trajectory (expected a JSON object with "
                f'"format": "{_FORMAT}"); write one with FourierTrajectory.save'
            )
        if data.get("version") != _VERSION:
            raise SpaceidError(
                f"{source}: field 'version' must be {_VERSION}, got {shown(data.get('version'))}"
            )
        missing = [k for k in ("joints", "duration", "a", "b") if k not in data]
        if missing:
            raise SpaceidError(f"{source}: missing field '{missing[0]}'")
        joints, boundary = data["joints"], data.get("boundary", {})
        if not isinstance(joints, list) or not all(isinstance(j, str) for j in joints):
            raise SpaceidError(f"{source}: field 'joints' must be a list of joint names")
        if not isinstance(boundary, dict) or set(boundary) - set(BOUNDARY_FIELDS):
            raise SpaceidError(
                f"{source}: field 'boundary' must be an object with keys among "
                f"{', '.join(BOUNDARY_FIELDS)}"
            )
        meta = data.get("meta", {})
        meta = {**(meta if isinstance(meta, dict) else {}), "source": str(source)}
        return cls(joints, data["duration"], data["a"], data["b"], **boundary, meta=meta)

    def save(self, path):
        """Write the trajectory to ``path`` as JSON (atomically)."""
        write_text_atomic(path, json.dumps(self.to_dict(), indent=2) + "\n")


def _jsonable(value):
    """``value`` with numpy arrays and scalars turned into plain lists and numbers."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _paper_table2():
    return FourierTrajectory(
        joints=("left_shoulder", "left_elbow"),
        duration=5.0,
        a=[[-0.1642, 0.2786, 0.3582], [0.0846, 0.0597, 0.0498]],
        b=[[0.0010, 0.2090, -0.1000], [0.3682, -0.1692, -0.3283]],
        meta={
            "name": "paper-table2",
            "source": "paper-table2",
            "reference": "The Cepheus paper's Table 2 as read in docs/theory/excitation.md "
            "(moderate confidence)",
        },
    )


NAMED_TRAJECTORIES = {"paper-table2": _paper_table2}
"""Built-in trajectories by name: name -> factory returning a :class:`FourierTrajectory`."""


def load_trajectory(name_or_path, joints=None):
    """A named trajectory or one saved by :meth:`FourierTrajectory.save`.

    Parameters
    ----------
    name_or_path : str or path-like
        A key of :data:`NAMED_TRAJECTORIES` or a JSON file.
    joints : sequence of str, optional
        The model's joint names; the trajectory must drive exactly these, in this order.

    Returns
    -------
    FourierTrajectory

    Raises
    ------
    SpaceidError
        Unknown name, missing or malformed file, or joints that do not match.
    """
    key = str(name_or_path)
    if key in NAMED_TRAJECTORIES:
        traj = NAMED_TRAJECTORIES[key]()
    else:
        path = Path(name_or_path)
        if not path.exists():
            raise SpaceidError(
                f"{key}: no such trajectory file and not a named trajectory "
                f"(named: {', '.join(NAMED_TRAJECTORIES)})"
            )
        traj = FourierTrajectory.from_dict(read_json(path, what="JSON trajectory"), source=str(path))
    if joints is not None and tuple(joints) != traj.joints:
        raise SpaceidError(
            f"{key}: trajectory drives joints ({', '.join(traj.joints)}) but the model has "
            f"({', '.join(joints)}); design one for this model or edit its 'joints' field"
        )
    return traj
