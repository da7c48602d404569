"""The base attitude of a spatial free-floating system under a prescribed joint motion, by
Gauss-Legendre collocation on the unit quaternions (docs/theory/momentum.md), and with it the
momentum under a constant external torque, viscous and Coulomb friction.

With constant momentum the base rate is ``w0 = A(t)^-1 (R0^T h - b(t))``: the locked inertia
``A`` and the joints' own momentum ``b`` follow from the joint motion alone, so they are
evaluated beforehand, vectorised, at every stage time of every step; what is left to integrate
step by step is a smooth, non-stiff ODE of the attitude, ``dq/dt = q (x) [0, w0] / 2``, which
this module's kernel does with the s-stage Gauss-Legendre method (order 2 s). Its stage
equations are solved by fixed-point iteration, and the method keeps |q| = 1 exactly (a
quadratic invariant of the flow) up to round-off. Under a constant external torque, viscous and
Coulomb friction the inertial momentum is integrated with the attitude, its rate
``tau - c R0 w0 - mu R0 w0 / |w0|`` at the same stages (smooth wherever the base turns, which in
space it does but for an instant).
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
def _stage_rate(state, inv_locked, offset, torque, viscous, coulomb, out):
    """``out (7,)``: the rate of the state ``[quat, h]`` (scalar-first attitude, inertial momentum [N m s]):
    ``quat (x) [0, w0] / 2`` with ``w0 = inv_locked (R^T h) - offset``, ``R`` the rotation of ``quat``
    normalised (base to inertial axes), and ``torque - viscous R w0 - coulomb R w0 / |w0|`` (zero for a
    constant momentum)."""
    norm = np.sqrt(state[0] ** 2 + state[1] ** 2 + state[2] ** 2 + state[3] ** 2)
    w, x, y, z = state[0] / norm, state[1] / norm, state[2] / norm, state[3] / norm
    hx, hy, hz = state[4], state[5], state[6]
    # R^T h, R = quat_to_matrix([w, x, y, z])
    bx = (1 - 2 * (y * y + z * z)) * hx + 2 * (x * y + w * z) * hy + 2 * (x * z - w * y) * hz
    by = 2 * (x * y - w * z) * hx + (1 - 2 * (x * x + z * z)) * hy + 2 * (y * z + w * x) * hz
    bz = 2 * (x * z + w * y) * hx + 2 * (y * z - w * x) * hy + (1 - 2 * (x * x + y * y)) * hz
    wx = inv_locked[0, 0] * bx + inv_locked[0, 1] * by + inv_locked[0, 2] * bz - offset[0]
    wy = inv_locked[1, 0] * bx + inv_locked[1, 1] * by + inv_locked[1, 2] * bz - offset[1]
    wz = inv_locked[2, 0] * bx + inv_locked[2, 1] * by + inv_locked[2, 2] * bz - offset[2]
    qw, qx, qy, qz = state[0], state[1], state[2], state[3]
    out[0] = 0.5 * (-qx * wx - qy * wy - qz * wz)
    out[1] = 0.5 * (qw * wx + qy * wz - qz * wy)
    out[2] = 0.5 * (qw * wy - qx * wz + qz * wx)
    out[3] = 0.5 * (qw * wz + qx * wy - qy * wx)
    # the friction opposes the base rate in inertial axes, R w0: viscous in proportion, Coulomb along it
    ix = (1 - 2 * (y * y + z * z)) * wx + 2 * (x * y - w * z) * wy + 2 * (x * z + w * y) * wz
    iy = 2 * (x * y + w * z) * wx + (1 - 2 * (x * x + z * z)) * wy + 2 * (y * z - w * x) * wz
    iz = 2 * (x * z - w * y) * wx + 2 * (y * z + w * x) * wy + (1 - 2 * (x * x + y * y)) * wz
    turning = np.sqrt(ix * ix + iy * iy + iz * iz)
    along = coulomb / turning if turning > 0 else 0.0
    out[4] = torque[0] - (viscous + along) * ix
    out[5] = torque[1] - (viscous + along) * iy
    out[6] = torque[2] - (viscous + along) * iz


@kernel
def collocation_steps(state0, inv_locked, offset, torque, viscous, coulomb, widths, a, b, out):
    """Gauss-Legendre collocation of the base attitude and the momentum over consecutive steps.

    Parameters
    ----------
    state0 : ndarray of shape (7,)
        Attitude (scalar first) and inertial momentum [N m s] at the first step's start.
    inv_locked : ndarray of shape (n_steps, s, 3, 3)
        The inverse locked inertia at each step's stage times [1/(kg m^2)].
    offset : ndarray of shape (n_steps, s, 3)
        ``A^-1 b`` there: the base rate the joints' own momentum cancels [rad/s].
    torque : ndarray of shape (3,)
        Constant external torque in inertial axes [N m] (zeros: with ``viscous`` 0, a constant momentum).
    viscous : float
        Viscous friction of the base [N m s/rad].
    coulomb : float
        Coulomb friction of the base [N m].
    widths : ndarray of shape (n_steps,)
        Step widths [s].
    a, b : ndarray
        The tableau (:func:`gauss_tableau`).
    out : ndarray of shape (n_steps + 1, 7)
        Receives the state at the start and after every step.

    Returns
    -------
    int
        -1, or the first step whose stage equations did not converge in :data:`ITERATIONS`.
    """
    s = b.shape[0]
    k = np.zeros((s, 7))
    new = np.zeros(7)
    stage = np.zeros(7)
    for c in range(7):
        out[0, c] = state0[c]
    for i in range(widths.shape[0]):
        dt = widths[i]
        for j in range(s):  # start: the rate at the step's start state, at each stage time
            _stage_rate(out[i], inv_locked[i, j], offset[i, j], torque, viscous, coulomb, new)
            for c in range(7):
                k[j, c] = new[c]
        change, last, converged = np.inf, np.inf, False
        for _ in range(ITERATIONS):
            change = 0.0
            for j in range(s):  # Gauss-Seidel sweep over the stages
                for c in range(7):
                    acc = 0.0
                    for m in range(s):
                        acc += a[j, m] * k[m, c]
                    stage[c] = out[i, c] + dt * acc
                _stage_rate(stage, inv_locked[i, j], offset[i, j], torque, viscous, coulomb, new)
                for c in range(4):  # the attitude's stages; the momentum's follow them (linear in the rate)
                    change = max(change, abs(new[c] - k[j, c]) * dt)
                for c in range(7):
                    k[j, c] = new[c]
            # converged to round-off, or no longer shrinking at a level round-off explains
            if change <= 2.2e-16 or (change >= 0.5 * last and change <= 1e-14):
                converged = True
                break
            last = change
        if not converged:
            return i
        for c in range(7):
            acc = 0.0
            for j in range(s):
                acc += b[j] * k[j, c]
            out[i + 1, c] = out[i, c] + dt * acc
    return -1
