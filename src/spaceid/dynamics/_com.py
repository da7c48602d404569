"""The system centre of mass in base axes, as a linear function of mass-distribution terms.

With the base origin at ``r0`` and body ``i`` at ``r0 + R0 (p_i(q) + R_i(q) c_i)`` (base axes),
the system CM relative to the base origin, in base axes, is

    c(q) = sum_i m_i (p_i + R_i c_i) / M = W(q) phi,

linear in the barycentric terms ``phi``: for the base ``g_0 = m_0 c_0 / M`` (its ``p`` is zero and
its ``R`` the identity), for every other body ``mu_i = m_i / M`` and ``g_i = m_i c_i / M`` (the
first moment about the body frame origin over the total mass). ``W`` holds the columns ``e_x,
e_y, e_z`` for the base, then ``p_i, R_i e_x, R_i e_y, R_i e_z`` for each body.
"""

from __future__ import annotations

import numpy as np

from ..models import Model
from ._kinematics import body_states

__all__ = ["com_regressor", "com_terms", "system_com"]


def com_terms(model: Model):
    """Names, definitions and true values of the terms ``phi`` of :func:`com_regressor`.

    Returns
    -------
    names, definitions : tuple of str
        ``gx_<base>, gy_<base>, gz_<base>``, then ``mu_<body>, gx_<body>, gy_<body>, gz_<body>``.
    values : ndarray of shape (3 + 4 (n_bodies - 1),)
        The terms of the model's own inertial values [-, m].
    """
    names, definitions, values = [], [], []
    total = model.mass
    for i, b in enumerate(model.bodies):
        if i:
            names.append(f"mu_{b.name}"), definitions.append(f"m_{b.name}/M"), values.append(b.mass / total)
        for axis, first in zip("xyz", b.inertial[1:4]):
            names.append(f"g{axis}_{b.name}"), definitions.append(f"mc{axis}_{b.name}/M")
            values.append(first / total)
    return tuple(names), tuple(definitions), np.array(values)


def com_regressor(model: Model, q) -> np.ndarray:
    """``W(q)`` with ``c(q) = W(q) phi`` [m], the system CM relative to the base origin in base axes.

    Parameters
    ----------
    model : Model
    q : array_like of shape (..., n_joints)

    Returns
    -------
    ndarray of shape (..., 3, 3 + 4 (n_bodies - 1))
    """
    q = np.asarray(q, float)
    st = body_states(model, q, np.zeros_like(q), np.zeros(q.shape[:-1] + (3,)))
    columns = np.concatenate([st.position[..., 1:, :, None], st.rotation[..., 1:, :, :]], -1)  # (..., nb-1, 3, 4)
    columns = np.moveaxis(columns, -3, -2).reshape(q.shape[:-1] + (3, -1))
    return np.concatenate([np.broadcast_to(np.eye(3), q.shape[:-1] + (3, 3)), columns], -1)


def system_com(model: Model, q) -> np.ndarray:
    """The system CM [m] relative to the base origin, base axes, shape ``(..., 3)``."""
    return com_regressor(model, q) @ com_terms(model)[2]
