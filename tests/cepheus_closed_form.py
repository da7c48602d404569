"""Closed-form momentum regressor of the planar Cepheus emulator (docs/theory/cepheus.md).

A test helper, independent of the package's own regressor: the columns Y1..Y8 and the
parameters pi are typed in from the reconstructed paper Appendix B, with the Table 1 values.
The base rate w0 comes from momentum conservation; because Y is affine in w0,
``Y = Y_a(q, qd) + w0 Y_b(q)``, it is ``w0 = (h - Y_a pi) / (Y_b pi)``.

References
----------
The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md):
 Eqs. 2 and 12 and Appendix B (reconstructed in docs/theory/cepheus.md).
"""

from __future__ import annotations

import numpy as np

__all__ = ["H", "TABLE1", "cepheus_pi", "base_rate", "regressor_terms", "cepheus_regressor"]

H = 0.4934
"""Angular momentum of the paper's experiment [N m s]."""

TABLE1 = dict(
    m0=9.951, I0=0.1214, r0x=0.17, r0y=0.09,
    m1=0.083, I1=3.46e-4, l1=0.119, r1=0.062,
    m2=0.187, I2=7.17e-4, l2=0.146, r2=0.084,
)  # fmt: skip
"""Paper Table 1 [kg, kg m^2, m]."""


def cepheus_pi(p=TABLE1):
    """Minimal parameters pi1..pi8 of docs/theory/cepheus.md; shape (8,), SI units."""
    m0, m1, m2 = p["m0"], p["m1"], p["m2"]
    l1, r1, l2 = p["l1"], p["r1"], p["l2"]
    r0x, r0y = p["r0x"], p["r0y"]
    M, L1 = m0 + m1 + m2, l1 + r1
    return np.array([
        m0 * (m1 * l1 + m2 * L1) * r0x / M,
        m0 * m2 * l2 * r0x / M,
        m0 * (m1 * l1 + m2 * L1) * r0y / M,
        m0 * m2 * l2 * r0y / M,
        p["I0"] + m0 * (m1 + m2) * (r0x**2 + r0y**2) / M,
        m2 * l2 * (m0 * L1 + m1 * r1) / M,
        p["I1"] + (m0 * m1 * l1**2 + m0 * m2 * L1**2 + m1 * m2 * r1**2) / M,
        p["I2"] + (m0 + m1) * m2 * l2**2 / M,
    ])  # fmt: skip


PI = cepheus_pi()


def regressor_terms(q, qd):
    """Split ``Y = Y_a + w0 Y_b``.

    Parameters
    ----------
    q, qd : ndarray of shape (..., 2)
        Joint angles [rad] and rates [rad/s].

    Returns
    -------
    Y_a, Y_b : ndarray of shape (..., 8)
    """
    q, qd = np.asarray(q, dtype=float), np.asarray(qd, dtype=float)
    q1, q2 = q[..., 0], q[..., 1]
    u1, u12 = qd[..., 0], qd[..., 0] + qd[..., 1]
    c1, s1, c2 = np.cos(q1), np.sin(q1), np.cos(q2)
    c12, s12 = np.cos(q1 + q2), np.sin(q1 + q2)
    zero, one = np.zeros_like(q1), np.ones_like(q1)
    Y_a = np.stack([c1 * u1, c12 * u12, s1 * u1, s12 * u12, zero, c2 * (u1 + u12), u1, u12], -1)
    Y_b = np.stack([2 * c1, 2 * c12, 2 * s1, 2 * s12, one, 2 * c2, one, one], -1)
    return Y_a, Y_b


def base_rate(q, qd, *, h=H, pi=PI):
    """Base angular rate w0 [rad/s], shape ``q.shape[:-1]``, from ``h = Y(q, qd, w0) pi``."""
    Y_a, Y_b = regressor_terms(q, qd)
    return (h - Y_a @ pi) / (Y_b @ pi)


def cepheus_regressor(q, qd, *, h=H, pi=PI):
    """Stacked planar regressor with w0 from momentum conservation.

    Parameters
    ----------
    q, qd : ndarray of shape (..., n_samples, 2)
        Joint angles [rad] and rates [rad/s].

    Returns
    -------
    ndarray of shape (..., n_samples, 8)
        One row per sample (planar: m = 1), columns Y1..Y8.
    """
    Y_a, Y_b = regressor_terms(q, qd)
    w0 = (h - Y_a @ pi) / (Y_b @ pi)
    return Y_a + w0[..., None] * Y_b
