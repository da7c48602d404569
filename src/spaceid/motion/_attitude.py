"""The base attitude of a spatial free-floating system under a prescribed joint motion, by
Gauss-Legendre collocation on the unit quaternions (docs/theory/momentum.md).

With constant momentum the base rate is ``w0 = A(t)^-1 (R0^T h - b(t))``: the locked inertia
``A`` and the joints' own momentum ``b`` follow from the joint motion alone, so they are
evaluated beforehand, vectorised, at every stage time of every step; what is left to integrate
step by step is a smooth, non-stiff ODE of the attitude, ``dq/dt = q (x) [0, w0] / 2``, which
this module's kernel does with the s-stage Gauss-Legendre method (order 2 s). Its stage
equations are solved by fixed-point iteration, and the method keeps |q| = 1 exactly (a
quadratic invariant of the flow) up to round-off.
"""

from __future__ import annotations

import numpy as np

from .._jit import kernel

__all__: list = []

STAGES = 4
"""Stages of the Gauss-Legendre collocation: order 8."""


def gauss_tableau(stages: int = STAGES):
    """The Butcher tableau of the ``stages``-stage Gauss-Legendre method.

    Returns
    -------
    c : ndarray of shape (s,)
        Stage times as fractions of the step (the Gauss-Legendre nodes on [0, 1]).
    b : ndarray of shape (s,)
        Weights (the quadrature weights on [0, 1]).
    a : ndarray of shape (s, s)
        ``a[i, j]``: the integral from 0 to ``c[i]`` of the Lagrange polynomial of node ``j``.
    """
    x, w = np.polynomial.legendre.leggauss(stages)
    c, b = (x + 1) / 2, w / 2
    a = np.empty((stages, stages))
    for j in range(stages):
        others = np.delete(c, j)
        basis = np.polynomial.Polynomial.fromroots(others) / np.prod(c[j] - others)
        a[:, j] = basis.integ()(c)
    return c, b, a


ITERATIONS = 60
"""Fixed-point iterations of a step's stage equations before the step counts as failed (the
caller then halves the steps): each gains about ``-log10(w0 dt)`` digits."""


@kernel
def _stage_rate(quat, inv_locked, offset, momentum, out):
    """``out (4,)`` = ``quat (x) [0, w0] / 2`` with ``w0 = inv_locked (R^T momentum) - offset``,
    ``R`` the rotation of ``quat`` normalised (base to inertial axes)."""
    norm = np.sqrt(quat[0] ** 2 + quat[1] ** 2 + quat[2] ** 2 + quat[3] ** 2)
    w, x, y, z = quat[0] / norm, quat[1] / norm, quat[2] / norm, quat[3] / norm
    hx, hy, hz = momentum[0], momentum[1], momentum[2]
    # R^T h, R = quat_to_matrix([w, x, y, z])
    bx = (1 - 2 * (y * y + z * z)) * hx + 2 * (x * y + w * z) * hy + 2 * (x * z - w * y) * hz
    by = 2 * (x * y - w * z) * hx + (1 - 2 * (x * x + z * z)) * hy + 2 * (y * z + w * x) * hz
    bz = 2 * (x * z + w * y) * hx + 2 * (y * z - w * x) * hy + (1 - 2 * (x * x + y * y)) * hz
    wx = inv_locked[0, 0] * bx + inv_locked[0, 1] * by + inv_locked[0, 2] * bz - offset[0]
    wy = inv_locked[1, 0] * bx + inv_locked[1, 1] * by + inv_locked[1, 2] * bz - offset[1]
    wz = inv_locked[2, 0] * bx + inv_locked[2, 1] * by + inv_locked[2, 2] * bz - offset[2]
    qw, qx, qy, qz = quat[0], quat[1], quat[2], quat[3]
    out[0] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[1] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[2] = 0.5 * (qw * wy - qx * wz + qz * wx)
    out[3] = 0.5 * (qw * wz + qx * wy - qy * wx)


@kernel
def collocation_steps(quat0, inv_locked, offset, momentum, widths, a, b, out):
    """Gauss-Legendre collocation of the base attitude over consecutive steps.

    Parameters
    ----------
    quat0 : ndarray of shape (4,)
        Attitude at the first step's start (scalar first).
    inv_locked : ndarray of shape (n_steps, s, 3, 3)
        The inverse locked inertia at each step's stage times [1/(kg m^2)].
    offset : ndarray of shape (n_steps, s, 3)
        ``A^-1 b`` there: the base rate the joints' own momentum cancels [rad/s].
    momentum : ndarray of shape (3,)
        Inertial angular momentum [N m s].
    widths : ndarray of shape (n_steps,)
        Step widths [s].
    a, b : ndarray
        The tableau (:func:`gauss_tableau`).
    out : ndarray of shape (n_steps + 1, 4)
        Receives the attitude at the start and after every step.

    Returns
    -------
    int
        -1, or the first step whose stage equations did not converge in :data:`ITERATIONS`.
    """
    s = b.shape[0]
    k = np.zeros((s, 4))
    new = np.zeros(4)
    stage = np.zeros(4)
    for c in range(4):
        out[0, c] = quat0[c]
    for i in range(widths.shape[0]):
        dt = widths[i]
        for j in range(s):  # start: the rate at the step's start attitude, at each stage time
            _stage_rate(out[i], inv_locked[i, j], offset[i, j], momentum, new)
            for c in range(4):
                k[j, c] = new[c]
        change, last, converged = np.inf, np.inf, False
        for _ in range(ITERATIONS):
            change = 0.0
            for j in range(s):  # Gauss-Seidel sweep over the stages
                for c in range(4):
                    acc = 0.0
                    for m in range(s):
                        acc += a[j, m] * k[m, c]
                    stage[c] = out[i, c] + dt * acc
                _stage_rate(stage, inv_locked[i, j], offset[i, j], momentum, new)
                for c in range(4):
                    change = max(change, abs(new[c] - k[j, c]) * dt)
                    k[j, c] = new[c]
            # converged to round-off, or no longer shrinking at a level round-off explains
            if change <= 2.2e-16 or (change >= 0.5 * last and change <= 1e-14):
                converged = True
                break
            last = change
        if not converged:
            return i
        for c in range(4):
            acc = 0.0
            for j in range(s):
                acc += b[j] * k[j, c]
            out[i + 1, c] = out[i, c] + dt * acc
    return -1
