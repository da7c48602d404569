"""Angular momentum of a free-floating system computed directly from rigid-body definitions.

This is the independent reference for every regressor: it uses each body's mass, CoM and
inertia as they are, never the lumped parameter combinations of :mod:`spaceid.dynamics`.

References
----------
.. [1] The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md), Eq. 1
   (docs/theory/momentum.md).
"""

from __future__ import annotations

import numpy as np

from ._kinematics import body_states
from ..models import Model
from ..models.internal import inertia_matrix
from ..data import quat_to_matrix

__all__ = ["angular_momentum"]


def angular_momentum(model: Model, q, qd, w0, base_quat=None):
    """Angular momentum about the system CM, with zero linear momentum.

    The base linear velocity is not an input: it is the one that makes the total linear
    momentum zero (the system CM is fixed in inertial space).

    Parameters
    ----------
    model : Model
    q, qd : array_like of shape (..., n_joints)
        Joint positions [rad or m] and rates [rad/s or m/s].
    w0 : array_like of shape (..., 3)
        Base angular velocity in base axes [rad/s].
    base_quat : array_like of shape (..., 4), optional
        Base attitude ``[w, x, y, z]``; when given the result is in inertial axes.

    Returns
    -------
    ndarray of shape (..., 3)
        Angular momentum [N m s], in base axes (or inertial axes with ``base_quat``).
    """
    st = body_states(model, q, qd, w0)
    masses = np.array([b.mass for b in model.bodies])
    com_local = np.array([b.com for b in model.bodies])  # (n_bodies, 3), body frames
    arm = np.einsum("...bij,bj->...bi", st.rotation, com_local)
    s = st.position + arm  # body CoMs relative to the base origin
    u = st.velocity + np.cross(st.omega, arm)  # their velocities relative to its motion
    s_c = np.einsum("b,...bi->...i", masses, s) / masses.sum()
    u_c = np.einsum("b,...bi->...i", masses, u) / masses.sum()
    # zero linear momentum: absolute velocity of CoM b is u_b - u_c; about the fixed system CM
    i_com = np.array(
        [inertia_matrix(b.inertial) - b.mass * (b.com @ b.com * np.eye(3) - np.outer(b.com, b.com))
         for b in model.bodies]
    )
    i_base = st.rotation @ i_com @ np.swapaxes(st.rotation, -1, -2)
    spin = np.einsum("...bij,...bj->...i", i_base, st.omega)
    orbit = np.einsum("b,...bi->...i", masses, np.cross(s - s_c[..., None, :], u - u_c[..., None, :]))
    h = spin + orbit
    if base_quat is not None:
        h = np.einsum("...ij,...j->...i", quat_to_matrix(base_quat), h)
    return h
