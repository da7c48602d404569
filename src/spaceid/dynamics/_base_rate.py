"""The base angular velocity that momentum conservation implies for a joint motion.

The minimal regressor is linear in the base rate ``w0``, so for given joint angles and rates
the momentum equations are a small linear system in ``w0`` (the locked inertia). Used by the
simulation, by instrumental variables and by the excitation design.
"""

from __future__ import annotations

import functools

import numpy as np

from ._regressor import Parameterization

__all__ = ["base_rate", "excitation_regressor", "rate_pieces"]


def rate_pieces(param: Parameterization, q, qd, evaluate):
    """``evaluate(q, qd, w0)`` split by linearity in the base rate ``w0``.

    Parameters
    ----------
    param : Parameterization
    q, qd : array_like of shape (..., n_joints)
        Joint positions [rad or m] and rates [rad/s or m/s].
    evaluate : callable
        ``evaluate(q, qd, w0)``, linear in ``w0 (..., 3)``: the regressor
        (``param.regressor``), or the momentum of some ``pi``
        (``functools.partial(param.momentum, pi=pi)``).

    Returns
    -------
    free : ndarray
        ``evaluate`` at zero base rate (the joints' own contribution).
    unit : list of ndarray
        ``evaluate`` per unit base rate about each axis in ``axes``, joint rates zero (for the
        momentum: the columns of the locked inertia).
    axes : list of int
        The base-rate axes: ``[2]`` for planar systems, ``[0, 1, 2]`` otherwise.
    """
    q, qd = np.asarray(q, float), np.asarray(qd, float)
    lead = q.shape[:-1]
    free = evaluate(q, qd, np.zeros(lead + (3,)))
    axes = [2] if param.model.planar else [0, 1, 2]
    unit = [evaluate(q, np.zeros_like(qd), np.broadcast_to(np.eye(3)[i], lead + (3,))) for i in axes]
    return free, unit, axes


def _solve_rate(param, free, unit, axes, h_base):
    """Base rate from the momentum pieces ``free (..., rows)``, ``unit[i] (..., rows)`` (the
    momentum per unit base rate: the locked inertia), so that the momentum is ``h_base``;
    shape ``(..., 3)``."""
    h_base = np.asarray(h_base, float)
    rows = slice(2, 3) if param.model.planar else slice(None)
    rhs = np.broadcast_to(h_base, free.shape[:-1] + (3,))[..., rows] - free
    w = np.zeros(free.shape[:-1] + (3,))
    w[..., axes] = np.linalg.solve(np.stack(unit, -1), rhs[..., None])[..., 0]
    return w


def base_rate(param: Parameterization, pi, q, qd, h_base) -> np.ndarray:
    """Base angular velocity that gives momentum ``h_base``.

    Parameters
    ----------
    param : Parameterization
    pi : array_like of shape (k,)
    q, qd : array_like of shape (..., n_joints)
    h_base : array_like of shape (..., 3)
        Angular momentum in base axes [N m s].

    Returns
    -------
    ndarray of shape (..., 3)
        Base angular velocity in base axes [rad/s] (x, y zero for planar systems).
    """
    return _solve_rate(param, *rate_pieces(param, q, qd, functools.partial(param.momentum, pi=pi)), h_base)


class excitation_regressor:  # noqa: N801 - used like a function; a class so it pickles
    """Stacked regressor of a joint motion, the base rate from momentum conservation.

    ``excitation_regressor(param, pi, momentum)(q, qd)`` with ``q, qd`` of shape
    ``(..., n_samples, n_joints)`` returns ``(..., n_samples * rows, k)``: what the excitation
    design conditions. The momentum is taken in base axes at every sample, exact for planar
    systems (a yaw does not change h_z) and the design-time approximation for spatial ones.
    """

    def __init__(self, param: Parameterization, pi, momentum):
        self.param, self.pi, self.momentum = param, np.asarray(pi, float), np.asarray(momentum, float)

    def __call__(self, q, qd):
        y = self.with_rate(q, qd)[0]
        return y.reshape(y.shape[:-3] + (-1, y.shape[-1]))

    def with_rate(self, q, qd):
        """Per-sample regressor ``(..., n_samples, rows, k)`` and the base rate it holds,
        ``w0 (..., n_samples, 3)`` in base axes [rad/s] (for the noise-aware design, which
        needs the signals the equations are built from)."""
        free, unit, axes = rate_pieces(self.param, q, qd, self.param.regressor)
        w0 = _solve_rate(self.param, free @ self.pi, [u @ self.pi for u in unit], axes, self.momentum)
        return free + sum(w0[..., i, None, None] * u for i, u in zip(axes, unit)), w0
