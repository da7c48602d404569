"""Analytic derivative of the momentum ``h = Y(q, qd, w0) pi`` w.r.t. the state, for any tree.

Every regressor column is a symmetric bilinear form of the rows of the pose table ``S`` (body
origins ``p_b`` and axes ``R_b e_k``) and of its inertial rate ``U = D S`` (:class:`FrameTable`),
plus the rotor terms ``R_b K_b R_b^T w_b``. Weighted by ``pi`` the momentum is

    h = sum_ac W_ac S_a x U_c + sum_b I_b w_b,      I_b = R_b K_b R_b^T,

with ``W`` symmetric over the table rows (:func:`_weights`). The velocities enter ``U = D S``
linearly, ``D S_a = w0 x S_a + sum_j qd_j d_j S_a``, and joint ``j`` moves the rows of its subtree:
``d_j S_a = a_j x (S_a - delta_a o_j)`` for a revolute joint (axis ``a_j`` through the origin
``o_j`` of its child body; ``delta_a`` is 1 on origin rows, 0 on axis rows), ``delta_a a_j`` for
a prismatic one. Derivatives in q commute with ``D`` (its coefficients are velocities), so
``d_j U_a = D(d_j S_a)``, with ``D a_j = w_parent x a_j`` and ``D o_j = v_child``. With
``Z = W S`` and ``V = W U`` the derivative is ``d_j h = sum_a d_j S_a x V_a + Z_a x d_j U_a``
plus the rotor terms; the triple products separate into a few per-body sums (``S V^T``,
``S Z^T``, ``U Z^T``, ``I_b``, ``I_b w_b`` and the origin rows of ``V`` and ``Z``) that are
summed over each joint's subtree from the leaves up. One kinematics evaluation per sample gives
all ``2 n_joints + 3`` columns; ``tests/test_momentum_jacobian.py`` checks them against
Richardson-extrapolated central differences of the momentum.
"""

from __future__ import annotations

import numpy as np

from .._threads import one_blas_thread
from ._kernels import _body_features, _joint_jacobian, _subtree_sums
from ._kinematics import _flatten_states, _Geometry, _joint_arrays, frame_table
from ._regressor import Parameterization

__all__ = ["momentum_jacobian"]


def _weights(param: Parameterization, pi):
    """``W (4 n_bodies, 4 n_bodies)`` and ``K (n_bodies, 3, 3)`` of the momentum of ``pi``.

    The columns basis weights its plan's columns by ``pi``; the planar basis is the full
    regressor's z row times ``pinv(projection)`` (its functions fit the full columns exactly),
    so its momentum is that of the full columns weighted by ``pinv(projection) @ pi``."""
    kind, data, _ = param._eval
    model = param.model
    if kind == "planar":
        plan, inverse = param._full_momentum
        weights = inverse @ pi
    else:
        plan, weights = data, pi
    nb = len(model.bodies)
    W = np.zeros((4 * nb, 4 * nb))
    a, c = plan.pair_rows
    w = plan.pair_weight * weights[plan.pair_at]
    np.add.at(W, (a, c), w)
    np.add.at(W, (c, a), w)
    K = np.zeros((nb, 3, 3))
    _, _, spin1, spin2 = plan.inertia
    body, m1, m2 = spin1 % nb, spin1 // nb, spin2 // nb
    k = weights[plan.inertia_at]
    np.add.at(K, (body, m1, m2), k)
    np.add.at(K, (body[m1 != m2], m2[m1 != m2], m1[m1 != m2]), k[m1 != m2])
    return W, K


def _chunk_jacobian(model, W, K, q, qd, w0):
    """:func:`momentum_jacobian` of ``m`` samples: ``(m, 3, 2 n_joints + 3)``."""
    nb, m = len(model.bodies), len(q)
    parents, revolute, joints = _joint_arrays(_Geometry(model))
    ft = frame_table(model, q, qd, w0, max(m, 1))
    table = ft.table[0]  # (3, 2, nb, 4, m): the kernels read it as it is laid out, no transposed copy
    weighted = (W @ table.reshape(3, 2, 4 * nb, m)).reshape(table.shape)  # Z = W S and V = W U
    features = np.empty((nb, 45, m))  # the per-body sums (S V^T, S Z^T, U Z^T, I, I w, V_0, Z_0), compiled
    _body_features(table, weighted, K, ft.omega[0], features)
    summed = np.empty((nb - 1, 45, m))
    _subtree_sums(features, parents, summed)  # over each joint's subtree
    jac = np.empty((m, 3, 2 * len(parents) + 3))
    local = np.ascontiguousarray(joints[:, :, 10])  # joint axes in parent axes
    _joint_jacobian(features, summed, table, ft.omega[0], local, parents, revolute, jac)
    return jac


def momentum_jacobian(param: Parameterization, q, qd, w0, pi, *, chunk: int = 2048) -> np.ndarray:
    """Derivative of the momentum ``regressor(q, qd, w0) @ pi`` w.r.t. ``[q, qd, w0]``.

    Exact (analytic), from one kinematics evaluation per sample; the velocity columns are the
    momentum matrix (the momentum is linear in ``qd`` and ``w0``).

    Parameters
    ----------
    param : Parameterization
    q, qd : array_like of shape (..., n_joints)
        Joint positions [rad or m] and rates [rad/s or m/s].
    w0 : array_like of shape (..., 3)
        Base angular velocity in base axes [rad/s].
    pi : array_like of shape (k,)
        Minimal parameters.
    chunk : int
        Samples per kinematics call (bounds the memory to ~100 kB per body and 1,000 samples).

    Returns
    -------
    ndarray of shape (..., rows, 2 n_joints + 3)
        Base-axes momentum rows by ``[q, qd, w0]`` [N m s per rad, m, rad/s or m/s]; for planar
        systems ``h_z`` by ``[q, qd, w0_z]``, shape ``(..., 1, 2 n_joints + 1)``.
    """
    model = param.model
    lead, (q, qd, w0) = _flatten_states(q, qd, w0)
    nj = model.n_joints
    W, K = _weights(param, np.asarray(pi, float))
    jac = np.empty((len(q), 3, 2 * nj + 3))
    with one_blas_thread():  # small products: threads only wait on busy cores
        for s in range(0, len(q), chunk):
            jac[s : s + chunk] = _chunk_jacobian(model, W, K, q[s : s + chunk], qd[s : s + chunk], w0[s : s + chunk])
    if model.planar:  # h_z, and w0 along z only (the planar regressor's domain)
        jac = np.delete(jac[:, 2:3], [2 * nj, 2 * nj + 1], -1)
    return jac.reshape(lead + jac.shape[1:])
